"""The compiled step's sparse path (``gym_gridloc._numba_sparse``): a belief with mass on few of
its states is filtered and read out over those states only, with the numbers of the dense kernels
and of the numpy reference, to the bit."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401  (registers the environments)
from gym_gridloc import kernels
from gym_gridloc.batch import KEEP, START, STEP, Batch

needs_numba = pytest.mark.skipif(kernels.compiled(1) is None, reason="numba is not installed (or switched off)")

CASES = [
    ("DepthMaze-v0", {"map_seed": 3}),  # noiseless: a handful of poses after a few readings
    ("DepthMaze-v0", {"size": 15, "map_seed": 1, "p_depth_error": 0.1, "p_move_fail": 0.1}),
    ("WindyMaze-v0", {}),  # wind: each state feeds several
    ("ColourGrid-v0", {"size": (60, 60)}),  # more than one chunk of cells per layer
]


def _pair(model, n, pose):
    rules = dict(threshold=0.6, pose=pose, reward="belief", limit=30, observed=True)
    compiled, reference = Batch(model, n, **rules), Batch(model, n, **rules)
    assert compiled.bank is not None
    reference.bank = None  # the numpy reference
    return compiled, reference


def _same_step(compiled, reference, actions, modes, a, b):
    got, want = compiled.advance(actions, modes, a), reference.advance(actions, modes, b)
    assert compiled.beliefs.tobytes() == reference.beliefs.tobytes()
    assert np.array_equal(compiled.rows.states, reference.rows.states)
    for k in got.info:
        assert got.info[k].tobytes() == want.info[k].tobytes(), k
    assert got.positions.tobytes() == want.positions.tobytes()
    for x, y in zip(got[3:], want[3:]):
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()


def _sparse_beliefs(model, n, rng, at_most):
    """``n`` beliefs with mass on 1..``at_most`` free states each (normalised)."""
    free = np.flatnonzero(np.broadcast_to(model.grid.free, model.belief_shape).reshape(-1))
    out = np.zeros((n, int(np.prod(model.belief_shape))))
    for i in range(n):
        chosen = rng.choice(free, size=int(rng.integers(1, at_most + 1)), replace=False)
        out[i, chosen] = rng.random(chosen.size) + 1e-3
        out[i] /= out[i].sum()
    return out


@needs_numba
@pytest.mark.parametrize("env_id, kwargs", CASES)
@pytest.mark.parametrize("pose", [False, True])
def test_sparse_beliefs_are_filtered_to_the_bit(env_id, kwargs, pose):
    """Beliefs on few states, set by hand: the compiled step (which finds their states with mass
    and takes the sparse path) equals the numpy reference, step after step (the sparse path then
    feeds itself its own lists of states)."""
    model = gym.make(env_id, **kwargs).unwrapped.model
    n = 9
    compiled, reference = _pair(model, n, pose)
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    rng = np.random.default_rng(0)
    _same_step(compiled, reference, None, np.full(n, START, dtype=np.int8), a, b)
    size = compiled.rows.beliefs.shape[2]
    start = _sparse_beliefs(model, n, rng, max(1, size // 16))
    # each row's true state: one with mass (its reading then possible)
    for batch in (compiled, reference):
        batch.rows.belief[:] = start
    picks = [int(rng.choice(np.flatnonzero(start[i]))) for i in range(n)]
    h, w = model.shape
    states = np.array([[p // (h * w), (p % (h * w)) // w, p % w] for p in picks], dtype=np.int64)
    compiled.rows.states[:], reference.rows.states[:] = states, states
    compiled.blocks.spans[:] = -1  # (the beliefs were set by hand: unknown)
    sparse = 0
    for t in range(20):
        actions = rng.integers(0, model.n_actions, size=n)
        modes = np.full(n, STEP, dtype=np.int8) if t < 10 else rng.choice([STEP, STEP, STEP, KEEP, START], size=n).astype(np.int8)
        _same_step(compiled, reference, actions, modes, a, b)
        sparse += int((compiled.blocks.spans >= 0).sum())
    assert sparse > 0  # the sparse path was taken
    assert a.random() == b.random()


@needs_numba
def test_a_maze_runs_sparse_and_the_fixed_maps_mostly_dense():
    """In DepthMaze's episodes most steps take the sparse path; RingSensor8x8's and WindyMaze's
    beliefs hold mass on too many positions, and their rows are mostly (WindyMaze: never) even
    searched for their states with mass (-2: known to be too many)."""
    for env_id, least in (("DepthMaze-v0", 0.5), ("RingSensor8x8-v0", 0.0), ("WindyMaze-v0", 0.0)):
        env = gym.make_vec(env_id, num_envs=16, vectorization_mode="vector_entry_point").unwrapped
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        spans = []
        for _ in range(200):
            env.step(rng.integers(0, env.single_action_space.n, size=16))
            spans.append(env.batch.blocks.spans.copy())
        spans = np.concatenate(spans[50:])
        if least:
            assert (spans >= 0).mean() > least
        else:
            assert (spans == -2).mean() > (0.999 if env_id == "WindyMaze-v0" else 0.9)
