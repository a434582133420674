"""HMMBeliefWrapper over every registered environment (issue 2).

The wrapper's belief is the environment's referee posterior when both use the same model, it is
computed from actions and observations only, and the wrapped environments pass ``check_env``,
are deterministic, pickle and vectorise.
"""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import gym_gridloc  # noqa: F401  (registers the environments)
from gym_gridloc import ForwardFilter, HMMBeliefWrapper, colour_grid_model, ring_sensor_model, windy_maze_model
try:  # tests/ is not a package (pytest puts it on sys.path); keep working if it becomes one
    from test_envs import CONFIG_IDS, CONFIGS, ENV_IDS, assert_same_rollouts, rollout, run_check_env
except ImportError:  # pragma: no cover
    from tests.test_envs import CONFIG_IDS, CONFIGS, ENV_IDS, assert_same_rollouts, rollout, run_check_env

WRAPPER_OPTIONS = [{}, {"flatten": True}, {"full_state": True}]
OPTION_IDS = ["dict", "flatten", "full_state"]

#: A model per environment whose sensor and motion differ from the environment's defaults, but
#: which emits the same observation space (so it can filter the environment's observations).
MISMATCHED = {
    "ColourGrid-v0": lambda: colour_grid_model(slip=0.5, accuracy=0.7),
    "RingSensor8x8-v0": lambda: ring_sensor_model((8, 8), keep_heading=0.4, p_true=0.2, p_ring1=0.06, p_ring2=0.02),
    "WindyMaze-v0": lambda: windy_maze_model(drift=0.25, p_detect=0.7, p_false_alarm=0.2),
}


def belief_of(wrapper, obs) -> np.ndarray:
    """The (position or full) belief inside a wrapped observation."""
    if wrapper.flatten:
        return obs[-int(np.prod(wrapper.belief_array().shape)):].reshape(wrapper.belief_array().shape)
    return obs[wrapper.key]


# -- check_env ---------------------------------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_wrapped(env_id, options):
    run_check_env(HMMBeliefWrapper(gym.make(env_id).unwrapped, **options))
    run_check_env(HMMBeliefWrapper(gym.make(env_id), **options))


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
def test_check_env_wrapped_ring_seed_dynamics(options):
    run_check_env(HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="seed"), **options))


def test_observation_spaces():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    assert env.observation_space == spaces.Dict(
        {"observation": spaces.MultiBinary(4), "belief": spaces.Box(0.0, 1.0, (6, 7), np.float32)}
    )
    flat = HMMBeliefWrapper(gym.make("ColourGrid-v0"), flatten=True)
    assert flat.observation_space == spaces.Box(0.0, 1.0, (4 + 25,), np.float32)
    full = HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="seed"), full_state=True)
    assert full.observation_space["belief"] == spaces.Box(0.0, 1.0, (4, 8, 8), np.float32)
    pos = HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="seed"))
    assert pos.observation_space["belief"] == spaces.Box(0.0, 1.0, (8, 8), np.float32)


# -- determinism, pickling, vector envs ----------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_same_seed_same_trajectory(env_id, kwargs, options):
    ra = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs), **options), seed=321, n_steps=120)
    rb = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs), **options), seed=321, n_steps=120)
    assert_same_rollouts(ra, rb)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_env_yields_the_env_trajectory(env_id, kwargs):
    """The wrapper changes the observation, nothing else: same seed, same readings, rewards, info."""
    ra = rollout(gym.make(env_id, **kwargs), seed=8, n_steps=100)
    rb = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs)), seed=8, n_steps=100)
    stripped = [tuple(v["observation"] if isinstance(v, dict) and "belief" in v else v for v in rec) for rec in rb]
    assert_same_rollouts(ra, stripped)


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_pickle_continues_identically(env_id, kwargs, options):
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs), **options)
    n = env.action_space.n
    env.reset(seed=4)
    for a in (1, 2, 3):
        env.step(a % n)
    clone = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(clone.belief_array(), env.belief_array())
    for a in (0, 0, 1, 2, 3, 3, 2):
        x, y = env.step(a % n), clone.step(a % n)
        for u, v in zip(x, y):
            if isinstance(u, dict):
                for k in u:
                    np.testing.assert_array_equal(u[k], v[k])
            else:
                np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_wrapped_sync_vector_env(env_id, options):
    venv = gym.vector.SyncVectorEnv([lambda: HMMBeliefWrapper(gym.make(env_id), **options) for _ in range(2)])
    single = HMMBeliefWrapper(gym.make(env_id), **options)
    vobs, _ = venv.reset(seed=[3, 4])
    sobs, _ = single.reset(seed=3)
    assert vobs in venv.observation_space
    first = (lambda o: o[0]) if options.get("flatten") else (lambda o: {k: v[0] for k, v in o.items()})
    rng = np.random.default_rng(0)
    for _ in range(40):
        actions = rng.integers(0, 4, size=2)
        vobs, _, vterm, vtrunc, _ = venv.step(actions)
        assert vobs in venv.observation_space
        sobs, _, term, trunc, _ = single.step(int(actions[0]))
        got = first(vobs)
        if isinstance(got, dict):
            for k in got:
                np.testing.assert_array_equal(got[k], np.asarray(sobs[k]))
        else:
            np.testing.assert_array_equal(got, sobs)
        if term or trunc:
            break
    venv.close()


# -- the belief --------------------------------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_belief_equals_referee_posterior_every_step(env_id, kwargs, options):
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs), **options)
    inner = env.unwrapped
    rng = np.random.default_rng(5)
    n_steps = episode = 0
    while episode < 3 or n_steps < 60:  # several episodes, at least 60 steps
        obs, info = env.reset(seed=50 + episode)
        episode += 1
        while True:
            b = belief_of(env, obs)
            assert b.dtype == np.float32 and obs in env.observation_space
            position = b.sum(axis=0) if env.full_state else b
            np.testing.assert_allclose(position, inner.posterior, rtol=0, atol=1e-6)
            assert abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
            assert np.all(position[~inner.model.grid.free] == 0)
            if env.full_state:
                np.testing.assert_allclose(b, inner._referee.full_belief, rtol=0, atol=1e-6)
            obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
            n_steps += 1
            if terminated or truncated:
                break


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_flattened_observation_layout(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), flatten=True)
    obs, _ = env.reset(seed=0)
    for a in (0, 1, 2, 3):
        raw = env.unwrapped.model.sensor.to_observation(env.unwrapped.last_reading)
        space = env.env.observation_space
        head_len = space.n if isinstance(space, spaces.Discrete) else 4
        head = obs[:head_len]
        if isinstance(space, spaces.Discrete):
            assert head.sum() == 1.0 and int(np.argmax(head)) == int(raw)
        else:
            np.testing.assert_array_equal(head, np.asarray(raw, dtype=np.float32))
        np.testing.assert_allclose(obs[head_len:].reshape(env.unwrapped.model.shape), env.unwrapped.posterior, atol=1e-6)
        obs, *_ = env.step(a)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_belief_is_computed_from_actions_and_observations_only(env_id, kwargs):
    """A separate filter fed only the actions passed on and the observations emitted gives the
    same belief; a wrapper with another model, on the same environment run, gives another."""
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs))
    f = ForwardFilter(env.unwrapped.model)
    obs, _ = env.reset(seed=9)
    f.reset(obs["observation"])
    for t in range(30):
        a = t % env.action_space.n
        obs, _, terminated, truncated, _ = env.step(a)
        f.step(a, obs["observation"])
        np.testing.assert_array_equal(obs["belief"], f.position_belief.astype(np.float32))
        if terminated or truncated:
            break


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_mismatched_model_gives_a_different_belief(env_id):
    other = MISMATCHED[env_id]()
    matched = HMMBeliefWrapper(gym.make(env_id))
    mismatched = HMMBeliefWrapper(gym.make(env_id), model=other, on_impossible="reset")
    assert mismatched.model is other and mismatched.filter.model is other
    om, _ = matched.reset(seed=12)
    ox, _ = mismatched.reset(seed=12)
    np.testing.assert_array_equal(om["observation"], ox["observation"])  # the same environment run
    largest_gap = float(np.abs(om["belief"] - ox["belief"]).max())
    for t in range(20):
        om, _, tm, trm, im = matched.step(t % 4)
        ox, _, tx, trx, ix = mismatched.step(t % 4)
        np.testing.assert_array_equal(om["observation"], ox["observation"])
        assert im["position"] == ix["position"]
        # The referee (the env's own model) is the same in both; only the wrapper's belief differs.
        np.testing.assert_allclose(om["belief"], matched.unwrapped.posterior, atol=1e-6)
        assert abs(float(ox["belief"].sum(dtype=np.float64)) - 1.0) < 1e-5
        largest_gap = max(largest_gap, float(np.abs(om["belief"] - ox["belief"]).max()))
        if tm or trm:
            break
    assert largest_gap > 1e-3
