"""Policies with one interface: ``reset(seed, model)`` then ``act(observation, belief) -> action``.

``observation`` is the raw sensor observation the environment emitted; ``belief`` is the exact
forward-filter belief over the hidden state, an ``(L, H, W)`` float64 array (``L = 1`` for
position-only models; an ``(H, W)`` position belief is accepted when ``L = 1``).  In the benchmark
every policy runs behind :class:`gym_gridloc.HMMBeliefWrapper`, so they all see the same
information; each uses what it needs:

- ``random``: uniform actions (the random walk), ignores both;
- ``greedy``: the action minimising the expected Shannon entropy of the position belief after the
  next move and reading, the expectation taken exactly over readings;
- ``greedy2``: a two-step expectimax over (action, reading, action, reading);
- ``ppo``: a stable-baselines3 PPO model on the belief observation, trained from the
  environment's reward alone (no planner);
- ``distilled``: a PPO network on the belief observation that imitated a planner (behaviour
  cloning and DAgger, then a short PPO phase): the planner's play at a network's speed;
- ``recurrent``: an sb3-contrib RecurrentPPO model on the raw observation only (LSTM memory).

Call ``reset(seed=..., model=...)`` at the start of every episode: it seeds the policy's own
random generator (random actions, tie-breaking), clears any memory, and gives the model of the
episode (a map redrawn at reset is followed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gym_gridloc.core.model import GridModel
from gym_gridloc.lookahead import Lookahead
from gym_gridloc.referee import LOCALISE_THRESHOLD
from gym_gridloc_agents.base import Policy
from gym_gridloc_agents.learned import (LEARNED_POLICIES, POLICY_DIR, DistilledPolicy, PPOPolicy, RecurrentPolicy,
                                        default_model_path, renamed_model, wrapped_observation)

__all__ = [
    "POLICIES", "POLICY_NAMES", "EXPERT_NAMES", "PLANNER_POLICIES", "LEARNED_NAMES", "DEFAULT_POLICIES", "POLICY_DIR",
    "LEARNED_POLICIES", "Policy", "RandomPolicy", "GreedyPolicy", "Greedy2Policy", "PPOPolicy", "DistilledPolicy",
    "RecurrentPolicy", "default_model_path", "renamed_model", "wrapped_observation", "make_policy",
]


#: The one table of policies, in the benchmark's order: name -> (kind, a warm start may imitate it,
#: ``gridloc bench`` runs it by default).  Kinds: ``baseline`` (random, the entropy lookaheads),
#: ``planner`` (plans on the exact belief: the "best planner" of the benchmark's gaps), ``learned``
#: (loads a model file).  :func:`make_policy` builds them; the benchmark, the configs, the warm
#: start, the viewer and the CLI read their lists from here.
POLICIES: dict[str, tuple[str, bool, bool]] = {
    "random": ("baseline", False, True),
    "greedy": ("baseline", True, True),
    "greedy2": ("baseline", True, True),
    "central": ("planner", True, False),
    "expectimax": ("planner", True, False),
    "mcts": ("planner", True, False),
    "optimal": ("planner", True, False),
    "pomcp": ("planner", False, False),
    "ppo": ("learned", False, True),
    "distilled": ("learned", False, True),
    "recurrent": ("learned", False, True),
}
#: Names accepted by :func:`make_policy`.
POLICY_NAMES = tuple(POLICIES)
#: Policies a warm start may imitate (no model file of their own).
EXPERT_NAMES = tuple(name for name, (_, expert, _) in POLICIES.items() if expert)
#: Policies that plan on the exact belief, and those that load a model file.
PLANNER_POLICIES = tuple(name for name, (kind, _, _) in POLICIES.items() if kind == "planner")
LEARNED_NAMES = tuple(name for name, (kind, _, _) in POLICIES.items() if kind == "learned")
#: The policies ``gridloc bench`` runs when none are named.
DEFAULT_POLICIES = tuple(name for name, (_, _, default) in POLICIES.items() if default)


class RandomPolicy(Policy):
    """Uniform random actions from the policy's own seeded generator."""

    name = "random"

    def act(self, observation: Any, belief: np.ndarray | None = None) -> int:
        return int(self.rng.integers(self.n_actions))


class GreedyPolicy(Policy):
    """One-step information gain: ``argmin_a E_z[H(position | belief, a, z)]``, exact.

    The prediction ``b' = T_a b`` is taken over the full hidden state (headings included), the
    expectation over every reading the sensor can give (:class:`~gym_gridloc.lookahead.Lookahead`).
    ``pose=True`` (where the referee tests poses) minimises the entropy of the full hidden state
    instead.  Ties (within 1e-9) are broken uniformly with the policy's seeded generator.
    """

    name = "greedy"

    def __init__(self, model: GridModel, *, seed: int | None = None, pose: bool = False) -> None:
        super().__init__(model, seed=seed)
        self.pose = bool(pose)
        self.look = Lookahead(model, pose=self.pose)

    def set_model(self, model: GridModel) -> None:
        super().set_model(model)
        self.look = Lookahead(model, pose=self.pose)

    def expected_entropies(self, belief: np.ndarray) -> np.ndarray:
        """Expected position entropy (bits) after each action's move and reading, shape (A,)."""
        return self.look.one_step(self._full_belief(belief))

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self._break_ties(self.expected_entropies(belief))

    def probabilities(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n_actions)
        ties = self.best(self.expected_entropies(belief))
        out[ties] = 1.0 / len(ties)
        return out


class Greedy2Policy(GreedyPolicy):
    """Two-step expectimax on the expected position entropy.

    ``value(a1) = E_{z1}[ min_{a2} E_{z2}[ H(position | b, a1, z1, a2, z2) ] ]``: the second action
    is chosen after seeing the first reading (closed loop), both expectations are exact.  With the
    unnormalised masses of the module's identity this is ``sum_{z1} min_{a2} W(a1, z1, a2)``, all
    batched in numpy.  Ties are broken as in ``greedy``.
    """

    name = "greedy2"

    def expected_entropies(self, belief: np.ndarray) -> np.ndarray:
        return self.look.two_step(self._full_belief(belief))


def make_policy(
    name: str,
    model: GridModel,
    *,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    seed: int | None = None,
    path: str | Path | None = None,
    pose: bool = False,
    **options: Any,
) -> Policy:
    """A policy by name (one of :data:`POLICY_NAMES`) for an environment's model.

    ``path`` gives the model file for ``ppo`` / ``distilled`` / ``recurrent`` (default: the shipped one for
    ``env_id``; a model trained with other ``env_kwargs`` is refused).  ``pose``: the referee
    tests poses (the entropy policies then minimise the entropy of the full hidden state).
    ``optimal`` (noiseless models only, :mod:`gym_gridloc_agents.planners.optimal`) plans for the
    environment's ``episode_length`` (or ``horizon=``, default 30).  An unknown option is an error."""
    takes = {"optimal": ("horizon",), "random": (), "greedy": (), "greedy2": (), **dict.fromkeys(LEARNED_POLICIES, ()),
             "pomcp": ("num_sims", "planning_time", "max_depth", "discount", "exploration_const", "n_particles", "threshold")}.get(name)
    if takes is not None and (extra := sorted(set(options) - set(takes))):  # never ignored (nor printed in a row's label)
        raise ValueError(f"policy {name!r} takes no option {', '.join(map(repr, extra))}"
                         f" ({'its options: ' + ', '.join(takes) if takes else 'it takes no options'})")
    if name == "random":
        return RandomPolicy(model, seed=seed)
    if name in ("greedy", "greedy2"):
        return {"greedy": GreedyPolicy, "greedy2": Greedy2Policy}[name](model, seed=seed, pose=pose)
    from gym_gridloc_agents.planners import PLANNER_NAMES, make_planner

    if name in PLANNER_NAMES:
        return make_planner(name, model, env_id=env_id, seed=seed, pose=pose, **options)
    if name == "optimal":
        from gym_gridloc_agents.planners.optimal import OptimalPolicy

        horizon = options.get("horizon") or (env_kwargs or {}).get("episode_length") or 30
        return OptimalPolicy(model, seed=seed, horizon=horizon)
    if name == "pomcp":
        from gym_gridloc_agents.planners.pomcp import PomcpPolicy

        threshold = options.pop("threshold", None) or (env_kwargs or {}).get("localise_threshold", LOCALISE_THRESHOLD)
        return PomcpPolicy(model, seed=seed, threshold=threshold, pose=pose, **options)
    if name in LEARNED_POLICIES:
        return LEARNED_POLICIES[name](model, env_id=env_id, env_kwargs=env_kwargs, path=path, seed=seed)
    raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICY_NAMES)}")
