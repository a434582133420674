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
- ``recurrent``: an sb3-contrib RecurrentPPO model on the raw observation only (LSTM memory);
- ``central``, ``expectimax``, ``mcts``, ``optimal``, ``pomcp``: the planners
  (:mod:`gym_gridloc_agents.planners`).

Every name is a line of the one table of policies (:data:`POLICIES`, from
:mod:`gym_gridloc_agents.registry`: constructor, options, kind, expert, default);
:func:`make_policy` is a lookup in it.

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
from gym_gridloc_agents.base import Policy
from gym_gridloc_agents.learned import (LEARNED_POLICIES, POLICY_DIR, DistilledPolicy, PPOPolicy, RecurrentPolicy,
                                        default_model_path, renamed_model, wrapped_observation)
from gym_gridloc_agents.registry import (DEFAULT_POLICIES, EXPERT_NAMES, LEARNED_NAMES, PLANNER_POLICIES, POLICIES,
                                         POLICY_NAMES, PolicyContext, PolicySpec, policy_spec)

__all__ = [
    "POLICIES", "POLICY_NAMES", "EXPERT_NAMES", "PLANNER_POLICIES", "LEARNED_NAMES", "DEFAULT_POLICIES", "POLICY_DIR",
    "LEARNED_POLICIES", "Policy", "PolicyContext", "PolicySpec", "RandomPolicy", "GreedyPolicy", "Greedy2Policy",
    "PPOPolicy", "DistilledPolicy", "RecurrentPolicy", "default_model_path", "renamed_model", "wrapped_observation",
    "make_policy", "policy_spec",
]


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

    @classmethod
    def build(cls, model: GridModel, context: PolicyContext) -> "GreedyPolicy":
        return cls(model, seed=context.seed, pose=context.pose)

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
    """A policy by name (one of :data:`POLICY_NAMES`) for an environment's model: a lookup in the
    table (:data:`POLICIES`), its options checked against the options the table gives it (an
    unknown one is a ``ValueError`` naming it and the accepted ones), then its constructor.

    ``path`` gives the model file for ``ppo`` / ``distilled`` / ``recurrent`` (default: the shipped one for
    ``env_id``; a model trained with other ``env_kwargs`` is refused).  ``pose``: the referee
    tests poses (the entropy policies then minimise the entropy of the full hidden state, the
    planners stop on the pose).  The planners' ``threshold`` defaults to the environment's
    ``localise_threshold`` (in ``env_kwargs``) or :data:`gym_gridloc.referee.LOCALISE_THRESHOLD`;
    ``optimal`` (noiseless models only, :mod:`gym_gridloc_agents.planners.optimal`) plans for the
    environment's ``episode_length`` (or ``horizon=``, default 30)."""
    spec = policy_spec(name)
    spec.check_options(options)
    context = PolicyContext(env_id=env_id, env_kwargs=None if env_kwargs is None else dict(env_kwargs), seed=seed, path=path,
                            pose=bool(pose))
    return spec.load()(model, context, **options)
