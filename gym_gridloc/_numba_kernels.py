"""The compiled (numba) filter kernels.  Imported only by :mod:`gym_gridloc.kernels`, and only
when a model small enough for them is first filtered: importing numba costs about 100 MiB of
resident memory, so a process that only works on large grids never pays it.

This module is longer than 400 lines on purpose: every compiled function is here, so that numba is
imported in one place only and the engine's, the referee's and the vector step's kernels can call
each other (a compiled function calls another compiled function, not a Python one)."""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.extending import intrinsic

from gym_gridloc._numba_filter import fused_step, pairwise_program, pairwise_sum  # noqa: F401 (re-exported)

_CHUNK = 2048
_U = np.uint64  # Offsets and indices are unsigned: numba then emits no negative-index checks, and
# flat arrays with offsets need no per-row views (a view, or a reshape, costs more than a small
# belief's arithmetic: tables and beliefs are flattened once per call and addressed by offset).


@numba.njit(cache=True, nogil=True)
def _stencil(b, bo, w, wo, meta, mo, K, lik, lo, out, oo, n_layers, hw, layered, mode):  # pragma: no cover - compiled
    """``out = T^T b`` over flat arrays, the belief at ``b[bo:]`` into ``out[oo:]`` (``L*hw``
    values), the action's ``(K, hw)`` weights at ``w[wo:]`` and its ``(5, K)`` meta at
    ``meta[mo:]`` (see :func:`stencil_update`), the likelihood (``hw``, or ``L*hw`` when
    ``layered`` is 1) at ``lik[lo:]``.  Each term is added over its whole destination layer, the
    terms in order (each cell sums its terms in that order), then each layer is weighed and
    summed in cache-sized chunks."""
    for i in range(_U(n_layers * hw)):
        out[oo + i] = 0.0
    for k in range(K):
        dst = meta[mo + _U(K + k)]
        if dst < 0:  # padding
            continue
        a = meta[mo + _U(3 * K + k)]
        e = meta[mo + _U(4 * K + k)]
        if e <= a:
            continue
        o = meta[mo + _U(2 * K + k)]
        wk = wo + _U(k * hw + a - o)
        bk = bo + _U(meta[mo + _U(k)] * hw + a - o)
        ok = oo + _U(dst * hw + a)
        for i in range(_U(e - a)):
            out[ok + i] += w[wk + i] * b[bk + i]
    if mode == 0:
        return 0.0
    z0 = z1 = z2 = z3 = 0.0
    for layer in range(n_layers):
        base = oo + _U(layer * hw)
        lbase = lo + _U(layer * hw * layered)
        for c0 in range(0, hw, _CHUNK):
            n = min(hw, c0 + _CHUNK) - c0
            cb = base + _U(c0)
            lb = lbase + _U(c0)
            for i in range(_U(n)):
                out[cb + i] *= lik[lb + i]
            # Four running sums: the additions overlap instead of waiting on each other.
            n4 = n - n % 4
            for i in range(0, n4, 4):
                j = cb + _U(i)
                z0 += out[j]
                z1 += out[j + _U(1)]
                z2 += out[j + _U(2)]
                z3 += out[j + _U(3)]
            for i in range(n4, n):
                z0 += out[cb + _U(i)]
    z = (z0 + z1) + (z2 + z3)
    if mode == 1 and z > 0.0 and np.isfinite(z):
        inv = 1.0 / z
        for i in range(_U(n_layers * hw)):
            out[oo + i] *= inv
    return z


@numba.njit(cache=True, nogil=True)
def stencil_update(b, w, meta, lik, layered, out, n_layers, mode):  # pragma: no cover - compiled
    """``out = T^T b`` for one belief; mode 0: predict only; 1: times ``lik``, normalised; 2:
    times ``lik``.  Returns the sum (modes 1, 2).  ``w`` is one action's ``(K, H*W)`` weights and
    ``meta`` its ``(5, K)`` table (source layer, destination layer, flat offset, first and end
    destination cell), both flat (``w[a].reshape(-1)``); ``lik`` holds one (H*W) likelihood, or
    one per layer when ``layered`` is 1.  ``b`` and ``out`` may be (L, H, W): C-contiguous arrays
    are read flat (no reshape in Python)."""
    K = meta.size // 5
    return _stencil(b.reshape(b.size), _U(0), w, _U(0), meta, _U(0), K, lik, _U(0), out.reshape(out.size), _U(0),
                    n_layers, w.size // K, layered, mode)


@numba.njit(cache=True, nogil=True)
def batch_update(beliefs, w, meta, actions, lik, layered, out, n_layers, mode, sel, z):  # pragma: no cover - compiled
    """:func:`stencil_update` on each selected row of ``beliefs`` ``(N, L*H*W)`` with its action
    (``w`` ``(A, K, H*W)`` and ``meta`` ``(A, 5, K)`` every action's; row ``i`` of ``lik`` is its
    likelihood, unused in mode 0)."""
    K, hw, size = w.shape[1], w.shape[2], beliefs.shape[1]
    bf, of, lf = beliefs.reshape(beliefs.size), out.reshape(out.size), lik.reshape(lik.size)
    wf, mf = w.reshape(w.size), meta.reshape(meta.size)
    for i in range(beliefs.shape[0]):
        if sel[i]:
            a = actions[i]
            z[i] = _stencil(bf, _U(i * size), wf, _U(a * K * hw), mf, _U(a * 5 * K), K, lf, _U(i * lik.shape[1]),
                            of, _U(i * size), n_layers, hw, layered, mode)
        else:
            z[i] = 1.0


# -- one belief's readout: what the referee and the observation read after each step ------------------
# Bit for bit what numpy computes (the callers' numpy paths are the reference; tests hold them equal):
# layers are summed in order (numpy's sum over the layer axis), float32 casts round to nearest, and
# the entropy's sum is numpy's pairwise summation.  log2 itself stays numpy's (its SIMD log2 may
# differ in the last bit from libm's).

@numba.njit(cache=True, nogil=True)
def _argmax(a, o, n):  # pragma: no cover - compiled
    """numpy's argmax of ``a[o:o+n]`` (``a`` flat, ``o`` unsigned): the first largest value, or
    the first NaN.  Finite rows (a belief's): the largest value over four running maxima (no
    branch per value), then its first index; a row with a NaN or an infinity: numpy's loop
    itself."""
    b0 = b1 = b2 = b3 = a[o]
    bad = 0.0  # x - x: NaN for a NaN or an infinity, else 0
    n4 = n - n % 4
    for c in range(0, n4, 4):
        j = o + _U(c)
        x0, x1, x2, x3 = a[j], a[j + _U(1)], a[j + _U(2)], a[j + _U(3)]
        b0 = x0 if x0 > b0 else b0
        b1 = x1 if x1 > b1 else b1
        b2 = x2 if x2 > b2 else b2
        b3 = x3 if x3 > b3 else b3
        bad += (x0 - x0) + (x1 - x1) + (x2 - x2) + (x3 - x3)
    for c in range(n4, n):
        x0 = a[o + _U(c)]
        b0 = x0 if x0 > b0 else b0
        bad += x0 - x0
    if bad == 0.0:
        best = max(max(b0, b1), max(b2, b3))
        for c in range(n):
            if a[o + _U(c)] == best:
                return c
    j = 0
    best = a[o]
    if best != best:
        return 0
    for c in range(1, n):
        x = a[o + _U(c)]
        if x != x:
            return c
        if x > best:
            best = x
            j = c
    return j


@numba.njit(cache=True, nogil=True)
def readout(flat, n_layers, pose, pos, q):  # pragma: no cover - compiled
    """For one hidden-state belief ``flat`` (L*H*W, layer-major): ``pos`` (H*W) = the position
    belief (the layers summed in order), ``q`` (H*W) = ``pos`` where ``pos`` is not ``<= 0``, else
    1 (the entropy's log2 argument, every cell's: for one small belief, cheaper than listing the
    cells with mass as :func:`batch_readout` does); returns the index of the first largest value
    (the first NaN, as numpy's argmax) of ``flat`` (``pose``) or of ``pos``."""
    hw = flat.size // n_layers
    for i in range(hw):
        x = flat[i]
        for layer in range(1, n_layers):
            x += flat[layer * hw + i]
        pos[i] = x
        q[i] = 1.0 if x <= 0.0 else x
    tested = flat if pose else pos
    return _argmax(tested, _U(0), tested.size)


@numba.njit(cache=True, nogil=True)
def _kept_block(p, po, lq, cells, j, stop, lo, n):  # pragma: no cover - compiled
    """numpy's pairwise sum of ``p * log2(q)`` over the cells ``lo..lo+n-1`` (``n <= 128``, one
    block: eight running sums, then the rest in order) of the row at ``p[po:]``, ``q = p`` where
    ``p > 0``, else 1 (the referee's entropy, ``0 log 0 = 0``), given the log2 of q
    (``lq[j:stop]``) at the cells ``cells[j:stop]`` (ascending; every cell with mass among them).
    The other cells' terms are zeros, and a zero changes no sum but a zero one's sign, which the
    entropy's ``0.0 +`` drops: the same number, in work for the cells listed only (each term
    added to its running sum by selects, no branch).  A block whose every cell is listed:
    :func:`_dense_block`.  Returns the sum and the next ``j``."""
    if stop - j >= n and cells[j] == lo and cells[j + n - 1] == lo + n - 1:  # (ascending: every cell)
        return _dense_block(p, po + _U(lo), lq, _U(j), n), j + n
    return _sparse_block(p, po, lq, cells, j, stop, lo, n)


@numba.njit(cache=True, nogil=True)
def _sparse_block(p, po, lq, cells, j, stop, lo, n):  # pragma: no cover - compiled
    """:func:`_kept_block` where not every cell is listed."""
    end = lo + n
    r0 = r1 = r2 = r3 = r4 = r5 = r6 = r7 = res = 0.0
    if n >= 8:
        main = end - n % 8
        while j < stop and cells[j] < main:
            c = cells[j]
            t = p[po + _U(c)] * lq[j]
            m = (c - lo) & 7
            r0 += t if m == 0 else 0.0
            r1 += t if m == 1 else 0.0
            r2 += t if m == 2 else 0.0
            r3 += t if m == 3 else 0.0
            r4 += t if m == 4 else 0.0
            r5 += t if m == 5 else 0.0
            r6 += t if m == 6 else 0.0
            r7 += t if m == 7 else 0.0
            j += 1
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while j < stop and cells[j] < end:
        res += p[po + _U(cells[j])] * lq[j]
        j += 1
    return res, j


@numba.njit(cache=True, nogil=True)
def _dense_block(p, o, lq, t, n):  # pragma: no cover - compiled
    """numpy's pairwise sum of ``p[o:o+n] * lq[t:t+n]`` for ``n <= 128`` (one block: eight
    running sums, then the rest in order)."""
    r0 = r1 = r2 = r3 = r4 = r5 = r6 = r7 = res = 0.0
    main = n - n % 8 if n >= 8 else 0
    for i in range(0, main, 8):
        a, b = o + _U(i), t + _U(i)
        r0 += p[a] * lq[b]
        r1 += p[a + _U(1)] * lq[b + _U(1)]
        r2 += p[a + _U(2)] * lq[b + _U(2)]
        r3 += p[a + _U(3)] * lq[b + _U(3)]
        r4 += p[a + _U(4)] * lq[b + _U(4)]
        r5 += p[a + _U(5)] * lq[b + _U(5)]
        r6 += p[a + _U(6)] * lq[b + _U(6)]
        r7 += p[a + _U(7)] * lq[b + _U(7)]
    if n >= 8:
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(main, n):
        res += p[o + _U(i)] * lq[t + _U(i)]
    return res


@numba.njit(cache=True, nogil=True)
def _kept_sum(p, po, lq, cells, j, stop, n):  # pragma: no cover - compiled
    """numpy's pairwise sum (``DOUBLE_pairwise_sum``) of :func:`_kept_block`'s terms over a row of
    ``n`` cells: blocks of at most 128, larger ranges split in two halves (the first a multiple of
    8) and the halves' sums added; the blocks are summed in order of their cells, so each takes
    its run of ``cells``.  The recursion is unrolled on a stack (numba's cache cannot hold a
    recursive function).  Returns the sum and the next ``j``.  (A row of at most 128 cells is
    summed by :func:`_dense_block` or :func:`_sparse_block` at its caller: this function's arrays,
    and each call of a compiled function that takes arrays, cost more than a small row.)"""
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    stage = np.zeros(64, dtype=np.int64)
    left = np.empty(64)
    top = 0
    los[0], ns[0] = 0, n
    ret = 0.0
    while True:
        m = ns[top]
        if m <= 128:
            ret, j = _kept_block(p, po, lq, cells, j, stop, los[top], m)
            top -= 1
        elif stage[top] < 2:
            n2 = m // 2
            n2 -= n2 % 8
            if stage[top] == 1:
                left[top] = ret
            child_lo, child_n = (los[top], n2) if stage[top] == 0 else (los[top] + n2, m - n2)
            stage[top] += 1
            top += 1
            los[top], ns[top], stage[top] = child_lo, child_n, 0
            continue
        else:
            ret = left[top] + ret
            top -= 1
        if top < 0:
            return ret, j


#: Every cell, in order: the ``kept`` cells of a q that holds every cell's value (a compiled constant;
#: as many as the longest row summed here, ``referee.COMPILED_ENTROPY_CELLS``).
_EVERY_CELL = np.arange(8192)


@numba.njit(cache=True, nogil=True)
def entropy_sum(p, log2q):  # pragma: no cover - compiled
    """``-np.add.reduce(p * np.log2(q)) + 0.0`` (the referee's entropy) of at most 8192 values,
    with numpy's order of additions, from ``log2q`` the log2 of :func:`readout`'s ``q``."""
    n = p.size
    res = _dense_block(p, _U(0), log2q, _U(0), n) if n <= 128 else _kept_sum(p, _U(0), log2q, _EVERY_CELL, 0, n, n)[0]
    return -(0.0 + res) + 0.0


@numba.njit(cache=True, nogil=True)
def observed32(flat, n_layers, out):  # pragma: no cover - compiled
    """``out`` (float32, H*W) = the position belief of one hidden-state belief ``flat`` (L*H*W,
    layer-major: the layers summed in order; ``n_layers`` 1 for the full belief itself), cast to
    float32 and clipped at 1."""
    hw = flat.size // n_layers
    for i in range(hw):
        x = flat[i]
        for layer in range(1, n_layers):
            x += flat[layer * hw + i]
        out[i] = min(np.float32(x), np.float32(1.0))


# -- a numpy bit generator's draws, as numpy's Generator makes them ---------------------------------
# (from the generator's own C functions, whose addresses come as integers: the compiled step draws
# what the Python calls it replaces drew, in the same order; tests hold them equal)
@intrinsic
def _next_u32(typingctx, function, state):  # pragma: no cover - compiled
    """A numpy bit generator's ``next_uint32(state)``: ``function`` and ``state`` are the
    addresses of its C function and its state (``bit_generator.ctypes``), passed as integers (a
    ctypes function argument costs about 1.5 us a call to unbox; an integer, nothing)."""
    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.IntType(32), [pointer]).as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], pointer)])

    return numba.types.uint32(numba.types.uintp, numba.types.uintp), codegen


@intrinsic
def _next_double(typingctx, function, state):  # pragma: no cover - compiled
    """A numpy bit generator's ``next_double(state)`` (addresses as for :func:`_next_u32`):
    ``Generator.random`` fills its arrays with these."""
    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.DoubleType(), [pointer]).as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], pointer)])

    return numba.types.float64(numba.types.uintp, numba.types.uintp), codegen


@intrinsic
def _trailing_zeros(typingctx, x):  # pragma: no cover - compiled
    """The number of trailing zero bits of the uint64 ``x`` (``x`` > 0): the index of its lowest set bit."""
    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 0))

    return numba.types.uint64(numba.types.uint64), codegen


@numba.njit(cache=True, nogil=True)
def _bounded(next_u32, state, top):  # pragma: no cover - compiled
    """numpy's ``buffered_bounded_lemire_uint32`` for ``0 < top < 2**32 - 1``: a uniform
    integer in ``0..top`` by Lemire's multiply and reject (``Generator.integers(top + 1)``
    draws each of its int64 values so)."""
    excl = np.uint64(top) + np.uint64(1)
    m = np.uint64(_next_u32(next_u32, state)) * excl
    leftover = m & np.uint64(0xFFFFFFFF)
    if leftover < excl:
        threshold = (np.uint64(0xFFFFFFFF) - np.uint64(top)) % excl
        while leftover < threshold:
            m = np.uint64(_next_u32(next_u32, state)) * excl
            leftover = m & np.uint64(0xFFFFFFFF)
    return np.int64(m >> np.uint64(32))


@numba.njit(cache=True, nogil=True)
def _interval(next_u32, state, top):  # pragma: no cover - compiled
    """numpy's ``random_interval(bitgen, top)`` for ``0 <= top < 2**32``: a uniform integer in
    ``0..top``, by rejection on the smallest all-ones mask covering ``top``."""
    if top == 0:
        return 0
    mask = np.uint64(top)
    mask |= mask >> np.uint64(1)
    mask |= mask >> np.uint64(2)
    mask |= mask >> np.uint64(4)
    mask |= mask >> np.uint64(8)
    mask |= mask >> np.uint64(16)
    while True:
        value = np.uint64(_next_u32(next_u32, state)) & mask
        if value <= np.uint64(top):
            return np.int64(value)


# -- a batch of N: the native vector environment's step ---------------------------------------------
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
def vector_advance(keys, w, meta, width, n_layers, layered, liks, kind, cum, total, values, per_draw,
                   free_cells, posts, possible, slots, modes, states, actions, beliefs, out, readings, bits, n_states,
                   walls, n_rooms, code_slots, codes, read, pose, threshold, rscratch, kept, ints, confidence, estimate, flags, observed,
                   end, restarted, elapsed, limit, fixed_length, belief_reward, rewards, ends):  # pragma: no cover - compiled
    """A vector step of N robots, row ``i`` on the model of slot ``slots[i]`` (every table has
    a leading slot axis: one model's tables, or a bank of models of the same sizes).  Row ``i``
    with ``modes[i]`` 0 moves under ``actions[i]``, reads and filters (``out[i]`` the normalised
    posterior of ``beliefs[i]``); 1 starts an episode at a state index drawn uniformly among the
    ``n_states`` free states (layer-major), reads, and takes the first posterior
    ``posts[reading]``; 2 keeps its state, reading and belief.  Random numbers from the numpy bit
    generator of ``bits`` (the addresses of its ``next_uint32``, its ``next_double`` and its
    state), as the engine's Python drew them: ``Generator.random`` of the moving rows' move
    uniforms, then their readings' (``per_draw`` each), rows in order; ``Generator.integers`` of
    the starting rows' states; ``Generator.random`` of their readings'.  With ``read``, every
    row's readout as :func:`batch_readout` fills it (``rscratch`` and the blocks after it); with
    ``end`` too, how every row's step ends, as :func:`batch_outcomes` (``restarted`` and after).
    With ``codes`` of N places (else none), the starting rows' maps are drawn first, in the same
    call: ``codes[j]`` the code of the ``j``-th starting row's maze (:func:`_maze_code` on ``walls`` (2, W), the rooms of
    each wall, and ``n_rooms``), ``slots`` its slot ``code_slots[code]``; when a code has no
    slot (-1), nothing else is drawn and the call returns -2 (the caller places those models,
    sets the rows' slots, and calls again without ``codes``).
    Returns -1, or the first row whose reading is impossible (z not positive and finite: the
    caller raises).  Moves are drawn from the filter's own weights ``w`` with the ``keys`` (as
    :func:`sample_moves` draws them).  The tables are read flat, each row's at its slot's offset."""
    n = states.shape[0]
    n_free = free_cells.shape[1]
    A, K, hw = w.shape[1], w.shape[2], w.shape[3]
    n_read, lsize = liks.shape[1], liks.shape[2]
    S, R = cum.shape[1], cum.shape[2]
    size = beliefs.shape[1]
    n_moving = 0
    n_starting = 0
    for i in range(n):
        n_moving += modes[i] == 0
        n_starting += modes[i] == 1
    u32, f64, state = bits[0], bits[1], bits[2]
    if codes.shape[0]:
        order = np.empty(walls.shape[1], dtype=np.int64)
        parent = np.empty(n_rooms, dtype=np.int64)
        j = 0
        placed = True
        for i in range(n):
            if modes[i] == 1:
                codes[j] = code = _maze_code(u32, state, walls[0], walls[1], n_rooms, order, parent)
                if code_slots[code] < 0:
                    placed = False
                slots[i] = code_slots[code] if placed else slots[i]
                j += 1
        if not placed:
            return -2
    u_move = np.empty(n_moving * (1 + per_draw))
    for j in range(u_move.size):
        u_move[j] = _next_double(f64, state)
    starts = np.zeros(n_starting, dtype=np.int64)
    if n_states > 1:
        for j in range(n_starting):
            starts[j] = _bounded(u32, state, n_states - 1)
    u_start = np.empty(n_starting * per_draw)
    for j in range(u_start.size):
        u_start[j] = _next_double(f64, state)
    kf, wf, mf = keys.reshape(keys.size), w.reshape(w.size), meta.reshape(meta.size)
    lf, pf, bf, of = liks.reshape(liks.size), posts.reshape(posts.size), beliefs.reshape(beliefs.size), out.reshape(out.size)
    cf, tf, vf = cum.reshape(cum.size), total.reshape(total.size), values.reshape(values.size)
    scratch = np.empty(K)
    jm = 0
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
            z = _stencil(bf, oi, wf, _U((m * A + a) * K * hw), mf, _U((m * A + a) * 5 * K), K,
                         lf, _U((m * n_read + rd) * lsize), of, oi, n_layers, hw, layered, 1)
            if not (z > 0.0 and z < np.inf) and bad < 0:
                bad = i
            jm += 1
        elif mode == 1:
            idx = starts[js]
            layer = idx // n_free
            cell = idx - layer * n_free
            states[i, 0] = layer
            states[i, 1] = free_cells[m, cell, 0]
            states[i, 2] = free_cells[m, cell, 1]
            s = (layer * hw if layered else 0) + states[i, 1] * width + states[i, 2]
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
    if read:
        batch_readout(out, n_layers, pose, width, states, threshold, rscratch, kept, ints, confidence, estimate, flags, observed)
        if end:
            batch_outcomes(flags[0], confidence, restarted, elapsed, limit, fixed_length, belief_reward, rewards, ends)
    return bad


@numba.njit(cache=True, nogil=True)
def batch_readout(flat, n_layers, pose, width, states, threshold, scratch, kept, ints, confidence, estimate, flags, observed):  # pragma: no cover - compiled
    """:func:`readout` of N hidden-state beliefs ``flat`` (N, L*H*W) and the referee's arrays of
    ``referee.summarise`` (the same numbers), in blocks (few arguments and allocations: the vector
    env pays them at every step): ``scratch`` (2, N, H*W) gets ``pos`` as :func:`readout` fills
    it, and in q's block the rows' log2 arguments one after the other, compactly: a row whose
    cells mostly hold mass (not ``<= 0``) whole, as :func:`readout`'s ``q``, another its cells with
    mass only (their cells in ``kept`` (N*H*W), at the same places; :func:`batch_entropy`); per
    row, ``ints`` (5, N) the index of the largest tested value, the estimated layer (pose), the Manhattan error to the
    true ``states`` (layer, row, col), where the row's values in q's block end and the true layer;
    ``confidence``; ``estimate`` (2, N, 2) the estimated and the true (row, column); ``flags`` (2, N) localised (confidence >=
    threshold) and success; ``observed`` (N, H*W) float32, unless it has no rows, the observed
    position beliefs (:func:`observed32`'s numbers).  Rows are indexed in place, not sliced (a
    row's view costs more than its work on small maps): the arrays are read flat."""
    n, size = flat.shape[0], flat.shape[1]
    hw = scratch.shape[2]
    ff, sc = flat.reshape(flat.size), scratch.reshape(scratch.size)
    qo = _U(n * hw)  # q's block, after pos's
    k = _U(0)
    for i in range(n):
        fo, po = _U(i * size), _U(i * hw)
        for c in range(_U(hw)):
            sc[po + c] = ff[fo + c]
        for lay in range(1, n_layers):  # the layers added in order, as numpy's sum over them
            lo = fo + _U(lay * hw)
            for c in range(_U(hw)):
                sc[po + c] += ff[lo + c]
        # the entropy's log2 arguments, in q's block (batch_entropy reads them)
        count = 0
        for c in range(_U(hw)):
            count += not sc[po + c] <= 0.0
        if 2 * count > hw:  # mostly cells with mass: every cell's q, 1 where none (its term a zero)
            for c in range(_U(hw)):
                x = sc[po + c]
                sc[qo + k + c] = 1.0 if x <= 0.0 else x
            k += _U(hw)
        else:  # the cells with mass only, and their cells in kept: 64 at a time, a bit per cell, lowest first
            for w0 in range(0, hw, 64):
                bits = _U(0)
                for c in range(w0, min(w0 + 64, hw)):
                    bits |= _U(not sc[po + _U(c)] <= 0.0) << _U(c - w0)
                while bits:
                    c = _U(w0) + _trailing_zeros(bits)
                    sc[qo + k] = sc[po + c]
                    kept[k] = c
                    k += _U(1)
                    bits &= bits - _U(1)
        ints[3, i] = k
        if observed.shape[0]:
            for c in range(hw):
                observed[i, c] = min(np.float32(sc[po + _U(c)]), np.float32(1.0))
        j = _argmax(ff, fo, size) if pose else _argmax(sc, po, hw)
        conf = ff[fo + _U(j)] if pose else sc[po + _U(j)]
        cell = j % hw if pose and n_layers > 1 else j
        er, ec = cell // width, cell % width
        lay = j // hw
        e = abs(er - states[i, 1]) + abs(ec - states[i, 2])
        ints[0, i] = j
        ints[1, i] = lay
        ints[2, i] = e
        ints[4, i] = states[i, 0]
        confidence[i] = conf
        estimate[0, i, 0] = er
        estimate[0, i, 1] = ec
        estimate[1, i, 0] = states[i, 1]
        estimate[1, i, 1] = states[i, 2]
        localised = conf >= threshold
        right = e == 0
        if pose:
            right = right and lay == states[i, 0]
        flags[0, i] = localised
        flags[1, i] = localised and right


@numba.njit(cache=True, nogil=True)
def batch_entropy(pos, log2q, kept, ends, out):  # pragma: no cover - compiled
    """:func:`entropy_sum` of each row of ``pos`` (C-contiguous ``(N, n)``, read flat: no row
    views): ``log2q`` is the log2 of :func:`batch_readout`'s compact ``q``, row ``i``'s ending at
    ``ends[i]``: n values (every cell), or its cells with mass, listed in ``kept``."""
    n = pos.shape[1]
    pf = pos.reshape(pos.size)
    j = 0
    for i in range(pos.shape[0]):
        po = _U(i * n)
        stop = ends[i]
        if stop - j == n:  # a row of every cell (its kept not written)
            res = _dense_block(pf, po, log2q, _U(j), n) if n <= 128 else _kept_sum(pf, po, log2q[j:stop], _EVERY_CELL, 0, n, n)[0]
        elif n <= 128:
            res = _sparse_block(pf, po, log2q, kept, j, stop, 0, n)[0]
        else:
            res = _kept_sum(pf, po, log2q, kept, j, stop, n)[0]
        j = stop
        out[i] = -(0.0 + res) + 0.0


@numba.njit(cache=True, nogil=True)
def batch_outcomes(localised, confidence, restarted, elapsed, limit, fixed_length, belief_reward, rewards, flags):  # pragma: no cover - compiled
    """The vector step's end of N steps, as the referee's numpy code computes it: ``elapsed``
    (N,) is advanced in place (+1, or 0 where ``restarted``); ``rewards`` (N,) gets
    -1.0 or the ``confidence`` (``belief_reward``), 0.0 where restarted; ``flags`` (3, N)
    terminated (localised, on a step, unless ``fixed_length``), truncated (``elapsed >= limit``,
    ``limit`` > 0) and their or."""
    for i in range(elapsed.shape[0]):
        r = restarted[i]
        elapsed[i] = 0 if r else elapsed[i] + 1
        rewards[i] = 0.0 if r else (confidence[i] if belief_reward else -1.0)
        term = localised[i] and not r and not fixed_length
        trunc = limit > 0 and elapsed[i] >= limit
        flags[0, i] = term
        flags[1, i] = trunc
        flags[2, i] = term or trunc


@numba.njit(cache=True, nogil=True)
def all_below(a, k):  # pragma: no cover - compiled
    """Whether every value of the int64 array ``a`` is in ``0..k-1`` (the vector env's actions)."""
    for i in range(a.shape[0]):
        if not (0 <= a[i] < k):
            return False
    return True


# -- maps: a batch of perfect mazes ---------------------------------------------------------------
@numba.njit(cache=True, nogil=True)
def perfect_maze_codes(next_u32, state, wall_a, wall_b, n_rooms, codes):  # pragma: no cover - compiled
    """``codes.size`` perfect mazes in a row, each as :func:`_maze_code` draws it (at most 63
    walls)."""
    order = np.empty(wall_a.shape[0], dtype=np.int64)
    parent = np.empty(n_rooms, dtype=np.int64)
    for m in range(codes.shape[0]):
        codes[m] = _maze_code(next_u32, state, wall_a, wall_b, n_rooms, order, parent)


@numba.njit(cache=True, nogil=True)
def _maze_code(next_u32, state, wall_a, wall_b, n_rooms, order, parent):  # pragma: no cover - compiled
    """One perfect maze drawn as ``generators.perfect_maze`` draws it: the walls shuffled as
    numpy's ``Generator.permutation`` shuffles ``arange(n_walls)`` (from the last position down,
    each swap partner by ``random_interval`` from the bit generator's ``next_uint32`` at
    ``state``: both addresses), then Kruskal's union-find with path halving until the rooms are
    one tree.  Returns its code: bit ``w`` set for each opened wall ``w``.  ``order`` (walls) and
    ``parent`` (rooms) are scratch."""
    n_walls = wall_a.shape[0]
    for i in range(n_walls):
        order[i] = i
    for i in range(n_walls - 1, 0, -1):
        j = _interval(next_u32, state, i)
        order[i], order[j] = order[j], order[i]
    for r in range(n_rooms):
        parent[r] = r
    opened = 0
    code = 0
    for t in range(n_walls):
        w = order[t]
        a, b = wall_a[w], wall_b[w]
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a != b:
            parent[a] = b
            code |= np.int64(1) << w
            opened += 1
            if opened == n_rooms - 1:
                break
    return code
