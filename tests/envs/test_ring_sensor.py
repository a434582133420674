"""RingSensor8x8-v0 (gym_gridloc/envs/ring_sensor.py): any size, dynamics and keyword arguments
either build a working environment or raise an error naming what is wrong (hypothesis); layouts
with obstacles; a 512 x 512 grid with no dense table anywhere."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import gym_gridloc
from gym_gridloc import RingSensorEnv
from tests.helpers import (
    PROPERTY_SETTINGS,
    arrays_of,
    bad_keywords,
    bad_probability,
    exercise,
    kwargs_for,
    maybe,
)


def ring_sum_check(kwargs, bad):
    if bad & {"p_true", "p_ring1", "p_ring2"}:
        return set()
    total = kwargs.get("p_true", 0.1) + 8 * kwargs.get("p_ring1", 0.05) + 16 * kwargs.get("p_ring2", 0.025)
    return {"p_true"} if total > 1.0 + 1e-12 else set()


SIZES = st.one_of(
    st.tuples(st.integers(1, 7), st.integers(1, 7)),
    st.tuples(st.integers(1, 7), st.integers(1, 7)),
    st.integers(1, 6),
    st.sampled_from([(0, 5), (5, 0), -1, 0, (2, -3)]),
)
#: "seed" is the deprecated spelling of "passive": still valid.
DYNAMICS = ("commanded", "passive", "seed")


@pytest.mark.filterwarnings('ignore:dynamics="seed" is deprecated:DeprecationWarning')
@PROPERTY_SETTINGS
@given(
    size=SIZES,
    dynamics=st.sampled_from(["commanded", "passive"] * 4 + ["seed", "foo", "Seed"]),
    kwargs=kwargs_for(RingSensorEnv, {
        "p_true": maybe(st.floats(0.0, 0.6) | st.sampled_from([0.0, 1.0]), bad_probability()),
        "p_ring1": maybe(st.floats(0.0, 0.06) | st.sampled_from([0.0, 0.125]), bad_probability()),
        "p_ring2": maybe(st.floats(0.0, 0.03) | st.sampled_from([0.0, 0.0625]), bad_probability()),
    }),
)
def test_ring_sensor_any_input(size, dynamics, kwargs):
    bad = bad_keywords(kwargs, [ring_sum_check])
    dims = (size, size) if isinstance(size, int) else size
    if min(dims) < 1:
        bad.add("size")
    if dynamics not in DYNAMICS:
        bad.add("dynamics")
    exercise(lambda: gym.make("RingSensor8x8-v0", size=size, dynamics=dynamics, **kwargs), bad, True)


def test_ring_sensor_layout_keeps_the_cell_readings_of_its_grid():
    env = gym.make("RingSensor8x8-v0", layout=["OO#", "OOO"])
    assert env.observation_space == gym.spaces.Discrete(2 * 3 + 1)
    model = env.unwrapped.model
    # A cell reading can name the obstacle cell (the sensor reports cells, not free cells) ...
    readings, probs = model.sensor.distribution(0, 1)
    assert 2 in readings.tolist()
    # ... but the robot is never there.
    assert model.prior()[0, 0, 2] == 0


def test_ring_sensor_size_that_disagrees_with_layout_is_an_error():
    with pytest.raises(ValueError, match="size=.*disagrees with the layout"):
        gym.make("RingSensor8x8-v0", size=(3, 3), layout=["OO#", "OOO"])


def test_ring_sensor_512x512_resets_and_steps_without_dense_tables():
    env = gym_gridloc.HMMBeliefWrapper(gym.make("RingSensor8x8-v0", size=(512, 512)))
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    model = env.unwrapped.model
    cells = 512 * 512
    assert model.sensor.n_readings == cells + 1
    # No table over readings: every array the sensor holds is at most one (H, W) map.
    assert max(a.size for a in arrays_of(model.sensor)) <= cells
    for t in range(5):
        obs, reward, terminated, truncated, info = env.step(t % 4)
        belief = env.get_wrapper_attr("filter").position_belief
        assert belief.shape == (512, 512)
        assert abs(belief.sum() - 1.0) < 1e-9
        np.testing.assert_allclose(obs["belief"], env.unwrapped.posterior, atol=1e-6)
    assert 0 <= info["error"] <= 2 * 511
