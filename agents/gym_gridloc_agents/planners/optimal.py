"""The exact optimal policy of a noiseless model (e.g. ``DepthMaze-v0`` without noise): what the
best possible policy does, found by search over belief sets.

Without noise the belief is uniform over the set B of states consistent with everything seen, and
an episode is localised when B has one state.  ``V(B, r)`` is the largest number of the states
of B that some closed-loop policy isolates within r more actions (so ``V(B, r) / |B|`` is the
best possible probability of being localised within r steps).  It is computed by depth-first
search over (action, reading) with memoised belief sets and a bound that prunes: a state of B
can only be isolated within r steps if no other state of B gives the same readings under every
sequence of r actions, which the partition refinement ``classes[r]`` (states split by their
reading and their successors' classes, r times) tells exactly.  A policy achieving ``V`` is
optimal for the research protocol's accuracy at L; among optimal actions it prefers those that
isolate more states within fewer steps (so it localises soon), then breaks ties at random.

Deterministic models only (every action leads each state to one next state, every state gives
one reading); anything else is refused with a clear error.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.model import GridModel
from gym_gridloc_agents.base import Policy


class NotDeterministic(ValueError):
    """The model has noise: the exact search over belief sets does not apply."""


class BeliefSetSearch:
    """``V(B, r)`` and its optimal actions on one deterministic model (see the module docstring)."""

    def __init__(self, model: GridModel) -> None:
        S = model.n_states
        states = engine.states_of(model, np.arange(S))
        self.next = np.empty((model.n_actions, S), dtype=np.int64)
        for a in range(model.n_actions):
            for s, st in enumerate(states):
                out = model.outcomes(tuple(int(v) for v in st), a)
                if len(out) != 1 or out[0][1] != 1.0:
                    raise NotDeterministic(f"{model!r} is not deterministic: action {a} from state {tuple(st)} has outcomes {out}")
                self.next[a, s] = model.state_index(out[0][0])
        table = np.stack([model.likelihood_vector(z) for z in range(model.sensor.n_readings)])  # (Z, S)
        if not np.all((table == 0) | (table == 1)):
            raise NotDeterministic(f"{model!r} has a noisy sensor: a state gives more than one reading")
        self.reading = table.argmax(axis=0)
        self.model = model
        self.classes = [np.unique(self.reading, return_inverse=True)[1].reshape(-1)]
        self.stable = False
        self.memo: dict[tuple[tuple[int, ...], int], int] = {}

    def _classes(self, r: int) -> np.ndarray:
        """States split by what r more actions can tell apart (refined until it stops changing)."""
        while len(self.classes) <= r and not self.stable:
            last = self.classes[-1]
            keys = np.stack([last, *(last[self.next[a]] for a in range(self.next.shape[0]))], axis=1)
            ids = np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1)
            if ids.max() == last.max():  # as many classes as before: deeper looks tell no more
                self.stable = True
            else:
                self.classes.append(ids)
        return self.classes[min(r, len(self.classes) - 1)]

    def bound(self, B: np.ndarray, r: int) -> int:
        """How many states of B could at best be isolated within r steps."""
        return int(np.count_nonzero(np.bincount(self._classes(r)[B]) == 1))

    def value(self, B: tuple[int, ...], r: int) -> int:
        if len(B) == 1:
            return 1
        if r == 0:
            return 0
        key = (B, r)
        v = self.memo.get(key)
        if v is None:
            arr = np.asarray(B)
            bound, v = self.bound(arr, r), 0
            if bound > 0:
                for a in range(self.next.shape[0]):
                    v = max(v, self.q(arr, r, a))
                    if v >= bound:
                        break
            self.memo[key] = v
        return v

    def q(self, B: np.ndarray, r: int, a: int) -> int:
        """States of B isolated within r steps when the first action is ``a`` (then optimally)."""
        nxt = self.next[a][B]
        z = self.reading[nxt]
        order = np.lexsort((nxt, z))  # by reading, then by state: each reading's successors, sorted
        nxt, z = nxt[order].tolist(), z[order]
        cuts = [0, *(np.flatnonzero(z[1:] != z[:-1]) + 1).tolist(), len(nxt)]
        return sum(self.value(tuple(nxt[i:j]), r - 1) for i, j in zip(cuts[:-1], cuts[1:]))

    def best_actions(self, B: np.ndarray, r: int) -> np.ndarray:
        """The actions optimal within r steps, narrowed by optimality within r-1, r-2, ... steps."""
        ok = np.ones(self.next.shape[0], dtype=bool)
        if len(B) <= 1 or r <= 0:
            return ok
        for rr in range(r, 0, -1):
            q = np.array([self.q(B, rr, a) if ok[a] else -1 for a in range(len(ok))])
            ok = q == q.max()
            if ok.sum() == 1:
                break
        return ok


class OptimalPolicy(Policy):
    """The exact optimal policy of a noiseless model for localising within ``horizon`` steps
    (the environment's ``episode_length`` when it has one).  ``name = "optimal"``."""

    name = "optimal"

    def __init__(self, model: GridModel, *, seed: int | None = None, horizon: int = 30) -> None:
        super().__init__(model, seed=seed)
        self.horizon = int(horizon)
        self.search = BeliefSetSearch(model)
        self.t = 0

    @classmethod
    def build(cls, model: GridModel, context, *, horizon: int | None = None) -> "OptimalPolicy":
        """As the policy table builds it: ``horizon``, else the environment's ``episode_length``, else 30."""
        return cls(model, seed=context.seed, horizon=horizon or (context.env_kwargs or {}).get("episode_length") or 30)

    def set_model(self, model: GridModel) -> None:
        super().set_model(model)
        self.search = BeliefSetSearch(model)

    def reset(self, seed: int | None = None, model: GridModel | None = None) -> None:
        super().reset(seed, model)
        self.t = 0

    def probabilities(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        """Even over the optimal actions of this step (a step: the horizon counts down)."""
        b = self.model.to_vector(self._full_belief(belief))
        ok = self.search.best_actions(np.flatnonzero(b > 0), max(self.horizon - self.t, 1))
        self.t += 1
        return ok / ok.sum()

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self.choose(self.probabilities(observation, belief))
