"""The compiled step of N robots (:func:`vector_advance`, on the named structures of
:mod:`gym_gridloc._numba_structs`): moves (:func:`sample_moves`, as ``engine.sample_next`` draws
them), readings from the sensors' draw tables (:func:`draw_reading`), new episodes, the filter
step, and the referee's readout and outcomes, with the generator's draws; the new episodes' maps
(:func:`draw_maps`), drawn first."""

from __future__ import annotations

import numba
import numpy as np

from gym_gridloc._numba_draws import bounded, draw_double, maze_code
from gym_gridloc._numba_filter import stencil
from gym_gridloc._numba_readout import batch_outcomes, batch_readout
from gym_gridloc._numba_sparse import sparse_enough, sparse_stencil, support

_U = np.uint64  # unsigned offsets and indices (see gym_gridloc._numba_filter)


@numba.njit(cache=True, nogil=True)
def _move(weights, wo, keys, ko, K, hw, layer, r, c, u, width, cum, states, i):  # pragma: no cover - compiled
    """One draw of :func:`sample_moves`: the next state of ``(layer, r, c)`` with the uniform
    ``u``, written to ``states[i]``; the action's ``(K, H*W)`` weights at ``weights[wo:]`` and
    its ``(4, K)`` keys at ``keys[ko:]`` (flat); ``cum`` is scratch (K,)."""
    cell = r * width + c
    total = 0.0
    last = K - 1
    for k in range(K):
        p = weights[wo + _U(k * hw + cell)] if keys[ko + _U(k)] == layer else 0.0
        total += p
        cum[k] = total
        if p > 0.0:
            last = k
    target = u * total
    chosen = last
    for k in range(K):
        if target < cum[k]:
            chosen = k
            break
    states[i, 0] = keys[ko + _U(K + chosen)]
    states[i, 1] = r + keys[ko + _U(2 * K + chosen)]
    states[i, 2] = c + keys[ko + _U(3 * K + chosen)]


@numba.njit(cache=True, nogil=True)
def sample_moves(weights, keys, actions, states, u, width, out):  # pragma: no cover - compiled
    """The engine's draw of N next states (``engine.sample_next`` without kidnapping), with the
    same arithmetic: state ``i`` under action ``actions[i]`` takes the first term whose running
    sum (left to right, as ``np.cumsum``) exceeds ``u[i]`` times the total, or, when the product
    rounds up to the total, the last term of positive weight.  ``weights`` ``(A + 1, K, H*W)`` and
    ``keys`` ``(A + 1, 4, K)`` are the engine's padded tables; ``states``/``out`` ``(N, 3)``."""
    K, hw = weights.shape[1], weights.shape[2]
    cum = np.empty(K)
    wf, kf = weights.reshape(weights.size), keys.reshape(keys.size)
    for i in range(states.shape[0]):
        a = actions[i]
        _move(wf, _U(a * K * hw), kf, _U(a * 4 * K), K, hw, states[i, 0], states[i, 1], states[i, 2], u[i], width, cum, out, i)


@numba.njit(cache=True, nogil=True)
def draw_reading(kind, cum, total, values, R, s, u, j):  # pragma: no cover - compiled
    """One reading of state ``s``, as the sensor's own ``sample`` draws it, from the sensor's
    draw table (``R`` columns): ``cum`` and ``values`` flat ``(S, R)`` and ``total`` ``(S,)``
    (a bank's tables: ``s`` is then ``slot * S + state``).  ``kind`` 0 (categorical, one uniform ``u[j]``):
    the first column whose running sum ``cum[s]`` exceeds ``u[j] * total[s]`` (at most the
    last), its ``values``; kind 1 (independent bits, one uniform each from ``u[j]`` on): the sum
    of ``values[s, b]`` over the bits with ``u[j + b] < cum[s, b]``."""
    row = _U(s * R)
    if kind == 1:
        r = 0
        for b in range(R):
            if u[j + b] < cum[row + _U(b)]:
                r += values[row + _U(b)]
        return r
    x = u[j] * total[_U(s)]
    k = 0
    while k < R and cum[row + _U(k)] <= x:
        k += 1
    return values[row + _U(min(k, R - 1))]


@numba.njit(cache=True, nogil=True)
def draw_maps(maze, slots, modes, bits):  # pragma: no cover - compiled
    """The maps of the rows that start an episode (``modes`` 1), drawn first in a step, in row
    order: ``maze.codes[j]`` the code of the ``j``-th starting row's maze (:func:`maze_code` on
    the graph ``maze.walls`` (2, W), the rooms of each wall, of ``maze.n_rooms`` rooms), and the
    row's slot ``maze.code_slots[code]``.  Returns how many codes have no slot (-1): from the
    first of them on, the rows' slots are left as they were, for the caller to place those
    codes' models and set every starting row's slot (the draws are made all the same)."""
    walls, code_slots, codes = maze.walls, maze.code_slots, maze.codes
    u32, state = bits[0], bits[2]
    order = np.empty(walls.shape[1], dtype=np.int64)
    parent = np.empty(maze.n_rooms, dtype=np.int64)
    j = 0
    missing = 0
    for i in range(modes.shape[0]):
        if modes[i] == 1:
            codes[j] = code = maze_code(u32, state, walls[0], walls[1], maze.n_rooms, order, parent)
            if code_slots[code] < 0:
                missing += 1
            if missing == 0:
                slots[i] = code_slots[code]
            j += 1
    return missing


@numba.njit(cache=True, nogil=True)
def vector_advance(tables, rows, actions, modes, blocks, bits):  # pragma: no cover - compiled
    """One step of N robots, row ``i`` on the model of slot ``rows.slots[i]`` (``tables``: every
    table with a leading slot axis, one model's or a bank's of models of the same sizes).  Row
    ``i`` with ``modes[i]`` 0 moves under ``actions[i]``, reads and filters (its posterior
    normalised); 1 starts an episode at a state drawn uniformly among the ``n_states`` free
    states (layer-major), reads and takes the first posterior ``posts[reading]``; 3 starts one
    at its state as given; 2 keeps its state, reading and belief.  The beliefs are read from
    ``rows.beliefs[current]`` and written to the other buffer, which becomes current.  Random
    numbers from the numpy bit generator of ``bits`` (the addresses of its ``next_uint32``, its
    ``next_double`` and its state), as ``Generator.random`` and ``Generator.integers`` draw them:
    the moving rows' move uniforms, then their readings' (``per_draw`` each), rows in order; the
    drawn starts' states; the starting rows' readings'.  Moves are drawn from the filter's own
    weights ``w`` with the ``keys`` (as :func:`sample_moves` draws them).  Then the referee's
    ``blocks``: every row's readout (:func:`batch_readout`) and how its step ended
    (:func:`batch_outcomes`).  The tables are read flat, each row's at its slot's offset.
    A moving row whose belief holds mass on few states (the last step's list of them in
    ``blocks.support``, ``blocks.spans`` how many; or found now) is filtered over those states
    only (:mod:`gym_gridloc._numba_sparse`: the same numbers), and its new list kept.
    Returns -1, or the first row whose reading is impossible (z not positive and finite: the
    caller raises)."""
    w, liks, cum, free_cells, posts, possible = tables.w, tables.liks, tables.cum, tables.free_cells, tables.posts, tables.possible
    width, n_layers, layered, kind, per_draw = tables.width, tables.n_layers, tables.layered, tables.kind, tables.per_draw
    states, readings, slots = rows.states, rows.readings, rows.slots
    cur = rows.current[0]
    beliefs, out = rows.beliefs[cur], rows.beliefs[1 - cur]
    n = states.shape[0]
    n_free = free_cells.shape[1]
    A, K, hw = w.shape[1], w.shape[2], w.shape[3]
    n_read, lsize = liks.shape[1], liks.shape[2]
    S, R = cum.shape[1], cum.shape[2]
    size = beliefs.shape[1]
    n_moving = 0
    n_drawn = 0
    n_starting = 0
    for i in range(n):
        n_moving += modes[i] == 0
        n_drawn += modes[i] == 1
        n_starting += modes[i] == 1 or modes[i] == 3
    u32, f64, state = bits[0], bits[1], bits[2]
    u_move = np.empty(n_moving * (1 + per_draw))
    for j in range(u_move.size):
        u_move[j] = draw_double(f64, state)
    starts = np.zeros(n_drawn, dtype=np.int64)
    if tables.n_states > 1:
        for j in range(n_drawn):
            starts[j] = bounded(u32, state, tables.n_states - 1)
    u_start = np.empty(n_starting * per_draw)
    for j in range(u_start.size):
        u_start[j] = draw_double(f64, state)
    kf, wf, mf = tables.keys.reshape(tables.keys.size), w.reshape(w.size), tables.meta.reshape(tables.meta.size)
    lf, pf, bf, of = liks.reshape(liks.size), posts.reshape(posts.size), beliefs.reshape(beliefs.size), out.reshape(out.size)
    cf, tf, vf = cum.reshape(cum.size), tables.total.reshape(tables.total.size), tables.values.reshape(tables.values.size)
    scratch = np.empty(K)
    spans, sup = blocks.spans, blocks.support
    src, marks = np.empty(size, dtype=np.int64), np.zeros(size, dtype=np.uint8)
    jm = 0
    jd = 0
    js = 0
    bad = -1
    for i in range(n):
        mode = modes[i]
        m = slots[i]
        oi = _U(i * size)
        if mode == 0:
            a = actions[i]
            _move(wf, _U((m * A + a) * K * hw), kf, _U((m * A + a) * 4 * K), K, hw, states[i, 0], states[i, 1],
                  states[i, 2], u_move[jm], width, scratch, states, i)
            s = (states[i, 0] * hw if layered else 0) + states[i, 1] * width + states[i, 2]
            rd = draw_reading(kind, cf, tf, vf, R, m * S + s, u_move, n_moving + jm * per_draw)
            readings[i] = rd
            span = spans[i]
            if span >= 0:  # the states with mass the last step listed
                n_src = span
                for c in range(span):
                    src[c] = sup[oi + _U(c)]
            else:  # (blocks without room for every row's states, as a readout's: never sparse)
                n_src = support(bf, oi, size, src) if span == -1 and sup.size >= n * size else size
            if sparse_enough(n_src, size):
                z, spans[i] = sparse_stencil(bf, oi, src, n_src, wf, _U((m * A + a) * K * hw), mf, _U((m * A + a) * 5 * K), K,
                                             lf, _U((m * n_read + rd) * lsize), of, oi, n_layers, hw, layered, marks, sup, oi)
            else:
                spans[i] = -1
                z = stencil(bf, oi, wf, _U((m * A + a) * K * hw), mf, _U((m * A + a) * 5 * K), K,
                            lf, _U((m * n_read + rd) * lsize), of, oi, n_layers, hw, layered, 1)
            if not (z > 0.0 and z < np.inf) and bad < 0:
                bad = i
            jm += 1
        elif mode == 1 or mode == 3:
            spans[i] = -1
            if mode == 1:
                idx = starts[jd]
                layer = idx // n_free
                cell = idx - layer * n_free
                states[i, 0] = layer
                states[i, 1] = free_cells[m, cell, 0]
                states[i, 2] = free_cells[m, cell, 1]
                jd += 1
            s = (states[i, 0] * hw if layered else 0) + states[i, 1] * width + states[i, 2]
            rd = draw_reading(kind, cf, tf, vf, R, m * S + s, u_start, js * per_draw)
            readings[i] = rd
            if possible[m, rd]:
                po = _U((m * n_read + rd) * size)
                for c in range(_U(size)):
                    of[oi + c] = pf[po + c]
            elif bad < 0:
                bad = i
            js += 1
        else:
            for c in range(_U(size)):
                of[oi + c] = bf[oi + c]
    rows.current[0] = 1 - cur
    batch_readout(out, n_layers, blocks.pose, width, states, blocks.threshold, blocks.scratch, blocks.kept, blocks.ints,
                  blocks.confidence, blocks.estimate, blocks.flags, blocks.observed, sup, spans)
    batch_outcomes(modes, blocks.flags[0], blocks.confidence, rows.elapsed, blocks.limit, blocks.fixed_length,
                   blocks.belief_reward, blocks.rewards, blocks.ends)
    return bad


@numba.njit(cache=True, nogil=True)
def all_below(a, k):  # pragma: no cover - compiled
    """Whether every value of the int64 array ``a`` is in ``0..k-1`` (the vector env's actions)."""
    for i in range(a.shape[0]):
        if not (0 <= a[i] < k):
            return False
    return True
