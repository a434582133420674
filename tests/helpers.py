"""The test suite's one helpers module: shared models, simulation on the engine, the dense
reference, comparisons, subprocesses (a runner; a started session's processes, and killing them
all) and the property-test machinery of the env families.

Every test file imports what it needs as ``from tests.helpers import ...``: one module, longer than
400 lines, so that no helper is written twice in two places.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
import weakref
from datetime import timedelta
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import load_env_creator
from gymnasium.utils.env_checker import check_env
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.control import currently_in_test_context, event

import gym_gridloc
from gym_gridloc import (
    BatchFilter,
    ForwardFilter,
    GridMap,
    HMMBeliefWrapper,
    colour_grid_model,
    depth_maze_model,
    engine,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.generators import perfect_maze

# -- the registry ------------------------------------------------------------------------------------
ENV_IDS = list(gym_gridloc.ENV_IDS)
#: The same environments under their namespaced ids (``gym_gridloc/WindyMaze-v0``).
NAMESPACED_IDS = list(gym_gridloc.NAMESPACED_IDS)
#: The environment class of every registered id.
ENV_CLASSES = {env_id: load_env_creator(gym.spec(env_id).entry_point) for env_id in ENV_IDS}
#: Every registered id, plus the ring sensor's other dynamics (hidden heading).
CONFIGS = [(env_id, {}) for env_id in ENV_IDS] + [("RingSensor8x8-v0", {"dynamics": "passive"})]
CONFIG_IDS = [f"{i}{'-' + '-'.join(f'{k}={v}' for k, v in kw.items()) if kw else ''}" for i, kw in CONFIGS]
WRAPPED_WARNING = "is different from the unwrapped version"


def run_check_env(env) -> None:
    """``check_env`` with every warning turned into a failure, except the one saying a wrapped env
    is being checked (we check wrapped envs on purpose)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    unexpected = [str(w.message) for w in caught if WRAPPED_WARNING not in str(w.message)]
    assert not unexpected, unexpected


def assert_same(a, b, where="") -> None:
    """Exact equality of nested observations / infos, including types of scalars."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), f"{where}: keys {a.keys()} != {b.keys()}"
        for k in a:
            assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b), f"{where}: {a!r} != {b!r}"
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} != {b!r}"


def rollout(env, seed: int, n_steps: int, action_seed: int = 0) -> list:
    """``n_steps`` steps with fixed random actions, resetting (unseeded) when an episode ends."""
    actions = np.random.default_rng(action_seed).integers(0, env.action_space.n, size=n_steps)
    obs, info = env.reset(seed=seed)
    out = [("reset", obs, info)]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(int(a))
        out.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            out.append(("reset", obs, info))
    return out


def assert_same_rollouts(ra: list, rb: list) -> None:
    assert len(ra) == len(rb)
    for i, (x, y) in enumerate(zip(ra, rb)):
        for j, (u, v) in enumerate(zip(x, y)):
            assert_same(u, v, f"record {i}, field {j}")


# -- models ------------------------------------------------------------------------------------------
COLOUR_MAP_WITH_WALLS = ["R,.,G,B", "Y,.,.,R", "G,B,.,Y"]
MAZE_WITH_WALLS = ["O#OOO", "O#O#O", "OOO#O", "##OOO"]
#: A cell enclosed on all sides (no move is possible from it) and a dead-end corridor.
MAZE_ENCLOSED = ["O#OO", "##OO", "OOO#"]


def obstacle_layout(rows) -> GridMap:
    """A map of ``O`` (free) and ``#`` (obstacle) rows as a GridMap (no parsing)."""
    return GridMap(np.array([[0 if ch == "O" else -1 for ch in row] for row in rows]), ("O",))


#: Every model variant: the builders' edges (slip 0 and 1, 1x1 maps, enclosed cells, keep 0 and 1,
#: walls, kidnapping).
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
    "ring seed dynamics": lambda: ring_sensor_model(dynamics="passive"),
    "ring 5x5 seed": lambda: ring_sensor_model((5, 5), dynamics="passive"),
    "ring 1x1 commanded": lambda: ring_sensor_model((1, 1)),
    "ring 1x1 seed": lambda: ring_sensor_model((1, 1), dynamics="passive"),
    "ring 1x6 commanded": lambda: ring_sensor_model((1, 6)),
    "ring 1x6 seed": lambda: ring_sensor_model((1, 6), dynamics="passive"),
    "ring 7x2 seed": lambda: ring_sensor_model((7, 2), dynamics="passive", keep_heading=0.5),
    "ring 3x9 keep 1": lambda: ring_sensor_model((3, 9), keep_heading=1.0, p_true=0.3, p_ring1=0.02, p_ring2=0.01),
    "ring keep 0 seed": lambda: ring_sensor_model((4, 4), dynamics="passive", keep_heading=0.0),
    "ring walls commanded": lambda: ring_sensor_model(layout=obstacle_layout(MAZE_WITH_WALLS)),
    "ring walls seed": lambda: ring_sensor_model(dynamics="passive", layout=obstacle_layout(MAZE_ENCLOSED)),
    "windy kidnapped": lambda: windy_maze_model(MAZE_WITH_WALLS).with_kidnapping(0.05),
    "depth default": lambda: depth_maze_model(perfect_maze(7, seed=1), max_depth=5),
    "depth noisy": lambda: depth_maze_model(perfect_maze(9, seed=2), p_turn_fail=0.1, p_move_fail=0.2, p_depth_error=0.3),
    "depth open room": lambda: depth_maze_model(["OOO", "O#O", "OOO"], p_depth_error=0.5),
    "depth kidnapped": lambda: depth_maze_model(perfect_maze(5, seed=3), p_depth_error=0.1).with_kidnapping(0.1),
}
ALL_VARIANTS = pytest.mark.parametrize("name", list(VARIANTS))

#: The registered environments' default models (the depth maze's with noise), and the environment of each.
DEFAULT_MODELS = {
    "colour": lambda: colour_grid_model(),
    "windy": lambda: windy_maze_model(),
    "ring": lambda: ring_sensor_model((8, 8)),
    "ring-seed": lambda: ring_sensor_model((8, 8), dynamics="passive"),
    # Noisy, so that its draws have something to be compared with (the default robot is exact).
    "depth-noisy": lambda: depth_maze_model(perfect_maze(7, seed=0), max_depth=5, p_turn_fail=0.1, p_move_fail=0.1,
                                            p_depth_error=0.2),
}
ENV_OF_MODEL = {
    "colour": ("ColourGrid-v0", {}),
    "windy": ("WindyMaze-v0", {}),
    "ring": ("RingSensor8x8-v0", {}),
    "ring-seed": ("RingSensor8x8-v0", {"dynamics": "passive"}),
    "depth-noisy": ("DepthMaze-v0", {"map_seed": 0, "p_turn_fail": 0.1, "p_move_fail": 0.1, "p_depth_error": 0.2}),
}


def likelihood_at(model, reading: int, state) -> float:
    """P(reading | state) for a ``(layer, row, col)`` state, for position and layered sensors."""
    lik = model.likelihood(int(reading))
    layer, r, c = (int(v) for v in state)
    return float(lik[layer, r, c] if lik.ndim == 3 else lik[r, c])


def arrays_of(obj) -> list[np.ndarray]:
    """Every numpy array reachable from obj's attributes (one level into tuples, lists, dicts)."""
    out = []
    for value in vars(obj).values():
        items = value.values() if isinstance(value, dict) else value if isinstance(value, (tuple, list)) else [value]
        for v in items:
            if isinstance(v, np.ndarray):
                out.append(v)
    return out


def actions_and_unknown(model) -> list:
    """Every action of ``model``, then None (the unknown action)."""
    return [*range(model.n_actions), None]


# -- simulation on the engine ------------------------------------------------------------------------
def simulate(model, n_steps: int, seed, actions=None) -> tuple[list, list, list]:
    """``(actions, observations, states)`` of an episode sampled from ``model`` by
    :func:`gym_gridloc.engine.simulate`: ``n_steps`` actions (drawn uniformly unless given),
    ``n_steps + 1`` observations as the environment emits them (the reset reading first) and
    ``n_steps + 1`` states as ``(layer, row, col)`` tuples.  ``seed``: an int or a Generator."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    states, acts, readings = engine.simulate(model, n_steps, rng, actions)
    obs = [model.sensor.to_observation(int(r)) for r in readings]
    return [int(a) for a in acts], obs, [tuple(int(v) for v in s) for s in states]


def one_state(state) -> np.ndarray:
    """A ``(layer, row, col)`` tuple as the engine's ``(1, 3)`` state array."""
    return np.array([state], dtype=np.int64)


# -- the dense reference -----------------------------------------------------------------------------
_DENSE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def dense_transition(model, action) -> np.ndarray:
    """``engine.transition_matrix(model, action)`` as a dense (S, S) array (cached per model)."""
    cache = _DENSE.setdefault(model, {})
    if action not in cache:
        cache[action] = engine.transition_matrix(model, action).toarray()
    return cache[action]


def dense_step(model, vector: np.ndarray, action, reading=None) -> np.ndarray:
    """The dense reference step on an (S,) vector: ``v' = T^T v`` (``reading`` None), else
    ``v' = O T^T v`` normalised (``O`` the reading's likelihood)."""
    v = dense_transition(model, action).T @ vector
    if reading is None:
        return v
    v = v * model.likelihood_vector(reading)
    return v / v.sum()


def random_belief(model, rng: np.random.Generator, power: float = 1.0) -> np.ndarray:
    """A random normalised (L, H, W) belief, zero on obstacles."""
    b = np.where(model.state_mask, rng.random(model.belief_shape) ** power, 0.0)
    return b / b.sum()


# -- batched vs single -------------------------------------------------------------------------------
def assert_batch_equals_singles(model, n: int, steps: int, seed: int) -> None:
    """``BatchFilter`` over ``n`` simulated robots equals ``n`` single ``ForwardFilter``s within
    1e-12 after every step (beliefs and log-likelihoods)."""
    rng = np.random.default_rng(seed)
    states = engine.sample_initial(model, n, rng)
    obs = [model.sensor.to_observation(int(r)) for r in engine.sample_readings(model, states, rng)]
    singles = [ForwardFilter(model).reset(o) for o in obs]
    batch = BatchFilter(model, n).reset(np.array(obs))
    for _ in range(steps):
        actions = rng.integers(0, model.n_actions, n)
        states = engine.sample_next(model, states, actions, rng)
        obs = [model.sensor.to_observation(int(r)) for r in engine.sample_readings(model, states, rng)]
        for f, a, o in zip(singles, actions, obs):
            f.step(int(a), o)
        batch.step(actions, np.array(obs))
        for i, f in enumerate(singles):
            np.testing.assert_allclose(batch.full_beliefs[i], f.full_belief, rtol=0, atol=1e-12)
            np.testing.assert_allclose(batch.log_likelihood[i], f.log_likelihood, rtol=1e-12, atol=1e-9)


# -- statistics --------------------------------------------------------------------------------------
SIGMAS = 5.0


def assert_counts_match(counts: dict, probs: dict, n: int, what: str) -> None:
    """Each outcome's count is within 5 binomial standard deviations of n p (plus one count of
    slack for p near 0 or 1), and outcomes of probability 0 never occur."""
    for outcome, c in counts.items():
        assert probs.get(outcome, 0.0) > 0.0, f"{what}: sampled {outcome}, which the model gives probability 0"
    for outcome, p in probs.items():
        c = counts.get(outcome, 0)
        sd = math.sqrt(n * p * (1 - p))
        assert abs(c - n * p) <= SIGMAS * sd + 1, f"{what}: outcome {outcome}: {c} of {n}, expected {n * p:.1f} ± {sd:.1f}"


def pick_states(model, k: int, seed: int) -> list[tuple[int, int, int]]:
    rng = np.random.default_rng(seed)
    idx = rng.choice(model.n_states, size=min(k, model.n_states), replace=False)
    return [model.state_of_index(int(s)) for s in idx]


# -- subprocesses ------------------------------------------------------------------------------------
def load_module(path: Path, name: str | None = None):
    """The Python file ``path`` (a script or an example, not a package module) loaded as a module."""
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_python(code: str, **env: str) -> str:
    """Run ``code`` in a fresh interpreter (``GYM_GRIDLOC_NO_NUMBA`` cleared unless given in
    ``env``); return its last line of output."""
    full = {k: v for k, v in os.environ.items() if k != "GYM_GRIDLOC_NO_NUMBA"}
    full.update(env)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    return res.stdout.strip().splitlines()[-1]


def session_processes(sid: int) -> dict[int, bytes]:
    """The live processes of session ``sid`` (a command started with ``start_new_session``: also
    the Ray workers of a Ray it started, which the raylet puts in process groups of their own, so
    that ``killpg`` misses them), with their command lines (a Ray worker's is its process title,
    ``ray::run_chunk`` while it runs a chunk).  Zombies are left out: they are dead."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            state, _, _, session = stat.read_text().rsplit(")", 1)[1].split()[:4]
            if int(session) == sid and state != "Z":
                found[int(stat.parent.name)] = (stat.parent / "cmdline").read_bytes()
    return found


def kill_session(sid: int, timeout: float = 30.0) -> None:
    """SIGKILL every process of session ``sid`` (its process group at once, then each one left)
    and wait until none is alive, so that nothing it started writes a file afterwards."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(sid, signal.SIGKILL)
    deadline = time.monotonic() + timeout
    while left := session_processes(sid):
        assert time.monotonic() < deadline, f"processes of session {sid} still alive after SIGKILL: {sorted(left)}"
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.05)


# -- property tests of the environment families (map text and keyword arguments) ---------------------
PROPERTY_SETTINGS = settings(
    max_examples=150,
    deadline=timedelta(seconds=10),  # a hang fails the example instead of stalling the suite
    derandomize=True,  # the same examples on every run (CI is reproducible)
    suppress_health_check=[HealthCheck.too_slow],
    database=None,
)
OMIT = object()


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
    import inspect

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
