"""The planners' view of the belief MDP (:class:`BeliefOps`: the core's
:class:`~gym_gridloc.lookahead.Lookahead` with the referee's test, on normalised beliefs); merging
equal beliefs; the beliefs after the first reading."""

from __future__ import annotations

import functools

import numpy as np

from gym_gridloc import engine, referee
from gym_gridloc.core.model import GridModel
from gym_gridloc.lookahead import Lookahead


def predict_batch(model: GridModel, beliefs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``b'_i = T_{a_i}^T b_i`` for ``beliefs`` ``(N, L, H, W)`` and ``actions`` ``(N,)`` (the engine's
    batched prediction; mass kept, kidnapping mixed in)."""
    return engine.predict(model, np.ascontiguousarray(beliefs, dtype=np.float64), np.asarray(actions, dtype=np.int64))


class BeliefOps:
    """What the planners need of a model: the core's belief MDP (:attr:`mdp`, a
    :class:`~gym_gridloc.lookahead.Lookahead`: prediction, the Bayes update, expected entropies)
    and the referee's test at ``threshold`` (on the pose with ``pose``), built once per model."""

    def __init__(self, model, threshold: float = referee.LOCALISE_THRESHOLD, *, pose: bool = False) -> None:
        self.model = model
        self.threshold = float(threshold)
        #: The referee tests poses (the most probable hidden state), not positions (DepthMaze).
        self.pose = bool(pose)
        #: The belief MDP (its expected entropies are of the pose where the referee tests poses).
        self.mdp = Lookahead(model, pose=self.pose)
        self.A = int(model.n_actions)
        self.Z = int(model.sensor.n_readings)
        self.shape = tuple(model.belief_shape)  # (L, H, W)
        self.lik = self.mdp.likelihood_table  # (Z, L, H, W); refused here when too large
        self.free = np.asarray(model.grid.free, dtype=bool)
        self.n_free = int(self.free.sum())

    # -- basic quantities -------------------------------------------------------------------------
    def full(self, belief: np.ndarray) -> np.ndarray:
        b = np.asarray(belief, dtype=np.float64)
        if b.shape == self.shape[1:] and self.shape[0] == 1:
            b = b[None]
        elif b.shape != self.shape:
            raise ValueError(f"belief must have shape {self.shape}, got {b.shape} (use wrapper.filter.full_belief)")
        s = b.sum()
        if not s > 0:
            raise ValueError("belief has no mass")
        return b / s

    @staticmethod
    def position(beliefs: np.ndarray) -> np.ndarray:
        """(N, L, H, W) -> (N, H, W)."""
        return beliefs.sum(axis=1)

    def max_position(self, beliefs: np.ndarray) -> np.ndarray:
        """What the referee tests: the largest position probability, or hidden-state probability
        with ``pose`` (:func:`gym_gridloc.referee.confidences`), ``(N,)``."""
        return referee.confidences(beliefs, pose=self.pose)

    def localised(self, beliefs: np.ndarray, slack: float = 0.0) -> np.ndarray:
        """The referee's test (:func:`gym_gridloc.referee.localised`), ``(N,)`` booleans."""
        return referee.localised(beliefs, self.threshold, pose=self.pose, slack=slack)

    def predict_all(self, beliefs: np.ndarray) -> np.ndarray:
        """Every action for every belief: (N, L, H, W) -> (N * A, L, H, W), node-major
        (:meth:`Lookahead.expand <gym_gridloc.lookahead.Lookahead.expand>`)."""
        return self.mdp.expand(beliefs)

    def reading_probs(self, preds: np.ndarray) -> np.ndarray:
        """P(z) (unnormalised by the predictions' mass) for (M, L, H, W) -> (M, Z)."""
        return self.mdp.reading_masses(preds)

    def update(self, preds: np.ndarray, z, pz=None) -> np.ndarray:
        """The Bayes update of predictions after readings ``z`` (normalised by ``pz``, their
        probabilities, where given): :meth:`Lookahead.update <gym_gridloc.lookahead.Lookahead.update>`."""
        return self.mdp.update(preds, z, pz)

    def posteriors(self, preds: np.ndarray, idx: np.ndarray, z: np.ndarray, pz: np.ndarray) -> np.ndarray:
        """The posteriors of predictions ``preds[idx]`` after readings ``z`` of probabilities ``pz``."""
        return self.mdp.update(preds[idx], z, pz)

    def entropy(self, beliefs: np.ndarray) -> np.ndarray:
        """The position entropy (bits) of N beliefs (:func:`gym_gridloc.referee.entropy`), ``(N,)``."""
        return referee.entropy(self.position(beliefs).reshape(beliefs.shape[0], -1))


def dedupe(beliefs: np.ndarray, decimals: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Unique beliefs and the inverse index.  Two beliefs are merged when their projections on two
    fixed random directions agree after rounding to ``decimals`` (a hash of the rounded belief;
    unequal beliefs colliding on both is vanishingly unlikely, and equal ones always merge unless
    a projection falls on a rounding boundary, which only costs a repeated evaluation)."""
    n = beliefs.shape[0]
    if n <= 1:
        return beliefs, np.zeros(n, dtype=np.int64)
    flat = beliefs.reshape(n, -1)
    proj = _projections(flat.shape[1])
    keys = np.round(flat @ proj, decimals) + 0.0  # (n, 2)
    _, first, inv = np.unique(keys[:, 0] * np.pi + keys[:, 1], return_index=True, return_inverse=True)
    return beliefs[first], inv.reshape(-1)


@functools.cache
def _projections(d: int) -> np.ndarray:
    return np.random.default_rng(12345).uniform(0.5, 1.5, (d, 2))


def initial_beliefs(ops: BeliefOps) -> tuple[np.ndarray, np.ndarray]:
    """The beliefs after the first reading from the uniform prior, and the readings' probabilities."""
    free = np.broadcast_to(ops.free, ops.shape).astype(np.float64)
    prior = free / free.sum()
    pz = ops.reading_probs(prior[None])[0]
    zs = np.flatnonzero(pz > 0)
    return ops.update(prior[None], zs, pz[zs]), pz[zs]
