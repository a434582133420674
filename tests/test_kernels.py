"""The filter kernels (gym_gridloc/kernels.py): numba only on small models and imported lazily (never
by a process that only builds large grids), chosen by the belief's cell count, and the numpy
diagonal path (its diagonal pass: tests/test_readout.py).  Both paths against the dense reference: tests/test_engine.py."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import engine, kernels
from gym_gridloc.core.model import mean_transition, move_terms
from gym_gridloc.generators import colour_map
from tests.helpers import run_python


def cells(model) -> int:
    return int(np.prod(model.belief_shape))


def test_a_large_environment_never_imports_numba():
    code = (
        "import sys, gymnasium as gym, gym_gridloc\n"
        "from gym_gridloc import engine\n"
        "env = gym_gridloc.HMMBeliefWrapper(gym.make('ColourGrid-v0', size=(512, 512)))\n"
        "env.reset(seed=0)\n"
        "for t in range(3):\n"
        "    env.step(t % 4)\n"
        "print('numba' in sys.modules, engine.path(env.unwrapped.model))\n"
    )
    assert run_python(code) == "False numpy"


def test_importing_the_package_and_kernels_does_not_import_numba():
    code = "import sys, gym_gridloc, gym_gridloc.kernels, gym_gridloc.engine; print('numba' in sys.modules)"
    assert run_python(code) == "False"


def test_a_small_model_loads_numba_on_first_filter_step():
    if importlib.util.find_spec("numba") is None:
        pytest.skip("numba is not installed")
    code = (
        "import sys, gym_gridloc\n"
        "from gym_gridloc import engine\n"
        "m = gym_gridloc.windy_maze_model()\n"
        "before = 'numba' in sys.modules\n"
        "f = gym_gridloc.ForwardFilter(m).reset([0, 0, 0, 1]).step(0, [0, 1, 0, 0])\n"
        "print(before, 'numba' in sys.modules, engine.path(m))\n"
    )
    assert run_python(code) == "False True numba"
    assert run_python(code, GYM_GRIDLOC_NO_NUMBA="1") == "False False numpy"


def test_uses_numba_by_belief_cells(monkeypatch):
    if importlib.util.find_spec("numba") is None:
        pytest.skip("numba is not installed")
    small = gym_gridloc.ring_sensor_model((64, 64))  # 4,096 cells
    seed = gym_gridloc.ring_sensor_model((64, 64), dynamics="passive")  # 4 layers: 16,384 cells
    big = gym_gridloc.ring_sensor_model((128, 128))
    monkeypatch.setattr(kernels, "AVAILABLE", True)
    assert kernels.uses_numba(cells(small))
    assert not kernels.uses_numba(cells(seed))
    assert not kernels.uses_numba(cells(big))
    assert kernels.uses_numba(kernels.NUMBA_MAX_CELLS - 1) and not kernels.uses_numba(kernels.NUMBA_MAX_CELLS)
    assert engine.path(seed) == "numpy" and engine.path(big) == "numpy"
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    assert not kernels.uses_numba(cells(small))
    assert engine.path(small) == "numpy"
    assert engine.path(small) == "numpy"  # built once per model: switching numba back on later
    monkeypatch.setattr(kernels, "AVAILABLE", True)  # changes the models built from then on
    assert engine.path(small) == "numpy"
    assert engine.path(gym_gridloc.ring_sensor_model((64, 64))) == "numba"


def test_make_plan_covers_every_action_and_their_average(monkeypatch):
    model = gym_gridloc.windy_maze_model()
    transitions = (*model.transitions, mean_transition(model.transitions))
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 0)
    plan = kernels.make_plan(transitions, model.n_layers, model.shape)
    assert isinstance(plan, kernels.NumpyPlan) and plan.path == "numpy" and len(plan.single) == 5
    if kernels.AVAILABLE:
        monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 10**9)
        fast = kernels.make_plan(transitions, model.n_layers, model.shape)
        assert isinstance(fast, kernels.NumbaPlan) and fast.path == "numba" and fast.w.shape[0] == 5
        b = np.ascontiguousarray(model.prior().reshape(-1))
        for a in range(5):
            one, two = np.empty_like(b), np.empty_like(b)
            plan.run_one(b, a, np.zeros(1), 0, one, 0)
            fast.run_one(b, a, np.zeros(1), 0, two, 0)
            np.testing.assert_allclose(one, two, rtol=0, atol=1e-15)


def test_diagonal_plan_of_raw_terms_equals_the_model():
    # Terms straight from move_terms (not merged or shared by a model): one diagonal each.
    model = gym_gridloc.colour_grid_model(colour_map((19, 24), obstacle_density=0.3, seed=2))
    probs = np.array([0.925, 0.025, 0.025, 0.025])  # action 0 with slip 0.1
    plan = kernels.NumpyPlan([move_terms(model.grid, probs)], model.n_layers, model.shape)
    zero, writes, adds = plan.single[0]
    assert zero == () and len(writes) == 1 and len(adds) == 4
    b = model.prior() * np.random.default_rng(0).random(model.belief_shape)
    out = np.full(model.belief_shape, np.nan)
    plan.predict_one(b.reshape(-1), 0, out.reshape(-1))
    ref = model.from_vector(engine.transition_matrix(model, 0).T @ model.to_vector(b))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
    assert np.all(out[:, ~model.grid.free] == 0.0)
    # The batched form of the same plan (shared shifts over N beliefs) gives the same numbers.
    batch = np.stack([b.reshape(-1), 2 * b.reshape(-1)])
    res = np.full_like(batch, np.nan)
    z = plan.run(batch, np.zeros(2, dtype=np.int64), np.zeros((2, 1)), 0, res, 0, np.ones(2, dtype=bool))
    np.testing.assert_array_equal(z, [1.0, 1.0])
    np.testing.assert_allclose(res[0], ref.reshape(-1), rtol=0, atol=1e-15)
    np.testing.assert_allclose(res[1], 2 * ref.reshape(-1), rtol=0, atol=1e-15)
