"""ForwardFilter is exact: equal to a dense ``f' = alpha * diag(O) @ T.T @ f`` within 1e-12 on random
maps, parameters and (possible) observation sequences, without ever forming an S x S product."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gym_gridloc import (
    ForwardFilter,
    GridMap,
    ImpossibleObservationError,
    colour_grid_model,
    ring_sensor_model,
    windy_maze_model,
)

COLOURS = ("R", "G", "B", "Y")
SETTINGS = settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

# Probabilities: the edges 0 and 1 and values well away from underflow over a few dozen steps.
prob = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.01, 0.99))


@st.composite
def grid_maps(draw, n_labels: int, symbols: tuple[str, ...]) -> GridMap:
    h = draw(st.integers(1, 7))
    w = draw(st.integers(1, 7))
    free = draw(st.lists(st.booleans(), min_size=h * w, max_size=h * w))
    if not any(free):
        free[draw(st.integers(0, h * w - 1))] = True
    labels = draw(st.lists(st.integers(0, n_labels - 1), min_size=h * w, max_size=h * w))
    grid = np.where(np.array(free), np.array(labels), -1).reshape(h, w)
    return GridMap(grid, symbols)


@st.composite
def models(draw):
    kind = draw(st.sampled_from(["colour", "maze", "ring commanded", "ring seed"]))
    if kind == "colour":
        model = colour_grid_model(draw(grid_maps(4, COLOURS)), slip=draw(prob), accuracy=draw(prob))
    elif kind == "maze":
        model = windy_maze_model(
            draw(grid_maps(1, ("O",))),
            drift=draw(st.one_of(st.sampled_from([0.0, 0.5]), st.floats(0.01, 0.49))),
            p_detect=draw(prob),
            p_false_alarm=draw(prob),
        )
    else:
        p_true = draw(prob)
        p_ring1 = draw(prob) * (1.0 - p_true) / 8
        p_ring2 = draw(prob) * max(0.0, 1.0 - p_true - 8 * p_ring1) / 16
        if draw(st.booleans()):  # an empty grid of a random size
            layout = None
            size = (draw(st.integers(1, 7)), draw(st.integers(1, 7)))
        else:  # a map with obstacles
            layout = draw(grid_maps(1, ("O",)))
            size = layout.shape
        model = ring_sensor_model(
            size, dynamics=kind.split()[1], keep_heading=draw(prob), p_true=p_true, p_ring1=p_ring1,
            p_ring2=p_ring2, layout=layout,
        )
    if draw(st.integers(0, 4)) == 0:
        model = model.with_kidnapping(draw(st.floats(0.01, 0.3)))
    return model


def simulate(model, actions, seed, tell_action):
    """Yield ``(filter_action, observation, reading)``: the true robot follows ``actions``; the
    filter is told the action, or None."""
    rng = np.random.default_rng(seed)
    state = model.sample_initial_state(rng)
    first = model.sample_reading(state, rng)
    yield None, model.sensor.to_observation(first), first
    for a in actions:
        a %= model.n_actions
        state = model.sample_next_state(state, a, rng)
        reading = model.sample_reading(state, rng)
        yield (a if tell_action else None), model.sensor.to_observation(reading), reading


def check_belief(f: ForwardFilter) -> None:
    model = f.model
    full = f.full_belief
    assert full.shape == model.belief_shape and full.dtype == np.float64
    assert np.all(full >= 0.0) and np.all(np.isfinite(full))
    assert np.all(full[~model.state_mask] == 0.0)
    assert abs(full.sum() - 1.0) <= 1e-12
    pos = f.position_belief
    assert pos.shape == model.shape and pos.dtype == np.float64
    assert np.all(pos >= 0.0) and np.all(pos[~model.grid.free] == 0.0)
    assert abs(pos.sum() - 1.0) <= 1e-12
    assert f.belief.shape == (model.n_states,)


def run_against_dense_reference(model, actions, seed, tell_action, use_first_reading, split):
    f = ForwardFilter(model)
    ref = np.full(model.n_states, 1.0 / model.n_states)
    log_lik = 0.0
    matrices = {}
    for i, (a, obs, reading) in enumerate(simulate(model, actions, seed, tell_action)):
        if i == 0:
            if use_first_reading:
                f.reset(obs)
            else:
                f.reset()
                np.testing.assert_array_equal(f.belief, ref)
                continue
        else:
            if a not in matrices:
                matrices[a] = model.transition_matrix(a).toarray()
            ref = matrices[a].T @ ref
            if split:
                f.predict(a)
                np.testing.assert_allclose(f.belief, ref, rtol=0, atol=1e-12)
                f.update(obs)
            else:
                f.step(a, obs)
        ref = model.likelihood_vector(reading) * ref
        z = ref.sum()
        ref /= z
        log_lik += np.log(z)
        np.testing.assert_allclose(f.belief, ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            f.position_belief, model.from_vector(ref).sum(axis=0), rtol=0, atol=1e-12
        )
        assert f.log_likelihood == pytest.approx(log_lik, rel=1e-9, abs=1e-9)
        check_belief(f)


@SETTINGS
@given(
    model=models(),
    actions=st.lists(st.integers(0, 3), max_size=20),
    seed=st.integers(0, 2**32 - 1),
    use_first_reading=st.booleans(),
    split=st.booleans(),
)
def test_filter_equals_dense_reference(model, actions, seed, use_first_reading, split):
    run_against_dense_reference(model, actions, seed, True, use_first_reading, split)


@SETTINGS
@given(model=models(), actions=st.lists(st.integers(0, 3), max_size=20), seed=st.integers(0, 2**32 - 1))
def test_filter_with_unknown_actions_equals_dense_reference(model, actions, seed):
    """``action=None``: the filter averages the actions' transitions (``transition_matrix(None)``)."""
    run_against_dense_reference(model, actions, seed, False, True, False)


def test_none_transition_is_the_average_of_the_actions():
    model = windy_maze_model(drift=0.2)
    mean = sum(model.transition_matrix(a).toarray() for a in range(4)) / 4
    np.testing.assert_allclose(model.transition_matrix(None).toarray(), mean, rtol=0, atol=1e-15)


def test_step_is_sparse_on_a_256x256_colour_grid():
    """65536 states: a dense S x S matrix would take 34 GB.  A step must take a few MB and match the
    sparse reference ``diag(O) T^T f``."""
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 4, size=(256, 256))
    labels[rng.random((256, 256)) < 0.2] = -1
    model = colour_grid_model(GridMap(labels, COLOURS), slip=0.2)
    assert model.n_states > 50_000
    f = ForwardFilter(model).reset(0)
    ref = f.belief
    for a, obs in [(0, 1), (1, 2), (3, 3)]:
        tracemalloc.start()
        try:
            f.step(a, obs)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 64 * 2**20, f"a filter step allocated {peak / 2**20:.0f} MB"
        ref = model.likelihood_vector(obs) * (model.transition_matrix(a).T @ ref)
        ref /= ref.sum()
        np.testing.assert_allclose(f.belief, ref, rtol=0, atol=1e-12)
        check_belief(f)


# -- impossible observations ---------------------------------------------------------------------------
def assert_rejected_and_unchanged(f: ForwardFilter, call, *args):
    before, ll = f.full_belief, f.log_likelihood
    with pytest.raises(ImpossibleObservationError, match="impossible"):
        call(*args)
    np.testing.assert_array_equal(f.full_belief, before)
    assert f.log_likelihood == ll
    check_belief(f)


def test_impossible_colour_raises_and_keeps_the_belief():
    model = colour_grid_model(["R,R,.", "R,.,R"], accuracy=1.0, slip=0.5)  # only red can be read
    f = ForwardFilter(model).reset(COLOURS.index("R"))
    f.step(1, 0)
    assert_rejected_and_unchanged(f, f.step, 2, COLOURS.index("G"))
    assert_rejected_and_unchanged(f, f.update, COLOURS.index("B"))
    with pytest.raises(ImpossibleObservationError):
        ForwardFilter(model).reset(COLOURS.index("Y"))
    f.step(0, 0)  # a possible observation still works afterwards
    check_belief(f)


def test_observation_impossible_given_the_belief_raises_and_keeps_it():
    """A sensor that reads the exact cell: after reading (0, 0) the robot cannot read (7, 7) one
    move later, though (7, 7) is a possible reading in general."""
    model = ring_sensor_model((8, 8), p_true=1.0, p_ring1=0.0, p_ring2=0.0)
    f = ForwardFilter(model).reset(0)
    assert f.position_belief[0, 0] == 1.0
    assert_rejected_and_unchanged(f, f.step, 1, 63)
    f.step(1, 1)
    assert f.position_belief[0, 1] == 1.0


def test_impossible_wall_reading_under_model_mismatch():
    """The filter believes in a perfect wall sensor; a noisy robot reads something it calls impossible."""
    perfect = windy_maze_model(p_detect=1.0, p_false_alarm=0.0)
    f = ForwardFilter(perfect).reset([1, 1, 0, 0])  # walls W and N only: (0, 0) or (2, 3)
    assert f.position_belief[0, 0] == f.position_belief[2, 3] == 0.5
    assert_rejected_and_unchanged(f, f.step, 1, [1, 1, 1, 1])
    assert_rejected_and_unchanged(f, f.update, np.array([0, 0, 0, 0], dtype=np.int8))
