"""Batched filtering and the native vector env equal the single environments (same seeds, 1e-12)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import gym_gridloc
from gym_gridloc import BatchFilter, ForwardFilter, ImpossibleObservationError
from gym_gridloc.generators import colour_map, maze_map

CASES = [
    ("ColourGrid-v0", {}),
    ("ColourGrid-v0", {"size": (7, 8), "n_colours": 5, "kidnap_prob": 0.05}),
    ("WindyMaze-v0", {}),
    ("WindyMaze-v0", {"size": (9, 8), "map_seed": 2}),
    ("RingSensor8x8-v0", {"size": (5, 6), "localise_threshold": 0.6}),
    ("RingSensor8x8-v0", {"size": (5, 5), "dynamics": "seed", "localise_threshold": 0.5}),
    ("RingSensor8x8-v0", {"layout": ["OOOOO", "O#O#O", "OOOOO", "O#OOO"], "localise_threshold": 0.6}),
]


def _models():
    return [
        gym_gridloc.colour_grid_model(colour_map((9, 11), seed=1)),
        gym_gridloc.colour_grid_model(slip=1.0),
        gym_gridloc.colour_grid_model().with_kidnapping(0.05),
        gym_gridloc.windy_maze_model(maze_map((8, 9), seed=2)),
        gym_gridloc.ring_sensor_model((7, 6)),
        gym_gridloc.ring_sensor_model((6, 5), dynamics="seed"),
    ]


def assert_batch_equals_singles(model, n: int, steps: int, seed: int) -> None:
    """``BatchFilter`` over ``n`` simulated robots equals ``n`` single ``ForwardFilter``s within
    1e-12 after every step (beliefs and log-likelihoods)."""
    rng = np.random.default_rng(seed)
    states = [model.sample_initial_state(rng) for _ in range(n)]
    obs = [model.sensor.to_observation(model.sample_reading(s, rng)) for s in states]
    singles = [ForwardFilter(model).reset(o) for o in obs]
    batch = BatchFilter(model, n).reset(np.array(obs))
    for _ in range(steps):
        actions = rng.integers(0, model.n_actions, n)
        states = [model.sample_next_state(s, int(a), rng) for s, a in zip(states, actions)]
        obs = [model.sensor.to_observation(model.sample_reading(s, rng)) for s in states]
        for f, a, o in zip(singles, actions, obs):
            f.step(int(a), o)
        batch.step(actions, np.array(obs))
        for i, f in enumerate(singles):
            np.testing.assert_allclose(batch.beliefs[i], f.full_belief, rtol=0, atol=1e-12)
            np.testing.assert_allclose(batch.log_likelihood[i], f.log_likelihood, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("model", _models(), ids=repr)
def test_batch_filter_equals_single_filters(model):
    assert_batch_equals_singles(model, n=7, steps=25, seed=1)


def test_batch_filter_mask_and_errors():
    model = gym_gridloc.colour_grid_model(accuracy=1.0)
    batch = BatchFilter(model, 3)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step([0, 0, 0], [0, 0, 0])
    batch.reset(np.array([0, 1, 2]))
    before = batch.beliefs.copy()
    batch.step(np.array([1, 1, 1]), np.array([0, 1, 2]), mask=np.array([True, False, True]))
    assert np.array_equal(batch.beliefs[1], before[1])
    assert not np.array_equal(batch.beliefs[0], before[0])
    with pytest.raises(ValueError, match="action 4 of belief 2"):
        batch.step(np.array([0, 0, 4]), np.array([0, 0, 0]))
    with pytest.raises(ValueError, match="observation"):
        batch.step(np.array([0, 0, 0]), np.array([0, 0, 9]))
    with pytest.raises(ValueError, match="n \\(the number of beliefs\\)"):
        BatchFilter(model, 0)
    # Colour 3 (Y) where no reachable cell is yellow under a perfect sensor: impossible for belief 0.
    single = ForwardFilter(model).reset(0)
    reachable = model.predict(single.full_belief, 0)[0] > 0
    impossible = [c for c in range(4) if not np.any(reachable & (model.grid.labels == c))]
    if impossible:
        kept = batch.beliefs.copy()
        with pytest.raises(ImpossibleObservationError, match="belief 0"):
            b2 = BatchFilter(model, 1).reset(np.array([0]))
            b2.step(np.array([0]), np.array([impossible[0]]))
        assert np.array_equal(batch.beliefs, kept)


def _compare_runs(env_id, kwargs, n=4, steps=150, seed=3):
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", belief=True, **kwargs)
    sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", wrappers=[gym_gridloc.HMMBeliefWrapper], **kwargs)
    assert native.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert native.single_observation_space == sync.single_observation_space
    o1, i1 = native.reset(seed=seed)
    o2, i2 = sync.reset(seed=seed)
    rng = np.random.default_rng(0)
    episodes_ended = 0
    for t in range(steps):
        assert native.observation_space.contains(o1)
        np.testing.assert_array_equal(o1["observation"], o2["observation"])
        np.testing.assert_allclose(o1["belief"], o2["belief"], rtol=0, atol=1e-7)
        singles = np.stack([e.get_wrapper_attr("filter").full_belief for e in sync.envs])
        np.testing.assert_allclose(native.unwrapped.beliefs, singles, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(i1["position"], np.array([list(p) for p in i2["position"]]))
        # The estimate is an argmax: where two cells tie exactly in exact arithmetic, rounding
        # (1e-16) may pick either; both must be most probable within 1e-12.
        pos_beliefs = singles.sum(axis=1)
        for i, (r, c) in enumerate(i1["estimate"]):
            assert pos_beliefs[i, r, c] >= pos_beliefs[i].max() - 1e-12
            if (r, c) == tuple(i2["estimate"][i]):
                assert i1["success"][i] == i2["success"][i] and i1["error"][i] == i2["error"][i]
        np.testing.assert_allclose(i1["confidence"], i2["confidence"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(i1["entropy"], i2["entropy"], rtol=0, atol=1e-9)
        actions = rng.integers(0, native.single_action_space.n, n)
        o1, r1, te1, tr1, i1 = native.step(actions)
        o2, r2, te2, tr2, i2 = sync.step(actions)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        episodes_ended += int(te1.sum() + tr1.sum())
    return episodes_ended


@pytest.mark.parametrize("env_id,kwargs", CASES, ids=[f"{e}-{k}" for e, k in CASES])
def test_native_vector_env_equals_sync_vector_env_of_wrapped_envs(env_id, kwargs):
    ended = _compare_runs(env_id, kwargs)
    assert ended > 0  # autoresets were exercised


def test_truncation_and_seed_lists():
    ended = _compare_runs("RingSensor8x8-v0", {"max_episode_steps": 7}, n=3, steps=30, seed=9)
    assert ended >= 9
    native = gym.make_vec("WindyMaze-v0", num_envs=3, vectorization_mode="vector_entry_point")
    single = gym_gridloc.HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    obs, _ = native.reset(seed=[5, 6, 7])
    one, _ = single.reset(seed=6)
    np.testing.assert_array_equal(obs["observation"][1], one["observation"])
    np.testing.assert_array_equal(obs["belief"][1], one["belief"])


def test_readings_only_and_flat_observations():
    n = 3
    native = gym.make_vec("WindyMaze-v0", num_envs=n, vectorization_mode="vector_entry_point", belief=False)
    sync = gym.make_vec("WindyMaze-v0", num_envs=n, vectorization_mode="sync")
    assert native.single_observation_space == sync.single_observation_space
    o1, _ = native.reset(seed=1)
    o2, _ = sync.reset(seed=1)
    for _ in range(40):
        np.testing.assert_array_equal(o1, o2)
        a = np.array([0, 1, 2])
        o1, *_ = native.step(a)
        o2, *_ = sync.step(a)
    flat = gym.make_vec("ColourGrid-v0", num_envs=n, vectorization_mode="vector_entry_point", flatten=True)
    ref = gym.make_vec("ColourGrid-v0", num_envs=n, vectorization_mode="sync",
                       wrappers=[lambda e: gym_gridloc.HMMBeliefWrapper(e, flatten=True)])
    o1, _ = flat.reset(seed=2)
    o2, _ = ref.reset(seed=2)
    for _ in range(20):
        np.testing.assert_allclose(o1, o2, atol=1e-7)
        assert flat.observation_space.contains(o1)
        o1, *_ = flat.step(np.array([1, 2, 3]))
        o2, *_ = ref.step(np.array([1, 2, 3]))


def test_same_step_autoreset_gives_final_observations():
    env = gym.make_vec("ColourGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                       autoreset_mode=AutoresetMode.SAME_STEP, max_episode_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        obs, rew, term, trunc, info = env.step(np.zeros(4, dtype=np.int64))
    done = term | trunc
    assert done.all()  # every episode ends by the 5th step at the latest
    assert np.array_equal(info["_final_obs"], done)
    assert set(info["final_obs"][0]) == {"observation", "belief"}
    assert np.all(env.unwrapped._elapsed == 0)  # already reset


def test_vector_env_arguments_are_checked():
    with pytest.raises(ValueError, match="new_map_each_reset"):
        gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point", new_map_each_reset=True)
    env = gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([0, 0]))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action 7 of env 1"):
        env.step(np.array([0, 7]))
    with pytest.raises(ValueError, match="actions must be 2 integers"):
        env.step(np.array([0, 1, 2]))
    with pytest.raises(TypeError, match="belief"):
        gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point", belief="yes")


def test_stable_baselines3_trains_on_the_adapter():
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import VecMonitor

    from gym_gridloc.vector import SB3VecEnv

    venv = SB3VecEnv.make("WindyMaze-v0", 8)
    venv.seed(4)
    obs = venv.reset()
    assert obs["belief"].shape == (8, 6, 7)
    # SB3's same-step autoreset: the finished episode's last observation is in the info.
    seen = False
    for _ in range(300):
        obs, rewards, dones, infos = venv.step(np.zeros(8, dtype=np.int64))
        assert rewards.dtype == np.float32
        for i in np.flatnonzero(dones):
            seen = True
            assert set(infos[i]["terminal_observation"]) == {"observation", "belief"}
            assert "TimeLimit.truncated" in infos[i]
    assert seen
    model = sb3.PPO("MultiInputPolicy", VecMonitor(SB3VecEnv.make("ColourGrid-v0", 4)), n_steps=64,
                    batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(512)
    assert model.num_timesteps >= 512


def test_vector_env_draws_the_same_numbers_as_numpy():
    """The vector env computes ``random()`` and ``integers(n)`` from raw outputs in blocks; they
    equal numpy's own draws, including Lemire's rare redraws (large n) and the buffered half."""
    from gymnasium.utils import seeding

    env = gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point").unwrapped
    env.reset(seed=[11, 12])
    refs = [seeding.np_random(11)[0], seeding.np_random(12)[0]]
    # Replay what the reset drew (a start state and a reading) on the reference generators.
    for g in refs:
        g.integers(env.model.n_states)
        g.random()
    idx = np.arange(2)
    rng = np.random.default_rng(0)
    for t in range(3000):
        if rng.random() < 0.5:
            n = int(rng.choice([2, 19, 1000, 3_000_000_000, 4_000_000_000]))
            got = env._integers(idx, n)
            want = [g.integers(n) for g in refs]
        else:
            k = int(rng.integers(1, 5))
            got = env._uniforms(idx, k)
            want = [g.random(k) for g in refs]
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
