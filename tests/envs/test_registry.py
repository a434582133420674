"""Every registered environment (``gym_gridloc.ENV_IDS``) as a Gymnasium environment, Minigrid style:
check_env bare and made, the registry, same-seed determinism, pickling mid-episode, render modes,
the documented spaces and limits, keyword checks, and the environments in worker processes
(Gymnasium's AsyncVectorEnv with fork and spawn, stable-baselines3's SubprocVecEnv).

Every test is parametrised over the registry, so a new id is tested the day it is registered."""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # check_env and render_mode="human": no real window
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import inspect
import pickle
import re
from pathlib import Path

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator
import numpy as np
import pytest

from gym_gridloc import HMMBeliefWrapper
from tests.helpers import (
    CONFIG_IDS,
    CONFIGS,
    ENV_CLASSES,
    ENV_IDS,
    NAMESPACED_IDS,
    assert_same,
    assert_same_rollouts,
    rollout,
    run_check_env,
    run_python,
)


# -- check_env and the registry -----------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_unwrapped(env_id):
    run_check_env(gym.make(env_id).unwrapped)


@pytest.mark.parametrize("env_id", ENV_IDS + NAMESPACED_IDS)
def test_check_env_made(env_id):
    run_check_env(gym.make(env_id))


def test_check_env_ring_seed_dynamics():
    run_check_env(gym.make("RingSensor8x8-v0", dynamics="passive").unwrapped)


def test_registry_is_complete():
    assert set(ENV_IDS) == {"ColourGrid-v0", "RingSensor8x8-v0", "WindyMaze-v0", "DepthMaze-v0"}
    assert NAMESPACED_IDS == [f"gym_gridloc/{env_id}" for env_id in ENV_IDS]
    for env_id in ENV_IDS + NAMESPACED_IDS:
        assert env_id in gym.registry
        spec = gym.spec(env_id)
        assert spec.vector_entry_point is not None  # a native vector env for gym.make_vec


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_namespaced_id_is_the_same_environment(env_id):
    """``gym_gridloc/<id>`` (Gymnasium's namespaced ids) and ``<id>``: one registration each, the
    same entry point, limits and keywords, the same seeded episodes, single and vector."""
    plain, spaced = gym.spec(env_id), gym.spec(f"gym_gridloc/{env_id}")
    assert (spaced.namespace, spaced.name, spaced.version) == ("gym_gridloc", plain.name, plain.version)
    for field in ("entry_point", "vector_entry_point", "max_episode_steps", "kwargs"):
        assert getattr(spaced, field) == getattr(plain, field), field
    assert_same_rollouts(rollout(gym.make(f"gym_gridloc/{env_id}"), seed=9, n_steps=60), rollout(gym.make(env_id), seed=9, n_steps=60))
    a = gym.make_vec(f"gym_gridloc/{env_id}", num_envs=2, vectorization_mode="vector_entry_point")
    b = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    for i, (x, y) in enumerate(zip((*a.reset(seed=4), *a.step(np.array([0, 1]))), (*b.reset(seed=4), *b.step(np.array([0, 1]))))):
        assert_same(x, y, f"vector reset and step, field {i}")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_vector_entry_point_adds_the_belief_as_documented(env_id):
    """``make_vec(..., "vector_entry_point")`` observes the reading and the exact belief (as
    ``HMMBeliefWrapper``); ``"sync"`` and ``"async"`` vectorize the single environment, whose
    observation is the reading alone; ``wrappers=[HMMBeliefWrapper]`` and ``belief=None`` make them
    agree.  The environment's docstring and docs/environments.md say so."""
    native = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    sync = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync")
    assert set(native.single_observation_space) == {"observation", "belief"}
    assert sync.single_observation_space == gym.make(env_id).observation_space
    wrapped = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync", wrappers=[HMMBeliefWrapper])
    assert wrapped.single_observation_space == native.single_observation_space
    bare = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", belief=None)
    assert bare.single_observation_space == sync.single_observation_space
    cls = load_env_creator(gym.spec(env_id).entry_point)
    docs = (Path(__file__).resolve().parents[2] / "docs" / "environments.md").read_text(encoding="utf-8")
    for text in (inspect.getdoc(cls), docs):
        assert "vector_entry_point" in text and "HMMBeliefWrapper" in text and "belief=None" in text


def test_make_without_import_prefix():
    env = gym.make("gym_gridloc:WindyMaze-v0")
    assert env.unwrapped.spec.id == "WindyMaze-v0"
    # In a fresh interpreter, where nothing has imported gym_gridloc yet.
    code = (
        "import sys, gymnasium as gym\n"
        "assert 'gym_gridloc' not in sys.modules\n"
        "out = []\n"
        "for i in ('ColourGrid-v0', 'RingSensor8x8-v0', 'WindyMaze-v0', 'DepthMaze-v0'):\n"
        "    env = gym.make('gym_gridloc:' + i)\n"
        "    env.reset(seed=0); env.step(0)\n"
        "    out += [env.spec.id, env.spec.max_episode_steps]\n"
        "print(*out)\n"
    )
    assert run_python(code).split() == ["ColourGrid-v0", "100", "RingSensor8x8-v0", "400", "WindyMaze-v0", "100",
                                        "DepthMaze-v0", "100"]


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_spaces_as_documented(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    model = env.unwrapped.model
    # N, E, S, W everywhere (SPEC section 1; the passive dynamics ignore the action), but the
    # depth maze's robot turns left or right or moves forward.
    expected_actions = {"DepthMaze-v0": gym.spaces.Discrete(3)}.get(env_id, gym.spaces.Discrete(4))
    assert env.action_space == expected_actions
    expected_obs = {
        "ColourGrid-v0": gym.spaces.Discrete(4),
        "RingSensor8x8-v0": gym.spaces.Discrete(8 * 8 + 1),
        "WindyMaze-v0": gym.spaces.MultiBinary(4),
        "DepthMaze-v0": gym.spaces.Discrete(7 - 2 + 1),
    }[env_id]
    assert env.observation_space == expected_obs
    assert model.shape == {"ColourGrid-v0": (5, 5), "RingSensor8x8-v0": (8, 8), "WindyMaze-v0": (6, 7),
                           "DepthMaze-v0": (7, 7)}[env_id]
    # A perfect 7 x 7 maze: 9 rooms joined by 8 opened walls.
    assert model.grid.n_free == {"ColourGrid-v0": 19, "RingSensor8x8-v0": 64, "WindyMaze-v0": 31, "DepthMaze-v0": 17}[env_id]


@pytest.mark.parametrize("env_id,steps", [("ColourGrid-v0", 100), ("RingSensor8x8-v0", 400), ("WindyMaze-v0", 100),
                                          ("DepthMaze-v0", 100)])
def test_truncated_at_max_episode_steps(env_id, steps):
    assert gym.spec(env_id).max_episode_steps == steps
    # With threshold 1 an episode (practically) never localises, so it runs to the limit.
    env = gym.make(env_id, localise_threshold=1.0)
    env.reset(seed=3)
    for t in range(1, steps + 1):
        _, _, terminated, truncated, _ = env.step(t % env.action_space.n)
        assert terminated is False
        assert truncated is (t == steps)


# -- determinism, pickling, Gymnasium's vector envs ------------------------------------------------------
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_same_seed_same_trajectory(env_id, kwargs):
    ra = rollout(gym.make(env_id, **kwargs), seed=123, n_steps=150)
    rb = rollout(gym.make(env_id, **kwargs), seed=123, n_steps=150)
    assert_same_rollouts(ra, rb)
    # A different seed gives a different trajectory (the seed is used).
    rc = rollout(gym.make(env_id, **kwargs), seed=124, n_steps=150)
    assert [r[-1]["position"] for r in ra] != [r[-1]["position"] for r in rc]


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_reseeding_restarts_the_same_trajectory(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    ra = rollout(env, seed=7, n_steps=40)
    rb = rollout(env, seed=7, n_steps=40)
    assert_same_rollouts(ra, rb)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_pickle_mid_episode_continues_identically(env_id, kwargs):
    for env in (gym.make(env_id, **kwargs), gym.make(env_id, **kwargs).unwrapped):
        env.reset(seed=5)
        n = env.action_space.n
        for a in (0, 1, 2):
            env.step(a % n)
        clone = pickle.loads(pickle.dumps(env))
        assert clone.unwrapped.state == env.unwrapped.state
        np.testing.assert_array_equal(clone.unwrapped.posterior, env.unwrapped.posterior)
        ra = [env.step(a % n) for a in (3, 3, 2, 1, 0, 0, 1)]
        rb = [clone.step(a % n) for a in (3, 3, 2, 1, 0, 0, 1)]
        for i, (x, y) in enumerate(zip(ra, rb)):
            for j, (u, v) in enumerate(zip(x, y)):
                assert_same(u, v, f"step {i}, field {j}")


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_sync_vector_env_matches_single_envs(env_id, kwargs):
    seeds = [11, 12]
    venv = gym.vector.SyncVectorEnv([lambda: gym.make(env_id, **kwargs) for _ in seeds])
    singles = [gym.make(env_id, **kwargs) for _ in seeds]
    vobs, vinfo = venv.reset(seed=seeds)
    sobs = [e.reset(seed=s)[0] for e, s in zip(singles, seeds)]
    for i in range(2):
        np.testing.assert_array_equal(np.asarray(vobs)[i], np.asarray(sobs[i]))
    rng = np.random.default_rng(0)
    pending_reset = [False, False]  # gymnasium's default autoreset: the step after an episode end resets
    n_resets = 0
    for _ in range(80):
        actions = rng.integers(0, venv.single_action_space.n, size=2)
        vobs, vrew, vterm, vtrunc, vinfo = venv.step(actions)
        assert vobs in venv.observation_space
        assert vrew.dtype.kind == "f"
        for i, e in enumerate(singles):
            if pending_reset[i]:
                o, info = e.reset()
                r, te, tr = 0.0, False, False
                n_resets += 1
            else:
                o, r, te, tr, info = e.step(int(actions[i]))
                assert r == -1.0
            assert vrew[i] == r
            np.testing.assert_array_equal(np.asarray(vobs)[i], np.asarray(o))
            assert vterm[i] == te and vtrunc[i] == tr
            assert tuple(vinfo["position"][i]) == info["position"]
            assert vinfo["confidence"][i] == info["confidence"]
            pending_reset[i] = te or tr
    venv.close()


# -- rendering -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_render_ansi(env_id, kwargs):
    env = gym.make(env_id, render_mode="ansi", **kwargs)
    env.reset(seed=0)
    env.step(env.action_space.n - 1)
    text = env.render()
    assert isinstance(text, str)
    model = env.unwrapped.model
    h, w = model.shape
    lines = text.rstrip("\n").splitlines()
    table = lines[-h:]
    assert len(table) == h
    for r, line in enumerate(table):
        cells = line.split()
        assert len(cells) == w
        for c, cell in enumerate(cells):
            if not model.grid.free[r, c]:
                assert cell.startswith("####")
            else:
                assert float(cell.rstrip("*")) == pytest.approx(100 * env.unwrapped.posterior[r, c], abs=0.006)
    assert text.count("*") >= 1  # the true position is marked


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_render_rgb_array(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    frames = [env.render()]
    env.step(env.action_space.n - 1)
    frames.append(env.render())
    for frame in frames:
        assert isinstance(frame, np.ndarray)
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
        assert frame.shape[0] >= env.unwrapped.model.shape[0] and frame.shape[1] >= env.unwrapped.model.shape[1]
        assert frame.std() > 0  # not a blank image


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_human_with_dummy_video_driver(env_id, monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    env = gym.make(env_id, render_mode="human")
    env.unwrapped.metadata = {**env.unwrapped.metadata, "render_fps": 1000}  # keep the test fast
    env.reset(seed=0)
    env.step(0)
    assert env.render() is None
    env.close()


# -- keyword checks --------------------------------------------------------------------------------------
NOT_PROBABILITIES = {"localise_threshold", "render_mode", "layout", "size", "dynamics"}


def probability_kwargs():
    """(env id, keyword) for every probability keyword of every registered environment: the
    float-valued keywords with a default in [0, 1] (so a new one is tested automatically)."""
    out = []
    for env_id in ENV_IDS:
        for name, p in inspect.signature(ENV_CLASSES[env_id].__init__).parameters.items():
            if name in NOT_PROBABILITIES or not isinstance(p.default, float):
                continue
            assert 0.0 <= p.default <= 1.0, (env_id, name)
            out.append((env_id, name))
    return out


PROB_KWARGS = probability_kwargs()


def test_probability_keywords_are_found():
    names = {n for _, n in PROB_KWARGS}
    assert {"slip", "accuracy", "keep_heading", "p_true", "p_ring1", "p_ring2", "drift", "p_detect",
            "p_false_alarm", "kidnap_prob"} <= names


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), float("inf"), -1e-9, 1 + 1e-9])
@pytest.mark.parametrize("env_id,name", PROB_KWARGS, ids=[f"{e}-{n}" for e, n in PROB_KWARGS])
def test_probability_outside_unit_interval(env_id, name, value):
    with pytest.raises(ValueError, match=rf"^{name} must be (a probability )?in \[0, 1"):
        gym.make(env_id, **{name: value})


@pytest.mark.parametrize("value", ["0.5", None, True, [0.5]])
@pytest.mark.parametrize("env_id,name", PROB_KWARGS, ids=[f"{e}-{n}" for e, n in PROB_KWARGS])
def test_probability_of_the_wrong_type(env_id, name, value):
    with pytest.raises(TypeError, match=rf"^{name} must be a probability \(a number in \[0, 1\]\), got {re.escape(repr(value))}"):
        gym.make(env_id, **{name: value})


@pytest.mark.parametrize("value", [0, 0.0, -0.1, 1.5, float("nan"), float("inf")])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_localise_threshold_outside_open_closed_interval(env_id, value):
    with pytest.raises(ValueError, match=rf"^localise_threshold must be in \(0, 1\], got {re.escape(repr(value))}"):
        gym.make(env_id, localise_threshold=value)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_localise_threshold_of_the_wrong_type(env_id):
    with pytest.raises(TypeError, match=r"^localise_threshold must be a number in \(0, 1\], got 'high'"):
        gym.make(env_id, localise_threshold="high")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_env_option_sets_the_simulated_and_referee_model(env_id):
    env = gym.make(env_id, kidnap_prob=0.05)
    assert env.unwrapped.model.kidnap_prob == 0.05
    assert env.unwrapped._referee.model is env.unwrapped.model
    assert gym.make(env_id).unwrapped.model.kidnap_prob == 0.0  # off by default
    with pytest.raises(ValueError, match="kidnap_prob"):
        gym.make(env_id, kidnap_prob=1.5)
    with pytest.raises(TypeError, match="kidnap_prob"):
        gym.make(env_id, kidnap_prob="often")


# -- worker processes ------------------------------------------------------------------------------------
# Gymnasium's AsyncVectorEnv and stable-baselines3's SubprocVecEnv (2 workers each) give exactly what
# SyncVectorEnv / DummyVecEnv give in one process, for the same seeds.  Kept short: process start-up
# is the slow part.
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


PROCESS_CASES = [(env_id, wrap, {}) for env_id in ENV_IDS for wrap in (None, "dict")] + [
    ("RingSensor8x8-v0", "full", {"dynamics": "passive"}),
    ("WindyMaze-v0", "flat", {}),
]
PROCESS_IDS = [f"{e}-{w or 'bare'}{'-passive' if kw else ''}" for e, w, kw in PROCESS_CASES]


@pytest.mark.parametrize("env_id,wrap,kwargs", PROCESS_CASES, ids=PROCESS_IDS)
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
