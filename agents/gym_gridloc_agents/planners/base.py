"""The planners' common policy: a cost per action at the exact belief, the cheapest played (ties
share the probability)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from gym_gridloc.core.model import GridModel
from gym_gridloc.referee import LOCALISE_THRESHOLD
from gym_gridloc_agents.base import Policy
from gym_gridloc_agents.planners.ops import BeliefOps


class PlannerPolicy(Policy):
    """A planner on the exact belief: ``reset(seed, model)``, ``act(observation, belief)``; the
    time spent deciding is kept (``seconds``, ``decisions``)."""

    name = "planner"

    def __init__(self, model: GridModel, *, threshold: float = LOCALISE_THRESHOLD, seed: int | None = None, pose: bool = False,
                 **_: Any) -> None:
        super().__init__(model, seed=seed)
        self.threshold = float(threshold)
        self.pose = bool(pose)  # stop where the referee does: on the pose (DepthMaze) or the position
        self.ops = BeliefOps(model, self.threshold, pose=self.pose)
        self.decisions = 0
        self.seconds = 0.0

    def set_model(self, model: GridModel) -> None:
        super().set_model(model)
        self.ops = BeliefOps(model, self.threshold, pose=self.pose)

    def values(self, b: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """Each action's cost (lower is better) at the normalised belief ``b``."""
        raise NotImplementedError

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self.choose(self.probabilities(observation, belief))

    def probabilities(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        return self.probabilities_and_values(observation, belief)[0]

    def probabilities_and_values(self, observation: Any, belief: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The action distribution (even over the tied best actions) and the actions' costs
        (:meth:`values`) it was chosen from: a warm start imitates either."""
        t = time.perf_counter()
        q = np.asarray(self.values(self.ops.full(belief)), dtype=np.float64)
        ties = self.best(q)
        self.seconds += time.perf_counter() - t
        self.decisions += 1
        out = np.zeros(self.n_actions)
        out[ties] = 1.0 / len(ties)
        return out, q
