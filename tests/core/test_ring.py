"""The ring sensor (gym_gridloc/core/ring.py): its likelihoods, "nothing" and samples, against a
brute-force walk over the 5x5 window, on grids with obstacles and edges."""

from __future__ import annotations

import numpy as np
import pytest

from gym_gridloc import RingSensor, ring_sensor_model
from tests.helpers import MAZE_WITH_WALLS, obstacle_layout

P = (0.2, 0.06, 0.02)


def brute_probability(sensor, reading: int, r: int, c: int) -> float:
    """P(reading | robot at (r, c)) from the definition: p_true, p_ring1 at Chebyshev distance 1,
    p_ring2 at 2, and "nothing" for the rest (readings off the grid included)."""
    h, w = sensor.grid.shape
    if not sensor.grid.free[r, c]:
        return 0.0
    by_distance = {0: sensor.p_true, 1: sensor.p_ring1, 2: sensor.p_ring2}
    if reading == h * w:
        inside = sum(by_distance[max(abs(i), abs(j))] for i in range(-2, 3) for j in range(-2, 3)
                     if 0 <= r + i < h and 0 <= c + j < w)
        return 1.0 - inside
    rr, cc = divmod(reading, w)
    d = max(abs(rr - r), abs(cc - c))
    return by_distance.get(d, 0.0)


@pytest.mark.parametrize("grid", [obstacle_layout(MAZE_WITH_WALLS), obstacle_layout(["O"]), obstacle_layout(["OO#OOOO"]),
                                  obstacle_layout(["O#", "OO", "#O", "OO", "OO", "O#"])],
                         ids=["walls", "1x1", "1x7", "6x2"])
def test_likelihoods_equal_the_definition(grid):
    sensor = RingSensor(grid, *P)
    h, w = grid.shape
    table = sensor.likelihoods(np.arange(sensor.n_readings)).reshape(sensor.n_readings, h, w)
    for z in range(sensor.n_readings):
        for r in range(h):
            for c in range(w):
                assert table[z, r, c] == pytest.approx(brute_probability(sensor, z, r, c), abs=1e-15), (z, r, c)
        np.testing.assert_array_equal(sensor.likelihood(z), table[z])
    np.testing.assert_array_equal(sensor.nothing_probability, table[sensor.nothing])
    # A reading may name an obstacle cell (the sensor reports cells); the robot is never there.
    assert table[:, ~grid.free].sum() == 0.0


def test_the_dense_table_of_small_grids_equals_the_scatters(monkeypatch):
    """Small grids keep every likelihood in one table, built by the scatters large grids use."""
    grid = obstacle_layout(MAZE_WITH_WALLS)
    readings = np.random.default_rng(0).integers(0, grid.free.size + 1, size=300)
    dense = RingSensor(grid, *P)
    assert dense.likelihoods(readings).tobytes() == dense.likelihoods(readings).tobytes()
    assert "_dense" in dense.__dict__ and "_dense" not in dense.__getstate__()
    monkeypatch.setattr(RingSensor, "DENSE_MAX", 0)
    scattered = RingSensor(grid, *P)
    got = scattered.likelihoods(readings)
    assert "_dense" not in scattered.__dict__
    assert got.tobytes() == dense.likelihoods(readings).tobytes()
    out = np.empty_like(got)
    assert dense.likelihoods(readings, out=out) is out and out.tobytes() == got.tobytes()


def test_samples_fall_in_the_window_or_say_nothing():
    model = ring_sensor_model(layout=obstacle_layout(MAZE_WITH_WALLS), size=(4, 5), p_true=0.3, p_ring1=0.04, p_ring2=0.02)
    sensor = model.sensor
    states = np.array([model.state_of_index(s) for s in range(model.n_states)] * 300, dtype=np.int64)
    z = sensor.sample(states, np.random.default_rng(0))
    cell = z != sensor.nothing
    rr, cc = np.divmod(z[cell], 5)
    assert np.all(np.maximum(np.abs(rr - states[cell, 1]), np.abs(cc - states[cell, 2])) <= 2)
    # The frequency of "nothing" in each state is its probability (5 binomial standard deviations).
    for s in range(model.n_states):
        _, r, c = model.state_of_index(s)
        k = int((z[s :: model.n_states] == sensor.nothing).sum())
        p = sensor.nothing_probability[r, c]
        assert abs(k - 300 * p) <= 5 * np.sqrt(300 * p * (1 - p)) + 1


def test_describe():
    sensor = ring_sensor_model((6, 7)).sensor
    assert sensor.describe(sensor.nothing) == "nothing" and sensor.describe(8) == "(1, 1)"
    assert sensor.n_readings == 43 and sensor.observation_space.n == 43
