"""Large grids: a 512 x 512 environment resets and steps in seconds with no S x S or
(readings x S) structure; the compiled kernels equal the numpy stencil on large grids."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import ForwardFilter, kernels
from gym_gridloc.generators import colour_map, maze_map

try:  # tests/ is not a package: pytest puts it on sys.path
    from test_vector import assert_batch_equals_singles
except ImportError:  # pragma: no cover - run as tests.test_large
    from tests.test_vector import assert_batch_equals_singles


def _arrays(obj, seen=None):
    """Every numpy array reachable from obj's attributes (one level into tuples, lists, dicts)."""
    out = []
    for value in vars(obj).values():
        items = value.values() if isinstance(value, dict) else value if isinstance(value, (tuple, list)) else [value]
        for v in items:
            if isinstance(v, np.ndarray):
                out.append(v)
    return out


def test_ring_sensor_512x512_resets_and_steps_without_dense_tables():
    env = gym_gridloc.HMMBeliefWrapper(gym.make("RingSensor8x8-v0", size=(512, 512)))
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    model = env.unwrapped.model
    cells = 512 * 512
    assert model.sensor.n_readings == cells + 1
    # No table over readings: every array the sensor holds is at most one (H, W) map.
    assert max(a.size for a in _arrays(model.sensor)) <= cells
    for t in range(5):
        obs, reward, terminated, truncated, info = env.step(t % 4)
        belief = env.get_wrapper_attr("filter").position_belief
        assert belief.shape == (512, 512)
        assert abs(belief.sum() - 1.0) < 1e-9
        np.testing.assert_allclose(obs["belief"], env.unwrapped.posterior, atol=1e-6)
    assert 0 <= info["error"] <= 2 * 511


def test_every_model_builds_at_512x512_with_stencil_sized_structures():
    cells = 512 * 512
    for model in (
        gym_gridloc.colour_grid_model(colour_map((512, 512), seed=0)),
        gym_gridloc.windy_maze_model(maze_map((512, 512), seed=0)),
        gym_gridloc.ring_sensor_model((512, 512), dynamics="seed"),
    ):
        # A transition term is one (H, W) weight array: never S x S.
        for terms in model.transitions:
            assert all(t.weight.shape == (512, 512) for t in terms)
            assert len(terms) <= 5 * model.n_layers
        assert max(a.size for a in _arrays(model.sensor)) <= 16 * cells
        f = ForwardFilter(model).reset(model.sensor.to_observation(0))
        f.step(0, model.sensor.to_observation(1))
        assert abs(f.full_belief.sum() - 1.0) < 1e-9


LARGE_MODELS = [
    lambda: gym_gridloc.colour_grid_model(colour_map((130, 131), obstacle_density=0.25, seed=3)),
    lambda: gym_gridloc.windy_maze_model(maze_map((130, 129), seed=4)),
    lambda: gym_gridloc.ring_sensor_model((128, 130)),
    lambda: gym_gridloc.ring_sensor_model((128, 128), dynamics="seed"),
]


@pytest.mark.parametrize("make", LARGE_MODELS, ids=["colour", "maze", "ring", "ring-seed"])
def test_compiled_kernel_equals_numpy_stencil_on_large_grids(make, monkeypatch):
    pytest.importorskip("numba")
    if not kernels.AVAILABLE:
        pytest.skip("kernels switched off (GYM_GRIDLOC_NO_NUMBA)")
    model = make()
    rng = np.random.default_rng(0)
    belief = np.where(model.state_mask, rng.random(model.belief_shape), 0.0)
    belief /= belief.sum()
    compiled = [model.predict(belief, a) for a in range(model.n_actions)]
    assert model.stencil_plan(0).hw == model.shape[0] * model.shape[1]
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    for a in range(model.n_actions):
        np.testing.assert_allclose(compiled[a], model.predict(belief, a), rtol=0, atol=1e-15)
    # A whole filter run: compiled step (predict, update, normalise in one call) vs numpy.
    monkeypatch.setattr(kernels, "AVAILABLE", True)
    state = model.sample_initial_state(rng)
    obs = [model.sensor.to_observation(model.sample_reading(state, rng))]
    acts = []
    for _ in range(8):
        a = int(rng.integers(model.n_actions))
        state = model.sample_next_state(state, a, rng)
        acts.append(a)
        obs.append(model.sensor.to_observation(model.sample_reading(state, rng)))
    fast = ForwardFilter(model).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        fast.step(a, o)
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    slow = ForwardFilter(model).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        slow.step(a, o)
    np.testing.assert_allclose(fast.full_belief, slow.full_belief, rtol=0, atol=1e-12)
    assert abs(fast.log_likelihood - slow.log_likelihood) < 1e-9


def test_batch_filter_on_a_large_grid_equals_single_filters():
    model = gym_gridloc.windy_maze_model(maze_map((129, 128), seed=1))
    assert_batch_equals_singles(model, n=3, steps=6, seed=2)


def test_native_vector_env_on_a_256x256_ring_grid():
    env = gym.make_vec("RingSensor8x8-v0", num_envs=4, vectorization_mode="vector_entry_point", size=(256, 256))
    obs, info = env.reset(seed=1)
    for _ in range(3):
        obs, rewards, terminated, truncated, info = env.step(np.array([0, 1, 2, 3]))
    assert obs["belief"].shape == (4, 256, 256)
    np.testing.assert_allclose(obs["belief"].sum(axis=(1, 2)), 1.0, atol=1e-4)
