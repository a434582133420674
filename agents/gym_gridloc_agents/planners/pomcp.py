"""``pomcp``: pomdp_py's POMCP planning every decision on the model, through
:func:`gym_gridloc.interop.to_pomdp_py`.

Each decision starts a new search: the agent's belief is ``n_particles`` hidden states drawn from
the exact belief the policy is given (the information every other policy gets), the planner runs
``num_sims`` simulations (or for ``planning_time`` seconds) on the adapter's planning model, which
ends a simulated episode where the referee would (the exact belief of the simulated history reaches
the threshold) and costs -1 per step until then, with uniformly random rollouts; the action with
the best estimated value is taken.  So POMCP estimates, per action, minus the expected number of
steps until the referee's test holds (cut at ``max_depth``), which is what the benchmark counts.

Every random number (particles, rollouts, simulated moves and readings) comes from the policy's
generator, reseeded by ``reset(seed)``: a fixed seed gives the same actions (unless the search is
stopped by ``planning_time``).  ``decision_times`` keeps the seconds each decision took.

Needs pomdp_py: ``pip install 'gym_gridloc[planning]'``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from gym_gridloc_agents.base import Policy

from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_int
from gym_gridloc.referee import LOCALISE_THRESHOLD

#: The defaults (WindyMaze-v0 and ColourGrid-v0: see the docstring of :class:`PomcpPolicy`).
NUM_SIMS = 300
MAX_DEPTH = 30
EXPLORATION = 10.0
N_PARTICLES = 1000


class PomcpPolicy(Policy):
    """POMCP (pomdp_py) from the exact belief at every decision.

    Parameters
    ----------
    num_sims:
        Simulations per decision (ignored when ``planning_time`` is given).
    planning_time:
        Seconds per decision instead of a number of simulations (then not reproducible).
    max_depth:
        Depth of the search and of the rollouts; a simulated episode not localised by then counts
        ``max_depth`` steps.
    discount:
        The planner's discount (1: the return is minus the number of steps).
    exploration_const:
        UCB1's constant, on the scale of the returns (minus a number of steps, up to ``max_depth``).
    n_particles:
        Hidden states drawn from the exact belief for the root of each search.
    threshold, pose:
        The referee's ``localise_threshold`` and ``referee_pose``.
    """

    name = "pomcp"

    def __init__(self, model: GridModel, *, seed: int | None = None, num_sims: int = NUM_SIMS,
                 planning_time: float | None = None, max_depth: int = MAX_DEPTH, discount: float = 1.0,
                 exploration_const: float = EXPLORATION, n_particles: int = N_PARTICLES,
                 threshold: float = LOCALISE_THRESHOLD, pose: bool = False) -> None:
        from gym_gridloc.interop import import_pomdp_py

        import_pomdp_py()  # the clear ImportError, before anything else
        super().__init__(model, seed=seed)
        positive = {"whole": True, "what": "a positive integer", "error": ValueError}
        if planning_time is None:
            check_int("num_sims", num_sims, **positive)
        if planning_time is not None and not planning_time > 0:
            raise ValueError(f"planning_time must be positive seconds, got {planning_time!r}")
        check_int("max_depth", max_depth, **positive)
        if not exploration_const >= 0:
            raise ValueError(f"exploration_const must be >= 0, got {exploration_const!r}")
        check_int("n_particles", n_particles, **positive)
        self.num_sims = int(num_sims)
        self.planning_time = None if planning_time is None else float(planning_time)
        self.max_depth = int(max_depth)
        self.discount = float(discount)
        self.exploration_const = float(exploration_const)
        self.n_particles = int(n_particles)
        self.threshold = float(threshold)
        self.pose = bool(pose)
        self.decision_times: list[float] = []
        self._build()

    @classmethod
    def build(cls, model: GridModel, context, **options: Any) -> "PomcpPolicy":
        """As the policy table builds it: the seed and the referee's pose from ``context``, the
        threshold the environment's unless given."""
        if options.get("threshold") is None:
            options["threshold"] = context.threshold
        return cls(model, seed=context.seed, pose=context.pose, **options)

    def _build(self) -> None:
        import pomdp_py

        from gym_gridloc.interop import to_pomdp_py

        self.adapter = to_pomdp_py(self.model, threshold=self.threshold, discount=self.discount, pose=self.pose,
                                   seed=self.rng)
        self.planner = pomdp_py.POMCP(
            max_depth=self.max_depth,
            num_sims=-1 if self.planning_time is not None else self.num_sims,
            planning_time=-1.0 if self.planning_time is None else self.planning_time,
            discount_factor=self.discount,
            exploration_const=self.exploration_const,
            rollout_policy=self.adapter.policy_model,
            show_progress=False,
        )

    def set_model(self, model: GridModel) -> None:
        super().set_model(model)
        self._build()

    def reset(self, seed: int | None = None, model: GridModel | None = None) -> None:
        super().reset(seed, model)
        self.adapter.seed(self.rng)  # the adapter draws from the policy's (new) generator

    def plan(self, belief: np.ndarray):
        """Run one search from the exact ``belief``; returns the pomdp_py agent (its ``tree`` holds
        the root's action values and visit counts)."""
        agent = self.adapter.agent(self._full_belief(belief), n_particles=self.n_particles)
        start = time.perf_counter()
        agent.add_attr("action", self.planner.plan(agent))
        self.decision_times.append(time.perf_counter() - start)
        return agent

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self.adapter.from_action(self.plan(belief).action)
