"""The numbers printed in the seed documents (SPEC section 6; transcribed in gym_gridloc/seeds.py),
reproduced by the model and filter."""

from __future__ import annotations

import numpy as np
import pytest

from gym_gridloc import (
    ForwardFilter,
    colour_grid_model,
    engine,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.seeds import (
    COLOUR_GRID_LAYOUT,
    SEED000_MOVES,
    SEED000_READINGS,
    SEED000_SKIPPED,
    SEED001_NOTHING,
    SEED003_ERROR_RANGE,
    SEED003_HIT_RANGE,
    SEED004_INITIAL,
    SEED004_TABLES,
    WINDY_MAZE_LAYOUT,
)

COLOURS = "RGBY"
#: Moves 1-8, then the move the printout skips (read Y), then moves 9-11.
READINGS_WITH_SKIPPED_STEP = list("RRRYRRRY") + ["Y"] + list("YGB")


def colour_beliefs(readings):
    f = ForwardFilter(colour_grid_model(list(COLOUR_GRID_LAYOUT), slip=1.0)).reset()
    out = []
    for colour in readings:
        f.step(0, COLOURS.index(colour))
        out.append(f.position_belief)
    return out


def test_seed_data_layouts_are_the_default_maps():
    assert colour_grid_model().grid.to_text(",") == list(COLOUR_GRID_LAYOUT)
    assert windy_maze_model().grid.to_text() == list(WINDY_MAZE_LAYOUT)
    assert colour_grid_model().grid.n_free == 19 and windy_maze_model().grid.n_free == 31


# -- seed 000 ----------------------------------------------------------------------------------------
def test_seed000_printed_readings_are_the_ones_we_replay():
    printed = [c for i, c in enumerate(READINGS_WITH_SKIPPED_STEP) if i != 8]
    assert printed == [c for c, _ in SEED000_MOVES]
    assert list(SEED000_READINGS) == READINGS_WITH_SKIPPED_STEP and SEED000_SKIPPED == 8


@pytest.mark.parametrize("move", range(1, 12))
def test_seed000_every_printed_move_with_the_skipped_step(move):
    beliefs = colour_beliefs(READINGS_WITH_SKIPPED_STEP)
    printed = [b for i, b in enumerate(beliefs) if i != 8]
    ours = printed[move - 1]
    seed = np.array(SEED000_MOVES[move - 1][1])
    assert np.abs(ours - seed).max() <= 0.00005
    assert abs(ours.sum() - 1.0) < 1e-12


def test_seed000_literal_readings_do_not_match_moves_9_to_11():
    beliefs = colour_beliefs([c for c, _ in SEED000_MOVES])
    diffs = [np.abs(b - np.array(t)).max() for b, (_, t) in zip(beliefs, SEED000_MOVES)]
    assert max(diffs[:8]) <= 0.00005  # moves 1-8 do not depend on the skipped step
    assert all(d > 0.01 for d in diffs[8:]), diffs[8:]


# -- seed 004 ----------------------------------------------------------------------------------------
def percent_table(table):
    return np.array([[np.nan if v is None else v for v in row] for row in table], dtype=float)


def test_seed004_initial_table():
    f = ForwardFilter(windy_maze_model()).reset()
    seed = percent_table(SEED004_INITIAL)
    assert np.array_equal(np.isnan(seed), ~f.model.grid.free)
    assert np.nanmax(np.abs(100 * f.position_belief - seed)) <= 0.01


def test_seed004_all_seven_tables():
    f = ForwardFilter(windy_maze_model()).reset()
    kinds = []
    for kind, arg, table in SEED004_TABLES:
        if kind == "filter":
            f.update(np.array(arg, dtype=np.int8))
        else:
            f.predict("NESW".index(arg))
        kinds.append(kind if kind == "filter" else f"predict {arg}")
        seed = percent_table(table)
        ours = 100.0 * f.position_belief
        assert np.all(ours[np.isnan(seed)] == 0.0)
        diff = np.nanmax(np.abs(ours - seed))
        assert diff <= 0.01, (len(kinds), kinds[-1], diff)
    assert kinds == ["filter", "predict N", "filter", "predict E", "filter", "predict E", "filter"]


# -- seed 001 ----------------------------------------------------------------------------------------
NOTHING_8X8 = {(0, 0): 0.625, (0, 1): 0.5, (0, 2): 0.425, (1, 1): 0.325, (1, 2): 0.225, (2, 2): 0.1}


@pytest.mark.parametrize("dynamics", ["commanded", "passive"])
def test_seed001_nothing_probabilities(dynamics):
    assert SEED001_NOTHING == NOTHING_8X8
    model = ring_sensor_model((8, 8), dynamics=dynamics)
    nothing = model.likelihood(model.sensor.nothing)
    assert nothing.shape == (8, 8)
    for r in range(8):
        for c in range(8):
            key = tuple(sorted((min(r, 7 - r, 2), min(c, 7 - c, 2))))
            assert abs(nothing[r, c] - NOTHING_8X8[key]) <= 1e-12, (r, c, nothing[r, c])
    # The named cells of SPEC section 2.
    assert nothing[0, 0] == pytest.approx(0.625, abs=1e-12)
    assert nothing[0, 1] == pytest.approx(0.5, abs=1e-12)
    assert nothing[0, 3] == pytest.approx(0.425, abs=1e-12)
    assert nothing[1, 1] == pytest.approx(0.325, abs=1e-12)
    assert nothing[1, 4] == pytest.approx(0.225, abs=1e-12)
    assert nothing[4, 3] == pytest.approx(0.1, abs=1e-12)


# -- seed 003 ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [(5, 5), (8, 8)])
@pytest.mark.parametrize("dynamics", ["passive", "commanded"])
def test_seed003_rows_and_reading_distributions_sum_to_one(size, dynamics):
    model = ring_sensor_model(size, dynamics=dynamics)
    for a in [*range(model.n_actions), None]:
        sums = np.asarray(engine.transition_matrix(model, a).sum(axis=1)).ravel()
        assert sums.shape == (model.n_states,)
        assert np.abs(sums - 1.0).max() <= 1e-12
    for r, c in model.grid.free_cells:
        _, probs = model.sensor.distribution(int(r), int(c))
        assert np.all(probs >= 0)
        assert abs(probs.sum() - 1.0) <= 1e-12


def test_seed003_tracking_figures():
    """5x5, passive dynamics, 20 runs of 1000 steps: exactly right 28-33%, mean Manhattan error 1.2-2."""
    assert SEED003_HIT_RANGE == (0.28, 0.33) and SEED003_ERROR_RANGE == (1.2, 2.0)
    model = ring_sensor_model((5, 5), dynamics="passive")
    rng = np.random.default_rng(2026)
    hits = errors = 0
    for _ in range(20):
        states = engine.sample_initial(model, 1, rng)
        f = ForwardFilter(model).reset()
        for _ in range(1000):
            states = engine.sample_next(model, states, 0, rng)
            f.step(0, int(engine.sample_readings(model, states, rng)[0]))
            er, ec = divmod(int(np.argmax(f.position_belief)), 5)
            d = abs(er - int(states[0, 1])) + abs(ec - int(states[0, 2]))
            hits += d == 0
            errors += d
    assert 0.28 <= hits / 20000 <= 0.33
    assert 1.2 <= errors / 20000 <= 2.0
