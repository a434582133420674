"""Planners on the exact belief: what a good policy can do, to measure learned ones against.

Policies (the :class:`~gym_gridloc_agents.base.Policy` interface; ``belief`` is the exact
hidden-state belief ``(L, H, W)``):

- :class:`CentralPolicy` (``central``): ``argmin_a P(next reading = "nothing" | belief, a)``.
- :class:`ExpectimaxPolicy` (``expectimax``): depth-``d`` expectimax on the exact belief; the cost
  is the number of steps until the referee's test (largest POSITION probability >= threshold)
  holds; exact expectation over readings (readings below ``prune`` dropped, the rest
  renormalised); a leaf estimate of the steps still needed at depth ``d``; equal beliefs merged.
- :class:`MCTSPolicy` (``mcts``): Monte Carlo tree search on the belief MDP with the exact filter
  at every node.  ``readings="enumerate"`` (default): exact expectations over readings, an
  incremental selective expectimax valued by the leaf; ``readings="sample"``: classic UCT,
  readings sampled from the exact predictive distribution, rollouts with a fast policy.

:func:`lower_bound` computes a number no policy's expected steps can go below; :func:`fit_leaf`
fits the entropy leaf from rollouts on the belief MDP (:func:`belief_rollouts`).  Every belief
prediction, Bayes update and expected entropy is the core's belief MDP's
(:class:`gym_gridloc.lookahead.Lookahead`, predictions through :func:`gym_gridloc.engine.predict`).

The modules: :mod:`~gym_gridloc_agents.planners.ops` (:class:`BeliefOps`: what the planners need
of a model, the core's belief MDP with the referee's test), :mod:`~gym_gridloc_agents.planners.leaves` (leaf estimates, rollouts on the belief
MDP, fitting), :mod:`~gym_gridloc_agents.planners.base` (:class:`PlannerPolicy`),
:mod:`~gym_gridloc_agents.planners.central`, :mod:`~gym_gridloc_agents.planners.expectimax` (with
:func:`lower_bound`, the same recursion) and :mod:`~gym_gridloc_agents.planners.mcts`.
"""

from __future__ import annotations

from typing import Any

from gym_gridloc.core.model import GridModel
from gym_gridloc_agents.planners.base import PlannerPolicy
from gym_gridloc_agents.planners.central import CentralPolicy, nothing_reading
from gym_gridloc_agents.planners.expectimax import ExpectimaxPolicy, expectimax_q, lower_bound
from gym_gridloc_agents.planners.leaves import LEAF_DIR, ConstantLeaf, EntropyLeaf, Leaf, belief_rollouts, fit_leaf, load_leaf
from gym_gridloc_agents.planners.mcts import ExpectedMCTSPolicy, MCTSPolicy
from gym_gridloc_agents.planners.ops import BeliefOps, initial_beliefs, predict_batch
from gym_gridloc_agents.registry import VALUE_NAMES

#: The planners of :class:`PlannerPolicy` (action values at the exact belief), from the policy table.
PLANNER_NAMES = VALUE_NAMES


def make_planner(name: str, model: GridModel, *, env_id: str | None = None, **kw: Any) -> PlannerPolicy:
    """``central``, ``expectimax`` or ``mcts`` with keyword options (see the classes), as
    :func:`gym_gridloc_agents.policies.make_policy` makes them from the policy table; ``leaf``
    defaults to ``"shipped"`` (the entropy leaf fitted for ``env_id``, if one ships)."""
    if name not in PLANNER_NAMES:
        raise ValueError(f"unknown planner {name!r}; allowed: {', '.join(PLANNER_NAMES)}")
    from gym_gridloc_agents.policies import make_policy

    return make_policy(name, model, env_id=env_id, **kw)


__all__ = ["LEAF_DIR", "PLANNER_NAMES", "BeliefOps", "CentralPolicy", "ConstantLeaf", "EntropyLeaf", "ExpectedMCTSPolicy",
           "ExpectimaxPolicy", "Leaf", "MCTSPolicy", "PlannerPolicy", "belief_rollouts", "expectimax_q", "fit_leaf",
           "initial_beliefs", "load_leaf", "lower_bound", "make_planner", "nothing_reading", "predict_batch"]
