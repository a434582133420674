"""The registered environments as Gymnasium environments (issue 2).

Every test is parametrised over the registry (``gym_gridloc.ENV_IDS``), so a new id is tested the
day it is registered.  The last part checks that the simulator samples exactly the model's
probabilities (the same model object the filter multiplies).
"""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # check_env and render_mode="human": no real window
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import math
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gym_gridloc
from gym_gridloc import colour_grid_model, ring_sensor_model, windy_maze_model

ENV_IDS = list(gym_gridloc.ENV_IDS)
# Every registered id, plus the ring sensor's other dynamics (hidden heading).
CONFIGS = [(env_id, {}) for env_id in ENV_IDS] + [("RingSensor8x8-v0", {"dynamics": "seed"})]
CONFIG_IDS = [f"{i}{'-' + '-'.join(f'{k}={v}' for k, v in kw.items()) if kw else ''}" for i, kw in CONFIGS]
INFO_KEYS = {"position", "estimate", "confidence", "error", "localised", "success", "entropy"}
WRAPPED_WARNING = "is different from the unwrapped version"


def run_check_env(env) -> None:
    """``check_env`` with every warning turned into a failure, except the one saying a wrapped env
    is being checked (we check wrapped envs on purpose)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    unexpected = [str(w.message) for w in caught if WRAPPED_WARNING not in str(w.message)]
    assert not unexpected, unexpected


def assert_same(a, b, where="") -> None:
    """Exact equality of nested observations / infos, including types of scalars."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), f"{where}: keys {a.keys()} != {b.keys()}"
        for k in a:
            assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b), f"{where}: {a!r} != {b!r}"
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} != {b!r}"


def rollout(env, seed: int, n_steps: int, action_seed: int = 0) -> list:
    """``n_steps`` steps with fixed random actions, resetting (unseeded) when an episode ends."""
    actions = np.random.default_rng(action_seed).integers(0, env.action_space.n, size=n_steps)
    obs, info = env.reset(seed=seed)
    out = [("reset", obs, info)]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(int(a))
        out.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            out.append(("reset", obs, info))
    return out


def assert_same_rollouts(ra: list, rb: list) -> None:
    assert len(ra) == len(rb)
    for i, (x, y) in enumerate(zip(ra, rb)):
        for j, (u, v) in enumerate(zip(x, y)):
            assert_same(u, v, f"record {i}, field {j}")


# -- check_env ---------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_unwrapped(env_id):
    run_check_env(gym.make(env_id).unwrapped)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_made(env_id):
    run_check_env(gym.make(env_id))


def test_check_env_ring_seed_dynamics():
    run_check_env(gym.make("RingSensor8x8-v0", dynamics="seed").unwrapped)


def test_registry_is_complete():
    assert set(ENV_IDS) == {"ColourGrid-v0", "RingSensor8x8-v0", "WindyMaze-v0"}
    for env_id in ENV_IDS:
        assert env_id in gym.registry


def test_make_without_import_prefix():
    env = gym.make("gym_gridloc:WindyMaze-v0")
    assert env.unwrapped.spec.id == "WindyMaze-v0"
    # In a fresh interpreter, where nothing has imported gym_gridloc yet.
    code = (
        "import sys, gymnasium as gym\n"
        "assert 'gym_gridloc' not in sys.modules\n"
        "for i in ('ColourGrid-v0', 'RingSensor8x8-v0', 'WindyMaze-v0'):\n"
        "    env = gym.make('gym_gridloc:' + i)\n"
        "    env.reset(seed=0); env.step(0)\n"
        "    print(env.spec.id, env.spec.max_episode_steps)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["ColourGrid-v0", "100", "RingSensor8x8-v0", "400", "WindyMaze-v0", "100"]


# -- determinism, pickling, vector envs ----------------------------------------------------------
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


# -- rendering ---------------------------------------------------------------------------------
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


def test_render_without_mode_warns_and_returns_none():
    env = gym.make("WindyMaze-v0").unwrapped
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


# -- episodes and info -------------------------------------------------------------------------
def entropy_bits(p: np.ndarray) -> float:
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def check_info(env, info) -> None:
    u = env.unwrapped
    post = u.posterior
    model = u.model
    assert INFO_KEYS <= set(info)
    pos, est = info["position"], info["estimate"]
    assert isinstance(pos, tuple) and len(pos) == 2 and all(isinstance(v, int) for v in pos)
    assert isinstance(est, tuple) and len(est) == 2 and all(isinstance(v, int) for v in est)
    assert pos == u.state[1:]
    assert model.grid.free[pos] and model.grid.free[est]
    assert isinstance(info["confidence"], float) and info["confidence"] == post.max() == post[est]
    assert isinstance(info["error"], int) and info["error"] == abs(pos[0] - est[0]) + abs(pos[1] - est[1])
    assert type(info["localised"]) is bool
    assert info["localised"] == (info["confidence"] >= u.localise_threshold)
    assert type(info["success"]) is bool and info["success"] == (info["localised"] and est == pos)
    assert isinstance(info["entropy"], float)
    assert info["entropy"] == pytest.approx(entropy_bits(post), abs=1e-9)
    assert 0.0 <= info["entropy"] <= math.log2(model.grid.n_free) + 1e-9
    assert abs(post.sum() - 1.0) < 1e-9 and np.all(post[~model.grid.free] == 0)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_info_keys_rewards_and_termination(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    rng = np.random.default_rng(1)
    n_terminated = 0
    for episode in range(4):
        obs, info = env.reset(seed=100 + episode)
        assert obs in env.observation_space
        check_info(env, info)
        for t in range(env.spec.max_episode_steps):
            obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
            assert obs in env.observation_space
            assert type(reward) is float and reward == -1.0
            assert type(terminated) is bool and type(truncated) is bool
            check_info(env, info)
            assert terminated == (info["confidence"] >= env.unwrapped.localise_threshold)
            if terminated or truncated:
                n_terminated += terminated
                break
    assert n_terminated >= 1  # episodes do end by localising


@pytest.mark.parametrize("env_id,steps", [("ColourGrid-v0", 100), ("RingSensor8x8-v0", 400), ("WindyMaze-v0", 100)])
def test_truncated_at_max_episode_steps(env_id, steps):
    assert gym.spec(env_id).max_episode_steps == steps
    # With threshold 1 an episode (practically) never localises, so it runs to the limit.
    env = gym.make(env_id, localise_threshold=1.0)
    env.reset(seed=3)
    for t in range(1, steps + 1):
        _, _, terminated, truncated, _ = env.step(t % 4)
        assert terminated is False
        assert truncated is (t == steps)


@pytest.mark.parametrize("threshold", [0.5, 0.75, 0.99])
def test_threshold_controls_termination(threshold):
    env = gym.make("WindyMaze-v0", localise_threshold=threshold)
    env.reset(seed=0)
    for t in range(100):
        _, _, terminated, truncated, info = env.step(t % 4)
        assert terminated == (info["confidence"] >= threshold)
        if terminated or truncated:
            break


def test_reset_option_state():
    env = gym.make("WindyMaze-v0").unwrapped
    _, info = env.reset(seed=0, options={"state": (5, 6)})
    assert info["position"] == (5, 6)
    env = gym.make("RingSensor8x8-v0", dynamics="seed").unwrapped
    _, info = env.reset(seed=0, options={"state": (2, 3, 4)})
    assert info["position"] == (3, 4) and info["heading"] == 2


# -- the simulator samples the model ---------------------------------------------------------------
MODELS = {
    "colour": lambda: colour_grid_model(),
    "windy": lambda: windy_maze_model(),
    "ring": lambda: ring_sensor_model((8, 8)),
    "ring-seed": lambda: ring_sensor_model((8, 8), dynamics="seed"),
}
ENV_OF_MODEL = {
    "colour": ("ColourGrid-v0", {}),
    "windy": ("WindyMaze-v0", {}),
    "ring": ("RingSensor8x8-v0", {}),
    "ring-seed": ("RingSensor8x8-v0", {"dynamics": "seed"}),
}
SIGMAS = 5.0


def assert_counts_match(counts: dict, probs: dict, n: int, what: str) -> None:
    """Each outcome's count is within 5 binomial standard deviations of n p (plus one count of
    slack for p near 0 or 1), and outcomes of probability 0 never occur."""
    for outcome, c in counts.items():
        assert probs.get(outcome, 0.0) > 0.0, f"{what}: sampled {outcome}, which the model gives probability 0"
    for outcome, p in probs.items():
        c = counts.get(outcome, 0)
        sd = math.sqrt(n * p * (1 - p))
        assert abs(c - n * p) <= SIGMAS * sd + 1, f"{what}: outcome {outcome}: {c} of {n}, expected {n * p:.1f} ± {sd:.1f}"


def pick_states(model, k: int, seed: int) -> list[tuple[int, int, int]]:
    rng = np.random.default_rng(seed)
    idx = rng.choice(model.n_states, size=min(k, model.n_states), replace=False)
    return [model.state_of_index(int(s)) for s in idx]


@pytest.mark.parametrize("name", list(MODELS))
def test_model_transitions_sum_to_one_and_sampler_matches(name):
    model = MODELS[name]()
    rng = np.random.default_rng(2024)
    n = 3000
    for state in pick_states(model, 8, seed=1):
        for a in range(model.n_actions):
            outcomes = model.outcomes(state, a)
            probs: dict = {}
            for nxt, p in outcomes:
                probs[nxt] = probs.get(nxt, 0.0) + p
            assert sum(probs.values()) == pytest.approx(1.0, abs=1e-12)
            counts: dict = {}
            for _ in range(n):
                nxt = model.sample_next_state(state, a, rng)
                counts[nxt] = counts.get(nxt, 0) + 1
            assert_counts_match(counts, probs, n, f"{name} state {state} action {a}")


@pytest.mark.parametrize("name", list(MODELS))
def test_env_steps_sample_the_model(name):
    """Stepping the environment from a chosen state lands where ``model.outcomes`` says, and the
    first reading at a state follows ``model.sensor.distribution``."""
    env_id, kwargs = ENV_OF_MODEL[name]
    env = gym.make(env_id, **kwargs).unwrapped
    model = env.model
    n = 2000
    env.reset(seed=77)
    for state in pick_states(model, 3, seed=2):
        a = model.n_actions - 1
        probs: dict = {}
        for nxt, p in model.outcomes(state, a):
            key = nxt if model.n_layers > 1 else nxt[1:]
            probs[key] = probs.get(key, 0.0) + p
        readings, rprobs = model.sensor.distribution(state[1], state[2])
        assert rprobs.sum() == pytest.approx(1.0, abs=1e-12)
        rdist: dict = {}
        for rd, p in zip(readings.tolist(), rprobs.tolist()):
            if p > 0:
                rdist[rd] = rdist.get(rd, 0.0) + p
        moves: dict = {}
        reads: dict = {}
        start = state if model.n_layers > 1 else state[1:]
        for _ in range(n):
            obs, _ = env.reset(options={"state": start})
            rd = model.sensor.to_reading(obs)
            reads[rd] = reads.get(rd, 0) + 1
            _, _, _, _, info = env.step(a)
            key = (info["heading"], *info["position"]) if model.n_layers > 1 else info["position"]
            moves[key] = moves.get(key, 0) + 1
        assert_counts_match(moves, probs, n, f"{name} env step from {state}")
        assert_counts_match(reads, rdist, n, f"{name} env reading at {state}")


@pytest.mark.parametrize("name", list(MODELS))
def test_sensor_sampler_matches_distribution_everywhere(name):
    """Pooled over every free cell: a chi-square test of sampled readings against
    ``model.sensor.distribution`` (fixed seed; rejects only at p < 1e-6)."""
    from scipy import stats

    model = MODELS[name]()
    rng = np.random.default_rng(9)
    n = 400
    chi2, dof = 0.0, 0
    for r, c in model.grid.free_cells[:: max(1, model.grid.n_free // 24)]:
        readings, probs = model.sensor.distribution(int(r), int(c))
        assert probs.sum() == pytest.approx(1.0, abs=1e-12)
        expected = {int(k): 0.0 for k in readings}
        for k, p in zip(readings.tolist(), probs.tolist()):
            expected[int(k)] += p * n
        counts = {k: 0 for k in expected}
        for _ in range(n):
            k = model.sample_reading((0, int(r), int(c)), rng)
            assert expected.get(k, 0.0) > 0.0, f"reading {k} at {(r, c)} has probability 0"
            counts[k] += 1
        # Pool outcomes with small expectations so the chi-square approximation holds.
        small_obs, small_exp = 0, 0.0
        for k, e in expected.items():
            if e == 0:
                continue
            if e < 5:
                small_obs += counts[k]
                small_exp += e
            else:
                chi2 += (counts[k] - e) ** 2 / e
                dof += 1
        if small_exp > 0:
            chi2 += (small_obs - small_exp) ** 2 / small_exp
            dof += 1
        dof -= 1
    assert stats.chi2.sf(chi2, dof) > 1e-6, (chi2, dof)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_spaces_as_documented(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    model = env.unwrapped.model
    # N, E, S, W everywhere (SPEC section 1); the seed dynamics ignore the action.
    assert env.action_space == gym.spaces.Discrete(4)
    expected_obs = {
        "ColourGrid-v0": gym.spaces.Discrete(4),
        "RingSensor8x8-v0": gym.spaces.Discrete(8 * 8 + 1),
        "WindyMaze-v0": gym.spaces.MultiBinary(4),
    }[env_id]
    assert env.observation_space == expected_obs
    assert model.shape == {"ColourGrid-v0": (5, 5), "RingSensor8x8-v0": (8, 8), "WindyMaze-v0": (6, 7)}[env_id]
    assert model.grid.n_free == {"ColourGrid-v0": 19, "RingSensor8x8-v0": 64, "WindyMaze-v0": 31}[env_id]
