"""Environments and wrappers in worker processes (issue 5, item 6).

Gymnasium's ``AsyncVectorEnv`` and stable-baselines3's ``SubprocVecEnv`` (2 workers each) give
exactly what ``SyncVectorEnv`` / ``DummyVecEnv`` give in one process, for the same seeds.
Kept short: process start-up is the slow part.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import HMMBeliefWrapper

ENV_IDS = list(gym_gridloc.ENV_IDS)
N_STEPS = 40


def make_env(env_id: str, wrap: str | None = None, **kwargs):
    """A picklable thunk (no lambda over loop variables) for vector envs."""

    def thunk():
        env = gym.make(env_id, **kwargs)
        if wrap == "dict":
            env = HMMBeliefWrapper(env)
        elif wrap == "flat":
            env = HMMBeliefWrapper(env, flatten=True)
        elif wrap == "full":
            env = HMMBeliefWrapper(env, full_state=True)
        return env

    return thunk


def as_arrays(x):
    return {k: np.asarray(v) for k, v in x.items()} if isinstance(x, dict) else np.asarray(x)


def assert_equal_nested(a, b, where=""):
    if isinstance(a, dict):
        assert set(a) == set(b), f"{where}: {set(a)} != {set(b)}"
        for k in a:
            assert_equal_nested(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)) and not isinstance(a, np.ndarray) and a and isinstance(a[0], dict):
        assert len(a) == len(b)
        for i, (u, v) in enumerate(zip(a, b)):
            assert_equal_nested(u, v, f"{where}[{i}]")
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=where)


def gym_run(venv, seeds, n_steps=N_STEPS):
    rng = np.random.default_rng(0)
    obs, info = venv.reset(seed=seeds)
    records = [(as_arrays(obs), info)]
    for _ in range(n_steps):
        actions = rng.integers(0, venv.single_action_space.n, size=venv.num_envs)
        obs, rew, term, trunc, info = venv.step(actions)
        assert obs in venv.observation_space
        records.append((as_arrays(obs), rew, term, trunc, info))
    venv.close()
    return records


CASES = [(env_id, wrap, {}) for env_id in ENV_IDS for wrap in (None, "dict")] + [
    ("RingSensor8x8-v0", "full", {"dynamics": "seed"}),
    ("WindyMaze-v0", "flat", {}),
]
CASE_IDS = [f"{e}-{w or 'bare'}{'-seed' if kw else ''}" for e, w, kw in CASES]


@pytest.mark.parametrize("env_id,wrap,kwargs", CASES, ids=CASE_IDS)
def test_async_vector_env_matches_sync(env_id, wrap, kwargs):
    fns = [make_env(env_id, wrap, **kwargs) for _ in range(2)]
    seeds = [21, 22]
    sync = gym_run(gym.vector.SyncVectorEnv(fns), seeds)
    asyn = gym_run(gym.vector.AsyncVectorEnv(fns), seeds)
    assert len(sync) == len(asyn)
    for i, (x, y) in enumerate(zip(sync, asyn)):
        for j, (u, v) in enumerate(zip(x, y)):
            assert_equal_nested(u, v, f"record {i}, field {j}")


def test_async_vector_env_with_spawned_workers():
    """Workers started by ``spawn`` import everything afresh: the environments must be importable
    and picklable, not only inherited by fork."""
    fns = [make_env("WindyMaze-v0", "flat") for _ in range(2)]
    seeds = [5, 6]
    sync = gym_run(gym.vector.SyncVectorEnv(fns), seeds, n_steps=10)
    asyn = gym_run(gym.vector.AsyncVectorEnv(fns, context="spawn"), seeds, n_steps=10)
    for x, y in zip(sync, asyn):
        for u, v in zip(x, y):
            assert_equal_nested(u, v)


def sb3_run(venv, seed, n_steps=N_STEPS):
    venv.seed(seed)
    obs = venv.reset()
    records = [(as_arrays(obs),)]
    rng = np.random.default_rng(1)
    for _ in range(n_steps):
        actions = rng.integers(0, venv.action_space.n, size=venv.num_envs)
        obs, rew, done, infos = venv.step(actions)
        records.append((as_arrays(obs), rew, done, infos))
    venv.close()
    return records


# stable-baselines3's default start method (forkserver) costs seconds per worker pool: one case
# uses it, the others fork.
SB3_CASES = [("ColourGrid-v0", "flat", None)] + [(e, "flat", "fork") for e in ENV_IDS[1:]] + [
    ("ColourGrid-v0", "dict", "fork")]


@pytest.mark.parametrize("env_id,wrap,start_method", SB3_CASES)
def test_sb3_subproc_vec_env_matches_dummy(env_id, wrap, start_method):
    vec_env = pytest.importorskip("stable_baselines3.common.vec_env")
    fns = [make_env(env_id, wrap) for _ in range(2)]
    single = sb3_run(vec_env.DummyVecEnv(fns), seed=31)
    multi = sb3_run(vec_env.SubprocVecEnv(fns, start_method=start_method), seed=31)
    assert len(single) == len(multi)
    n_done = 0
    for i, (x, y) in enumerate(zip(single, multi)):
        for j, (u, v) in enumerate(zip(x, y)):
            assert_equal_nested(u, v, f"record {i}, field {j}")
        if len(x) > 2:
            n_done += int(np.sum(x[2]))
    if env_id != "RingSensor8x8-v0":  # episodes end (and auto-reset) within the run
        assert n_done >= 1
