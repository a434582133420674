"""The planners' common policy: a cost per action at the exact belief, the cheapest played (ties
share the probability)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from gym_gridloc.core.model import GridModel
from gym_gridloc.referee import LOCALISE_THRESHOLD
from gym_gridloc_agents.base import Policy
from gym_gridloc_agents.planners.leaves import load_leaf
from gym_gridloc_agents.planners.ops import BeliefOps


class PlannerPolicy(Policy):
    """A planner on the exact belief: ``reset(seed, model)``, ``act(observation, belief)``; the
    time spent deciding is kept (``seconds``, ``decisions``)."""

    name = "planner"
    #: Whether the planner values beliefs beyond its horizon with a leaf (``leaf=``).
    takes_leaf = False

    def __init__(self, model: GridModel, *, threshold: float = LOCALISE_THRESHOLD, seed: int | None = None,
                 pose: bool = False) -> None:
        super().__init__(model, seed=seed)
        self.threshold = float(threshold)
        self.pose = bool(pose)  # stop where the referee does: on the pose (DepthMaze) or the position
        self.ops = BeliefOps(model, self.threshold, pose=self.pose)
        self.decisions = 0
        self.seconds = 0.0

    @classmethod
    def build(cls, model: GridModel, context, **options: Any) -> "PlannerPolicy":
        """As the policy table builds a planner: the seed and the referee's pose from ``context``,
        the threshold the environment's unless given; a ``leaf`` (where the planner takes one)
        defaults to ``"shipped"``, the entropy leaf fitted for the environment if one ships."""
        if options.get("threshold") is None:
            options["threshold"] = context.threshold
        if cls.takes_leaf:
            options["leaf"] = load_leaf(options.get("leaf", "shipped"), context.env_id)
        return cls(model, seed=context.seed, pose=context.pose, **options)

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


def keywords(cls: type) -> set[str]:
    """The keyword arguments the ``__init__`` methods of ``cls`` and its bases name (``model`` left out)."""
    import inspect

    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" in vars(klass) and klass is not object:
            params = inspect.signature(vars(klass)["__init__"]).parameters.values()
            names |= {p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}
    return names - {"self", "model"}
