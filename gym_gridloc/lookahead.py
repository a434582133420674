"""The belief MDP of one model (:class:`Lookahead`): its prediction, its Bayes update and the exact
one- and two-step expected entropies, what the entropy-greedy policies, the planners (through
their view, ``gym_gridloc_agents.planners.ops.BeliefOps``) and the wrapper's ``lookahead``
observation (:func:`lookahead_features`) compute.

Every prediction goes through :func:`gym_gridloc.engine.predict` (batched, kidnapping included,
never a dense S x S matrix); every Bayes update is :meth:`Lookahead.update` (the prediction times
the reading's likelihood, normalised); the expected entropies take their expectations over
readings through the sensor's :meth:`~gym_gridloc.Sensor.reading_probabilities` and
:meth:`~gym_gridloc.Sensor.reading_entropy`, so no (readings x states) posterior table is built.

The identity used: for an unnormalised predicted mass ``c`` over the target variable X (positions,
or full states where the referee tests poses) and a sensor ``P(z | x)``, the expected posterior
entropy times the mass is ``m * E_z[H(X | z)] = sum_x c(x) h(x) - sum_x c log c + sum_z q log q``
with ``q(z) = sum_x P(z | x) c(x)`` and ``h(x)`` the entropy of the reading at x (bits).  It holds
for positions when the sensor sees the position only (the headings of a position are summed
first), and for full states always.
"""

from __future__ import annotations

import functools
import weakref

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.sensors import xlogx

#: A lookahead refuses to build more than this many predicted beliefs x cells in one call.
MAX_WORK = 50_000_000


class Lookahead:
    """The belief MDP of one model: prediction, Bayes update, exact one- and two-step expectations
    (see the module docstring).

    ``pose``: the target variable is the full hidden state (the referee of DepthMaze), else the
    position.  ``weak``: hold the model by a weak reference (for a cache keyed by the model, which a
    strong one would keep alive for good).
    """

    def __init__(self, model: GridModel, *, pose: bool = False, weak: bool = False) -> None:
        model = engine.checked_model(model, "a lookahead needs the environment's GridModel")
        self._model, self._model_ref = (None, weakref.ref(model)) if weak else (model, None)
        self.pose = bool(pose or model.sensor.layered)
        self.n_actions = model.n_actions
        self.h = model.sensor.reading_entropy()
        if self.pose and self.h.ndim == 2:
            self.h = np.broadcast_to(self.h, model.belief_shape)

    @property
    def model(self) -> GridModel:
        return self._model if self._model_ref is None else self._model_ref()

    def _check_work(self, n_beliefs: int, what: str) -> None:
        work = n_beliefs * self.model.n_layers * self.model.shape[0] * self.model.shape[1]
        if work > MAX_WORK:
            raise ValueError(
                f"{what} would predict {n_beliefs} beliefs of {self.model.n_states} states on {self.model!r} "
                f"({work:.3g} cells, limit {MAX_WORK:.3g}); use a one-step policy (greedy) or a smaller map"
            )

    # -- the belief MDP: prediction, the readings' likelihoods, the Bayes update -------------------
    def expand(self, beliefs: np.ndarray) -> np.ndarray:
        """Every action applied to each of N beliefs ``(N, L, H, W)``, node-major: ``(N * A, L, H, W)``
        (row ``i * A + a`` is belief ``i`` after action ``a``; mass kept, kidnapping mixed in)."""
        n, A = beliefs.shape[0], self.n_actions
        return engine.predict(self.model, np.repeat(beliefs, A, axis=0), np.tile(np.arange(A), n))

    def predict_all(self, beliefs: np.ndarray) -> np.ndarray:
        """:meth:`expand` as ``(N, A, L, H, W)``, refused above ``MAX_WORK`` cells."""
        n, A = beliefs.shape[0], self.n_actions
        self._check_work(n * A, "the lookahead")
        return self.expand(beliefs).reshape(n, A, *self.model.belief_shape)

    @functools.cached_property
    def likelihood_table(self) -> np.ndarray:
        """``P(z | state)`` of every reading, ``(Z, L, H, W)`` (a position sensor's repeated over
        the layers), built on first use; refused above ``MAX_WORK`` entries."""
        model = self.model
        Z, (L, H, W) = int(model.sensor.n_readings), model.belief_shape
        if Z * L * H * W > MAX_WORK:
            raise ValueError(f"{model!r}: a (readings x cells) likelihood table of {Z} x {L * H * W} is too large")
        table = np.empty((Z, L, H, W))
        table[:] = engine.likelihoods(model, np.arange(Z)).reshape(Z, -1, H, W)
        return table

    def likelihoods(self, readings) -> np.ndarray:
        """``P(z | state)`` of ``readings`` (an index or an array of them), ``(*readings.shape, L, H, W)``
        from :attr:`likelihood_table`; where that table would be too large, computed for these
        readings alone (a position sensor's with one layer, which broadcasts over the layers)."""
        L, H, W = self.model.belief_shape
        if "likelihood_table" in self.__dict__ or self.model.sensor.n_readings * L * H * W <= MAX_WORK:
            return self.likelihood_table[readings]
        z = np.asarray(readings, dtype=np.int64)
        lik = engine.likelihoods(self.model, z.reshape(-1))
        return lik.reshape(*z.shape, L if lik.shape[1] == L * H * W else 1, H, W)

    @functools.cached_property
    def _likelihood_columns(self) -> np.ndarray:
        table = self.likelihood_table
        return np.ascontiguousarray(table.reshape(table.shape[0], -1).T)  # (L*H*W, Z)

    def reading_masses(self, predicted: np.ndarray) -> np.ndarray:
        """``(M, Z)``: each reading's probability under M predicted masses ``(M, L, H, W)`` (times
        their mass), through :attr:`likelihood_table`, the table :meth:`update` weighs with."""
        return predicted.reshape(predicted.shape[0], -1) @ self._likelihood_columns

    def joint(self, predicted: np.ndarray, readings) -> np.ndarray:
        """The Bayes update's numerator: predicted masses ``(..., L, H, W)`` times the likelihoods
        of ``readings`` (an index, or indices broadcasting against ``predicted``'s leading axes)."""
        return predicted * self.likelihoods(readings)

    def update(self, predicted: np.ndarray, readings, mass=None) -> np.ndarray:
        """The Bayes update: :meth:`joint` normalised, by ``mass`` (the readings' probabilities
        under the predictions, :meth:`reading_masses`, where the caller has them: ``(M,)``) or by
        its own sum (one belief ``(L, H, W)`` and one reading, or ``(M, L, H, W)`` and ``(M,)``)."""
        post = self.joint(predicted, readings)
        if mass is not None:
            return post / np.reshape(mass, (-1, 1, 1, 1))
        if post.ndim == 3:
            return post / post.sum()
        return post / post.reshape(post.shape[0], -1).sum(axis=1)[:, None, None, None]

    # -- expectations over readings ----------------------------------------------------------------
    def target(self, masses: np.ndarray) -> np.ndarray:
        """Masses over hidden states ``(..., L, H, W)`` as masses over the target variable."""
        return masses if self.pose else masses.sum(axis=-3)

    def reading_probabilities(self, masses: np.ndarray) -> np.ndarray:
        """``(M, Z)`` reading probabilities of M masses over hidden states ``(M, L, H, W)``."""
        sensor = self.model.sensor
        return sensor.reading_probabilities(masses if sensor.layered else masses.sum(axis=1))

    def weighted_entropy(self, masses: np.ndarray) -> np.ndarray:
        """``m * E_z[H(X | z)]`` for unnormalised masses over hidden states ``(..., L, H, W)``."""
        full = masses.reshape(-1, *self.model.belief_shape)
        q = self.reading_probabilities(full)
        flat = self.target(full).reshape(full.shape[0], -1)
        w = flat @ self.h.reshape(-1) - xlogx(flat).sum(axis=1) + xlogx(q).sum(axis=1)
        return w.reshape(masses.shape[:-3])

    def one_step(self, belief: np.ndarray) -> np.ndarray:
        """Expected target entropy (bits) after each action's move and reading, ``(A,)``."""
        b = belief / belief.sum()
        return self.weighted_entropy(self.predict_all(b[None])[0])

    def readings_after(self, predicted: np.ndarray, *, prune: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The posterior masses after each possible reading of M predicted beliefs
        ``(M, L, H, W)``: ``(readings (K,), masses (M, K, L, H, W))`` for the K readings some
        belief can give (probability above ``prune`` for one of them)."""
        keep = np.flatnonzero(self.reading_probabilities(predicted).max(axis=0) > prune)
        self._check_work(predicted.shape[0] * keep.size, "the lookahead")
        return keep, self.joint(predicted[:, None], keep[None])

    def two_step(self, belief: np.ndarray) -> np.ndarray:
        """``sum_{z1} min_{a2} m * E_z2[H]`` for each first action (the two-step expectimax)."""
        b = belief / belief.sum()
        pred1 = self.predict_all(b[None])[0]  # (A1, L, H, W)
        _, joint = self.readings_after(pred1)  # (A1, K, L, H, W), mass p(z1 | a1)
        a1, k = joint.shape[:2]
        w = self.weighted_entropy(self.predict_all(joint.reshape(a1 * k, *joint.shape[2:])))  # (A1*K, A2)
        return w.reshape(a1, k, -1).min(axis=-1).sum(axis=-1)


def target_size(model: GridModel, pose: bool) -> int:
    """How many values the lookahead's target variable has on ``model``'s grid (an upper bound,
    the same for every map of that size): ``L * H * W`` poses, or ``H * W`` positions."""
    h, w = model.shape
    return h * w * (model.n_layers if pose or model.sensor.layered else 1)


#: The lookaheads of :func:`lookahead_features`, per model and target (let go with the model).
_LOOKAHEADS: "weakref.WeakKeyDictionary[GridModel, dict[bool, Lookahead]]" = weakref.WeakKeyDictionary()


def lookahead_features(model: GridModel, belief: np.ndarray, depth: int, *, pose: bool = False) -> np.ndarray:
    """The expected entropies of the target after each first action, as a fraction of the largest
    entropy the grid allows (``log2(target_size)`` bits): ``(depth, A)`` float32 in [0, 1].  Row 0
    is the one-step expectation (what ``greedy`` minimises), row 1 (``depth=2``) the two-step
    expectimax over the second action (what ``greedy2`` minimises).  ``belief`` is over the hidden
    states ``(L, H, W)``; ``pose``: the target is the full hidden state.  The :class:`Lookahead`
    of each model is built once and kept while the model lives."""
    if depth not in (1, 2):
        raise ValueError(f"lookahead depth must be 1 or 2, got {depth!r}")
    looks = _LOOKAHEADS.setdefault(model, {})
    look = looks.get(bool(pose))
    if look is None:
        look = looks[bool(pose)] = Lookahead(model, pose=pose, weak=True)
    b = np.asarray(belief, dtype=float)
    rows = [look.one_step(b)] + ([look.two_step(b)] if depth == 2 else [])
    out = np.asarray(rows, dtype=float) / np.log2(max(target_size(model, look.pose), 2))
    return np.clip(out, 0.0, 1.0).astype(np.float32)
