"""One owner per concept (issue 22): the wrapper serves the environment's posterior (one filter
step per environment step), one observation builder for the wrapper, the vector env and the
learned policies, one KEY=VALUE reader, the planners stop where the referee does."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import HMMBeliefWrapper, engine, referee
from gym_gridloc.filter import ForwardFilter
from gym_gridloc.observation import BeliefObservation

ENV_IDS = ("ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0", "DepthMaze-v0")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_wrapper_serves_the_environments_posterior(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), full_state=True)
    obs, _ = env.reset(seed=0)
    inner = env.unwrapped
    assert env.filter is inner.exact_filter  # one belief: the referee's object
    rng = np.random.default_rng(0)
    for _ in range(15):
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        assert env.filter is inner.exact_filter
        np.testing.assert_array_equal(obs["belief"], np.minimum(inner.exact_filter.full_belief, 1).astype(np.float32))
        if terminated or truncated:
            obs, _ = env.reset()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_one_filter_step_per_environment_step(env_id, monkeypatch):
    env = HMMBeliefWrapper(gym.make(env_id))
    env.reset(seed=1)
    calls = []
    real = ForwardFilter.step
    monkeypatch.setattr(ForwardFilter, "step", lambda self, *a, **k: (calls.append(1), real(self, *a, **k))[1])
    steps = 0
    for a in [0, 1, 2, 1, 0, 2, 2, 1]:
        _, _, terminated, truncated, _ = env.step(a)
        steps += 1
        if terminated or truncated:
            break
    assert len(calls) == steps


def test_another_model_or_particles_keep_a_filter_of_their_own():
    env = gym.make("ColourGrid-v0")
    other = gym_gridloc.colour_grid_model(slip=0.3)
    mismatched = HMMBeliefWrapper(env, model=other, on_impossible="reset")
    mismatched.reset(seed=0)
    assert mismatched.filter is not env.unwrapped.exact_filter and mismatched.filter.model is other
    particles = HMMBeliefWrapper(gym.make("ColourGrid-v0"), belief="particles", n_particles=100)
    particles.reset(seed=0)
    assert particles.filter is not particles.unwrapped.exact_filter
    same = HMMBeliefWrapper(env, model=env.unwrapped.model)  # the environment's model, given: served too
    same.reset(seed=0)
    assert same.filter is env.unwrapped.exact_filter


def test_a_redrawn_map_is_served_too():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0", size=9, new_map_each_reset=True))
    env.reset(seed=0)
    first = env.unwrapped.model
    env.reset(seed=1)
    assert env.unwrapped.model is not first and env.model is env.unwrapped.model
    assert env.filter is env.unwrapped.exact_filter


@pytest.mark.parametrize("options", [{}, {"flatten": True}, {"full_state": True}, {"map": True, "lookahead": 1},
                                     {"flatten": True, "map": True, "lookahead": 2}])
@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "DepthMaze-v0"])
def test_one_observation_builder_for_the_wrapper_the_vector_env_and_the_policies(env_id, options):
    from gym_gridloc_agents.policies import PPOPolicy

    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **options)
    single = HMMBeliefWrapper(gym.make(env_id), **options)
    vobs, _ = vec.reset(seed=4)
    sobs, _ = single.reset(seed=4)
    model = single.unwrapped.model
    policy = PPOPolicy.__new__(PPOPolicy)  # the encoding only (no model file)
    policy.model, policy.wrapper, policy._builder = model, dict(options), None
    policy.n_actions = model.n_actions
    for a in [1, 0, 2, 1]:
        raw = model.sensor.to_observation(single.unwrapped.last_reading)
        mine = policy.encode(raw, single.filter.full_belief)
        if isinstance(sobs, dict):
            for k in sobs:
                np.testing.assert_array_equal(np.asarray(sobs[k]), np.asarray(vobs[k][0]))
                np.testing.assert_array_equal(np.asarray(sobs[k]), np.asarray(mine[k]))
        else:
            np.testing.assert_array_equal(sobs, vobs[0])
            np.testing.assert_array_equal(sobs, mine)
        assert policy.observation_options == single.builder.options
        sobs, *_ = single.step(a)
        vobs, *_ = vec.step(np.array([a]))


def test_the_builder_checks_its_options():
    model = gym_gridloc.colour_grid_model()
    with pytest.raises(TypeError, match="flatten must be True or False"):
        BeliefObservation(model, flatten="yes")
    with pytest.raises(ValueError, match="lookahead must be 0, 1 or 2"):
        BeliefObservation(model, lookahead=3)
    assert BeliefObservation(model, flatten=True).space == HMMBeliefWrapper(gym.make("ColourGrid-v0"), flatten=True).observation_space


def test_the_referees_test_is_pose_aware():
    b = np.zeros((2, 4, 3, 3))
    b[0, :, 1, 1] = 0.25  # sure of the position, not of the heading
    b[1, 2, 0, 0] = 1.0
    np.testing.assert_array_equal(referee.localised(b, 0.9), [True, True])
    np.testing.assert_array_equal(referee.localised(b, 0.9, pose=True), [False, True])
    np.testing.assert_allclose(referee.confidences(b, pose=True), [0.25, 1.0])


def test_the_planners_stop_on_the_pose_where_the_referee_does():
    from gym_gridloc_agents.policies import make_policy

    env = HMMBeliefWrapper(gym.make("DepthMaze-v0"))
    env.reset(seed=0)
    model = env.unwrapped.model
    assert env.unwrapped.referee_pose
    planner = make_policy("expectimax", model, env_id="DepthMaze-v0", seed=0, pose=True)
    assert planner.ops.pose
    b = np.zeros(model.belief_shape)
    r, c = (int(v) for v in model.grid.free_cells[0])
    b[:, r, c] = 0.25  # localised on the position, not on the pose: the environment goes on
    assert not planner.ops.localised(b[None])[0]
    assert make_policy("expectimax", model, env_id="DepthMaze-v0", seed=0).ops.localised(b[None])[0]


def test_kidnapping_mixed_in_one_place():
    model = gym_gridloc.windy_maze_model().with_kidnapping(0.1)
    assert engine.kidnapped(model, 0.5) == pytest.approx(0.9 * 0.5 + 0.1 / model.n_states)
    assert engine.kidnapped(gym_gridloc.windy_maze_model(), 0.5) == 0.5


def test_one_key_value_reader_for_bench_view_and_sweep():
    from gym_gridloc_agents.evaluation.bench_command import _key_values
    from gym_gridloc_agents.sweeps.sweep_spec import parse_grid
    from gym_gridloc_agents.values import key_values, parse_value
    from gym_gridloc_agents.viewer.args import parse_kw

    items = ["slip=1e-4", "size=16,16", "new_map_each_reset=true", "map_seed=3", "dynamics=passive", "layout=none"]
    want = {"slip": 0.0001, "size": (16, 16), "new_map_each_reset": True, "map_seed": 3, "dynamics": "passive",
            "layout": None}
    assert key_values(items, "--kw") == want
    assert _key_values(items, "--env-kwarg") == want
    assert parse_kw(items) == want
    grid = parse_grid(["env_kwargs.slip=1e-4,0.2", "env_kwargs.map_seed=3,4"])
    assert grid["env_kwargs.slip"] == [0.0001, 0.2] and grid["env_kwargs.map_seed"] == [3, 4]
    assert parse_value("[16, 16]") == [16, 16] and parse_value("2.5e3") == 2500.0 and parse_value("-3") == -3


def test_one_policy_table():
    from gym_gridloc_agents.evaluation import bench
    from gym_gridloc_agents import policies

    assert policies.POLICY_NAMES == tuple(policies.POLICIES)
    assert set(policies.LEARNED_POLICIES) == set(policies.LEARNED_NAMES) == set(bench.LEARNED)
    assert set(bench.PLANNERS) == {n for n, (kind, *_) in policies.POLICIES.items() if kind == "planner"}
    assert bench.DEFAULT_POLICIES == policies.DEFAULT_POLICIES
