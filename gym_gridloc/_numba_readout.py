"""The compiled readout of beliefs: what the referee and the observation read after each step
(position beliefs, the largest value, the entropy's sums, the float32 observed belief), for one
belief or N (the vector step's blocks), and how N steps end (:func:`batch_outcomes`).

Bit for bit what numpy computes (the callers' numpy paths are the reference; tests hold them equal):
layers are summed in order (numpy's sum over the layer axis), float32 casts round to nearest, and
the entropy's sum is numpy's pairwise summation.  log2 itself stays numpy's (its SIMD log2 may
differ in the last bit from libm's)."""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.extending import intrinsic

from gym_gridloc._numba_sparse import sparse_argmax, sparse_enough, sparse_positions

_U = np.uint64  # unsigned offsets and indices (see gym_gridloc._numba_filter)


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


@intrinsic
def _trailing_zeros(typingctx, x):  # pragma: no cover - compiled
    """The number of trailing zero bits of the uint64 ``x`` (``x`` > 0): the index of its lowest set bit."""
    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 0))

    return numba.types.uint64(numba.types.uint64), codegen


@numba.njit(cache=True, nogil=True)
def batch_readout(flat, n_layers, pose, width, states, threshold, scratch, kept, ints, confidence, estimate, flags, observed,
                  support, spans):  # pragma: no cover - compiled
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
    position beliefs (:func:`observed32`'s numbers).  A row whose states with mass the step listed
    (``spans[i]`` >= 0 of them at ``support[i * L*H*W:]``, ascending) is read over those states
    only (:mod:`gym_gridloc._numba_sparse`: the same numbers); every other row's ``spans[i]`` is
    set to -1, or to -2 when too many of its positions hold mass for a sparse step.  Rows are
    indexed in place, not sliced (a row's view costs more than its work on small maps): the
    arrays are read flat."""
    n, size = flat.shape[0], flat.shape[1]
    hw = scratch.shape[2]
    ff, sc = flat.reshape(flat.size), scratch.reshape(scratch.size)
    qo = _U(n * hw)  # q's block, after pos's
    k = _U(0)
    for i in range(n):
        fo, po = _U(i * size), _U(i * hw)
        span = spans[i]
        if span >= 0:
            sparse_positions(ff, fo, support, fo, span, hw, sc, po)
        else:
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
        if span < 0:
            spans[i] = -1 if sparse_enough(count, size) else -2
        if observed.shape[0]:
            for c in range(hw):
                observed[i, c] = min(np.float32(sc[po + _U(c)]), np.float32(1.0))
        if pose:
            j = sparse_argmax(ff, fo, support, fo, span) if span >= 0 else _argmax(ff, fo, size)
        else:
            j = _argmax(sc, po, hw)
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
def batch_outcomes(modes, localised, confidence, elapsed, limit, fixed_length, belief_reward, rewards, flags):  # pragma: no cover - compiled
    """How N rows' steps end, as the referee's numpy code computes it (``referee.outcomes``):
    ``modes`` as the step's (0 a step, 1 or 3 a new episode, 2 kept); ``elapsed`` (N,) is
    advanced in place (+1 on a step, 0 on a new episode, kept); ``rewards`` (N,) gets -1.0 or the
    ``confidence`` (``belief_reward``) on a step, else 0.0; ``flags`` (3, N) terminated
    (localised, on a step, unless ``fixed_length``), truncated (``elapsed >= limit``, ``limit`` >
    0, not on a kept row) and their or."""
    for i in range(elapsed.shape[0]):
        mode = modes[i]
        stepped = mode == 0
        if mode != 2:
            elapsed[i] = elapsed[i] + 1 if stepped else 0
        rewards[i] = (confidence[i] if belief_reward else -1.0) if stepped else 0.0
        term = localised[i] and stepped and not fixed_length
        trunc = limit > 0 and mode != 2 and elapsed[i] >= limit
        flags[0, i] = term
        flags[1, i] = trunc
        flags[2, i] = term or trunc
