"""agents/gym_gridloc_agents/planners/pomcp.py: pomdp_py's POMCP as a policy (valid actions, reproducible for a seed, follows the
episode's model, registered as ``pomcp``)."""

from __future__ import annotations

import numpy as np
import pytest
from gym_gridloc_agents.envs import make_env
from gym_gridloc_agents.policies import POLICY_NAMES, make_policy
from gym_gridloc_agents.evaluation.rollout import rollout

import gym_gridloc

pytest.importorskip("pomdp_py", reason="pomdp_py is not installed (pip install 'gym_gridloc[planning]')")

from gym_gridloc_agents.planners.pomcp import PomcpPolicy

SIMS = 60


def _actions(env, policy, seed: int, steps: int = 3) -> list[int]:
    return rollout(env, policy, seed, keep=True, max_steps=steps).actions


@pytest.mark.parametrize("env_id", ["WindyMaze-v0", "DepthMaze-v0"])
def test_pomcp_plays_valid_actions_reproducibly(env_id):
    env = make_env(env_id)
    u = env.unwrapped
    policy = make_policy("pomcp", u.model, env_id=env_id, pose=u.referee_pose, num_sims=SIMS)
    assert isinstance(policy, PomcpPolicy) and policy.name == "pomcp" and policy.pose == u.referee_pose
    first = _actions(env, policy, 5)
    assert first and all(isinstance(a, int) and env.action_space.contains(a) for a in first)
    assert _actions(env, policy, 5) == first  # the same seed, the same search
    assert len(policy.decision_times) == 2 * len(first) and min(policy.decision_times) > 0
    other = [_actions(env, policy, s) for s in range(3)]
    assert all(env.action_space.contains(a) for acts in other for a in acts)


def test_pomcp_searches_on_the_planning_model():
    """The root's actions are all tried and valued as minus a number of steps (at most max_depth);
    the plain POMDP (-1 everywhere, no end) cannot tell the actions apart."""
    model = gym_gridloc.windy_maze_model()
    policy = PomcpPolicy(model, num_sims=200, max_depth=20)
    policy.reset(seed=0)
    belief = model.prior()
    agent = policy.plan(belief)
    values = {a.index: q.value for a, q in agent.tree.children.items()}
    assert sorted(values) == [0, 1, 2, 3]
    assert all(-20.0 <= v <= -1.0 for v in values.values())
    assert agent.tree[agent.action].value == max(values.values())
    plain = policy.adapter.agent(belief, n_particles=50, plan=False)
    policy.planner.plan(plain)
    assert len({q.value for q in plain.tree.children.values()}) == 1


def test_pomcp_follows_the_episodes_model():
    model = gym_gridloc.colour_grid_model()
    policy = PomcpPolicy(model, num_sims=20)
    other = gym_gridloc.windy_maze_model()
    policy.reset(seed=1, model=other)
    assert policy.adapter.model is other
    assert 0 <= policy.act(None, other.prior()) < other.n_actions


def test_pomcp_is_registered_and_checks_its_options():
    assert "pomcp" in POLICY_NAMES
    model = gym_gridloc.colour_grid_model()
    p = make_policy("pomcp", model, env_kwargs={"localise_threshold": 0.8}, max_depth=7)
    assert p.threshold == 0.8 and p.adapter.threshold == 0.8 and p.max_depth == 7
    for bad in ({"num_sims": 0}, {"max_depth": 0}, {"planning_time": -1.0}, {"n_particles": 0}):
        with pytest.raises(ValueError):
            PomcpPolicy(model, **bad)
    with pytest.raises(ValueError, match="belief must be"):
        p.act(None, np.ones((2, 2)))
