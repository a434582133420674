"""GridModel as data (gym_gridloc/core/model.py): every variant is a proper HMM (transition rows sum
to 1, outcomes agree with the sparse matrix), state vectors round-trip, and the model is frozen,
copied by ``with_kidnapping`` and pickled without anything the engine derives from it."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from gym_gridloc import GridModel, engine, ring_sensor_model, windy_maze_model
from gym_gridloc.core.model import mean_transition
from tests.helpers import (
    ALL_VARIANTS,
    VARIANTS,
    actions_and_unknown,
    obstacle_layout,
    random_belief,
)


@ALL_VARIANTS
def test_transition_rows_sum_to_one(name):
    model = VARIANTS[name]()
    S = model.n_states
    for a in actions_and_unknown(model):
        T = engine.transition_matrix(model, a)
        assert T.shape == (S, S)
        dense = T.toarray()
        assert np.all(dense >= 0.0)
        assert np.abs(dense.sum(axis=1) - 1.0).max() <= 1e-12, (name, a)


@ALL_VARIANTS
def test_outcomes_sum_to_one_and_match_the_matrix(name):
    model = VARIANTS[name]()
    # outcomes() lists the moves; teleporting (kidnap_prob) is drawn apart by engine.sample_next
    # and mixed into the matrix as (1 - p) * moves + p / S.
    p_kidnap = model.kidnap_prob
    for a in actions_and_unknown(model):
        dense = engine.transition_matrix(model, a).toarray()
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


def test_none_transition_is_the_average_of_the_actions():
    model = windy_maze_model(drift=0.2)
    mean = sum(engine.transition_matrix(model, a).toarray() for a in range(4)) / 4
    np.testing.assert_allclose(engine.transition_matrix(model, None).toarray(), mean, rtol=0, atol=1e-15)
    # The model's average and the engine's cached one are the same terms.
    ours = {(t.src, t.dst, t.dr, t.dc): t.weight for t in model.terms(None)}
    cached = {(t.src, t.dst, t.dr, t.dc): t.weight for t in engine.terms(model, None)}
    assert ours.keys() == cached.keys()
    for key, weight in ours.items():
        np.testing.assert_array_equal(weight, cached[key])
    assert engine.terms(model, None) is engine.terms(model, None)  # merged once


def test_vector_round_trip():
    model = ring_sensor_model((3, 4), dynamics="passive", layout=obstacle_layout(["OO#O", "OOOO", "#OOO"]))
    v = np.arange(model.n_states, dtype=float)
    assert np.array_equal(model.to_vector(model.from_vector(v)), v)
    assert model.from_vector(v).shape == model.belief_shape == (4, 3, 4)
    assert np.all(model.from_vector(v)[:, ~model.grid.free] == 0.0)
    for s in range(model.n_states):
        assert model.state_index(model.state_of_index(s)) == s
    # engine.states_of orders states as to_vector does.
    np.testing.assert_array_equal(engine.states_of(model, np.arange(model.n_states)),
                                  [model.state_of_index(s) for s in range(model.n_states)])


# -- frozen data -----------------------------------------------------------------------------------
def test_a_model_is_frozen():
    model = windy_maze_model()
    with pytest.raises(AttributeError, match="frozen"):
        model.kidnap_prob = 0.5
    with pytest.raises(AttributeError, match="frozen"):
        model.cache = {}
    for terms in model.transitions:
        for t in terms:
            assert not t.weight.flags.writeable
            with pytest.raises(dataclasses.FrozenInstanceError):
                t.dr = 1
    assert not model.sensor.table.flags.writeable


def test_the_engine_stores_nothing_on_the_model():
    model = windy_maze_model()
    before = dict(vars(model))
    b = model.prior()
    engine.predict(model, b, 0)
    engine.step(model, b, 1, 3)
    engine.step(model, np.stack([b, b]), [0, None], [3, 5])
    engine.sample_next(model, engine.sample_initial(model, 5, np.random.default_rng(0)), 2, np.random.default_rng(1))
    assert vars(model).keys() == before.keys()
    assert all(vars(model)[k] is v for k, v in before.items())


def test_with_kidnapping_is_a_copy():
    base = windy_maze_model()
    kid = base.with_kidnapping(0.1)
    assert kid is not base and kid.kidnap_prob == 0.1 and base.kidnap_prob == 0.0
    assert kid.grid is base.grid and kid.sensor is base.sensor and kid.transitions is base.transitions
    assert base.with_kidnapping(0.0) is base and kid.with_kidnapping(0.1) is kid
    assert kid.with_kidnapping(0.0).kidnap_prob == 0.0
    with pytest.raises(AttributeError, match="frozen"):
        kid.kidnap_prob = 0.2
    with pytest.raises(ValueError, match="kidnap_prob"):
        base.with_kidnapping(1.5)
    with pytest.raises(TypeError, match="kidnap_prob"):
        base.with_kidnapping("often")
    # Each model has its own numbers in the engine.
    b = random_belief(base, np.random.default_rng(0))
    assert not np.allclose(engine.predict(base, b, 0), engine.predict(kid, b, 0))


@pytest.mark.parametrize("name", ["colour map with walls", "ring 5x5 seed", "windy kidnapped"])
def test_pickled_model_gives_the_same_numbers(name):
    model = VARIANTS[name]()
    rng = np.random.default_rng(4)
    b = random_belief(model, rng)
    engine.predict(model, b, 0)  # the engine has derived a plan: it must not travel with the model
    clone = pickle.loads(pickle.dumps(model))
    assert isinstance(clone, GridModel) and clone is not model
    assert repr(clone) == repr(model) and clone.kidnap_prob == model.kidnap_prob
    assert clone.params == model.params and clone.action_names == model.action_names
    for a in actions_and_unknown(model):
        assert (engine.transition_matrix(clone, a) != engine.transition_matrix(model, a)).nnz == 0
        np.testing.assert_array_equal(engine.predict(clone, b, a), engine.predict(model, b, a))
    for z in range(model.sensor.n_readings):
        np.testing.assert_array_equal(clone.likelihood(z), model.likelihood(z))
    with pytest.raises(AttributeError, match="frozen"):
        clone.name = "other"


def test_model_arguments_are_checked():
    ring = ring_sensor_model((4, 4))
    with pytest.raises(ValueError, match="at least one action"):
        GridModel(ring.grid, [], ring.sensor)
    with pytest.raises(ValueError, match="action_names needs one name per action"):
        GridModel(ring.grid, ring.transitions, ring.sensor, action_names=["a"])
    with pytest.raises(ValueError, match="do not sum to 1"):
        GridModel(ring.grid, [mean_transition(ring.transitions)[:-1]], ring.sensor)
    other = ring_sensor_model((4, 5))
    with pytest.raises(ValueError, match="another map"):
        GridModel(ring.grid, ring.transitions, other.sensor)
    assert ring.check_action(np.int64(3)) == 3
    with pytest.raises(ValueError, match=r"action must be an integer in 0\.\.3 \(0=N, 1=E, 2=S, 3=W\), got 4"):
        ring.check_action(4)
    with pytest.raises(TypeError, match="action must be an integer"):
        ring.check_action(True)
