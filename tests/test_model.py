"""Every model variant is a proper HMM: transition rows and reading distributions sum to 1, and the
model's views of the same numbers (stencil, sparse matrix, outcomes, likelihood, distribution)
agree."""

from __future__ import annotations

import numpy as np
import pytest

from gym_gridloc import GridMap, colour_grid_model, parse_colour_map, parse_maze, ring_sensor_model, windy_maze_model

COLOUR_MAP_WITH_WALLS = ["R,.,G,B", "Y,.,.,R", "G,B,.,Y"]
MAZE_WITH_WALLS = ["O#OOO", "O#O#O", "OOO#O", "##OOO"]
# A cell enclosed on all sides (no move is possible from it) and a dead-end corridor.
MAZE_ENCLOSED = ["O#OO", "##OO", "OOO#"]


def obstacle_layout(rows):
    return GridMap(np.array([[0 if ch == "O" else -1 for ch in row] for row in rows]), ("O",))


VARIANTS = {
    "colour default": lambda: colour_grid_model(),
    "colour slip 0": lambda: colour_grid_model(slip=0.0),
    "colour slip 1": lambda: colour_grid_model(slip=1.0),
    "colour accuracy 1": lambda: colour_grid_model(accuracy=1.0),
    "colour map with walls": lambda: colour_grid_model(COLOUR_MAP_WITH_WALLS, slip=0.3, accuracy=0.6),
    "colour 1x1": lambda: colour_grid_model(["B"]),
    "colour 1x4": lambda: colour_grid_model(["R,G,.,Y"], slip=0.5),
    "windy default": lambda: windy_maze_model(),
    "windy drift 0": lambda: windy_maze_model(drift=0.0),
    "windy drift 0.5": lambda: windy_maze_model(drift=0.5),
    "windy maze with walls": lambda: windy_maze_model(MAZE_WITH_WALLS, drift=0.2, p_detect=0.7, p_false_alarm=0.2),
    "windy enclosed cell": lambda: windy_maze_model(MAZE_ENCLOSED, p_detect=1.0, p_false_alarm=0.0),
    "windy 1x1": lambda: windy_maze_model(["O"]),
    "windy 5x1": lambda: windy_maze_model(["O", "O", "#", "O", "O"]),
    "ring default": lambda: ring_sensor_model(),
    "ring seed dynamics": lambda: ring_sensor_model(dynamics="seed"),
    "ring 5x5 seed": lambda: ring_sensor_model((5, 5), dynamics="seed"),
    "ring 1x1 commanded": lambda: ring_sensor_model((1, 1)),
    "ring 1x1 seed": lambda: ring_sensor_model((1, 1), dynamics="seed"),
    "ring 1x6 commanded": lambda: ring_sensor_model((1, 6)),
    "ring 1x6 seed": lambda: ring_sensor_model((1, 6), dynamics="seed"),
    "ring 7x2 seed": lambda: ring_sensor_model((7, 2), dynamics="seed", keep_heading=0.5),
    "ring 3x9 keep 1": lambda: ring_sensor_model((3, 9), keep_heading=1.0, p_true=0.3, p_ring1=0.02, p_ring2=0.01),
    "ring keep 0 seed": lambda: ring_sensor_model((4, 4), dynamics="seed", keep_heading=0.0),
    "ring walls commanded": lambda: ring_sensor_model(layout=obstacle_layout(MAZE_WITH_WALLS)),
    "ring walls seed": lambda: ring_sensor_model(dynamics="seed", layout=obstacle_layout(MAZE_ENCLOSED)),
    "windy kidnapped": lambda: windy_maze_model(MAZE_WITH_WALLS).with_kidnapping(0.05),
}

ALL = pytest.mark.parametrize("name", list(VARIANTS))


def actions(model):
    return [*range(model.n_actions), None]


@ALL
def test_transition_rows_sum_to_one(name):
    model = VARIANTS[name]()
    S = model.n_states
    for a in actions(model):
        T = model.transition_matrix(a)
        assert T.shape == (S, S)
        dense = T.toarray()
        assert np.all(dense >= 0.0)
        assert np.abs(dense.sum(axis=1) - 1.0).max() <= 1e-12, (name, a)


@ALL
def test_outcomes_sum_to_one_and_match_the_matrix(name):
    model = VARIANTS[name]()
    # outcomes() lists the moves; teleporting (kidnap_prob) is drawn apart by sample_next_state and
    # mixed into the matrix as (1 - p) * moves + p / S.
    p_kidnap = model.kidnap_prob
    for a in actions(model):
        dense = model.transition_matrix(a).toarray()
        for s in range(model.n_states):
            state = model.state_of_index(s)
            assert model.state_index(state) == s
            outs = model.outcomes(state, a)
            assert outs, (name, a, state)
            row = np.zeros(model.n_states)
            for nxt, p in outs:
                layer, r, c = nxt
                assert 0 <= layer < model.n_layers and model.grid.is_free(r, c), (name, state, nxt)
                assert p > 0.0
                row[model.state_index(nxt)] += p
            assert abs(row.sum() - 1.0) <= 1e-12, (name, a, state)
            expected = (1.0 - p_kidnap) * row + p_kidnap / model.n_states
            np.testing.assert_allclose(expected, dense[s], rtol=0, atol=1e-15)


@ALL
def test_reading_distributions_sum_to_one_and_agree_with_likelihood(name):
    model = VARIANTS[name]()
    sensor = model.sensor
    table = np.stack([sensor.likelihood(k) for k in range(sensor.n_readings)])  # (readings, H, W)
    assert table.shape == (sensor.n_readings, *model.shape)
    assert np.all(table >= 0.0)
    assert np.all(table[:, ~model.grid.free] == 0.0)
    for r, c in model.grid.free_cells:
        r, c = int(r), int(c)
        readings, probs = sensor.distribution(r, c)
        assert len(readings) == len(probs)
        assert np.all(probs >= 0.0)
        assert abs(probs.sum() - 1.0) <= 1e-12, (name, r, c)
        dist = np.zeros(sensor.n_readings)
        np.add.at(dist, np.asarray(readings), probs)
        np.testing.assert_allclose(dist, table[:, r, c], rtol=0, atol=1e-15, err_msg=f"{name} at {(r, c)}")
    # Every reading converts to an observation in the space and back.
    for k in range(sensor.n_readings):
        obs = sensor.to_observation(k)
        assert sensor.observation_space.contains(obs)
        assert sensor.to_reading(obs) == k
        np.testing.assert_array_equal(model.likelihood_vector(k), np.tile(table[k][model.grid.free], model.n_layers))


@ALL
def test_transition_matrix_agrees_with_predict(name):
    model = VARIANTS[name]()
    rng = np.random.default_rng(7)
    for a in actions(model):
        T = model.transition_matrix(a)
        for _ in range(3):
            f = rng.random(model.n_states) ** 3
            f /= f.sum()
            ours = model.to_vector(model.predict(model.from_vector(f), a))
            np.testing.assert_allclose(ours, T.T @ f, rtol=0, atol=1e-14)
            assert np.all(model.predict(model.from_vector(f), a)[~model.state_mask] == 0.0)


@ALL
def test_sampling_follows_the_model(name):
    """The simulator only ever goes where the matrix says it can, and reads what the sensor can."""
    model = VARIANTS[name]()
    rng = np.random.default_rng(3)
    state = model.sample_initial_state(rng)
    for t in range(200):
        a = int(rng.integers(model.n_actions))
        nxt = model.sample_next_state(state, a, rng)
        assert model.transition_matrix(a)[model.state_index(state), model.state_index(nxt)] > 0 or model.kidnap_prob > 0
        reading = model.sample_reading(nxt, rng)
        assert model.likelihood(reading)[nxt[1], nxt[2]] > 0
        state = nxt


def test_vector_round_trip():
    model = ring_sensor_model((3, 4), dynamics="seed", layout=obstacle_layout(["OO#O", "OOOO", "#OOO"]))
    v = np.arange(model.n_states, dtype=float)
    assert np.array_equal(model.to_vector(model.from_vector(v)), v)
    assert model.from_vector(v).shape == model.belief_shape == (4, 3, 4)
    assert np.all(model.from_vector(v)[:, ~model.grid.free] == 0.0)


def test_parsed_maps_have_their_obstacles():
    assert parse_colour_map(COLOUR_MAP_WITH_WALLS).n_free == 8
    assert parse_maze(MAZE_WITH_WALLS).n_free == 14
