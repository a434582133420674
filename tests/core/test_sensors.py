"""Sensors (gym_gridloc/core/sensors.py): likelihood tables, the batched methods (likelihoods,
sample, observations, readings, encode), reading_probabilities and reading_entropy against a
brute-force table, and sampled readings against the distribution."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from scipy import stats

from gym_gridloc import (
    ColourSensor,
    RingSensor,
    WallSensor,
    colour_grid_model,
    ring_sensor_model,
    windy_maze_model,
)
from tests.helpers import ALL_VARIANTS, DEFAULT_MODELS, VARIANTS, likelihood_at


def brute_table(sensor) -> np.ndarray:
    """P(reading | cell) for every reading, (n_readings, H, W) ((n_readings, L, H, W) for a layered
    sensor), one reading at a time."""
    return np.stack([np.asarray(sensor.likelihood(k)) for k in range(sensor.n_readings)])


@ALL_VARIANTS
def test_reading_distributions_sum_to_one_and_agree_with_likelihood(name):
    model = VARIANTS[name]()
    sensor = model.sensor
    table = brute_table(sensor)  # (readings, H, W) or (readings, L, H, W)
    lik_shape = model.belief_shape if sensor.layered else model.shape
    assert table.shape == (sensor.n_readings, *lik_shape)
    assert np.all(table >= 0.0)
    assert np.all(table[..., ~model.grid.free] == 0.0)
    for layer in range(model.n_layers if sensor.layered else 1):
        column_of = (lambda r, c, layer=layer: table[:, layer, r, c]) if sensor.layered else (lambda r, c: table[:, r, c])
        for r, c in model.grid.free_cells:
            r, c = int(r), int(c)
            readings, probs = sensor.distribution(r, c, layer)
            assert len(readings) == len(probs)
            assert np.all(probs >= 0.0)
            assert abs(probs.sum() - 1.0) <= 1e-12, (name, layer, r, c)
            dist = np.zeros(sensor.n_readings)
            np.add.at(dist, np.asarray(readings), probs)
            np.testing.assert_allclose(dist, column_of(r, c), rtol=0, atol=1e-15, err_msg=f"{name} at {(layer, r, c)}")
    # Every reading converts to an observation in the space and back.
    for k in range(sensor.n_readings):
        obs = sensor.to_observation(k)
        assert sensor.observation_space.contains(obs)
        assert sensor.to_reading(obs) == k
        expected = table[k][:, model.grid.free].reshape(-1) if sensor.layered else np.tile(table[k][model.grid.free], model.n_layers)
        np.testing.assert_array_equal(model.likelihood_vector(k), expected)


@ALL_VARIANTS
def test_batched_likelihoods_equal_the_single_ones(name):
    sensor = VARIANTS[name]().sensor
    assert sensor.layered == name.startswith("depth")  # the depth sensor reads ahead of the heading
    table = brute_table(sensor).reshape(sensor.n_readings, -1)
    rng = np.random.default_rng(0)
    readings = rng.integers(0, sensor.n_readings, size=40)
    got = sensor.likelihoods(readings)
    assert got.shape == (40, table.shape[1]) and got.dtype == np.float64
    np.testing.assert_array_equal(got, table[readings])
    out = np.full((40, table.shape[1]), np.nan)
    assert sensor.likelihoods(readings, out=out) is out
    np.testing.assert_array_equal(out, table[readings])
    np.testing.assert_array_equal(sensor.likelihoods(np.arange(sensor.n_readings)), table)


@ALL_VARIANTS
def test_reading_probabilities_and_entropy_equal_a_brute_force_table(name):
    model = VARIANTS[name]()
    sensor = model.sensor
    table = brute_table(sensor)  # (Z, H, W) or (Z, L, H, W)
    rng = np.random.default_rng(1)
    shape = model.belief_shape if sensor.layered else model.shape  # masses over what the sensor sees
    masses = np.where(model.grid.free, rng.random((5, *shape)), 0.0)
    masses[0] /= masses[0].sum()  # one normalised belief; the others are unnormalised masses
    q = sensor.reading_probabilities(masses)
    assert q.shape == (5, sensor.n_readings)
    ref = masses.reshape(5, -1) @ table.reshape(sensor.n_readings, -1).T
    np.testing.assert_allclose(q, ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(q.sum(axis=1), masses.reshape(5, -1).sum(axis=1), rtol=1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        plogp = np.where(table > 0, table * np.log2(table), 0.0)
    entropy = sensor.reading_entropy()
    assert entropy.shape == shape
    np.testing.assert_allclose(entropy, -plogp.sum(axis=0), rtol=1e-12, atol=1e-12)
    assert np.all(entropy[..., ~model.grid.free] == 0.0) and np.all(entropy >= -1e-15)


@ALL_VARIANTS
def test_observations_readings_and_encode_are_batched_inverses(name):
    sensor = VARIANTS[name]().sensor
    rs = np.arange(sensor.n_readings)
    obs = sensor.observations(rs)
    assert len(obs) == sensor.n_readings
    for k in rs:
        np.testing.assert_array_equal(obs[k], sensor.to_observation(int(k)))
        assert sensor.observation_space.contains(np.asarray(sensor.to_observation(int(k))) if isinstance(sensor, WallSensor) else int(obs[k]))
    back = sensor.readings(obs, sensor.n_readings)
    assert back.dtype == np.int64
    np.testing.assert_array_equal(back, rs)
    enc = sensor.encode(rs)
    assert enc.shape == (sensor.n_readings, sensor.encoded_size) and enc.dtype == np.float32
    assert np.all((enc == 0.0) | (enc == 1.0))
    if isinstance(sensor.observation_space, spaces.Discrete):
        np.testing.assert_array_equal(enc, np.eye(sensor.n_readings, dtype=np.float32))
    else:
        np.testing.assert_array_equal(enc, obs.astype(np.float32))


def test_readings_of_bad_observations_name_the_belief():
    colour = colour_grid_model().sensor
    with pytest.raises(ValueError, match=r"observation 9 of belief 2 is not in the sensor's space Discrete\(4\)"):
        colour.readings(np.array([0, 1, 9]), 3)
    with pytest.raises(ValueError, match=r"observations must be 3 integers \(one per belief\)"):
        colour.readings(np.array([0, 1]), 3)
    with pytest.raises(ValueError, match=r"observations must be 2 integers"):
        colour.readings(np.array([0.5, 1.0]), 2)
    np.testing.assert_array_equal(colour.readings(np.array([1.0, 3.0]), 2), [1, 3])  # whole floats
    with pytest.raises(ValueError, match=r"observation 7 is not in the sensor's space Discrete\(4\)"):
        colour.to_reading(7)
    with pytest.raises(ValueError, match=r"observation 'R' must be an integer"):
        colour.to_reading("R")
    wall = windy_maze_model().sensor
    with pytest.raises(ValueError, match=r"observation \[0, 2, 0, 0\] of belief 1 is not in the sensor's space MultiBinary\(4\)"):
        wall.readings(np.array([[0, 0, 0, 0], [0, 2, 0, 0]]), 2)
    with pytest.raises(ValueError, match=r"observations must be \(2, 4\) bits \(four per belief\)"):
        wall.readings(np.array([0, 0, 0, 0]), 2)
    with pytest.raises(ValueError, match=r"observation \[1, 0\] must be 4 bits"):
        wall.to_reading([1, 0])
    with pytest.raises(ValueError, match=r"^observation \[0, 2, 0, 0\] is not in the sensor's space MultiBinary\(4\)$"):
        wall.to_reading([0, 2, 0, 0])
    np.testing.assert_array_equal(wall.readings(np.array([[True, False, False, True]]), 1), [9])
    # The environment's own int8 observations take a table lookup; other forms the checked path:
    # the same readings, and the same errors.
    for k in range(16):
        obs = wall.to_observation(k)
        assert type(wall.to_reading(obs)) is int and wall.to_reading(obs) == k == wall.to_reading(obs.tolist())
        assert wall.to_reading(obs.astype(np.int64)) == k == wall.to_reading(obs.astype(bool))
    with pytest.raises(ValueError, match=r"observation array\(\[0, 2, 0, 0\], dtype=int8\) is not in the sensor's space"):
        wall.to_reading(np.array([0, 2, 0, 0], dtype=np.int8))
    with pytest.raises(ValueError, match=r"must be 4 bits"):
        wall.to_reading(np.zeros((2, 4), dtype=np.int8))


def test_observation_text_says_what_a_reading_means():
    assert colour_grid_model().sensor.observation_text(3) == "3 (Y)"
    ring = ring_sensor_model((8, 8)).sensor
    assert ring.observation_text(ring.nothing) == "64 (nothing)"
    assert ring.observation_text(13) == "13 ((1, 5))"
    assert windy_maze_model().sensor.observation_text(4) == "[0, 1, 0, 0] ([-, o, -, -]  (W, N, E, S))"


def test_sensor_arrays_are_read_only_and_public():
    colour = colour_grid_model().sensor
    wall = windy_maze_model().sensor
    ring = ring_sensor_model((6, 7)).sensor
    assert isinstance(colour, ColourSensor) and isinstance(wall, WallSensor) and isinstance(ring, RingSensor)
    for arr in (colour.table, wall.table, wall.p_bits, ring.kernel, ring.nothing_probability):
        assert not arr.flags.writeable
    # The wall table is the product of the four independent bits.
    for z in range(16):
        bits = [(z >> (3 - i)) & 1 for i in range(4)]
        expected = np.prod([wall.p_bits[i] if b else 1 - wall.p_bits[i] for i, b in enumerate(bits)], axis=0)
        np.testing.assert_allclose(wall.table[z], np.where(wall.grid.free, expected, 0.0), rtol=0, atol=1e-15)
    # The ring kernel: p_true in the middle, p_ring1 around it, p_ring2 on the outer ring.
    assert ring.kernel.shape == (5, 5) and ring.kernel[2, 2] == ring.p_true
    assert ring.kernel[1, 2] == ring.kernel[3, 3] == ring.p_ring1 and ring.kernel[0, 4] == ring.kernel[4, 1] == ring.p_ring2


# -- sampling --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(DEFAULT_MODELS))
def test_sensor_sampler_matches_distribution_everywhere(name):
    """Pooled over every free cell: a chi-square test of sampled readings against
    ``model.sensor.distribution`` (fixed seed; rejects only at p < 1e-6)."""
    model = DEFAULT_MODELS[name]()
    rng = np.random.default_rng(9)
    n = 400
    chi2, dof = 0.0, 0
    for r, c in model.grid.free_cells[:: max(1, model.grid.n_free // 24)]:
        layer = int(rng.integers(model.n_layers))
        readings, probs = model.sensor.distribution(int(r), int(c), layer)
        assert probs.sum() == pytest.approx(1.0, abs=1e-12)
        expected = {int(k): 0.0 for k in readings}
        for k, p in zip(readings.tolist(), probs.tolist()):
            expected[int(k)] += p * n
        counts = {k: 0 for k in expected}
        drawn = model.sensor.sample(np.tile([layer, int(r), int(c)], (n, 1)), rng)
        assert drawn.shape == (n,) and drawn.dtype == np.int64
        for k in drawn.tolist():
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


@ALL_VARIANTS
def test_one_state_draws_the_same_reading_as_the_batch(name):
    """The single-state fast path of ``sample`` draws the same numbers as the batched path: N
    one-state calls on a generator equal one N-state call on the same generator."""
    model = VARIANTS[name]()
    rng = np.random.default_rng(5)
    idx = rng.integers(model.n_states, size=300)
    states = np.array([model.state_of_index(int(s)) for s in idx], dtype=np.int64)
    batch = model.sensor.sample(states, np.random.default_rng(11))
    one_rng = np.random.default_rng(11)
    singles = [int(model.sensor.sample(states[i : i + 1], one_rng)[0]) for i in range(len(states))]
    np.testing.assert_array_equal(batch, singles)
    for state, z in zip(states, batch):
        assert likelihood_at(model, z, state) > 0
