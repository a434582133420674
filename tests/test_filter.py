"""ForwardFilter and BatchFilter (gym_gridloc/filter.py) are exact: equal to a dense
``f' = alpha * diag(O) @ T.T @ f`` within 1e-12 on random maps, parameters and (possible)
observation sequences, without ever forming an S x S product; a batch equals single filters; lazy
normalisation is invisible; impossible observations leave the belief alone; long runs stay finite."""

from __future__ import annotations

import math
import pickle
import re
import sys
import tracemalloc
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import gym_gridloc
from gym_gridloc import (
    BatchFilter,
    ForwardFilter,
    GridMap,
    ImpossibleObservationError,
    colour_grid_model,
    depth_maze_model,
    engine,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.generators import colour_map, maze_map, perfect_maze
from tests.helpers import assert_batch_equals_singles, dense_transition, load_module, simulate

ROOT = Path(__file__).resolve().parents[1]
COLOURS = ("R", "G", "B", "Y")
SETTINGS = settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

LONG_RUN = load_module(ROOT / "scripts" / "long_run.py")  # (the million-step check)


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
    kind = draw(st.sampled_from(["colour", "maze", "ring commanded", "ring passive", "depth"]))
    if kind == "depth":  # a heading and a layered (depth) sensor; any map, walled or not
        layout = perfect_maze(draw(st.sampled_from([5, 7])), seed=draw(st.integers(0, 99))) if draw(st.booleans()) \
            else draw(grid_maps(1, ("O",)))
        model = depth_maze_model(layout, p_turn_fail=draw(prob), p_move_fail=draw(prob), p_depth_error=draw(prob))
    elif kind == "colour":
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


def episode(model, actions, seed, tell_action):
    """``(filter_action, observation, reading)`` per step: the true robot follows ``actions``; the
    filter is told the action, or None.  The first entry is the reading at the start."""
    acts, obs, _ = simulate(model, len(actions), seed, actions=[a % model.n_actions for a in actions])
    readings = [model.sensor.to_reading(o) for o in obs]
    out = [(None, obs[0], readings[0])]
    for a, o, r in zip(acts, obs[1:], readings[1:]):
        out.append((a if tell_action else None, o, r))
    return out


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
    assert f.belief_vector.shape == (model.n_states,)


def run_against_dense_reference(model, actions, seed, tell_action, use_first_reading, split):
    f = ForwardFilter(model)
    ref = np.full(model.n_states, 1.0 / model.n_states)
    log_lik = 0.0
    for i, (a, obs, reading) in enumerate(episode(model, actions, seed, tell_action)):
        if i == 0:
            if use_first_reading:
                f.reset(obs)
            else:
                f.reset()
                np.testing.assert_array_equal(f.belief_vector, ref)
                continue
        else:
            ref = dense_transition(model, a).T @ ref
            if split:
                f.predict(a)
                np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)
                f.update(obs)
            else:
                f.step(a, obs)
        ref = model.likelihood_vector(reading) * ref
        z = ref.sum()
        ref /= z
        log_lik += np.log(z)
        np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)
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


def test_step_is_sparse_on_a_256x256_colour_grid():
    """65536 states: a dense S x S matrix would take 34 GB.  A step must take a few MB and match the
    sparse reference ``diag(O) T^T f``."""
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 4, size=(256, 256))
    labels[rng.random((256, 256)) < 0.2] = -1
    model = colour_grid_model(GridMap(labels, COLOURS), slip=0.2)
    assert model.n_states > 50_000
    f = ForwardFilter(model).reset(0)
    ref = f.belief_vector
    for a, obs in [(0, 1), (1, 2), (3, 3)]:
        tracemalloc.start()
        try:
            f.step(a, obs)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 64 * 2**20, f"a filter step allocated {peak / 2**20:.0f} MB"
        ref = model.likelihood_vector(obs) * (engine.transition_matrix(model, a).T @ ref)
        ref /= ref.sum()
        np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)
        check_belief(f)



@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0"])
def test_building_a_512x512_environment_with_its_filter_allocates_little_at_its_peak(env_id):
    """The models' tables are built a slice at a time: building a 512 x 512 environment with its
    HMMBeliefWrapper and resetting it peaks under 128 MB of traced allocations (about 70-95 MB;
    a (16, 4, H, W) temporary in the wall sensor's table once took it to 215 MB)."""
    gym.make(env_id)  # imports and registrations outside the trace
    tracemalloc.start()
    try:
        env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id, size=(512, 512)))
        env.reset(seed=0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 128 * 2**20, f"building {env_id} 512x512 peaked at {peak / 2**20:.0f} MB"

# -- the belief: reading it, setting it, lazy normalisation, pickling ---------------------------------------
def test_set_belief_is_checked_and_normalised():
    model = ring_sensor_model((3, 4), dynamics="passive", layout=["OO#O", "OOOO", "#OOO"])
    f = ForwardFilter(model).reset()
    v = np.arange(1, model.n_states + 1, dtype=float)
    f.set_belief(v)
    np.testing.assert_allclose(f.belief_vector, v / v.sum(), rtol=1e-15)
    full = model.from_vector(v)
    f.set_belief(3.0 * full)
    np.testing.assert_allclose(f.full_belief, full / full.sum(), rtol=1e-15)
    f.set_belief(1e308 * model.prior())  # scaled before summing: no overflow to inf
    np.testing.assert_allclose(f.full_belief, model.prior(), rtol=1e-12)
    with pytest.raises(ValueError, match=r"belief must have shape \(4, 3, 4\) or \(40,\), got \(3, 4\)"):
        f.set_belief(np.ones((3, 4)))
    bad = full.copy()
    bad[0, 0, 2] = 1.0  # an obstacle
    for b in (bad, -full, np.where(model.state_mask, np.nan, 0.0)):
        with pytest.raises(ValueError, match="belief must be finite, non-negative and zero on obstacles"):
            f.set_belief(b)
    with pytest.raises(ValueError, match="belief must have positive total mass"):
        f.set_belief(np.zeros(model.n_states))
    with pytest.raises(TypeError, match="belief must be an array of numbers, got str"):
        f.set_belief("uniform")
    # one layer: an (H, W) array like position_belief is accepted too
    wm = windy_maze_model()
    g = ForwardFilter(wm).reset([0, 0, 0, 1])
    g.set_belief(2.0 * wm.prior()[0])
    np.testing.assert_allclose(g.position_belief, wm.prior()[0], rtol=1e-15)
    with pytest.raises(ValueError, match=r"belief must have shape \(1, 6, 7\), \(6, 7\) or \(31,\), got \(7, 6\)"):
        g.set_belief(np.ones((7, 6)))
    # A step from a set belief is the dense step.
    f.set_belief(v)
    f.step(2, 5)
    ref = dense_transition(model, 2).T @ (v / v.sum()) * model.likelihood_vector(5)
    np.testing.assert_allclose(f.belief_vector, ref / ref.sum(), rtol=0, atol=1e-12)


def test_deprecated_names_warn_and_agree():
    model = windy_maze_model()
    f = ForwardFilter(model).reset([0, 0, 0, 1]).step(0, [0, 1, 0, 0])
    with pytest.warns(DeprecationWarning, match="ForwardFilter.belief is deprecated: use belief_vector"):
        old = f.belief
    np.testing.assert_array_equal(old, f.belief_vector)
    b = BatchFilter(model, 2).reset([[0, 0, 0, 1], [1, 0, 0, 1]])
    with pytest.warns(DeprecationWarning, match="BatchFilter.beliefs is deprecated: use full_beliefs"):
        old = b.beliefs
    np.testing.assert_array_equal(old, b.full_beliefs)


def test_using_the_filter_before_reset_is_an_error():
    f = ForwardFilter(windy_maze_model())
    for call in (lambda: f.step(0, [0, 0, 0, 0]), lambda: f.predict(0), lambda: f.update([0, 0, 0, 0]),
                 lambda: f.full_belief):
        with pytest.raises(RuntimeError, match=r"call ForwardFilter\.reset\(\) before using the filter"):
            call()
    with pytest.raises(TypeError, match="ForwardFilter needs a GridModel, got str"):
        ForwardFilter("windy")


def test_a_pickled_filter_continues_identically():
    model = ring_sensor_model((5, 5), dynamics="passive")
    acts, obs, _ = simulate(model, 30, 2)
    f = ForwardFilter(model).reset(obs[0])
    for a, o in zip(acts[:10], obs[1:11]):
        f.step(a, o)  # left unnormalised: the clone must carry the deferred scale
    clone = pickle.loads(pickle.dumps(f))
    for a, o in zip(acts[10:], obs[11:]):
        f.step(a, o)
        clone.step(a, o)
    np.testing.assert_array_equal(clone.full_belief, f.full_belief)
    assert clone.log_likelihood == f.log_likelihood


@pytest.mark.parametrize("name", list(LONG_RUN.SHARP))
def test_unread_filter_matches_a_filter_read_every_step(name):
    """The filter may normalise lazily when nobody reads the belief: a filter left alone for 1,000
    steps at a time agrees with one read (normalised) every step, and neither underflows."""
    env_id, kwargs = LONG_RUN.SHARP[name]
    model = gym.make(env_id, **kwargs).unwrapped.model
    acts, obs, _ = simulate(model, 5000, 11)
    eager, lazy = ForwardFilter(model), ForwardFilter(model)
    eager.reset(obs[0])
    lazy.reset(obs[0])
    for t in range(1, 5001):
        a, o = acts[t - 1], obs[t]
        eager.step(a, o)
        lazy.step(a, o)
        b = eager.full_belief
        assert np.all(np.isfinite(b)) and abs(b.sum() - 1.0) < 1e-9
        if t % 1000 == 0:
            c = lazy.full_belief
            np.testing.assert_allclose(c, b, rtol=0, atol=1e-9)
            assert lazy.log_likelihood == pytest.approx(eager.log_likelihood, rel=1e-9)


# -- long runs -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(LONG_RUN.SHARP))
def test_long_run_quick(name):
    """The long-run script's check, 20,000 steps: finite, summing to 1, memory flat."""
    steps = 20_000 if name in ("colour", "windy") else 8_000
    r = LONG_RUN.long_run(name, steps, seed=1, warmup=1000, trace_from=0.5, progress=False)
    assert r["max_abs_sum_error"] < 1e-9
    assert math.isfinite(r["min_log_normaliser"])
    assert r["map_accuracy"] > 0.5  # sharp sensors: the most probable position is usually right
    assert r["traced_kib_end"] - r["traced_kib_after_warmup"] < 32


def test_sharp_sensor_belief_never_all_zero():
    """With the sharpest sensors short of certainty and readings the model finds very unlikely
    (a filter with accuracy 0.999 reading a 0.5-accurate sensor), every update renormalises:
    no underflow to an all-zero or NaN belief."""
    env = gym.make("ColourGrid-v0", accuracy=0.5, slip=0.0).unwrapped
    f = ForwardFilter(colour_grid_model(accuracy=0.999999, slip=0.0))
    obs, _ = env.reset(seed=0)
    f.reset(obs)
    rng = np.random.default_rng(0)
    for _ in range(5000):
        a = int(rng.integers(4))
        obs, *_ = env.step(a)
        f.step(a, obs)
        b = f.position_belief
        assert np.all(np.isfinite(b)) and b.max() > 0 and abs(b.sum() - 1.0) < 1e-9


# -- impossible observations ---------------------------------------------------------------------------------
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
    message = (f"observation 3 (Y) is impossible under the filter's model ({model!r}) given the belief so far: "
               "every state that could be reached gives it probability 0 (model mismatch?)")
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape(message) + "$"):
        ForwardFilter(model).reset(COLOURS.index("Y"))
    with pytest.raises(ImpossibleObservationError, match="^" + re.escape(message) + "$"):
        f.step(0, COLOURS.index("Y"))
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


# -- kidnapping ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("p", [0.0, 0.02, 0.5])
def test_filter_option_equals_dense_mixing(p):
    base = windy_maze_model()
    rng = np.random.default_rng(1)
    f = ForwardFilter(base, kidnap_prob=p).reset([0, 1, 0, 1])
    assert f.model.kidnap_prob == p and base.kidnap_prob == 0.0  # the given model is not changed
    S = base.n_states
    ref = base.to_vector(f.full_belief)
    for _ in range(6):
        a = int(rng.integers(4))
        obs = rng.integers(0, 2, size=4).astype(np.int8)
        f.step(a, obs)
        T = engine.transition_matrix(base, a).toarray()
        ref = ((1 - p) * T.T @ ref + p / S) * base.likelihood_vector(base.sensor.to_reading(obs))
        ref /= ref.sum()
        np.testing.assert_allclose(f.belief_vector, ref, atol=1e-12)
    # and the option overrides a model's own kidnapping in both directions
    assert ForwardFilter(base.with_kidnapping(0.1), kidnap_prob=0.0).model.kidnap_prob == 0.0
    assert ForwardFilter(base.with_kidnapping(0.1)).model.kidnap_prob == 0.1


def test_mixing_makes_a_kidnap_possible():
    """Perfect sensor, no slip: without mixing a kidnap gives an impossible observation; with the
    mixing the belief jumps to the only explanation."""
    model = colour_grid_model(["R,G", "B,Y"], slip=0.0, accuracy=1.0)
    plain = ForwardFilter(model).reset(0)  # on R at (0, 0)
    with pytest.raises(ImpossibleObservationError):
        plain.step(1, 2)  # moving E reads B: only a kidnap explains it
    mixed = ForwardFilter(model, kidnap_prob=0.01).reset(0)
    mixed.step(1, 2)
    assert mixed.position_belief[1, 0] == pytest.approx(1.0)
    # in an environment with kidnapping, a wrapper whose model has no mixing needs
    # on_impossible="reset"; with the environment's own model (mixing on) it never restarts
    env = gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3)
    plain_env = gym_gridloc.HMMBeliefWrapper(env, model=env.model.with_kidnapping(0.0), on_impossible="reset")
    mixed_env = gym_gridloc.HMMBeliefWrapper(gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3))
    for wrapped in (plain_env, mixed_env):
        wrapped.reset(seed=0)
        resets = 0
        for k in range(100):
            obs, _, _, _, info = wrapped.step(k % 4)
            resets += bool(info.get("belief_reset", False))
            assert np.isfinite(obs["belief"]).all() and obs["belief"].sum() == pytest.approx(1.0, abs=1e-6)
            if wrapped is mixed_env:  # the mixing filter is exact: it agrees with the referee
                np.testing.assert_allclose(obs["belief"], wrapped.unwrapped.posterior, atol=1e-6)
        if wrapped is plain_env:
            assert resets > 5
    with pytest.raises(ImpossibleObservationError):
        strict = gym_gridloc.HMMBeliefWrapper(gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3),
                                              model=env.model.with_kidnapping(0.0))
        strict.reset(seed=0)
        for k in range(100):
            strict.step(k % 4)


# -- BatchFilter -------------------------------------------------------------------------------------------
def _batch_models():
    return [
        colour_grid_model(colour_map((9, 11), seed=1)),
        colour_grid_model(slip=1.0),
        colour_grid_model().with_kidnapping(0.05),
        windy_maze_model(maze_map((8, 9), seed=2)),
        ring_sensor_model((7, 6)),
        ring_sensor_model((6, 5), dynamics="passive"),
    ]


@pytest.mark.parametrize("model", _batch_models(), ids=repr)
def test_batch_filter_equals_single_filters(model):
    assert_batch_equals_singles(model, n=7, steps=25, seed=1)


def test_batch_filter_on_a_large_grid_equals_single_filters():
    model = windy_maze_model(maze_map((129, 128), seed=1))
    assert engine.path(model) == "numpy"
    assert_batch_equals_singles(model, n=3, steps=6, seed=2)


def test_batch_filter_mask_and_errors():
    model = colour_grid_model(accuracy=1.0)
    batch = BatchFilter(model, 3)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step([0, 0, 0], [0, 0, 0])
    batch.reset(np.array([0, 1, 2]))
    before = batch.full_beliefs.copy()
    batch.step(np.array([1, 1, 1]), np.array([0, 1, 2]), mask=np.array([True, False, True]))
    assert np.array_equal(batch.full_beliefs[1], before[1])
    assert not np.array_equal(batch.full_beliefs[0], before[0])
    with pytest.raises(ValueError, match="action 4 of belief 2"):
        batch.step(np.array([0, 0, 4]), np.array([0, 0, 0]))
    with pytest.raises(ValueError, match="observation"):
        batch.step(np.array([0, 0, 0]), np.array([0, 0, 9]))
    with pytest.raises(ValueError, match="n \\(the number of beliefs\\)"):
        BatchFilter(model, 0)
    # Colour 3 (Y) where no reachable cell is yellow under a perfect sensor: impossible for belief 0.
    single = ForwardFilter(model).reset(0)
    reachable = engine.predict(model, single.full_belief, 0)[0] > 0
    impossible = [c for c in range(4) if not np.any(reachable & (model.grid.labels == c))]
    if impossible:
        kept = batch.full_beliefs.copy()
        with pytest.raises(ImpossibleObservationError, match="belief 0"):
            b2 = BatchFilter(model, 1).reset(np.array([0]))
            b2.step(np.array([0]), np.array([impossible[0]]))
        assert np.array_equal(batch.full_beliefs, kept)


def test_batch_filter_readings_masks_and_unknown_actions():
    model = windy_maze_model()
    acts, obs, _ = simulate(model, 6, 3)
    readings = [model.sensor.to_reading(o) for o in obs]
    a = BatchFilter(model, 2).reset(readings=np.array([readings[0]] * 2))
    b = BatchFilter(model, 2).reset(np.array([obs[0]] * 2))
    np.testing.assert_array_equal(a.full_beliefs, b.full_beliefs)
    single = ForwardFilter(model).reset(obs[0])
    unknown = ForwardFilter(model).reset(obs[0])
    for act, o, r in zip(acts, obs[1:], readings[1:]):
        a.step(np.array([act, None], dtype=object), readings=np.array([r, r]))
        single.step(act, o)
        unknown.step(None, o)
    np.testing.assert_allclose(a.full_beliefs[0], single.full_belief, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.full_beliefs[1], unknown.full_belief, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.position_beliefs, a.full_beliefs[:, 0], rtol=0, atol=0)
    np.testing.assert_allclose(a.log_likelihood, [single.log_likelihood, unknown.log_likelihood], rtol=1e-12)
    # Resetting one belief leaves the other.
    kept = a.full_beliefs[1].copy()
    a.reset(readings=np.array([readings[0]] * 2), mask=np.array([True, False]))
    np.testing.assert_array_equal(a.full_beliefs[1], kept)
    np.testing.assert_allclose(a.full_beliefs[0], ForwardFilter(model).reset(obs[0]).full_belief, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"readings must be 2 reading indices in 0\.\.15"):
        a.step([0, 0], readings=np.array([0, 16]))
    with pytest.raises(ValueError, match=r"mask must be 2 booleans"):
        a.step([0, 0], readings=np.array([0, 1]), mask=[1, 0])
    with pytest.raises(ValueError, match=r"actions must be 2 actions \(one per belief\)"):
        a.step([0], readings=np.array([0, 1]))
    with pytest.raises(TypeError, match="BatchFilter needs a GridModel"):
        BatchFilter("windy", 2)


def test_bench_filter_script_runs_and_refuses_bad_counts():
    """scripts/bench_filter.py end to end on tiny settings (the stencil and CSR beliefs agree), and
    a count below 1 is an argument error naming it, not a crash or an infinite time."""
    import subprocess

    script = Path(__file__).resolve().parents[1] / "scripts" / "bench_filter.py"
    run = [sys.executable, str(script), "--sizes", "8", "--steps", "2", "--no-memory"]
    out = subprocess.run([*run, "--repeats", "1"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    diff = re.search(r"largest \|stencil - csr\| belief difference: (\S+)", out.stdout)
    assert diff and float(diff.group(1)) < 1e-12
    for flag in ("--repeats", "--steps"):
        bad = subprocess.run([*run, flag, "0"], capture_output=True, text=True, timeout=300)
        assert bad.returncode == 2 and f"{flag} must be at least 1, got 0" in bad.stderr


def test_the_environments_filter_refuses_a_log_likelihood_it_does_not_have():
    """The environment's exact_filter shows the step's posterior, which is computed without
    log P(readings): asking for it is an error that says what to run instead, never a 0.0."""
    from gym_gridloc import HMMBeliefWrapper

    env = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    env.reset(seed=0)
    env.step(0)
    with pytest.raises(ValueError, match=r"ForwardFilter\(env.unwrapped.model\)"):
        env.filter.log_likelihood
    own = ForwardFilter(env.unwrapped.model).reset(reading=0)
    assert own.log_likelihood < 0.0
