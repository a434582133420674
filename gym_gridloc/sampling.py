"""The engine's simulator side, batched: hidden states are ``(N, 3)`` int64 arrays of ``(layer,
row, col)``.  :func:`sample_initial` (uniform over the free states), :func:`sample_next` (the
model's transition, kidnapping drawn here), :func:`sample_readings` (the sensor), :func:`simulate`
(one robot's trajectory).  :mod:`gym_gridloc.engine` re-exports them; the step of N robots
(:mod:`gym_gridloc.batch`) is built on them.
"""

from __future__ import annotations

import bisect
import itertools
from typing import Any

import numpy as np

from gym_gridloc import derived, kernels
from gym_gridloc.core.model import GridModel, Term

__all__ = ["states_of", "sample_initial", "sample_next", "sample_readings", "simulate", "OUTCOMES_CACHED"]


def states_of(model: GridModel, indices: np.ndarray) -> np.ndarray:
    """State indices (layer-major over free cells, as :meth:`GridModel.to_vector` orders them)
    as ``(N, 3)`` states (layer, row, col)."""
    layer, cell = np.divmod(np.asarray(indices, dtype=np.int64).reshape(-1), model.grid.n_free)
    out = np.empty((layer.size, 3), dtype=np.int64)
    out[:, 0] = layer
    out[:, 1:] = model.grid.free_cells[cell]
    return out


def sample_initial(model: GridModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` hidden states drawn uniformly over the free states, ``(n, 3)`` (layer, row, col)."""
    return states_of(derived.checked_model(model), rng.integers(model.n_states, size=n))


def sample_next(model: GridModel, states: np.ndarray, actions: Any, rng: np.random.Generator) -> np.ndarray:
    """The next hidden states of ``states`` ``(N, 3)`` under ``actions`` (N, or one for all;
    ``None``: unknown), drawn from the model's transition (kidnapping included).

    Random numbers, in this order: with kidnapping, one uniform per state (kidnapped if below
    ``kidnap_prob``) and a uniform state for each kidnapped one; then one uniform per moving
    state, which picks the next state by the cumulative probabilities of the action's terms in
    their order.
    """
    d = derived.of(model)  # checks the model
    transitions = d.transitions
    st = np.asarray(states, dtype=np.int64).reshape(-1, 3)
    n = st.shape[0]
    if n == 1 and model.kidnap_prob == 0.0 and type(actions) is int and 0 <= actions < model.n_actions:
        # one state: the same draw, without array overheads
        return np.array([_next_one(transitions[actions], st[0], rng, d.outcomes, actions)], dtype=np.int64)
    acts = derived.action_indices(model, actions, n)
    out = st.copy()
    moving = np.arange(n)
    if model.kidnap_prob > 0.0:
        kidnapped = rng.random(n) < model.kidnap_prob
        if kidnapped.any():
            out[kidnapped] = sample_initial(model, int(kidnapped.sum()), rng)
            moving = np.flatnonzero(~kidnapped)
    if moving.size == 1:
        i = int(moving[0])
        a = int(acts[i])
        out[i] = _next_one(transitions[a], st[i], rng, d.outcomes, a)
        return out
    if moving.size == 0:
        return out
    u = rng.random(moving.size)
    weights, keys = d.moves
    fast = kernels.compiled(model.n_layers * model.shape[0] * model.shape[1])
    if fast is not None:  # one compiled pass, the same arithmetic (tests/test_readout.py)
        if moving.size == n:
            fast.sample_moves(weights, keys, acts, st, u, model.shape[1], out)
        else:
            moved = np.empty((moving.size, 3), dtype=np.int64)
            fast.sample_moves(weights, keys, acts[moving], st[moving], u, model.shape[1], moved)
            out[moving] = moved
        return out
    acts, st_m = acts[moving], st[moving]
    p = weights[acts, :, st_m[:, 1] * model.shape[1] + st_m[:, 2]]  # (n, K): each state's action's terms
    key = keys[acts]  # (n, 4, K)
    p[key[:, 0] != st_m[:, :1]] = 0.0  # terms of another source layer
    cum = np.cumsum(p, axis=1)
    below = (u * cum[:, -1])[:, None] < cum
    k = np.argmax(below, axis=1)
    none = ~below.any(axis=1)
    if none.any():  # u * total rounded up to the total: the last possible outcome
        k[none] = p.shape[1] - 1 - np.argmax((p[none] > 0)[:, ::-1], axis=1)
    chosen = np.take_along_axis(key, k[:, None, None], axis=2)[:, :, 0]  # (n, 4)
    out[moving] = chosen[:, 1:] + st_m * (0, 1, 1)  # (destination layer, row + dr, col + dc)
    return out


#: At most this many single states' outcomes are kept per model (for one-state draws).
OUTCOMES_CACHED = 1 << 16


def _next_one(ts: tuple[Term, ...], state: np.ndarray, rng: np.random.Generator,
              cache: dict | None = None, action: int = -1) -> tuple[int, int, int]:
    """:func:`sample_next` for one moving state ``(3,)`` (an array, or a tuple of ints) (the same
    uniform and arithmetic, on scalars).  ``cache`` (keyed by ``action`` and the state) keeps each
    state's cumulative sums."""
    layer, r, c = state.tolist() if type(state) is np.ndarray else state
    x = rng.random()
    key = (action, layer, r, c)
    found = None if cache is None else cache.get(key)
    if found is None:
        p = [float(t.weight[r, c]) if t.src == layer else 0.0 for t in ts]
        cum = tuple(itertools.accumulate(p))  # summed left to right, as np.cumsum does (a tuple of floats: not tracked by the GC)
        found = cum, max(j for j, q in enumerate(p) if q > 0.0)
        if cache is not None and len(cache) < OUTCOMES_CACHED:
            cache[key] = found
    cum, last = found
    k = bisect.bisect_right(cum, x * cum[-1])  # the first term whose cumulative sum exceeds x * total
    if k == len(cum):  # x rounded up to the total: the last possible outcome
        k = last
    t = ts[k]
    return t.dst, r + t.dr, c + t.dc


def sample_readings(model: GridModel, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One reading per state ``(N, 3)``, drawn from the sensor (N,) int64."""
    return derived.checked_model(model).sensor.sample(np.asarray(states, dtype=np.int64).reshape(-1, 3), rng)


def simulate(model: GridModel, steps: int, rng: np.random.Generator, actions: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A trajectory of one robot: ``(states (T+1, 3), actions (T,), readings (T+1,))`` with
    ``T = steps``.  ``actions`` (T of them) are taken as given; by default each is drawn uniformly
    just before its move (the same generator draws, in this order: start, first reading, then per
    step: action, move, reading)."""
    derived.checked_model(model)
    states = np.empty((steps + 1, 3), dtype=np.int64)
    readings = np.empty(steps + 1, dtype=np.int64)
    acts = np.empty(steps, dtype=np.int64)
    st = sample_initial(model, 1, rng)
    states[0], readings[0] = st[0], sample_readings(model, st, rng)[0]
    for k in range(steps):
        a = int(rng.integers(model.n_actions)) if actions is None else model.check_action(actions[k])
        st = sample_next(model, st, a, rng)
        states[k + 1], readings[k + 1], acts[k] = st[0], sample_readings(model, st, rng)[0], a
    return states, acts, readings
