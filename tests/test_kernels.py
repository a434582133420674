"""The filter kernels (gym_gridloc/kernels.py): numba only on small models and imported lazily,
the numpy/scipy diagonal path on the others, both equal to the dense reference."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import ForwardFilter, kernels
from gym_gridloc.core.model import move_terms
from gym_gridloc.generators import colour_map, maze_map

MODELS = {
    "colour": lambda: gym_gridloc.colour_grid_model(colour_map((23, 31), obstacle_density=0.25, seed=3)),
    "maze": lambda: gym_gridloc.windy_maze_model(maze_map((21, 26), seed=4)),
    "ring": lambda: gym_gridloc.ring_sensor_model((17, 22)),
    "ring-seed": lambda: gym_gridloc.ring_sensor_model((15, 14), dynamics="seed"),
}


def _run(code: str, **env: str) -> str:
    full = {k: v for k, v in os.environ.items() if k != "GYM_GRIDLOC_NO_NUMBA"}
    full.update(env)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=120)
    assert res.returncode == 0, res.stderr
    return res.stdout.strip().splitlines()[-1]


def test_a_large_environment_never_imports_numba():
    code = (
        "import sys, gymnasium as gym, gym_gridloc\n"
        "env = gym_gridloc.HMMBeliefWrapper(gym.make('ColourGrid-v0', size=(512, 512)))\n"
        "env.reset(seed=0)\n"
        "for t in range(3):\n"
        "    env.step(t % 4)\n"
        "print('numba' in sys.modules, env.unwrapped.model.stencil_plan(0).path)\n"
    )
    assert _run(code) == "False numpy"


def test_importing_the_package_and_kernels_does_not_import_numba():
    code = "import sys, gym_gridloc, gym_gridloc.kernels; print('numba' in sys.modules)"
    assert _run(code) == "False"


def test_a_small_model_loads_numba_on_first_filter_step():
    if importlib.util.find_spec("numba") is None:
        pytest.skip("numba is not installed")
    code = (
        "import sys, gym_gridloc\n"
        "m = gym_gridloc.windy_maze_model()\n"
        "before = 'numba' in sys.modules\n"
        "f = gym_gridloc.ForwardFilter(m).reset([0, 0, 0, 1]).step(0, [0, 1, 0, 0])\n"
        "print(before, 'numba' in sys.modules, m.stencil_plan(0).path)\n"
    )
    assert _run(code) == "False True numba"
    assert _run(code, GYM_GRIDLOC_NO_NUMBA="1") == "False False numpy"


def test_uses_numba_by_belief_cells(monkeypatch):
    if importlib.util.find_spec("numba") is None:
        pytest.skip("numba is not installed")
    small = gym_gridloc.ring_sensor_model((64, 64))  # 4,096 cells
    seed = gym_gridloc.ring_sensor_model((64, 64), dynamics="seed")  # 4 layers: 16,384 cells
    big = gym_gridloc.ring_sensor_model((128, 128))
    monkeypatch.setattr(kernels, "AVAILABLE", True)
    assert kernels.uses_numba(small)
    assert not kernels.uses_numba(seed)
    assert not kernels.uses_numba(big)
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    assert not kernels.uses_numba(small)
    assert small.stencil_plan(0).path == "numpy"


def _dense_step(model, belief_vec, action, reading):
    v = model.transition_matrix(action).T @ belief_vec
    if reading is None:
        return v
    v = v * model.likelihood_vector(reading)
    return v / v.sum()


def _paths():
    paths = ["numpy"]
    if kernels.AVAILABLE:
        paths.append("numba")
    return paths


@pytest.mark.parametrize("path", ["numpy", "numba"])
@pytest.mark.parametrize("name", sorted(MODELS))
def test_each_path_equals_the_dense_reference(name, path, monkeypatch):
    if path not in _paths():
        pytest.skip("numba is not installed or switched off")
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 10**9 if path == "numba" else 0)
    model = MODELS[name]()
    rng = np.random.default_rng(1)
    belief = np.where(model.state_mask, rng.random(model.belief_shape), 0.0)
    belief /= belief.sum()
    vec = model.to_vector(belief)
    for action in [*range(model.n_actions), None]:
        assert model.stencil_plan(action).path == path
        pred = model.predict(belief, action)
        assert np.all(pred[~model.state_mask] == 0.0)
        np.testing.assert_allclose(model.to_vector(pred), _dense_step(model, vec, action, None), rtol=0, atol=1e-12)
    # A filter run (predict, update and normalise in one kernel call) against the dense filter.
    state = model.sample_initial_state(rng)
    first = model.sample_reading(state, rng)
    f = ForwardFilter(model).reset(model.sensor.to_observation(first))
    ref = model.to_vector(model.prior()) * model.likelihood_vector(first)
    ref /= ref.sum()
    for _ in range(12):
        a = int(rng.integers(model.n_actions))
        state = model.sample_next_state(state, a, rng)
        r = model.sample_reading(state, rng)
        f.step(a, model.sensor.to_observation(r))
        ref = _dense_step(model, ref, a, r)
        np.testing.assert_allclose(f.belief, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_two_paths_agree_on_a_filter_run(name, monkeypatch):
    if "numba" not in _paths():
        pytest.skip("numba is not installed or switched off")
    model = MODELS[name]()
    rng = np.random.default_rng(5)
    state = model.sample_initial_state(rng)
    obs = [model.sensor.to_observation(model.sample_reading(state, rng))]
    acts = []
    for _ in range(20):
        acts.append(int(rng.integers(model.n_actions)))
        state = model.sample_next_state(state, acts[-1], rng)
        obs.append(model.sensor.to_observation(model.sample_reading(state, rng)))
    runs = []
    for limit in (10**9, 0):
        monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", limit)
        f = ForwardFilter(model).reset(obs[0])
        for a, o in zip(acts, obs[1:]):
            f.step(a, o)
        runs.append(f)
    np.testing.assert_allclose(runs[0].full_belief, runs[1].full_belief, rtol=0, atol=1e-14)
    assert abs(runs[0].log_likelihood - runs[1].log_likelihood) < 1e-9


def test_diagonal_plan_of_raw_terms_equals_the_model():
    # Terms straight from move_terms (not merged or shared by a model): one diagonal each.
    model = gym_gridloc.colour_grid_model(colour_map((19, 24), obstacle_density=0.3, seed=2))
    probs = np.array([0.925, 0.025, 0.025, 0.025])  # action 0 with slip 0.1
    plan = kernels.DiagonalPlan(model, move_terms(model.grid, probs))
    assert len(plan.writes) == 1 and len(plan.adds) == 4
    b = model.prior() * np.random.default_rng(0).random(model.belief_shape)
    out = np.full(model.belief_shape, np.nan)
    plan.run(b, out, None)
    ref = model.from_vector(model.transition_matrix(0).T @ model.to_vector(b))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
    assert np.all(out[:, ~model.grid.free] == 0.0)


def test_numpy_fallback_equals_scipy_dia_matvec():
    from scipy.sparse._sparsetools import dia_matvec

    rng = np.random.default_rng(0)
    for n_row, n_col in [(50, 50), (30, 70), (70, 30)]:
        offsets = np.array([0, 1, -1, 7, -9, 40, -45], dtype=np.int32)
        length = max(n_row, n_col)
        data = rng.random((len(offsets), length))
        x = rng.random(n_col)
        y0 = rng.random(n_row)
        a, b = y0.copy(), y0.copy()
        dia_matvec(n_row, n_col, len(offsets), length, offsets, data, x, a)
        kernels._dia_matvec_numpy(n_row, n_col, len(offsets), length, offsets, data, x, b)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)


def test_predict_rejects_a_bad_out_buffer():
    model = gym_gridloc.windy_maze_model()
    b = model.prior()
    with pytest.raises(ValueError, match="out must be"):
        model.predict(b, 0, out=np.empty(model.belief_shape, dtype=np.float32))
    with pytest.raises(ValueError, match="out must be"):
        model.predict(b, 0, out=b)
    with pytest.raises(ValueError, match="belief must have shape"):
        model.predict(np.ones((2, 2)), 0)
