"""Robustness (issue 5): arbitrary inputs, model mismatch and long runs.

1. Property-based tests (hypothesis) over map text and keyword arguments: every input either
   builds a working environment or raises ValueError/TypeError naming what is wrong; never an
   IndexError, a ZeroDivisionError, a NaN or a hang.  An independent oracle says which inputs are
   valid, so both directions are checked.
2. Model mismatch: an impossible observation raises ImpossibleObservationError (a ValueError), or
   with ``on_impossible="reset"`` restarts the belief from the prior and says so in ``info``.
3. Long runs with sharp sensors: the belief stays finite and normalised and memory stays flat.
"""

from __future__ import annotations

import contextlib
import importlib.util
import inspect
import math
import signal
import threading
import tempfile
import tracemalloc
import warnings
from datetime import timedelta
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis.control import currently_in_test_context, event
from hypothesis import strategies as st

import gym_gridloc
from gym_gridloc import (
    ColourGridEnv,
    ForwardFilter,
    HMMBeliefWrapper,
    ImpossibleObservationError,
    RingSensorEnv,
    WindyMazeEnv,
    colour_grid_model,
    ring_sensor_model,
    windy_maze_model,
)

ROOT = Path(__file__).resolve().parents[1]
PROPERTY_SETTINGS = settings(
    max_examples=150,
    deadline=timedelta(seconds=10),  # a hang fails the example instead of stalling the suite
    derandomize=True,  # the same examples on every run (CI is reproducible)
    suppress_health_check=[HealthCheck.too_slow],
    database=None,
)
OMIT = object()


# -- strategies ----------------------------------------------------------------------------------
def good_probability():
    return st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1.0, 0, 1, 0.5]))


def bad_probability():
    return st.one_of(
        st.floats(allow_nan=True, allow_infinity=True).filter(lambda v: not 0.0 <= v <= 1.0),
        st.sampled_from(["0.5", None, True, [0.5], -1, 2]),
    )


def maybe(good, bad):
    """Omitted 4 times in 10, a good value 5 times, a bad one once."""
    return st.integers(0, 9).flatmap(lambda k: st.just(OMIT) if k < 4 else (good if k < 9 else bad))


def is_probability(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0.0 <= v <= 1.0


def probability_names(cls) -> list[str]:
    """The float keywords of an environment class with defaults in [0, 1] (new ones included)."""
    skip = {"localise_threshold"}
    return [n for n, p in inspect.signature(cls.__init__).parameters.items()
            if n not in skip and isinstance(p.default, float) and 0.0 <= p.default <= 1.0]


def threshold_strategy():
    good = st.one_of(st.floats(0.0, 1.0, exclude_min=True), st.just(1.0), st.just(1))
    bad = st.sampled_from([0, 0.0, -0.1, 1.5, float("nan"), float("inf"), "0.9", None])
    return maybe(good, bad)


@st.composite
def kwargs_for(draw, cls, special=None):
    """Keyword arguments for ``cls``: every probability keyword, the threshold."""
    special = special or {}
    kwargs = {}
    for name in probability_names(cls):
        strategy = special[name] if name in special else maybe(good_probability(), bad_probability())
        v = draw(strategy)
        if v is not OMIT:
            kwargs[name] = v
    t = draw(threshold_strategy())
    if t is not OMIT:
        kwargs["localise_threshold"] = t
    return kwargs


def bad_keywords(kwargs: dict, extra_checks=()) -> set[str]:
    """The keyword names whose values an oracle calls invalid."""
    bad = set()
    for k, v in kwargs.items():
        if k == "localise_threshold":
            if not (is_probability(v) and v > 0):
                bad.add(k)
        elif k in ("size", "dynamics"):
            continue
        elif not is_probability(v):
            bad.add(k)
    for check in extra_checks:
        bad |= check(kwargs, bad)
    return bad


COLOUR_CELLS = ["R", "G", "B", "Y", "."]
ODD_CELLS = ["X", "", " R", "G ", "r", "RR", "\t", "é", "O", "#"]


@st.composite
def colour_rows(draw):
    """Rows of comma-separated cells: mostly rectangular and valid, sometimes ragged or odd."""
    clean = draw(st.integers(0, 3)) > 0  # only valid symbols 3 times in 4
    cell = st.sampled_from(COLOUR_CELLS) if clean else st.one_of(st.sampled_from(COLOUR_CELLS), st.sampled_from(ODD_CELLS))
    if draw(st.integers(0, 3)) > 0:  # rectangular
        h, w = draw(st.integers(1, 5)), draw(st.integers(1, 5))
        cells = [[draw(cell) for _ in range(w)] for _ in range(h)]
    else:
        cells = draw(st.lists(st.lists(cell, max_size=5), max_size=5))
    return [",".join(r) for r in cells]


def colour_map_ok(rows: list[str]) -> bool:
    if not rows:
        return False
    split = [[c.strip() for c in r.split(",")] for r in rows]
    if any(r == "" for r in rows) or len({len(s) for s in split}) != 1:
        return False
    if any(c not in COLOUR_CELLS for s in split for c in s):
        return False
    return any(c != "." for s in split for c in s)


@st.composite
def maze_rows(draw):
    clean = draw(st.integers(0, 3)) > 0
    char = st.sampled_from("OOO#") if clean else st.sampled_from("OO##x. \t")
    if draw(st.integers(0, 3)) > 0:
        h, w = draw(st.integers(1, 6)), draw(st.integers(1, 6))
        return ["".join(draw(char) for _ in range(w)) for _ in range(h)]
    return draw(st.lists(st.text(char, max_size=6), max_size=5))


def maze_ok(rows: list[str]) -> bool:
    if not rows or any(r == "" for r in rows) or len({len(r) for r in rows}) != 1:
        return False
    if any(c not in "O#" for r in rows for c in r):
        return False
    return any("O" in r for r in rows)


# -- the property ----------------------------------------------------------------------------------
@contextlib.contextmanager
def hard_timeout(seconds: int):
    """Fail (instead of hanging forever) if the block runs longer than ``seconds``; hypothesis's
    deadline only judges an example after it returns."""
    if not hasattr(signal, "SIGALRM") or threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_alarm(signum, frame):
        raise TimeoutError(f"an example ran for more than {seconds} s (a hang?)")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def exercise(make, bad_names: set[str], map_ok: bool, source: str | None = None) -> None:
    """``make()`` either fails with ValueError/TypeError naming something bad, or gives an
    environment that resets, steps, and keeps finite beliefs summing to 1."""
    expect_error = bool(bad_names) or not map_ok
    with hard_timeout(30), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # divide by zero, invalid value, overflow
        try:
            env = make()
        except (ValueError, TypeError) as exc:
            message = str(exc)
            names = set(bad_names)
            if not map_ok:
                names |= {"layout", "<layout>"} | ({source} if source else set())
            assert expect_error, f"valid input rejected: {message}"
            assert any(n in message for n in names), f"message {message!r} names none of {sorted(names)}"
            if currently_in_test_context():  # statistics: pytest --hypothesis-show-statistics
                event(f"rejected: {type(exc).__name__}")
            return
        assert not expect_error, f"invalid input accepted (bad: {sorted(bad_names)}, map ok: {map_ok})"
        if currently_in_test_context():
            event("built and ran")
        wrapped = HMMBeliefWrapper(env, full_state=True)
        rng = np.random.default_rng(0)
        obs, info = wrapped.reset(seed=int(rng.integers(1000)))
        for t in range(6):
            b = obs["belief"]
            assert np.all(np.isfinite(b)) and abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
            post = env.unwrapped.posterior
            assert np.all(np.isfinite(post)) and abs(post.sum() - 1.0) < 1e-9
            assert 0.0 <= info["confidence"] <= 1.0 and math.isfinite(info["entropy"]) and info["entropy"] >= 0
            assert env.unwrapped.model.grid.free[info["position"]] and env.unwrapped.model.grid.free[info["estimate"]]
            obs, reward, terminated, truncated, info = wrapped.step(int(rng.integers(wrapped.action_space.n)))
            assert reward == -1.0 and type(terminated) is bool and type(truncated) is bool
            assert terminated == (info["confidence"] >= env.unwrapped.localise_threshold)


def drift_check(kwargs, bad):
    v = kwargs.get("drift", 0.1)
    return {"drift"} if is_probability(v) and v > 0.5 else set()


def ring_sum_check(kwargs, bad):
    if bad & {"p_true", "p_ring1", "p_ring2"}:
        return set()
    total = kwargs.get("p_true", 0.1) + 8 * kwargs.get("p_ring1", 0.05) + 16 * kwargs.get("p_ring2", 0.025)
    return {"p_true"} if total > 1.0 + 1e-12 else set()


@PROPERTY_SETTINGS
@given(rows=colour_rows(), kwargs=kwargs_for(ColourGridEnv), as_file=st.booleans())
def test_colour_grid_any_input(rows, kwargs, as_file):
    if as_file:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "map.csv"
            path.write_text("\n".join(rows) + "\n", encoding="utf-8")
            # A file's trailing blank lines are not rows.
            trimmed = list(rows)
            while trimmed and not trimmed[-1].strip():
                trimmed.pop()
            ok = colour_map_ok(trimmed) and "\r" not in "".join(rows)
            exercise(lambda: gym.make("ColourGrid-v0", layout=str(path), **kwargs), bad_keywords(kwargs), ok, str(path))
    else:
        exercise(lambda: gym.make("ColourGrid-v0", layout=rows, **kwargs), bad_keywords(kwargs), colour_map_ok(rows))


@PROPERTY_SETTINGS
@given(rows=maze_rows(), kwargs=kwargs_for(WindyMazeEnv, {"drift": maybe(st.floats(0.0, 0.5) | st.sampled_from([0.0, 0.5]),
                                                                          st.floats(0.5, 1.0, exclude_min=True))}))
def test_windy_maze_any_input(rows, kwargs):
    exercise(lambda: gym.make("WindyMaze-v0", layout=rows, **kwargs), bad_keywords(kwargs, [drift_check]), maze_ok(rows))


SIZES = st.one_of(
    st.tuples(st.integers(1, 7), st.integers(1, 7)),
    st.tuples(st.integers(1, 7), st.integers(1, 7)),
    st.integers(1, 6),
    st.sampled_from([(0, 5), (5, 0), -1, 0, (2, -3)]),
)


@PROPERTY_SETTINGS
@given(
    size=SIZES,
    dynamics=st.sampled_from(["commanded", "seed"] * 4 + ["foo", "Seed"]),
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
    if dynamics not in ("commanded", "seed"):
        bad.add("dynamics")
    exercise(lambda: gym.make("RingSensor8x8-v0", size=size, dynamics=dynamics, **kwargs), bad, True)


# Edge cases named in the issue, run explicitly (they are also in the strategies' reach).
EDGES = [
    ("WindyMaze-v0", {"layout": ["O"]}),  # 1x1
    ("ColourGrid-v0", {"layout": ["Y"]}),
    ("ColourGrid-v0", {"layout": [".,.,.", ".,G,.", ".,.,."]}),  # a single free cell
    ("WindyMaze-v0", {"layout": ["O#O", "###", "O#O"]}),  # four disconnected parts
    ("ColourGrid-v0", {"layout": ["R,.,R", ".,.,.", "R,.,G"], "slip": 0.0, "accuracy": 1.0}),
    ("ColourGrid-v0", {"accuracy": 1.0, "slip": 1.0, "localise_threshold": 1.0}),
    ("ColourGrid-v0", {"accuracy": 0.0, "slip": 0.0}),
    ("WindyMaze-v0", {"p_detect": 1.0, "p_false_alarm": 0.0, "drift": 0.0, "localise_threshold": 1.0}),
    ("WindyMaze-v0", {"p_detect": 0.0, "p_false_alarm": 1.0, "drift": 0.5}),
    ("RingSensor8x8-v0", {"p_true": 1.0, "p_ring1": 0.0, "p_ring2": 0.0}),
    ("RingSensor8x8-v0", {"p_true": 1.0, "p_ring1": 0.0, "p_ring2": 0.0, "dynamics": "seed", "localise_threshold": 1.0}),
    ("RingSensor8x8-v0", {"size": (1, 1)}),
    ("RingSensor8x8-v0", {"size": (1, 1), "dynamics": "seed"}),
    ("RingSensor8x8-v0", {"size": (1, 5), "keep_heading": 1.0}),
    ("RingSensor8x8-v0", {"size": (3, 3), "keep_heading": 0.0, "dynamics": "seed"}),
    ("RingSensor8x8-v0", {"p_true": 0.0, "p_ring1": 0.0, "p_ring2": 0.0}),  # the sensor says nothing
]


@pytest.mark.parametrize("env_id,kwargs", EDGES, ids=[f"{e}-{k}" for e, k in EDGES])
def test_edge_cases_run(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    exercise(lambda: env, set(), True)
    # Under the true model no observation is ever impossible, even with 0/1 probabilities.
    wrapped = HMMBeliefWrapper(gym.make(env_id, **kwargs))
    wrapped.reset(seed=1)
    for t in range(300):
        obs, _, terminated, truncated, _ = wrapped.step(t % wrapped.action_space.n)
        assert np.all(np.isfinite(obs["belief"]))
        if terminated or truncated:
            wrapped.reset()


def test_single_free_cell_is_localised_at_once():
    env = gym.make("ColourGrid-v0", layout=[".,.,.", ".,G,.", ".,.,."])
    _, info = env.reset(seed=0)
    assert info["confidence"] == 1.0 and info["localised"] and info["success"] and info["entropy"] == 0.0
    _, _, terminated, _, info = env.step(0)
    assert terminated and info["position"] == (1, 1)


# -- model mismatch --------------------------------------------------------------------------------
#: Filter models that call some of the environment's readings impossible.
SHARP_MISMATCH = {
    "ColourGrid-v0": lambda: colour_grid_model(accuracy=1.0, slip=0.0),
    "RingSensor8x8-v0": lambda: ring_sensor_model((8, 8), p_true=1.0, p_ring1=0.0, p_ring2=0.0),
    "WindyMaze-v0": lambda: windy_maze_model(p_detect=1.0, p_false_alarm=0.0, drift=0.0),
}


@pytest.mark.parametrize("env_id", list(gym_gridloc.ENV_IDS))
def test_impossible_observation_raises_by_default(env_id):
    env = HMMBeliefWrapper(gym.make(env_id).unwrapped, model=SHARP_MISMATCH[env_id]())
    pattern = (r"impossible under the filter's model .* \(model mismatch\?\); "
               r"pass on_impossible='reset' to HMMBeliefWrapper to restart the belief from the prior")
    seed = 0
    while True:  # find a start whose first reading the sharp model allows
        try:
            env.reset(seed=seed)
            break
        except ImpossibleObservationError as exc:
            assert isinstance(exc, ValueError) and "impossible" in str(exc)
            seed += 1
    with pytest.raises(ImpossibleObservationError, match=pattern) as caught:
        for t in range(2000):
            before = env.belief_array().copy()
            env.step(t % 4)
    assert isinstance(caught.value, ValueError)
    # The belief is left as it was before the failed step (not poisoned with NaN).
    np.testing.assert_array_equal(env.belief_array(), before)
    assert np.all(np.isfinite(env.belief_array()))


@pytest.mark.parametrize("env_id", list(gym_gridloc.ENV_IDS))
def test_impossible_observation_resets_the_belief_when_asked(env_id):
    other = SHARP_MISMATCH[env_id]()
    env = HMMBeliefWrapper(gym.make(env_id).unwrapped, model=other, on_impossible="reset")
    obs, info = env.reset(seed=0)
    assert info["belief_reset"] in (True, False)
    for t in range(2000):
        obs, _, _, _, info = env.step(t % 4)
        assert type(info["belief_reset"]) is bool
        if info["belief_reset"]:
            break
    else:
        pytest.fail("no impossible observation in 2000 mismatched steps")
    # The belief restarted from the prior, updated with the observation if that is possible.
    fresh = ForwardFilter(other)
    try:
        fresh.reset(obs["observation"])
    except ImpossibleObservationError:
        fresh.reset()
    np.testing.assert_allclose(obs["belief"], fresh.position_belief, atol=1e-7)
    # The next ordinary step says False again.
    for t in range(50):
        obs, _, _, _, info = env.step(t % 4)
        if not info["belief_reset"]:
            break
    assert info["belief_reset"] is False


def test_on_impossible_reset_on_the_first_reading():
    """An impossible first reading (before any move) also restarts from the prior."""
    other = colour_grid_model(layout=["R,R", "R,R"], accuracy=1.0)
    env_model_map = ["G,G", "G,G"]
    env = HMMBeliefWrapper(gym.make("ColourGrid-v0", layout=env_model_map, accuracy=1.0), model=other,
                           on_impossible="reset")
    obs, info = env.reset(seed=0)
    assert info["belief_reset"] is True
    np.testing.assert_allclose(obs["belief"], np.full((2, 2), 0.25, dtype=np.float32))
    strict = HMMBeliefWrapper(gym.make("ColourGrid-v0", layout=env_model_map, accuracy=1.0), model=other)
    with pytest.raises(ImpossibleObservationError):
        strict.reset(seed=0)


@pytest.mark.parametrize("env_id", list(gym_gridloc.ENV_IDS))
def test_ten_thousand_mismatched_steps(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), model=SHARP_MISMATCH[env_id](), on_impossible="reset")
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=3)
    resets = episodes = 0
    for _ in range(10_000):
        obs, _, terminated, truncated, info = env.step(int(rng.integers(4)))
        b = obs["belief"]
        assert not np.isnan(b).any() and np.all(np.isfinite(b))
        assert abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
        resets += info["belief_reset"]
        if terminated or truncated:
            obs, info = env.reset()
            episodes += 1
    assert resets > 10 and episodes > 0


def test_mismatch_with_soft_model_never_resets():
    """A mismatched model with no zero probabilities can never call a reading impossible."""
    env = HMMBeliefWrapper(gym.make("ColourGrid-v0", accuracy=0.88), model=colour_grid_model(accuracy=0.999),
                           on_impossible="reset")
    env.reset(seed=0)
    for t in range(3000):
        obs, _, terminated, truncated, info = env.step(t % 4)
        assert info["belief_reset"] is False
        if terminated or truncated:
            env.reset()


# -- long runs -------------------------------------------------------------------------------------
def _load_long_run():
    spec = importlib.util.spec_from_file_location("long_run", ROOT / "scripts" / "long_run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


LONG_RUN = _load_long_run()


@pytest.mark.parametrize("name", list(LONG_RUN.SHARP))
def test_long_run_quick(name):
    """The long-run script's check, 20,000 steps: finite, summing to 1, memory flat."""
    steps = 20_000 if name in ("colour", "windy") else 8_000
    r = LONG_RUN.long_run(name, steps, seed=1, warmup=1000, trace_from=0.5, progress=False)
    assert r["max_abs_sum_error"] < 1e-9
    assert math.isfinite(r["min_log_normaliser"])
    assert r["map_accuracy"] > 0.5  # sharp sensors: the most probable position is usually right
    assert r["traced_kib_end"] - r["traced_kib_after_warmup"] < 32


@pytest.mark.parametrize("env_id,kwargs", [
    ("WindyMaze-v0", {"p_detect": 0.999, "p_false_alarm": 0.001}),
    ("ColourGrid-v0", {"accuracy": 0.999}),
])
def test_env_memory_does_not_grow(env_id, kwargs):
    """20,000 steps of a wrapped environment (never reset): the memory traced by tracemalloc at
    step 20,000 is not above that at step 5,000."""
    env = HMMBeliefWrapper(gym.make(env_id, localise_threshold=1.0, **kwargs).unwrapped)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 4, size=20_000)
    env.reset(seed=0)
    traced = {}
    for t, a in enumerate(actions, start=1):
        obs, _, _, _, info = env.step(int(a))
        if t == 4_000:
            tracemalloc.start()
        elif t in (5_000, 20_000):
            traced[t] = tracemalloc.get_traced_memory()[0]
            b = obs["belief"]
            assert np.all(np.isfinite(b)) and abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
    tracemalloc.stop()
    assert traced[20_000] - traced[5_000] < 16 * 1024, traced


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


@pytest.mark.parametrize("name", list(LONG_RUN.SHARP))
def test_unread_filter_matches_a_filter_read_every_step(name):
    """The filter may normalise lazily when nobody reads the belief: a filter left alone for 1,000
    steps at a time agrees with one read (normalised) every step, and neither underflows."""
    env_id, kwargs = LONG_RUN.SHARP[name]
    model = gym.make(env_id, **kwargs).unwrapped.model
    rng = np.random.default_rng(11)
    eager, lazy = ForwardFilter(model), ForwardFilter(model)
    state = model.sample_initial_state(rng)
    first = model.sensor.to_observation(model.sample_reading(state, rng))
    eager.reset(first)
    lazy.reset(first)
    for t in range(1, 5001):
        a = int(rng.integers(model.n_actions))
        state = model.sample_next_state(state, a, rng)
        obs = model.sensor.to_observation(model.sample_reading(state, rng))
        eager.step(a, obs)
        lazy.step(a, obs)
        b = eager.full_belief
        assert np.all(np.isfinite(b)) and abs(b.sum() - 1.0) < 1e-9
        if t % 1000 == 0:
            c = lazy.full_belief
            np.testing.assert_allclose(c, b, rtol=0, atol=1e-9)
            assert lazy.log_likelihood == pytest.approx(eager.log_likelihood, rel=1e-9)
