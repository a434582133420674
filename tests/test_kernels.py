"""The filter kernels (gym_gridloc/kernels.py): numba only on small models and imported lazily (never
by a process that only builds large grids), chosen by the belief's cell count, and the numpy
diagonal path (its diagonal pass: tests/test_readout.py).  Both paths against the dense reference: tests/test_engine.py."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import ForwardFilter, engine, kernels
from gym_gridloc.core.model import mean_transition, move_terms
from gym_gridloc.generators import colour_map, maze_map, perfect_maze
from tests.helpers import actions_and_unknown, dense_step, random_belief, run_python, simulate


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


# -- the fused step of large models (FusedPlan): the numpy plan's numbers, bit for bit -------------------
needs_numba = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed or switched off")


def fused_and_numpy(make, monkeypatch):
    """Two models from ``make``: one on the fused plan, one on the numpy plan (a plan is made once
    per model, when the model is first filtered)."""
    if not kernels._sums_in_one_piece():
        pytest.skip("this numpy sums long arrays buffer by buffer: the fused plan is not used with it")
    monkeypatch.setattr(kernels, "NUMBA_MAX_CELLS", 0)  # every model "large"
    monkeypatch.setattr(kernels, "NUMBA_LARGE", True)
    fused = make()
    assert engine.path(fused) == "fused"
    monkeypatch.setattr(kernels, "NUMBA_LARGE", False)
    plain = make()
    assert engine.path(plain) == "numpy"
    return fused, plain


RANDOM_MAKERS = {
    "colour": lambda rng: gym_gridloc.colour_grid_model(
        colour_map((int(rng.integers(2, 30)), int(rng.integers(2, 30))), obstacle_density=float(rng.uniform(0, 0.5)),
                   seed=int(rng.integers(1000))), slip=float(rng.uniform(0, 1))),
    "maze": lambda rng: gym_gridloc.windy_maze_model(maze_map((int(rng.integers(3, 25)), int(rng.integers(3, 25))),
                                                              seed=int(rng.integers(1000))), drift=float(rng.uniform(0, 0.5))),
    "ring": lambda rng: gym_gridloc.ring_sensor_model((int(rng.integers(2, 20)), int(rng.integers(2, 20)))),
    "ring-passive": lambda rng: gym_gridloc.ring_sensor_model((int(rng.integers(2, 14)), int(rng.integers(2, 14))),
                                                             dynamics="passive"),
    "depth": lambda rng: gym_gridloc.depth_maze_model(perfect_maze(int(rng.choice([5, 7, 9])), seed=int(rng.integers(1000)))),
}


@needs_numba
@pytest.mark.parametrize("coded", [False, True])
@pytest.mark.parametrize("kidnap", [0.0, 0.05])
@pytest.mark.parametrize("family", sorted(RANDOM_MAKERS))
@pytest.mark.parametrize("seed", range(3))
def test_the_fused_step_is_the_numpy_plans_to_the_bit(family, seed, kidnap, coded, monkeypatch):
    """Random maps (obstacles, mazes, headings as layers, kidnapping): every action and the unknown
    one, every mode (predict; weigh and normalise; weigh), through the plan and through the engine
    (predict, step, a filter run): the same bits as the numpy plan, and the dense reference; with
    the layers' first terms read as weights or as codes."""
    monkeypatch.setattr(kernels, "CODED_BYTES", 0 if coded else 2**62)
    fused, plain = fused_and_numpy(
        lambda: RANDOM_MAKERS[family](np.random.default_rng([seed, len(family)])).with_kidnapping(kidnap), monkeypatch)
    model, fp, pp = plain, engine.plan(fused), engine.plan(plain)
    assert (fp.spans[:, :, 4] == 2).any() == (coded and family in ("colour", "maze", "depth"))
    rng = np.random.default_rng(seed)
    layered = int(model.sensor.layered)
    for _ in range(3):
        b = random_belief(model, rng, power=float(rng.choice([1.0, 8.0]))).reshape(-1)
        b[rng.random(b.size) < 0.2] = 0.0
        b = b / b.sum() if b.sum() > 0 else model.prior().reshape(-1)
        reading = int(rng.integers(model.sensor.n_readings))
        lik = engine.likelihood(model, reading).reshape(-1)
        for action in range(model.n_actions + 1):
            for mode in (0, 1, 2):
                one, two = np.full_like(b, np.nan), np.full_like(b, np.nan)
                z1 = fp.run_one(b, action, lik, layered, one, mode)
                z2 = pp.run_one(b, action, lik, layered, two, mode)
                assert one.tobytes() == two.tobytes() and repr(z1) == repr(z2), (action, mode)
        belief = b.reshape(model.belief_shape)
        for action in actions_and_unknown(model):
            got = engine.predict(fused, belief, action)
            assert got.tobytes() == engine.predict(plain, belief, action).tobytes()
            np.testing.assert_allclose(model.to_vector(got), dense_step(model, model.to_vector(belief), action), rtol=0, atol=1e-12)
    acts, obs, _ = simulate(fused, 15, rng)
    for read_every_step in (False, True):
        f = ForwardFilter(fused, read_every_step=read_every_step).reset(obs[0])
        g = ForwardFilter(plain, read_every_step=read_every_step).reset(obs[0])
        for a, o in zip(acts, obs[1:]):
            f.step(a, o)
            g.step(a, o)
            assert f.full_belief.tobytes() == g.full_belief.tobytes()
        assert f.log_likelihood == g.log_likelihood


@needs_numba
def test_the_fused_step_on_a_large_grid(monkeypatch):
    """A grid above the numba limit (its default plan the numpy one) with GYM_GRIDLOC_NUMBA=all's
    setting: the fused plan, every action's layer in one loop, the same bits on a filter run."""
    if not kernels._sums_in_one_piece():
        pytest.skip("this numpy sums long arrays buffer by buffer: the fused plan is not used with it")
    make = lambda: gym_gridloc.colour_grid_model(colour_map((131, 140), obstacle_density=0.25, seed=7))  # noqa: E731
    monkeypatch.setattr(kernels, "NUMBA_LARGE", True)
    monkeypatch.setattr(kernels, "CODED_BYTES", 2**19)  # (this grid's stay weights: 5 x 143 KiB)
    fused = make()
    assert engine.path(fused) == "fused" and np.all(engine.plan(fused).spans[:, :, 4] == 2)
    monkeypatch.setattr(kernels, "NUMBA_LARGE", False)
    plain = make()
    assert engine.path(plain) == "numpy"
    acts, obs, _ = simulate(plain, 10, 3)
    f, g = ForwardFilter(fused).reset(obs[0]), ForwardFilter(plain).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        f.step(a, o)
        g.step(a, o)
    assert f.full_belief.tobytes() == g.full_belief.tobytes() and f.log_likelihood == g.log_likelihood


@needs_numba
def test_the_fused_sum_is_numpys_sum():
    """The pairwise program sums as ``np.add.reduce`` does, for lengths at and around its blocks
    and halves, short and long."""
    from gym_gridloc import _numba_kernels as fast

    if not kernels._sums_in_one_piece():
        pytest.skip("this numpy sums long arrays buffer by buffer: the fused plan is not used with it")
    rng = np.random.default_rng(0)
    for n in (1, 5, 7, 8, 9, 127, 128, 129, 255, 256, 257, 1000, 8191, 8192, 8193, 16384, 17161, 65537):
        a = rng.random(n) ** 5
        a[rng.random(n) < 0.3] = 0.0
        bounds, ops = fast.pairwise_program(n)
        assert bounds[0] == 0 and bounds[-1] == n and np.all(np.diff(bounds) <= 128)
        assert repr(float(fast.pairwise_sum(a, bounds, ops))) == repr(float(np.add.reduce(a))), n


def test_without_numba_large_models_keep_the_numpy_plan(monkeypatch):
    """The fused plan needs numba: switched off (or not installed), GYM_GRIDLOC_NUMBA=all's setting
    leaves a large model on the numpy plan, which filters as before."""
    fused = "fused" if kernels.AVAILABLE and kernels._sums_in_one_piece() else "numpy"  # (what a process with numba uses)
    monkeypatch.setattr(kernels, "NUMBA_LARGE", True)
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    model = gym_gridloc.colour_grid_model(colour_map((130, 129), obstacle_density=0.2, seed=1))
    assert engine.path(model) == "numpy" and type(engine.plan(model)) is kernels.NumpyPlan
    acts, obs, _ = simulate(model, 5, 0)
    f = ForwardFilter(model).reset(obs[0])
    ref = model.to_vector(model.prior()) * model.likelihood_vector(model.sensor.to_reading(obs[0]))
    ref /= ref.sum()
    for a, o in zip(acts, obs[1:]):
        f.step(a, o)
        ref = dense_step(model, ref, a, model.sensor.to_reading(o))
    np.testing.assert_allclose(f.belief_vector, ref, rtol=0, atol=1e-12)
    code = ("import sys, gym_gridloc\nfrom gym_gridloc import engine\nfrom gym_gridloc.generators import colour_map\n"
            "m = gym_gridloc.colour_grid_model(colour_map((130, 129), seed=1))\n"
            "gym_gridloc.ForwardFilter(m).reset(0).step(0, 1)\nprint('numba' in sys.modules, engine.path(m))\n")
    assert run_python(code, GYM_GRIDLOC_NUMBA="all", GYM_GRIDLOC_NO_NUMBA="1") == "False numpy"
    if importlib.util.find_spec("numba") is not None:
        assert run_python(code, GYM_GRIDLOC_NUMBA="all") == f"True {fused}"
        assert run_python(code, GYM_GRIDLOC_NUMBA="") == "False numpy"  # (not asked for: a large grid never loads numba)
