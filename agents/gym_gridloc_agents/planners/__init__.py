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
from gym_gridloc.core.validation import unknown_names
from gym_gridloc_agents.planners.base import PlannerPolicy
from gym_gridloc_agents.planners.central import CentralPolicy, nothing_reading
from gym_gridloc_agents.planners.expectimax import ExpectimaxPolicy, expectimax_q, lower_bound
from gym_gridloc_agents.planners.leaves import LEAF_DIR, ConstantLeaf, EntropyLeaf, Leaf, belief_rollouts, fit_leaf, load_leaf
from gym_gridloc_agents.planners.mcts import ExpectedMCTSPolicy, MCTSPolicy
from gym_gridloc_agents.planners.ops import BeliefOps, initial_beliefs, predict_batch

#: The planners :func:`make_planner` builds.
PLANNER_NAMES = ("central", "expectimax", "mcts")


def _options(*classes: type) -> set[str]:
    """The keyword arguments the ``__init__`` methods of ``classes`` (and their bases) name."""
    import inspect

    names: set[str] = set()
    for cls in classes:
        for klass in cls.__mro__:
            if "__init__" in vars(klass) and klass is not object:
                params = inspect.signature(vars(klass)["__init__"]).parameters.values()
                names |= {p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}
    return names - {"self", "model"}


def make_planner(name: str, model: GridModel, *, env_id: str | None = None, **kw: Any) -> PlannerPolicy:
    """``central``, ``expectimax`` or ``mcts`` with keyword options (see the classes); ``leaf``
    defaults to ``"shipped"`` (the entropy leaf fitted for ``env_id``, if one ships)."""
    classes = {"central": (CentralPolicy,), "expectimax": (ExpectimaxPolicy,), "mcts": (ExpectedMCTSPolicy, MCTSPolicy)}
    unknown = sorted(set(kw) - _options(*classes.get(name, ())) - {"leaf", "readings" if name == "mcts" else "leaf"})
    if name in classes and unknown:  # (the classes take **kw: an unknown option would be ignored)
        raise ValueError(f"planner {name!r} takes no option {unknown_names(unknown, sorted(_options(*classes[name]) | {'leaf'}))} "
                         f"(its options: {', '.join(sorted(_options(*classes[name]) | {'leaf'}))})")
    if "leaf" in kw or name in ("expectimax", "mcts"):
        kw["leaf"] = load_leaf(kw.get("leaf", "shipped"), env_id)
    if name == "central":
        kw.pop("leaf", None)
        return CentralPolicy(model, **kw)
    if name == "expectimax":
        return ExpectimaxPolicy(model, **kw)
    if name == "mcts":
        readings = kw.pop("readings", "enumerate")
        if readings not in ("enumerate", "sample"):
            raise ValueError(f"mcts readings must be 'enumerate' or 'sample', got {readings!r}")
        return (ExpectedMCTSPolicy if readings == "enumerate" else MCTSPolicy)(model, **kw)
    raise ValueError(f"unknown planner {name!r}; allowed: {', '.join(PLANNER_NAMES)}")


__all__ = ["LEAF_DIR", "PLANNER_NAMES", "BeliefOps", "CentralPolicy", "ConstantLeaf", "EntropyLeaf", "ExpectedMCTSPolicy",
           "ExpectimaxPolicy", "Leaf", "MCTSPolicy", "PlannerPolicy", "belief_rollouts", "expectimax_q", "fit_leaf",
           "initial_beliefs", "load_leaf", "lower_bound", "make_planner", "nothing_reading", "predict_batch"]
