"""The compiled code gives the numbers of the numpy code it stands for, bit for bit: the step of N
robots against its numpy reference, the compiled readout (the referee's summary, the observed
float32 belief), the sensors' draw tables, a filter normalised in its step against the lazy one
read after every step, and the numpy diagonal pass against its definition."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import gym_gridloc
from gym_gridloc import ForwardFilter, engine, kernels, observation, referee

needs_numba = pytest.mark.skipif(kernels.compiled(1) is None, reason="numba is not installed (or switched off)")


def beliefs(rng: np.random.Generator):
    """Beliefs of many shapes and spreads: 1 to 4 layers, up to just below the compiled path's
    limit (the pairwise sums' blocks and halves), zeros, ties, a sure belief."""
    shapes = [(1, 1, 1), (1, 1, 7), (1, 6, 7), (4, 7, 7), (2, 3, 5), (1, 11, 12), (1, 40, 41), (4, 17, 19),
              (1, 127, 129), (3, 50, 60)]
    for shape in shapes:
        for power in (1.0, 4.0, 40.0):
            b = rng.random(shape) ** power
            b[rng.random(shape) < 0.3] = 0.0
            b.reshape(-1)[0] += 1e-3
            yield b / b.sum()
        tie = np.zeros(shape)
        tie.reshape(-1)[[0, -1]] = 0.5
        yield tie
        sure = np.zeros(shape)
        sure.reshape(-1)[-1] = 1.0
        yield sure


def numpy_only(monkeypatch):
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    assert kernels.compiled(1) is None


def same(a, b) -> bool:
    """Equal to the bit, with the same types (floats compared by repr, arrays by bytes)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, tuple):
        return type(b) is tuple and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and repr(a) == repr(b)


def test_the_compiled_entropy_sums_only_rows_numpy_sums_in_one_piece():
    """numpy 2.0 and older reduce a row longer than their buffer buffer by buffer (numpy 2.4 in one
    piece): the compiled pairwise sum, which sums a row in one piece, is used only up to the
    default buffer, and a longer position belief's entropy is numpy's own, in both readouts."""
    assert referee.COMPILED_ENTROPY_CELLS <= np.getbufsize()
    for seed in range(8):  # (with numpy 1.26 the one-piece sum differs in seeds 1, 2, 4, 6)
        rng = np.random.default_rng(seed)
        b = rng.random((1, 100, 120))  # 12000 cells: compiled readout, numpy's entropy
        b /= b.sum()
        assert referee.summary(b, (0, 0, 0), 0.5)["entropy"] == float(referee.entropy(b.reshape(-1)))
        batch = np.stack([b, b[:, ::-1].copy()])
        np.testing.assert_array_equal(referee.summarise(batch, np.zeros((2, 3), dtype=np.int64), 0.5)["entropy"],
                                      referee.entropy(batch.reshape(2, -1)))


@needs_numba
@pytest.mark.parametrize("pose", [False, True])
def test_compiled_summary_equals_numpy_summary(pose, monkeypatch):
    rng = np.random.default_rng(0)
    cases = list(beliefs(rng))
    fast = [referee.summary(b, (0, 0, 0), 0.5, pose=pose) for b in cases]
    numpy_only(monkeypatch)
    for b, got in zip(cases, fast):
        ref = referee.summary(b, (0, 0, 0), 0.5, pose=pose)
        assert same(got, ref), (b.shape, got, ref)


@needs_numba
@pytest.mark.parametrize("pose", [False, True])
def test_compiled_summarise_equals_numpy_summarise(pose, monkeypatch):
    """The batched referee (the native vector env's info) on its compiled path, row by row."""
    rng = np.random.default_rng(5)
    by_shape: dict = {}
    for b in beliefs(rng):
        by_shape.setdefault(b.shape, []).append(b)
    cases = []
    for shape, group in by_shape.items():
        batch = np.ascontiguousarray(np.stack(group))
        states = np.stack([rng.integers(0, d, size=len(group)) for d in shape], axis=1)
        cases.append((batch, states))
    fast = [referee.summarise(b, s, 0.5, pose=pose) for b, s in cases]
    read = [referee.readout(b, s, 0.5, pose=pose) for b, s in cases]
    numpy_only(monkeypatch)
    for (b, s), got, (info, positions) in zip(cases, fast, read):
        assert same(got, referee.summarise(b, s, 0.5, pose=pose)), b.shape
        # readout: the same infos, and the position beliefs as numpy sums the layers, to the bit
        assert same(info, got)
        assert positions.tobytes() == b.sum(axis=1).reshape(b.shape[0], -1).tobytes()
        numpy_info, numpy_positions = referee.readout(b, s, 0.5, pose=pose)
        assert same(numpy_info, got) and numpy_positions.tobytes() == positions.tobytes()


@needs_numba
def test_the_entropy_of_the_cells_with_mass_only_is_numpys_to_the_bit(monkeypatch):
    """The compiled readouts take numpy's log2 of the cells with mass only (the others' terms are
    zeros): the same entropies as numpy's sum of every term, in single and batched readouts, for
    rows whose mass sits before, inside and after the pairwise sum's blocks and tails, and for
    -0.0, subnormal, infinite and NaN values and rows without mass."""
    rng = np.random.default_rng(11)
    rows = []
    for hw in (5, 8, 49, 64, 65, 127, 128, 129, 300, 1000, 3000):
        for kept in (0, 1, 2, 7, 9, hw):
            row = np.zeros(hw)
            row[rng.choice(hw, size=min(kept, hw), replace=False)] = rng.random(min(kept, hw))
            rows.append(row)
        odd = rng.random(hw)
        odd[rng.random(hw) < 0.5] = -0.0
        odd[rng.integers(hw)] = 5e-324
        rows.append(odd.copy())
        odd[rng.integers(hw)] = np.inf
        rows.append(odd.copy())
        odd[rng.integers(hw)] = np.nan
        rows.append(odd)
    with np.errstate(all="ignore"):
        fast = [(referee.summary(r.reshape(1, 1, -1), (0, 0, 0), 0.5)["entropy"],
                 referee.summarise(np.stack([r, r[::-1]]).reshape(2, 1, 1, -1), np.zeros((2, 3), dtype=np.int64), 0.5)["entropy"])
                for r in rows]
        numpy_only(monkeypatch)
        for r, (one, two) in zip(rows, fast):
            ref = referee.summarise(np.stack([r, r[::-1]]).reshape(2, 1, 1, -1), np.zeros((2, 3), dtype=np.int64), 0.5)["entropy"]
            assert repr(one) == repr(float(ref[0])), (r.size, one, ref[0])
            np.testing.assert_array_equal(two, ref)  # (a NaN's sign bit is the machine's, here as before)
            assert two[~np.isnan(two)].tobytes() == ref[~np.isnan(ref)].tobytes(), (r.size, two, ref)


@needs_numba
@pytest.mark.parametrize("env_id, kwargs", [("WindyMaze-v0", {}), ("DepthMaze-v0", {"map_seed": 3}),
                                             ("RingSensor8x8-v0", {"dynamics": "passive"}), ("ColourGrid-v0", {})])
def test_compiled_sample_next_equals_numpy(env_id, kwargs, monkeypatch):
    """The engine's batched draw of next states: the compiled pass takes the same uniforms to the
    same states, including uniforms next to 1 (the product rounds up to the total)."""
    model = gym.make(env_id, **kwargs).unwrapped.model
    rng = np.random.default_rng(2)
    states = engine.sample_initial(model, 500, rng)
    actions = rng.integers(0, model.n_actions, size=500)
    actions[:7] = np.arange(7) % model.n_actions
    fast = engine.sample_next(model, states, actions, np.random.default_rng(9))
    numpy_only(monkeypatch)
    assert np.array_equal(fast, engine.sample_next(model, states, actions, np.random.default_rng(9)))
    ones = np.full(7, np.nextafter(1.0, 0.0))

    class Near1:  # a generator whose uniforms are all just below 1
        def random(self, n=None):
            return ones[:n].copy() if n is not None else float(ones[0])

    monkeypatch.setattr(kernels, "AVAILABLE", True)
    top = engine.sample_next(model, states[:7], actions[:7], Near1())
    numpy_only(monkeypatch)
    assert np.array_equal(top, engine.sample_next(model, states[:7], actions[:7], Near1()))


@needs_numba
@pytest.mark.parametrize("full_state", [False, True])
def test_compiled_observed_belief_equals_numpy(full_state, monkeypatch):
    rng = np.random.default_rng(1)
    cases = list(beliefs(rng))
    cases.append(np.full((2, 3, 3), 0.75))  # sums above 1: clipped
    fast = [observation.observed_belief(b, full_state) for b in cases]
    numpy_only(monkeypatch)
    for b, got in zip(cases, fast):
        assert same(got, observation.observed_belief(b, full_state)), b.shape


@pytest.mark.parametrize("no_numba", [False, True])
@pytest.mark.parametrize("env_id, kwargs", [("WindyMaze-v0", {}), ("DepthMaze-v0", {"map_seed": 3}),
                                             ("ColourGrid-v0", {"kidnap_prob": 0.05}),
                                             ("WindyMaze-v0", {"size": 131})])
def test_a_filter_normalised_in_its_step_equals_the_lazy_one_read_every_step(env_id, kwargs, no_numba, monkeypatch):
    if no_numba:
        numpy_only(monkeypatch)
    model = gym.make(env_id, **kwargs).unwrapped.model
    _, actions, readings = engine.simulate(model, 60, np.random.default_rng(2))
    lazy = ForwardFilter(model).reset(reading=int(readings[0]))
    eager = ForwardFilter(model, read_every_step=True).reset(reading=int(readings[0]))
    for a, r in zip(actions.tolist(), readings[1:].tolist()):
        lazy.step(a, reading=r)
        eager.step(a, reading=r)
        assert lazy.full_belief.tobytes() == eager.belief_view.tobytes()
        assert repr(lazy.log_likelihood) == repr(eager.log_likelihood)


def test_diagonal_add_is_the_dia_product_of_one_diagonal():
    rng = np.random.default_rng(5)
    for n, chunk in [(50, 7), (50, 50), (1000, 64), (300, 1)]:
        tmp = np.empty(chunk)
        for offset in (0, 1, -1, 7, -9, n - 1, 1 - n, n, -n - 3):
            w, x, y = rng.random(n), rng.random(n), rng.random(n)
            ref = y.copy()
            for i in range(n):  # y[i] += w[j] x[j], j = i + offset
                j = i + offset
                if 0 <= j < n:
                    ref[i] = ref[i] + w[j] * x[j]
            kernels.diagonal_add(w, x, y, offset, tmp)
            assert y.tobytes() == ref.tobytes(), (n, chunk, offset)


def test_the_single_step_pickles_with_its_environment():
    import pickle

    env = gym_gridloc.HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    env.reset(seed=0)
    env.step(1)
    copy = pickle.loads(pickle.dumps(env))
    for a in (0, 2, 3, 1):
        one, two = env.step(a), copy.step(a)
        assert same(one[4], two[4]) and same(one[0]["belief"], two[0]["belief"])


SENSOR_ENVS = [("WindyMaze-v0", {}), ("ColourGrid-v0", {}), ("RingSensor8x8-v0", {}), ("DepthMaze-v0", {"map_seed": 3}),
               ("DepthMaze-v0", {"map_seed": 5, "p_depth_error": 0.2})]


@needs_numba
@pytest.mark.parametrize("env_id, kwargs", SENSOR_ENVS)
def test_the_sensors_draw_tables_draw_what_sample_draws(env_id, kwargs):
    """The compiled draw of a reading from a sensor's draw_table: the same readings from the same
    uniforms as Sensor.sample, for every free state, in batches and one at a time."""
    from gym_gridloc import _numba_kernels as fast

    model = gym.make(env_id, **kwargs).unwrapped.model
    sensor = model.sensor
    kind, cum, total, values = sensor.draw_table()
    per = cum.shape[1] if kind == 1 else 1
    R, cum, values = cum.shape[1], cum.reshape(-1), values.reshape(-1)  # (the kernel reads them flat)
    h, w = model.shape
    states = engine.states_of(model, np.arange(model.n_states))
    for n in (1, 3, len(states)):
        for start in range(0, len(states), n):
            batch = states[start:start + n]
            seed = 1000 + start
            ref = sensor.sample(batch, np.random.default_rng(seed))
            u = np.random.default_rng(seed).random(len(batch) * per)
            rows = (batch[:, 0] * h * w if sensor.layered else 0) + batch[:, 1] * w + batch[:, 2]
            got = [fast.draw_reading(kind, cum, total, values, R, s, u, i * per) for i, s in enumerate(rows)]
            assert got == ref.tolist()
    # uniforms at the edges: 0 and just below 1
    for u0 in (0.0, np.nextafter(1.0, 0.0)):
        u = np.full(len(states) * per, u0)

        class Fixed:
            def random(self, size=None):
                return u[: int(np.prod(size))].reshape(size) if size is not None else float(u0)

        ref = sensor.sample(states, Fixed())
        rows = (states[:, 0] * h * w if sensor.layered else 0) + states[:, 1] * w + states[:, 2]
        assert [fast.draw_reading(kind, cum, total, values, R, s, u, i * per) for i, s in enumerate(rows)] == ref.tolist()


@needs_numba
@pytest.mark.parametrize("n", [1, 2, 37])
@pytest.mark.parametrize("env_id, kwargs", SENSOR_ENVS[:4])
@pytest.mark.parametrize("pose, reward", [(False, "step"), (True, "belief")])
def test_the_compiled_step_equals_its_numpy_reference(env_id, kwargs, n, pose, reward):
    """The one step of N robots (batch.Batch.advance) has two implementations: the compiled call
    and the numpy reference (the engine's sample_next, sample_readings and step for moving rows;
    sample_initial, sample_readings and first_posterior for starting rows, moving rows drawn
    first; kept rows untouched; then the referee's readout and outcomes).  The same draws, states,
    readings, beliefs, step counts, infos, rewards and ends, to the bit."""
    from gym_gridloc.batch import KEEP, START, START_AT, STEP, Batch

    model = gym.make(env_id, **kwargs).unwrapped.model
    rules = dict(threshold=0.6, pose=pose, reward=reward, limit=6, observed=True)
    compiled, reference = Batch(model, n, **rules), Batch(model, n, **rules)
    assert compiled.bank is not None
    reference.bank = None  # the numpy reference
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    rng = np.random.default_rng(n)
    for t in range(12):
        actions = rng.integers(0, model.n_actions, size=n)
        modes = np.full(n, START, dtype=np.int8) if t == 0 else rng.choice([STEP, STEP, START, KEEP, START_AT], size=n).astype(np.int8)
        at = np.flatnonzero(modes == START_AT)
        for batch in (compiled, reference):
            batch.rows.states[at] = engine.sample_initial(model, at.size, np.random.default_rng(t))
        got, want = compiled.advance(actions, modes, a), reference.advance(actions, modes, b)
        for name in ("states", "readings", "elapsed"):
            assert np.array_equal(getattr(compiled.rows, name), getattr(reference.rows, name)), name
        assert compiled.beliefs.tobytes() == reference.beliefs.tobytes()
        assert got.info.keys() == want.info.keys() and all(same(got.info[k], want.info[k]) for k in got.info)
        assert same(got.positions, want.positions)
        for x, y in zip(got[3:], want[3:]):  # rewards, terminated, truncated, done
            assert same(np.asarray(x), np.asarray(y))
        assert want.observed is None  # (the numpy reference leaves the observation to the caller: the same numbers)
        assert same(got.observed, observation.observed_belief(reference.beliefs, False).reshape(n, -1))
    assert a.random() == b.random()  # the same number of draws


def test_there_is_no_compiled_step_where_there_is_no_compiled_path():
    assert engine.vector_bank(gym.make("ColourGrid-v0", kidnap_prob=0.05).unwrapped.model, 1) is None


class _Replay:
    """A generator stand-in that hands out given draws: ``random`` and ``integers`` return the
    next array of their list (what a recorded call drew)."""

    def __init__(self, randoms, integers=()):
        self.randoms, self.integers_ = list(randoms), list(integers)

    def random(self, size=None):
        return np.asarray(self.randoms.pop(0), dtype=np.float64)

    def integers(self, high, size=None):
        return np.asarray(self.integers_.pop(0), dtype=np.int64)


@needs_numba
@pytest.mark.parametrize("kwargs", [{}, {"p_depth_error": 0.2, "p_move_fail": 0.1}])
def test_a_vector_bank_steps_each_row_on_its_own_model(kwargs):
    """engine.VectorBank, the compiled step with maps redrawn at reset: every row moves,
    starts or keeps on its own model as the engine's functions do for that row alone, given the
    same draws: the bank draws from the generator's bit stream what Generator.random and
    Generator.integers would (the moving rows' moves, then their readings, in row order; the
    starting rows' states; their readings), to the bit, and leaves the generator where they
    would."""
    env = gym.make("DepthMaze-v0", **kwargs).unwrapped
    factory = env.map_factory
    maze_rng = np.random.default_rng(0)
    models = [factory(maze_rng) for _ in range(6)]
    n = 11
    bank = engine.vector_bank(models[0], n)
    rng = np.random.default_rng(1)
    slots = np.array([bank.slot(models[i % 6], np.zeros(0, dtype=np.int64)) for i in range(n)], dtype=np.int64)
    assert len(set(slots.tolist())) == 6 and bank.slot(models[2], slots) == slots[2]  # placed once
    states = np.concatenate([engine.sample_initial(models[i % 6], 1, rng) for i in range(n)])
    readings = np.concatenate([engine.sample_readings(models[i % 6], states[i:i + 1], rng) for i in range(n)])
    beliefs = np.concatenate([engine.first_posterior(models[i % 6], readings[i:i + 1]).reshape(1, -1) for i in range(n)])
    rows = engine.Rows(n, beliefs.shape[1])
    rows.slots[:], rows.states[:], rows.readings[:], rows.belief[:] = slots, states, readings, beliefs
    per = 1  # DepthSensor: one uniform per reading
    n_states = models[0].n_states
    for _ in range(6):
        actions = rng.integers(0, 3, size=n)
        modes = rng.integers(0, 3, size=n).astype(np.int8)
        seed = int(rng.integers(1000))
        drawn, replayed = np.random.default_rng(seed), np.random.default_rng(seed)
        blocks = referee.Blocks(n, 49, 0.9, True, states=196)  # the referee's readout, in the same call
        bank.advance(rows, actions, modes, drawn, blocks)
        new_states, new_readings, out = rows.states.copy(), rows.readings.copy(), rows.belief.copy()
        info, positions = blocks.infos(4)
        ref_info, ref_positions = referee.readout(out.reshape(n, 4, 7, 7).copy(), new_states, 0.9, pose=True)
        assert positions.tobytes() == ref_positions.tobytes() and info.keys() == ref_info.keys()
        assert all(info[k].tobytes() == ref_info[k].tobytes() for k in info)
        moving, starting = np.flatnonzero(modes == 0), np.flatnonzero(modes == 1)
        u_move = replayed.random(moving.size * (1 + per)) if moving.size else None
        starts = replayed.integers(n_states, size=starting.size) if starting.size else None
        u_start = replayed.random(starting.size * per) if starting.size else None
        assert drawn.random() == replayed.random()  # the same number of draws
        for i in range(n):
            model = models[i % 6]
            s, r, o = states[i:i + 1].copy(), readings[i:i + 1].copy(), beliefs[i].reshape(1, *model.belief_shape).copy()
            if modes[i] == 0:
                j = int(np.flatnonzero(moving == i)[0])
                s = engine.sample_next(model, s, actions[i:i + 1], _Replay([u_move[j:j + 1]]))
                r = engine.sample_readings(model, s, _Replay([u_move[moving.size + j * per: moving.size + (j + 1) * per]]))
                o = engine.step(model, o, actions[i:i + 1], r)[0]
            elif modes[i] == 1:
                js = int(np.flatnonzero(starting == i)[0])
                s = engine.sample_initial(model, 1, _Replay([], [starts[js:js + 1]]))
                r = engine.sample_readings(model, s, _Replay([u_start[js * per:(js + 1) * per]]))
                o = engine.first_posterior(model, r)
            assert np.array_equal(new_states[i], s[0]) and new_readings[i] == r[0]
            assert out[i].tobytes() == o.reshape(-1).tobytes()
        states, readings, beliefs = new_states, new_readings, out


@needs_numba
def test_a_full_vector_bank_reuses_only_slots_no_row_is_on(monkeypatch):
    """The bank's size is bounded (at least N + 1 slots): when it is full, a new model takes a
    slot no row uses, the least recently placed, and a model placed again keeps its slot."""
    monkeypatch.setattr(engine.VectorBank, "BYTES", 1)  # the bound: N + 1 slots
    factory = gym.make("DepthMaze-v0").unwrapped.map_factory
    maze_rng = np.random.default_rng(0)
    n = 3
    first = factory(maze_rng)
    bank = engine.vector_bank(first, n)
    assert bank.limit == n + 1
    in_use = np.array([0, 0, 0], dtype=np.int64)
    seen = {id(first)}
    for k in range(40):
        model = factory(maze_rng)
        if id(model) in seen:
            continue
        seen.add(id(model))
        s = bank.slot(model, in_use)
        assert s not in in_use.tolist() and bank.models[s] is model
        in_use[k % n] = s
        assert all(bank.models[t] is not None for t in in_use.tolist())
        assert len(bank.models) <= n + 1
    assert bank.slot(bank.models[in_use[0]], in_use) == in_use[0]
    # a model of other sizes is not placed
    assert bank.slot(gym.make("DepthMaze-v0", size=9).unwrapped.model, in_use) is None


@needs_numba
@settings(max_examples=300, deadline=None)
@given(hnp.arrays(np.float64, st.integers(1, 23),
                  elements=st.one_of(st.sampled_from([0.0, -0.0, 0.5, 1.0, np.nan, np.inf, -np.inf]),
                                     st.floats(-2, 2, allow_nan=False))))
def test_the_compiled_argmax_is_numpys(row):
    """The readout's argmax (four running maxima on finite rows, numpy's loop otherwise) is
    numpy's: the first largest value, the first NaN; ties, signed zeros, infinities."""
    from gym_gridloc import _numba_readout as fast

    a = np.stack([row, row[::-1].copy()])
    flat, n = a.reshape(-1), a.shape[1]
    for i in range(2):
        assert fast._argmax(flat, np.uint64(i * n), n) == int(np.argmax(a[i]))


@pytest.mark.parametrize("options", [{}, {"flatten": True}, {"full_state": True}, {"map": True}])
def test_an_observation_from_the_referees_positions_is_the_same(options):
    """BeliefObservation.encode given the position beliefs the referee read (referee.readout, as
    the native vector env passes them) builds the observation it builds from the beliefs alone."""
    env = gym.make("DepthMaze-v0", map_seed=2).unwrapped
    model = env.model
    rng = np.random.default_rng(3)
    states = engine.sample_initial(model, 9, rng)
    readings = engine.sample_readings(model, states, rng)
    full = engine.first_posterior(model, readings)  # (9, 4, 7, 7): spread over headings and cells
    builder = observation.BeliefObservation(model, **options)
    obs = model.sensor.observations(readings)
    _, positions = referee.readout(full, states, 0.9, pose=True)
    a, b = builder.encode(model, obs, readings, full), builder.encode(model, obs, readings, full, positions)
    for x, y in ((a, b),) if not isinstance(a, dict) else ((a[k], b[k]) for k in a):
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
