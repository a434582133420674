"""The one table of policies (:data:`POLICIES`), as Gymnasium's registry holds environments and
stable-baselines3's ``policy_aliases`` their policies: a name gives a :class:`PolicySpec` (the
constructor as an entry point, the options it accepts, its kind, whether a warm start may imitate
it, whether ``gridloc bench`` runs it by default).  :func:`gym_gridloc_agents.policies.make_policy`
is a lookup in it; every list of policy names (the CLI's choices and help texts, the viewer, the
benchmark, the configs, the model loaders) is read from it.

The module imports nothing of the agents (the constructors are named, not imported: an entry point
is loaded when a policy is made), so every other module may read the table.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from gym_gridloc.core.validation import unknown_names
from gym_gridloc.referee import LOCALISE_THRESHOLD

#: The kinds of policies: ``baseline`` (random, the entropy lookaheads), ``planner`` (plans on the
#: exact belief: the "best planner" of the benchmark's gaps), ``learned`` (loads a model file).
KINDS = ("baseline", "planner", "learned")


@dataclass(frozen=True)
class PolicyContext:
    """What :func:`~gym_gridloc_agents.policies.make_policy` knows of the environment, handed to a
    constructor beside the options: the environment's id and keywords (None: not given, so a
    learned policy's model file is not checked against them), the policy's seed, a model file
    (learned policies) and whether the referee tests poses (``referee_pose``)."""

    env_id: str | None = None
    env_kwargs: Mapping[str, Any] | None = None
    seed: int | None = None
    path: str | Path | None = None
    pose: bool = False

    @property
    def threshold(self) -> float:
        """The referee's threshold: the environment's ``localise_threshold``, else the default."""
        value = (self.env_kwargs or {}).get("localise_threshold")
        return LOCALISE_THRESHOLD if value is None else value


@dataclass(frozen=True)
class PolicySpec:
    """One line of the table.

    ``entry_point``: ``"module:name"`` of the constructor, called as
    ``constructor(model, context, **options)`` (``name`` may be dotted: ``Class.build``).
    ``options``: the option names it accepts (every other one is refused).  ``kind``: one of
    :data:`KINDS`.  ``expert``: a warm start may imitate it (``pretrain.expert``).  ``values``: it
    has action values a warm start may imitate (``pretrain.temperature``).  ``default``:
    ``gridloc bench`` runs it when no policy is named.  ``summary``: one line for help texts.
    """

    name: str
    kind: str
    entry_point: str
    summary: str
    options: tuple[str, ...] = ()
    expert: bool = False
    values: bool = False
    default: bool = False

    def check_options(self, options: Mapping[str, Any]) -> None:
        """Refuse an option this policy does not take (never ignored, nor printed in a row's label)."""
        extra = sorted(set(options) - set(self.options))
        if extra:
            raise ValueError(f"policy {self.name!r} takes no option {unknown_names(extra, self.options)} "
                             f"({'its options: ' + ', '.join(self.options) if self.options else 'it takes no options'})")

    def load(self) -> Callable[..., Any]:
        """The constructor the entry point names (its module imported now)."""
        module, _, name = self.entry_point.partition(":")
        obj: Any = importlib.import_module(module)
        for part in name.split("."):
            obj = getattr(obj, part)
        return obj


def _spec(name: str, kind: str, entry_point: str, summary: str, **kw: Any) -> tuple[str, PolicySpec]:
    return name, PolicySpec(name, kind, entry_point, summary, **kw)


_PLANNING = ("threshold",)  # the referee's threshold the planners stop at (default: the environment's)
_ACTING = ("deterministic",)  # the learned policies: the most probable action, or sampled (default: as the model's metadata says)
_BELIEF_ACTING = (*_ACTING, "break_cycles")  # those of the belief: sampled where the belief comes back (default: as the metadata says)

#: The one table of policies, in the benchmark's order.
POLICIES: dict[str, PolicySpec] = dict([
    _spec("random", "baseline", "gym_gridloc_agents.policies:RandomPolicy.build",
          "uniform random actions (the random walk)", default=True),
    _spec("greedy", "baseline", "gym_gridloc_agents.policies:GreedyPolicy.build",
          "the action of least expected entropy after one move and reading", expert=True, default=True),
    _spec("greedy2", "baseline", "gym_gridloc_agents.policies:Greedy2Policy.build",
          "two-step expectimax on the expected entropy", expert=True, default=True),
    _spec("central", "planner", "gym_gridloc_agents.planners.central:CentralPolicy.build",
          "the action least likely to read 'nothing' (sensors with a 'nothing' reading)",
          options=("depth", "nothing", *_PLANNING), expert=True, values=True),
    _spec("expectimax", "planner", "gym_gridloc_agents.planners.expectimax:ExpectimaxPolicy.build",
          "depth-d expectimax on the expected steps to localise",
          options=("depth", "leaf", "prune", "memo", *_PLANNING), expert=True, values=True),
    _spec("mcts", "planner", "gym_gridloc_agents.planners.mcts:mcts_policy",
          "Monte Carlo tree search on the belief MDP (readings enumerated or sampled)",
          options=("readings", "simulations", "time_ms", "c", "leaf", "prune", "max_depth", "rollout", "rollout_steps",
                   "nothing", *_PLANNING), expert=True, values=True),
    _spec("optimal", "planner", "gym_gridloc_agents.planners.optimal:OptimalPolicy.build",
          "the exact optimum of a noiseless model", options=("horizon",), expert=True),
    _spec("pomcp", "planner", "gym_gridloc_agents.planners.pomcp:PomcpPolicy.build",
          "pomdp_py's POMCP from the exact belief (the planning extra)",
          options=("num_sims", "planning_time", "max_depth", "discount", "exploration_const", "n_particles", *_PLANNING)),
    _spec("ppo", "learned", "gym_gridloc_agents.learned:PPOPolicy.build",
          "a PPO model on the belief, trained from the reward alone", options=_BELIEF_ACTING, default=True),
    _spec("distilled", "learned", "gym_gridloc_agents.learned:DistilledPolicy.build",
          "a PPO network that imitated a planner", options=_BELIEF_ACTING, default=True),
    _spec("recurrent", "learned", "gym_gridloc_agents.learned:RecurrentPolicy.build",
          "a RecurrentPPO (LSTM) model on the raw readings", options=_ACTING, default=True),
])

#: Names accepted by :func:`~gym_gridloc_agents.policies.make_policy`.
POLICY_NAMES = tuple(POLICIES)
#: Policies a warm start may imitate (no model file of their own), and those with action values.
EXPERT_NAMES = tuple(name for name, spec in POLICIES.items() if spec.expert)
VALUE_NAMES = tuple(name for name, spec in POLICIES.items() if spec.values)
#: Policies that plan on the exact belief, and those that load a model file.
PLANNER_POLICIES = tuple(name for name, spec in POLICIES.items() if spec.kind == "planner")
LEARNED_NAMES = tuple(name for name, spec in POLICIES.items() if spec.kind == "learned")
#: The policies ``gridloc bench`` runs when none are named.
DEFAULT_POLICIES = tuple(name for name, spec in POLICIES.items() if spec.default)


def policy_spec(name: str) -> PolicySpec:
    """The table's line of ``name``; an unknown name is a ``ValueError`` naming the closest one."""
    spec = POLICIES.get(name) if isinstance(name, str) else None
    if spec is None:
        raise ValueError(f"unknown policy {unknown_names([name], POLICY_NAMES)}; allowed: {', '.join(POLICY_NAMES)}")
    return spec


def either(names: tuple[str, ...] | list[str]) -> str:
    """``a, b or c``: names for a sentence."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def names_by_kind() -> str:
    """``baselines random, greedy, ...; planners ...; learned ...``: the names for a help text."""
    plural = {"baseline": "baselines", "planner": "planners", "learned": "learned"}
    return "; ".join(f"{plural[k]} {', '.join(n for n, s in POLICIES.items() if s.kind == k)}" for k in KINDS)


def options_text() -> str:
    """``central: depth, nothing, threshold; expectimax: ...``: each policy's options, for a help text."""
    return "; ".join(f"{name}: {', '.join(spec.options)}" for name, spec in POLICIES.items() if spec.options)


__all__ = ["DEFAULT_POLICIES", "EXPERT_NAMES", "KINDS", "LEARNED_NAMES", "PLANNER_POLICIES", "POLICIES", "POLICY_NAMES",
           "PolicyContext", "PolicySpec", "VALUE_NAMES", "either", "names_by_kind", "options_text", "policy_spec"]
