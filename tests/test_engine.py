"""The engine (gym_gridloc/engine.py): predict, step, update and backward against the dense reference
on both kernel paths, unknown actions, kidnap mixing, impossible observations, batches against
single beliefs, layered likelihoods, and the samplers against the model's probabilities."""

from __future__ import annotations

import gc
import re
import weakref

import numpy as np
import pytest
from gymnasium import spaces
from scipy import stats

import gym_gridloc
from gym_gridloc import (
    ForwardFilter,
    GridModel,
    ImpossibleObservationError,
    Sensor,
    colour_grid_model,
    derived,
    engine,
    kernels,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.generators import colour_map, maze_map
from tests.helpers import (
    ALL_VARIANTS,
    DEFAULT_MODELS,
    MAZE_WITH_WALLS,
    VARIANTS,
    actions_and_unknown,
    assert_counts_match,
    dense_step,
    dense_transition,
    likelihood_at,
    pick_states,
    random_belief,
    simulate,
)

#: Models of a few hundred states on each kernel path (the numba limit is patched per test).
PATH_MODELS = {
    "colour": lambda: colour_grid_model(colour_map((23, 31), obstacle_density=0.25, seed=3)),
    "maze": lambda: windy_maze_model(maze_map((21, 26), seed=4)),
    "ring": lambda: ring_sensor_model((17, 22)),
    "ring-seed": lambda: ring_sensor_model((15, 14), dynamics="passive"),
    "maze-kidnap": lambda: windy_maze_model(maze_map((9, 12), seed=4)).with_kidnapping(0.05),
}
PATHS = ["numpy", "numba"]


def use_path(monkeypatch, path: str) -> None:
    """Route models built from now on to ``path`` (plans are cached per model: build afresh)."""
    if path == "numba" and not kernels.AVAILABLE:
        pytest.skip("numba is not installed or switched off")
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 10**9 if path == "numba" else 0)


def likely_reading(model, belief: np.ndarray) -> int:
    """The most probable reading after predicting ``belief`` with the unknown action (possible)."""
    pos = engine.predict(model, belief, None).sum(axis=0)
    return int(np.argmax(model.sensor.reading_probabilities(pos[None])[0]))


# -- predict, step, update, backward against the dense reference -----------------------------------------
@ALL_VARIANTS
def test_transition_matrix_agrees_with_predict(name):
    model = VARIANTS[name]()
    rng = np.random.default_rng(7)
    for a in actions_and_unknown(model):
        T = engine.transition_matrix(model, a)
        for _ in range(3):
            f = rng.random(model.n_states) ** 3
            f /= f.sum()
            ours = model.to_vector(engine.predict(model, model.from_vector(f), a))
            np.testing.assert_allclose(ours, T.T @ f, rtol=0, atol=1e-14)
            assert np.all(engine.predict(model, model.from_vector(f), a)[~model.state_mask] == 0.0)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("name", sorted(PATH_MODELS))
def test_each_path_equals_the_dense_reference(name, path, monkeypatch):
    use_path(monkeypatch, path)
    model = PATH_MODELS[name]()
    assert engine.path(model) == path
    rng = np.random.default_rng(1)
    belief = random_belief(model, rng)
    vec = model.to_vector(belief)
    for action in actions_and_unknown(model):
        pred = engine.predict(model, belief, action)
        assert np.all(pred[~model.state_mask] == 0.0)
        np.testing.assert_allclose(model.to_vector(pred), dense_step(model, vec, action), rtol=0, atol=1e-12)
        back = engine.backward(model, belief, action)
        np.testing.assert_allclose(model.to_vector(back), dense_transition(model, action) @ vec, rtol=0, atol=1e-12)
        reading = likely_reading(model, belief)
        out, z = engine.step(model, belief, action, reading)
        np.testing.assert_allclose(model.to_vector(out), dense_step(model, vec, action, reading), rtol=0, atol=1e-12)
        raw = dense_step(model, vec, action) * model.likelihood_vector(reading)
        assert z == pytest.approx(raw.sum(), rel=1e-12)
        upd = pred.copy()
        zu = engine.update(model, upd, reading)
        np.testing.assert_allclose(upd, out, rtol=0, atol=1e-12)
        assert zu.shape == (1,) and zu[0] == pytest.approx(z, rel=1e-12)
    # A filter run (predict, update and normalise in one kernel call) against the dense filter.
    acts, obs, _ = simulate(model, 12, rng)
    readings = [model.sensor.to_reading(o) for o in obs]
    f = ForwardFilter(model).reset(obs[0])
    ref = model.to_vector(model.prior()) * model.likelihood_vector(readings[0])
    ref /= ref.sum()
    for a, o, r in zip(acts, obs[1:], readings[1:]):
        f.step(a, o)
        ref = dense_step(model, ref, a, r)
        np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(PATH_MODELS))
def test_the_two_paths_agree_on_a_filter_run(name, monkeypatch):
    if not kernels.AVAILABLE:
        pytest.skip("numba is not installed or switched off")
    acts, obs, _ = simulate(PATH_MODELS[name](), 20, 5)
    runs = []
    for limit, path in ((10**9, "numba"), (0, "numpy")):
        monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", limit)
        model = PATH_MODELS[name]()  # a fresh model: the engine caches one plan per model
        assert engine.path(model) == path
        f = ForwardFilter(model).reset(obs[0])
        for a, o in zip(acts, obs[1:]):
            f.step(a, o)
        runs.append(f)
    np.testing.assert_allclose(runs[0].full_belief, runs[1].full_belief, rtol=0, atol=1e-14)
    assert abs(runs[0].log_likelihood - runs[1].log_likelihood) < 1e-9


@pytest.mark.parametrize("kidnap", [0.0, 0.05])
def test_backward_is_the_transpose_of_predict(kidnap):
    model = ring_sensor_model((3, 4), dynamics="passive").with_kidnapping(kidnap)
    rng = np.random.default_rng(0)
    msg = model.from_vector(rng.random(model.n_states))
    T = engine.transition_matrix(model, None).toarray()
    np.testing.assert_allclose(model.to_vector(engine.backward(model, msg, None)), T @ model.to_vector(msg), atol=1e-14)
    np.testing.assert_allclose(model.to_vector(engine.predict(model, msg, None)), T.T @ model.to_vector(msg), atol=1e-14)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("p", [0.02, 0.3])
def test_kidnap_mixing_equals_the_dense_mixture(p, path, monkeypatch):
    """predict mixes ``(1 - p) T^T v + p / S * mass``; backward its transpose; step and update
    weigh the mixture (single and batched, with a mask)."""
    use_path(monkeypatch, path)
    base = windy_maze_model(MAZE_WITH_WALLS, drift=0.2)
    model = base.with_kidnapping(p)
    S, mask = model.n_states, model.state_mask
    rng = np.random.default_rng(2)
    v = model.from_vector(3.0 * rng.random(S))  # an unnormalised mass of about 1.5 S
    for a in actions_and_unknown(model):
        T = dense_transition(base, a)
        mixed = (1 - p) * T.T @ model.to_vector(v) + p / S * v.sum()
        pred = engine.predict(model, v, a)
        np.testing.assert_allclose(model.to_vector(pred), mixed, rtol=1e-13, atol=0)
        assert pred.sum() == pytest.approx(v.sum(), rel=1e-13)  # the mass is kept
        assert np.all(pred[~mask] == 0.0)
        back = (1 - p) * T @ model.to_vector(v) + p / S * v.sum()
        np.testing.assert_allclose(model.to_vector(engine.backward(model, v, a)), back, rtol=1e-13, atol=0)
        np.testing.assert_allclose(dense_transition(model, a), (1 - p) * T + p / S, rtol=0, atol=1e-15)
    beliefs = np.stack([random_belief(model, rng) for _ in range(4)])
    acts = np.array([0, 3, None, 1], dtype=object)
    readings = np.array([5, 0, 15, 9])  # possible anywhere once kidnapping is mixed in (p_detect < 1)
    out, z = engine.step(model, beliefs, acts, readings)
    for i in range(4):
        ref = dense_step(model, model.to_vector(beliefs[i]), acts[i], int(readings[i]))
        np.testing.assert_allclose(model.to_vector(out[i]), ref, rtol=0, atol=1e-12)
        one, zi = engine.step(model, beliefs[i], acts[i], int(readings[i]))
        np.testing.assert_allclose(one, out[i], rtol=0, atol=1e-12)
        assert zi == pytest.approx(z[i], rel=1e-12)
    kept = np.full_like(beliefs, -1.0)
    sel = np.array([True, False, True, False])
    engine.step(model, beliefs, acts, readings, out=kept, mask=sel)
    np.testing.assert_allclose(kept[sel], out[sel], rtol=0, atol=1e-12)
    assert np.all(kept[~sel] == -1.0)


# -- batches ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("name", sorted(PATH_MODELS))
def test_a_batch_equals_single_beliefs(name, path, monkeypatch):
    use_path(monkeypatch, path)
    model = PATH_MODELS[name]()
    rng = np.random.default_rng(3)
    n = 7
    beliefs = np.stack([random_belief(model, rng) for _ in range(n)])
    before = beliefs.copy()
    acts = np.array([0, 1, 2, 3, None, 1, 0], dtype=object)
    readings = np.array([likely_reading(model, b) for b in beliefs])
    out, z = engine.step(model, beliefs, acts, readings)
    pred = engine.predict(model, beliefs, acts)
    assert out.shape == z.shape[:1] + model.belief_shape and z.shape == (n,)
    for i in range(n):
        one, zi = engine.step(model, beliefs[i], acts[i], int(readings[i]))
        np.testing.assert_allclose(out[i], one, rtol=0, atol=1e-12)
        assert zi == pytest.approx(z[i], rel=1e-12)
        np.testing.assert_allclose(pred[i], engine.predict(model, beliefs[i], acts[i]), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(beliefs, before)  # the inputs are left alone
    # The same action for all, as a scalar.
    same = engine.predict(model, beliefs, 2)
    for i in range(n):
        np.testing.assert_allclose(same[i], engine.predict(model, beliefs[i], 2), rtol=0, atol=1e-12)
    # Unnormalised steps: the result times z; the caller divides later.
    raw, z_raw = engine.step(model, beliefs, acts, readings, normalise=False)
    np.testing.assert_allclose(z_raw, z, rtol=1e-12)
    np.testing.assert_allclose(raw / z_raw[:, None, None, None], out, rtol=0, atol=1e-12)
    # update conditions the predicted beliefs in place.
    zu = engine.update(model, pred, readings)
    np.testing.assert_allclose(pred, out, rtol=0, atol=1e-12)
    np.testing.assert_allclose(zu, z, rtol=1e-12)
    # A mask steps some beliefs; the other rows of out keep what they held.
    sel = np.array([True, False, True, True, False, False, True])
    held = np.full_like(beliefs, 0.5)
    res, zm = engine.step(model, beliefs, acts, np.where(sel, readings, 0), out=held, mask=sel)
    assert res is held
    np.testing.assert_allclose(held[sel], out[sel], rtol=0, atol=1e-12)
    assert np.all(held[~sel] == 0.5)
    np.testing.assert_allclose(zm[sel], z[sel], rtol=1e-12)


def test_bad_arguments_are_named():
    model = windy_maze_model()
    b = model.prior()
    with pytest.raises(ValueError, match="out must be"):
        engine.predict(model, b, 0, out=np.empty(model.belief_shape, dtype=np.float32))
    with pytest.raises(ValueError, match="out must be"):
        engine.predict(model, b, 0, out=b)
    with pytest.raises(ValueError, match="belief must have shape"):
        engine.predict(model, np.ones((2, 2)), 0)
    batch = np.stack([b, b, b])
    with pytest.raises(ValueError, match=r"^action 4 of belief 2 is outside 0\.\.3$"):
        engine.predict(model, batch, np.array([0, 0, 4]))
    with pytest.raises(ValueError, match=r"^action -1 of belief 0 is outside 0\.\.3$"):
        engine.sample_next(model, np.zeros((3, 3), dtype=np.int64) + [0, 1, 1], np.array([-1, 0, 0]), np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"actions must be 3 actions \(one per belief\), got shape \(2,\)"):
        engine.predict(model, batch, np.array([0, 1]))
    with pytest.raises(ValueError, match=r"actions must be integers in 0\.\.3"):
        engine.predict(model, batch, np.array([0.5, 1.0, 2.0]))
    with pytest.raises(ValueError, match=r"action must be an integer in 0\.\.3 \(0=N, 1=E, 2=S, 3=W\), got 7"):
        engine.step(model, b, 7, 0)
    with pytest.raises(ValueError, match=r"step\(\) needs one reading per belief: 3 beliefs, 2 readings"):
        engine.step(model, batch, 0, [0, 1])
    with pytest.raises(ValueError, match=r"update\(\) needs one reading per belief: 3 beliefs, 1 readings"):
        engine.update(model, batch.copy(), [0])
    with pytest.raises(ValueError, match=r"update\(\) works in place"):
        engine.update(model, np.asfortranarray(batch[:, 0]), [0])
    with pytest.raises(ValueError, match=r"update\(\) works in place"):
        engine.update(model, b.astype(np.float32), 0)
    with pytest.raises(TypeError, match="expected a GridModel, got str"):
        engine.path("windy")


@pytest.mark.parametrize("name", ["colour", "maze", "ring", "maze-kidnap"])
def test_first_posterior_is_the_update_of_the_prior(name):
    """The first belief of an episode: the prior updated on each reading, the same numbers on the
    first call (no table) and later ones (every reading's posterior kept)."""
    model = PATH_MODELS[name]()
    rng = np.random.default_rng(1)
    readings = engine.sample_readings(model, engine.sample_initial(model, 40, rng), rng)
    ref = np.broadcast_to(model.prior(), (40, *model.belief_shape)).copy()
    engine.update(model, ref, readings)
    first = engine.first_posterior(model, readings)
    again = engine.first_posterior(model, readings)  # the second call builds the table
    assert derived.of(model)._first is not None
    assert first.tobytes() == ref.tobytes() and again.tobytes() == ref.tobytes()
    assert again.shape == (40, *model.belief_shape)


def test_first_posterior_names_impossible_and_bad_readings():
    model = colour_grid_model(colour_map((2, 2), n_colours=5, seed=0), accuracy=1.0)  # two cells: colours 1, 2
    assert sorted(model.grid.labels[model.grid.free].tolist()) == [1, 2]
    with pytest.raises(ImpossibleObservationError, match="of belief 1"):
        engine.first_posterior(model, [1, 4])  # without the table
    engine.first_posterior(model, [1, 2])  # builds it
    with pytest.raises(ImpossibleObservationError, match="of belief 1"):
        engine.first_posterior(model, [2, 0])
    with pytest.raises(ValueError, match=r"reading 9 of belief 1 is outside 0\.\.4"):
        engine.first_posterior(model, [1, 9])


# -- impossible observations --------------------------------------------------------------------------------
@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("kidnap", [0.0, 0.1])
def test_an_impossible_observation_raises_and_changes_nothing(kidnap, path, monkeypatch):
    use_path(monkeypatch, path)
    model = colour_grid_model(["R,R,.", "R,.,R"], accuracy=1.0, slip=0.5).with_kidnapping(kidnap)  # reads red only
    text = (f"is impossible under the filter's model ({model!r}) given the belief so far: every state that "
            "could be reached gives it probability 0 (model mismatch?)")
    b = model.prior()
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape("observation 3 (Y) " + text) + "$"):
        engine.step(model, b, 0, 3)
    post = b.copy()
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape("observation 1 (G) " + text) + "$"):
        engine.update(model, post, 1)
    np.testing.assert_array_equal(post, b)
    batch = np.stack([b, b, b])
    kept = batch.copy()
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape("observation 3 (Y) of belief 1 " + text) + "$"):
        engine.step(model, batch, [0, 1, 2], [0, 3, 0])
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape("observation 2 (B) of belief 2 " + text) + "$"):
        engine.update(model, batch, [0, 0, 2])
    np.testing.assert_array_equal(batch, kept)
    # A masked-out belief's reading is not judged.
    out, z = engine.step(model, batch, [0, 1, 2], [0, 3, 0], mask=np.array([True, False, True]))
    assert np.all(np.isfinite(out[[0, 2]])) and z[0] == pytest.approx(1.0) and z[2] == pytest.approx(1.0)
    # The error is a ValueError too, and the message of an impossible reading is the engine's one.
    assert issubclass(ImpossibleObservationError, ValueError)
    assert str(engine.impossible(model, 3)) == "observation 3 (Y) " + text


# -- layered likelihoods ------------------------------------------------------------------------------------
class HeadingSensor(Sensor):
    """Reads the heading (the layer) right with ``accuracy``, else one of the others: a sensor
    whose likelihood depends on the layer (``layered``)."""

    layered = True

    def __init__(self, grid, accuracy: float = 0.7) -> None:
        super().__init__(grid)
        self.n_readings = 4
        self.observation_space = spaces.Discrete(4)
        table = np.full((4, 4, *grid.shape), (1.0 - accuracy) / 3)
        for h in range(4):
            table[h, h] = accuracy
        table[:, :, ~grid.free] = 0.0
        self.table = table  # (reading, layer, H, W)

    def likelihood(self, reading: int) -> np.ndarray:
        return self.table[reading]

    def sample(self, states, rng):
        probs = self.table[:, states[:, 0], states[:, 1], states[:, 2]].T
        return self._categorical(np.ascontiguousarray(probs), rng)


def heading_model(kidnap: float = 0.0) -> GridModel:
    ring = ring_sensor_model(layout=["OOOOO", "O#OO#", "OOOOO", "OO#OO"], size=(4, 5), dynamics="passive")
    return GridModel(ring.grid, ring.transitions, HeadingSensor(ring.grid), n_layers=4,
                     name="Heading", kidnap_prob=kidnap)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("kidnap", [0.0, 0.05])
def test_layered_likelihoods(kidnap, path, monkeypatch):
    use_path(monkeypatch, path)
    model = heading_model(kidnap)
    assert engine.path(model) == path
    lik = engine.likelihoods(model, [0, 3])
    assert lik.shape == (2, model.n_states // model.grid.n_free * model.shape[0] * model.shape[1])
    np.testing.assert_array_equal(lik[1], model.likelihood(3).reshape(-1))
    np.testing.assert_array_equal(model.likelihood_vector(3), model.likelihood(3)[:, model.grid.free].reshape(-1))
    rng = np.random.default_rng(8)
    beliefs = np.stack([random_belief(model, rng) for _ in range(3)])
    acts, readings = [0, None, 2], [1, 3, 0]
    out, z = engine.step(model, beliefs, np.array(acts, dtype=object), readings)
    for i in range(3):
        ref = dense_step(model, model.to_vector(beliefs[i]), acts[i], readings[i])
        np.testing.assert_allclose(model.to_vector(out[i]), ref, rtol=0, atol=1e-12)
        one, zi = engine.step(model, beliefs[i], acts[i], readings[i])
        np.testing.assert_allclose(one, out[i], rtol=0, atol=1e-12)
        assert zi == pytest.approx(z[i], rel=1e-12)
        upd = beliefs[i].copy()
        engine.update(model, upd, readings[i])
        ref = model.to_vector(beliefs[i]) * model.likelihood_vector(readings[i])
        np.testing.assert_allclose(model.to_vector(upd), ref / ref.sum(), rtol=0, atol=1e-12)
    # The filters and the simulator on a layered model.
    acts, obs, states = simulate(model, 30, 4)
    for (layer, r, c), o in zip(states, obs):
        assert model.likelihood(o)[layer, r, c] > 0
    f = ForwardFilter(model).reset(obs[0])
    ref = model.to_vector(model.prior()) * model.likelihood_vector(obs[0])
    ref /= ref.sum()
    for a, o in zip(acts, obs[1:]):
        f.step(a, o)
        ref = dense_step(model, ref, a, o)
        np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)
    q = model.sensor.reading_probabilities(f.full_belief[None])
    np.testing.assert_allclose(q[0], [model.likelihood_vector(z) @ f.belief_vector for z in range(4)], rtol=1e-12)


# -- the samplers -------------------------------------------------------------------------------------------
SAMPLER_MODELS = {
    "colour": colour_grid_model,
    "maze": windy_maze_model,
    "ring-commanded": lambda: ring_sensor_model((5, 5)),
    "ring-seed": lambda: ring_sensor_model((4, 4), dynamics="passive"),
    "maze-kidnap": lambda: windy_maze_model().with_kidnapping(0.05),
}


@pytest.mark.parametrize("name", sorted(SAMPLER_MODELS))
def test_sample_next_matches_the_transition(name):
    model = SAMPLER_MODELS[name]()
    rng = np.random.default_rng(0)
    n = 40_000
    for action in (0, model.n_actions - 1, None):
        state = model.state_of_index(int(rng.integers(model.n_states)))
        nxt = engine.sample_next(model, np.tile(state, (n, 1)), action, rng)
        assert nxt.shape == (n, 3) and nxt.dtype == np.int64
        counts = np.bincount([model.state_index(tuple(s)) for s in nxt.tolist()], minlength=model.n_states)
        expected = engine.transition_matrix(model, action).toarray()[model.state_index(state)]
        # within 5 standard deviations of a binomial count
        assert np.all(np.abs(counts - n * expected) <= 5 * np.sqrt(n * expected * (1 - expected)) + 1)


def test_sample_next_never_picks_a_zero_weight_term():
    model = windy_maze_model()
    rng = np.random.default_rng(3)
    states = np.array([model.state_of_index(s) for s in range(model.n_states)] * 200, dtype=np.int64)
    nxt = engine.sample_next(model, states, 2, rng)
    assert model.grid.free[nxt[:, 1], nxt[:, 2]].all()
    T = engine.transition_matrix(model, 2).toarray()
    src = [model.state_index(tuple(s)) for s in states.tolist()]
    dst = [model.state_index(tuple(s)) for s in nxt.tolist()]
    assert np.all(T[src, dst] > 0)


@pytest.mark.parametrize("name", list(DEFAULT_MODELS))
def test_model_transitions_sum_to_one_and_sampler_matches(name):
    model = DEFAULT_MODELS[name]()
    rng = np.random.default_rng(2024)
    n = 3000
    for state in pick_states(model, 8, seed=1):
        for a in range(model.n_actions):
            probs: dict = {}
            for nxt, p in model.outcomes(state, a):
                probs[nxt] = probs.get(nxt, 0.0) + p
            assert sum(probs.values()) == pytest.approx(1.0, abs=1e-12)
            counts: dict = {}
            for nxt in engine.sample_next(model, np.tile(state, (n, 1)), a, rng).tolist():
                counts[tuple(nxt)] = counts.get(tuple(nxt), 0) + 1
            assert_counts_match(counts, probs, n, f"{name} state {state} action {a}")


@pytest.mark.parametrize("name", ["colour map with walls", "ring 5x5 seed", "windy 5x1"])
def test_sample_initial_is_uniform_over_free_states(name):
    model = VARIANTS[name]()
    n = 20_000
    st = engine.sample_initial(model, n, np.random.default_rng(6))
    assert st.shape == (n, 3) and st.dtype == np.int64
    assert np.all((st[:, 0] >= 0) & (st[:, 0] < model.n_layers)) and model.grid.free[st[:, 1], st[:, 2]].all()
    counts = np.bincount([model.state_index(tuple(s)) for s in st.tolist()], minlength=model.n_states)
    assert stats.chisquare(counts).pvalue > 1e-6


def test_sample_readings_are_the_sensors_draws():
    model = ring_sensor_model((6, 5), dynamics="passive")
    states = engine.sample_initial(model, 500, np.random.default_rng(0))
    np.testing.assert_array_equal(engine.sample_readings(model, states, np.random.default_rng(1)),
                                  model.sensor.sample(states, np.random.default_rng(1)))


@ALL_VARIANTS
def test_one_state_draws_the_same_next_state_as_the_batch(name):
    """The scalar fast path (one state, an int action) draws the same numbers as the batched path:
    N one-state calls on a generator equal one N-state call on the same generator."""
    model = VARIANTS[name]()
    if model.kidnap_prob > 0:  # kidnapping draws its uniforms for the whole batch first
        model = model.with_kidnapping(0.0)
    rng = np.random.default_rng(12)
    n = 400
    states = engine.sample_initial(model, n, rng)
    acts = rng.integers(model.n_actions, size=n)
    batch = engine.sample_next(model, states, acts, np.random.default_rng(13))
    one_rng = np.random.default_rng(13)
    singles = np.concatenate([engine.sample_next(model, states[i : i + 1], int(acts[i]), one_rng) for i in range(n)])
    np.testing.assert_array_equal(batch, singles)
    # np.int64 actions and one-element arrays take the general path: the same numbers again.
    other_rng = np.random.default_rng(13)
    general = np.concatenate([engine.sample_next(model, states[i : i + 1], acts[i : i + 1], other_rng) for i in range(n)])
    np.testing.assert_array_equal(batch, general)


@ALL_VARIANTS
def test_sampling_follows_the_model(name):
    """The simulator only ever goes where the matrix says it can, and reads what the sensor can."""
    model = VARIANTS[name]()
    acts, obs, states = simulate(model, 200, 3)
    for t, a in enumerate(acts):
        state, nxt = states[t], states[t + 1]
        assert engine.transition_matrix(model, a)[model.state_index(state), model.state_index(nxt)] > 0 or model.kidnap_prob > 0
        reading = model.sensor.to_reading(obs[t + 1])
        assert likelihood_at(model, reading, nxt) > 0


def test_simulate_draws_in_its_documented_order():
    """start, first reading, then per step: action, move, reading (one generator)."""
    model = windy_maze_model().with_kidnapping(0.1)
    st, acts, readings = engine.simulate(model, 50, np.random.default_rng(21))
    assert st.shape == (51, 3) and acts.shape == (50,) and readings.shape == (51,)
    rng = np.random.default_rng(21)
    s = engine.sample_initial(model, 1, rng)
    assert np.array_equal(s[0], st[0]) and engine.sample_readings(model, s, rng)[0] == readings[0]
    for k in range(50):
        a = int(rng.integers(model.n_actions))
        s = engine.sample_next(model, s, a, rng)
        assert a == acts[k] and np.array_equal(s[0], st[k + 1])
        assert engine.sample_readings(model, s, rng)[0] == readings[k + 1]
    given = [3, 2, 1, 0] * 5
    _, acts2, _ = engine.simulate(model, 20, np.random.default_rng(0), actions=given)
    assert acts2.tolist() == given


# -- large grids ---------------------------------------------------------------------------------------------
LARGE_MODELS = [
    lambda: gym_gridloc.colour_grid_model(colour_map((130, 131), obstacle_density=0.25, seed=3)),
    lambda: gym_gridloc.windy_maze_model(maze_map((130, 129), seed=4)),
    lambda: gym_gridloc.ring_sensor_model((128, 130)),
    lambda: gym_gridloc.ring_sensor_model((128, 128), dynamics="passive"),
]


@pytest.mark.parametrize("make", LARGE_MODELS, ids=["colour", "maze", "ring", "ring-seed"])
def test_compiled_kernel_equals_numpy_stencil_on_large_grids(make, monkeypatch):
    pytest.importorskip("numba")
    if not kernels.AVAILABLE:
        pytest.skip("kernels switched off (GYM_GRIDLOC_NO_NUMBA)")
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 10**9)
    compiled_model = make()
    assert engine.path(compiled_model) == "numba"
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 0)
    numpy_model = make()  # the engine caches a plan per model: one model per path
    assert engine.path(numpy_model) == "numpy"
    rng = np.random.default_rng(0)
    belief = random_belief(numpy_model, rng)
    for a in range(numpy_model.n_actions):
        np.testing.assert_allclose(engine.predict(compiled_model, belief, a), engine.predict(numpy_model, belief, a),
                                   rtol=0, atol=1e-15)
    # A whole filter run: compiled step (predict, update, normalise in one call) vs numpy.
    acts, obs, _ = simulate(numpy_model, 8, rng)
    fast = ForwardFilter(compiled_model).reset(obs[0])
    slow = ForwardFilter(numpy_model).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        fast.step(a, o)
        slow.step(a, o)
    np.testing.assert_allclose(fast.full_belief, slow.full_belief, rtol=0, atol=1e-12)
    assert abs(fast.log_likelihood - slow.log_likelihood) < 1e-9


def test_the_engine_and_lookahead_caches_let_go_of_a_redrawn_map():
    """The per-model caches (the engine's derived data and stepper, the lookahead features) hold
    their model weakly: a map redrawn at reset is freed, not kept for the life of the process.
    (A maze of 17 x 17 cells: larger than the small maps whose models redraw keeps.)"""
    import gymnasium as gym

    from gym_gridloc import engine
    from gym_gridloc import lookahead as la
    from gym_gridloc.envs import base

    assert 17 * 17 > base.REDRAWN_CELLS
    env = gym_gridloc.HMMBeliefWrapper(gym.make("DepthMaze-v0", size=17), lookahead=2)
    env.reset(seed=0)
    env.step(0)
    first = weakref.ref(env.unwrapped.model)
    assert first() in derived._DERIVED and first() in la._LOOKAHEADS
    for seed in range(1, 4):
        env.reset(seed=seed)
        env.step(0)
    gc.collect()
    assert first() is None
    assert env.unwrapped.model in la._LOOKAHEADS and sum(m.shape == (17, 17) for m in la._LOOKAHEADS) <= 2
