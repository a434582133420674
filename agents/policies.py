"""Policies with one interface: ``act(observation, belief) -> action``.

``observation`` is the raw sensor observation the environment emitted; ``belief`` is the exact
forward-filter belief over the hidden state, an ``(L, H, W)`` float64 array (``L = 1`` for
position-only models; an ``(H, W)`` position belief is accepted when ``L = 1``).  In the benchmark
every policy runs behind :class:`gym_gridloc.HMMBeliefWrapper`, so they all see the same
information; each uses what it needs:

- ``random``: uniform actions (the random walk), ignores both;
- ``greedy``: the action minimising the expected Shannon entropy of the position belief after the
  next move and reading, the expectation taken exactly over readings;
- ``greedy2``: a two-step expectimax over (action, reading, action, reading);
- ``ppo``: a stable-baselines3 PPO model on the flattened belief observation;
- ``recurrent``: an sb3-contrib RecurrentPPO model on the raw observation only (LSTM memory).

Call ``reset(seed=...)`` at the start of every episode: it seeds the policy's own random
generator (random actions, tie-breaking) and clears any memory.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.model import GridModel

#: Names accepted by :func:`make_policy`.
POLICY_NAMES = ("random", "greedy", "greedy2", "ppo", "recurrent")

#: Where the shipped models live: ``<env_id>.zip`` (PPO) and ``<env_id>-recurrent.zip``.
POLICY_DIR = Path(__file__).resolve().parent / "policies"

_TIE_TOL = 1e-9


class Policy:
    """Base class.  ``act`` returns an ``int`` action in ``0..n_actions-1``."""

    name = "policy"

    def __init__(self, model: GridModel, *, seed: int | None = None) -> None:
        if not isinstance(model, GridModel):
            raise TypeError(f"a policy needs the environment's GridModel, got {type(model).__name__}")
        self.model = model
        self.n_actions = model.n_actions
        self.rng = np.random.default_rng(seed)

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: reseed the policy's generator, forget any memory."""
        self.rng = np.random.default_rng(seed)

    def act(self, observation: Any, belief: np.ndarray) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def _full_belief(self, belief: np.ndarray) -> np.ndarray:
        b = np.asarray(belief, dtype=np.float64)
        shape = self.model.belief_shape
        if b.shape == shape:
            return b
        if b.shape == shape[1:] and shape[0] == 1:
            return b[None]
        raise ValueError(
            f"belief must be the hidden-state belief of shape {shape}"
            + (f" or the position belief {shape[1:]}" if shape[0] == 1 else "")
            + f", got shape {b.shape} (use HMMBeliefWrapper(..., full_state=True) or wrapper.filter.full_belief)"
        )

    def _break_ties(self, values: np.ndarray) -> int:
        best = values.min()
        candidates = np.flatnonzero(values <= best + _TIE_TOL * max(1.0, abs(best)))
        if len(candidates) == 1:
            return int(candidates[0])
        return int(self.rng.choice(candidates))


class RandomPolicy(Policy):
    """Uniform random actions from the policy's own seeded generator."""

    name = "random"

    def act(self, observation: Any, belief: np.ndarray | None = None) -> int:
        return int(self.rng.integers(self.n_actions))


# -- exact expected entropy -----------------------------------------------------------------------
def _xlogx(x: np.ndarray) -> np.ndarray:
    """``x * log2(x)`` elementwise with ``0 log 0 = 0`` (x >= 0)."""
    return x * np.log2(np.where(x > 0.0, x, 1.0))


class _Lookahead:
    """The model as matrices over free states, and the exact expected entropy.

    ``T[a]`` is the sparse transition of action ``a`` (``model.transition_matrix``, kidnapping
    included), ``TP[a] = T[a] @ P`` the same followed by the projection of hidden states onto
    positions.  For an unnormalised predicted position mass ``c(x)`` and the sensor ``P(z | x)``
    (the likelihoods stacked once, ``Lz``), the expected posterior entropy times the mass is
    ``E_z[H(X | z)] * m = sum_x c(x) h(x) - sum_x c log c + sum_z q(z) log q(z)`` with
    ``q = Lz @ c`` and ``h(x)`` the entropy of the reading at ``x`` (in bits): the
    ``(readings x cells)`` joint is never formed.
    """

    def __init__(self, model: GridModel) -> None:
        from scipy import sparse

        self.model = model
        free = model.grid.free
        self.free = free
        n_free = model.grid.n_free
        if model.sensor.n_readings * model.n_states > 20_000_000:
            raise ValueError(
                f"greedy lookahead keeps a (readings x states) table: {model.sensor.n_readings} x {model.n_states} "
                f"is too large for {model!r}; use greedy policies on maps with fewer cells or readings"
            )
        lz = np.stack([model.likelihood(z)[free] for z in range(model.sensor.n_readings)])  # (Z, F)
        self.lz = lz
        self.lz_t = np.ascontiguousarray(lz.T)
        self.lz_states = np.tile(lz, (1, model.n_layers))  # (Z, S): the sensor sees the position only
        self.sensor_entropy = -_xlogx(lz).sum(axis=0)  # (F,) bits
        proj = sparse.csr_matrix(
            (np.ones(model.n_states), (np.arange(model.n_states), np.tile(np.arange(n_free), model.n_layers))),
            shape=(model.n_states, n_free),
        )
        self.T = [model.transition_matrix(a).tocsr() for a in range(model.n_actions)]
        self.TP = [(t @ proj).tocsr() for t in self.T]

    def weighted_entropy(self, c: np.ndarray) -> np.ndarray:
        """``m * E_z[H(position | z)]`` for unnormalised position masses ``c`` of shape (..., F)."""
        q = c @ self.lz_t  # (..., Z)
        return c @ self.sensor_entropy - _xlogx(c).sum(axis=-1) + _xlogx(q).sum(axis=-1)

    def one_step(self, b: np.ndarray) -> np.ndarray:
        """Expected position entropy after each action, for a hidden-state vector ``b`` (S,)."""
        c = np.stack([np.asarray(tp.T @ b) for tp in self.TP])  # (A, F)
        return self.weighted_entropy(c)

    def two_step(self, b: np.ndarray) -> np.ndarray:
        """``sum_{z1} min_{a2} W(a1, z1, a2)`` for each first action ``a1`` (see Greedy2Policy)."""
        pred1 = np.stack([np.asarray(t.T @ b) for t in self.T])  # (A1, S)
        joint1 = pred1[:, None, :] * self.lz_states[None]  # (A1, Z1, S), mass p(z1 | a1)
        keep = joint1.sum(axis=2).max(axis=0) > 0.0  # readings possible after some action
        joint1 = joint1[:, keep]
        a1, z1, n = joint1.shape
        flat = joint1.reshape(a1 * z1, n)
        c2 = np.stack([np.asarray((tp.T @ flat.T).T) for tp in self.TP], axis=1)  # (A1*Z1, A2, F)
        w = self.weighted_entropy(c2).reshape(a1, z1, -1)
        return w.min(axis=-1).sum(axis=-1)


class GreedyPolicy(Policy):
    """One-step information gain: ``argmin_a E_z[H(position | belief, a, z)]``, exact.

    The prediction ``b' = T_a b`` is taken over the full hidden state (headings included), the
    expectation over every reading the sensor can give.  Ties (within 1e-9) are broken uniformly
    with the policy's seeded generator.
    """

    name = "greedy"

    def __init__(self, model: GridModel, *, seed: int | None = None) -> None:
        super().__init__(model, seed=seed)
        self.look = _Lookahead(model)

    def expected_entropies(self, belief: np.ndarray) -> np.ndarray:
        """Expected position entropy (bits) after each action's move and reading, shape (A,)."""
        b = self.model.to_vector(self._full_belief(belief))
        return self.look.one_step(b / b.sum())

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self._break_ties(self.expected_entropies(belief))


class Greedy2Policy(GreedyPolicy):
    """Two-step expectimax on the expected position entropy.

    ``value(a1) = E_{z1}[ min_{a2} E_{z2}[ H(position | b, a1, z1, a2, z2) ] ]``: the second action
    is chosen after seeing the first reading (closed loop), both expectations are exact.  With the
    unnormalised masses of the module's identity this is ``sum_{z1} min_{a2} W(a1, z1, a2)``, all
    batched in numpy.  Ties are broken as in ``greedy``.
    """

    name = "greedy2"

    def expected_entropies(self, belief: np.ndarray) -> np.ndarray:
        b = self.model.to_vector(self._full_belief(belief))
        return self.look.two_step(b / b.sum())


class PPOPolicy(Policy):
    """A stable-baselines3 PPO model trained on ``HMMBeliefWrapper(env, flatten=True)``.

    ``path`` defaults to the shipped model for ``env_id`` (``agents/policies/<env_id>.zip``).
    Model zip files are pickles: load only files from a trusted source.
    """

    name = "ppo"
    algo = "ppo"

    def __init__(
        self,
        model: GridModel,
        *,
        env_id: str | None = None,
        observation_space: spaces.Space | None = None,
        path: str | Path | None = None,
        seed: int | None = None,
        deterministic: bool = True,
    ) -> None:
        super().__init__(model, seed=seed)
        from agents.train import load_model  # heavy imports (torch) only when needed

        if path is None:
            if env_id is None:
                raise ValueError(f"policy {self.name!r} needs env_id=... (for the shipped model) or path=...")
            path = default_model_path(env_id, self.algo)
        self.path = Path(path)
        self.sensor_space = model.sensor.observation_space
        expected = self.expected_space(model) if observation_space is None else observation_space
        self.sb3, self.meta = load_model(self.path, algo=self.algo, env_id=env_id, observation_space=expected)
        self.deterministic = bool(deterministic)

    @staticmethod
    def expected_space(model: GridModel) -> spaces.Space:
        from gym_gridloc.wrappers import _encoded_size

        n = _encoded_size(model.sensor.observation_space) + int(np.prod(model.shape))
        return spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)

    def encode(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        """The flat observation ``HMMBeliefWrapper(flatten=True)`` would give."""
        from gym_gridloc.wrappers import _encode

        b = self._full_belief(belief)
        pos = (b[0] if b.shape[0] == 1 else b.sum(axis=0)).astype(np.float32)
        np.clip(pos, 0.0, 1.0, out=pos)
        return np.concatenate([_encode(self.sensor_space, observation), pos.ravel()])

    def act(self, observation: Any, belief: np.ndarray) -> int:
        action, _ = self.sb3.predict(self.encode(observation, belief), deterministic=self.deterministic)
        return int(action)


class RecurrentPolicy(PPOPolicy):
    """An sb3-contrib RecurrentPPO model on the raw observations (no belief), with LSTM memory.

    ``path`` defaults to ``agents/policies/<env_id>-recurrent.zip``.  The belief argument of
    ``act`` is ignored.
    """

    name = "recurrent"
    algo = "recurrent_ppo"

    def __init__(self, model: GridModel, **kwargs: Any) -> None:
        super().__init__(model, **kwargs)
        self._state = None
        self._start = np.ones((1,), dtype=bool)

    @staticmethod
    def expected_space(model: GridModel) -> spaces.Space:
        return model.sensor.observation_space

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._state = None
        self._start = np.ones((1,), dtype=bool)

    def act(self, observation: Any, belief: np.ndarray | None = None) -> int:
        obs = np.asarray(observation)
        action, self._state = self.sb3.predict(
            obs, state=self._state, episode_start=self._start, deterministic=self.deterministic
        )
        self._start = np.zeros((1,), dtype=bool)
        return int(np.asarray(action).reshape(-1)[0])


def default_model_path(env_id: str, algo: str = "ppo") -> Path:
    """The shipped model file for ``env_id`` and ``algo`` (``ppo`` or ``recurrent_ppo``)."""
    suffix = "" if algo == "ppo" else "-recurrent"
    return POLICY_DIR / f"{env_id}{suffix}.zip"


def make_policy(
    name: str,
    model: GridModel,
    *,
    env_id: str | None = None,
    seed: int | None = None,
    path: str | Path | None = None,
) -> Policy:
    """A policy by name (one of :data:`POLICY_NAMES`) for an environment's model.

    ``path`` gives the model file for ``ppo`` / ``recurrent`` (default: the shipped one for
    ``env_id``).
    """
    if name == "random":
        return RandomPolicy(model, seed=seed)
    if name == "greedy":
        return GreedyPolicy(model, seed=seed)
    if name == "greedy2":
        return Greedy2Policy(model, seed=seed)
    if name == "ppo":
        return PPOPolicy(model, env_id=env_id, path=path, seed=seed)
    if name == "recurrent":
        return RecurrentPolicy(model, env_id=env_id, path=path, seed=seed)
    raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICY_NAMES)}")


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The JSON written next to a model (``<model>.json``), or an empty dict if there is none."""
    meta = Path(path).with_suffix(".json")
    if not meta.exists():
        return {}
    with open(meta, encoding="utf-8") as fh:
        return json.load(fh)
