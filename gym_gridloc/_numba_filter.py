"""The compiled filter step of one belief on a large model: :class:`gym_gridloc.kernels.FusedPlan`'s.

The numpy plan's numbers, bit for bit, in one pass over the belief: each cell sums its stencil
terms in the plan's order (the ``(0, 0)`` term written first, then the others as
:func:`gym_gridloc.kernels.diagonal_add` adds them), is multiplied by its likelihood and written
once, and the sum is numpy's ``np.add.reduce`` of the result (its pairwise summation, whose blocks
are summed while in cache, in the order of a precomputed program).  A term whose weights are one
value ``v`` where they are not zero reads ``v`` and a bit of the cell's byte in ``bits`` (the
cells it feeds), not a weight array; the others read their weights (``wcols``).  Adding a zero
product (a bit not set) leaves a sum of non-negative numbers as it was, so the numbers are the
numpy plan's.  Imported by :mod:`gym_gridloc._numba_kernels` (numba is imported with it).
"""

from __future__ import annotations

import numba
import numpy as np

_U = np.uint64  # unsigned offsets: no negative-index checks (see _numba_kernels)
#: Cells computed before their pairwise blocks are summed (16 KiB of results, still in cache).
CHUNK = 2048
#: Ops of a pairwise-sum program (:func:`pairwise_program`).
PUSH, ADD = 1, 0


def pairwise_program(n: int, block: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """``(bounds, ops)``: numpy's pairwise sum of ``n`` values as blocks and a program.  numpy sums
    a block of at most ``block`` values with eight running sums, and a longer range as its two
    halves (the first a multiple of 8) added; ``bounds`` are the blocks' edges in order, ``ops``
    the sum's postfix program (:data:`PUSH` the next block's sum, :data:`ADD` the last two)."""
    bounds, ops = [0], []
    stack = [(0, n, False)]  # (start, length, halves pushed)
    while stack:
        lo, m, done = stack.pop()
        if m <= block:
            bounds.append(lo + m)
            ops.append(PUSH)
        elif done:
            ops.append(ADD)
        else:
            half = m // 2
            half -= half % 8
            stack += [(lo, m, True), (lo + half, m - half, False), (lo, half, False)]
    return np.array(bounds, dtype=np.int64), np.array(ops, dtype=np.int8)


@numba.njit(cache=True, nogil=True)
def _block(a, o, n):  # pragma: no cover - compiled
    """numpy's sum of one block ``a[o:o+n]`` (``n <= 128``): eight running sums, then the rest in
    order (fewer than 8 values: in order from 0.0)."""
    if n < 8:
        res = 0.0
        for i in range(_U(n)):
            res += a[o + i]
        return res
    r0, r1, r2, r3 = a[o], a[o + _U(1)], a[o + _U(2)], a[o + _U(3)]
    r4, r5, r6, r7 = a[o + _U(4)], a[o + _U(5)], a[o + _U(6)], a[o + _U(7)]
    main = n - n % 8
    for i in range(8, main, 8):
        j = o + _U(i)
        r0 += a[j]
        r1 += a[j + _U(1)]
        r2 += a[j + _U(2)]
        r3 += a[j + _U(3)]
        r4 += a[j + _U(4)]
        r5 += a[j + _U(5)]
        r6 += a[j + _U(6)]
        r7 += a[j + _U(7)]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(main, n):
        res += a[o + _U(i)]
    return res


@numba.njit(cache=True, nogil=True)
def _run(sums, ops):  # pragma: no cover - compiled
    """The pairwise program ``ops`` on the blocks' ``sums``: ``0.0 +`` the total (as numpy's add
    reduction starts from its identity)."""
    stack = np.empty(128)
    top = 0
    k = 0
    for op in ops:
        if op == PUSH:
            stack[top] = sums[k]
            top += 1
            k += 1
        else:
            top -= 1
            stack[top - 1] = stack[top - 1] + stack[top]
    return 0.0 + stack[0]


@numba.njit(cache=True, nogil=True)
def pairwise_sum(a, bounds, ops):  # pragma: no cover - compiled
    """``np.add.reduce(a)`` of a flat array by :func:`pairwise_program`'s ``bounds`` and ``ops``."""
    sums = np.empty(bounds.size - 1)
    for k in range(sums.size):
        sums[k] = _block(a, _U(bounds[k]), bounds[k + 1] - bounds[k])
    return _run(sums, ops)


@numba.njit(cache=True, nogil=True)
def _cells(b, bits, wcols, vals, terms, t0, t1, hw, ob, lo, hi, out, lik, lb, mode):  # pragma: no cover - compiled
    """Cells ``lo..hi-1`` of one destination layer (``out[ob + c]``), term by term (any terms;
    those whose source is outside the layer are skipped, as numpy's diagonals leave them out)."""
    for c in range(_U(lo), _U(hi)):
        out[ob + c] = 0.0
    for t in range(t0, t1):
        s = terms[t, 1]
        a, e = max(lo, s), min(hi, hw + s)
        p = _U(terms[t, 0] * hw - s)
        if terms[t, 3] < 0:
            w = _U(terms[t, 2] * hw - s)
            for c in range(_U(a), _U(max(a, e))):
                out[ob + c] += wcols[w + c] * b[p + c]
        else:
            v, m = vals[t], np.uint8(1 << terms[t, 3])
            for c in range(_U(a), _U(max(a, e))):
                out[ob + c] += (v if bits[c] & m else 0.0) * b[p + c]
    if mode:
        for c in range(_U(lo), _U(hi)):
            out[ob + c] *= lik[lb + c]


@numba.njit(cache=True, nogil=True)
def _chunk(b, bits, wcols, vals, terms, span, hw, ob, lo, hi, out, lik, lb, mode):  # pragma: no cover - compiled
    """Cells ``lo..hi-1`` of one destination layer with its terms ``span`` (first term, end, the
    cells where every term's source is inside the layer, and whether the layer has one to five
    terms, the first with weights and the others bits): those cells in one loop (a term of the
    five that the layer lacks adds a zero: bit 7, set nowhere), the others by :func:`_cells`."""
    t0, t1, a, e = span[0], span[1], max(lo, span[2]), min(hi, span[3])
    nt = t1 - t0
    if not span[4] or e <= a:
        _cells(b, bits, wcols, vals, terms, t0, t1, hw, ob, lo, hi, out, lik, lb, mode)
        return
    w0 = _U(terms[t0, 2] * hw - terms[t0, 1])
    p0 = _U(terms[t0, 0] * hw - terms[t0, 1])
    p1 = p2 = p3 = p4 = p0
    v1 = v2 = v3 = v4 = 0.0
    m1 = m2 = m3 = m4 = np.uint8(128)
    if nt > 1:
        p1, v1, m1 = _U(terms[t0 + 1, 0] * hw - terms[t0 + 1, 1]), vals[t0 + 1], np.uint8(1 << terms[t0 + 1, 3])
    if nt > 2:
        p2, v2, m2 = _U(terms[t0 + 2, 0] * hw - terms[t0 + 2, 1]), vals[t0 + 2], np.uint8(1 << terms[t0 + 2, 3])
    if nt > 3:
        p3, v3, m3 = _U(terms[t0 + 3, 0] * hw - terms[t0 + 3, 1]), vals[t0 + 3], np.uint8(1 << terms[t0 + 3, 3])
    if nt > 4:
        p4, v4, m4 = _U(terms[t0 + 4, 0] * hw - terms[t0 + 4, 1]), vals[t0 + 4], np.uint8(1 << terms[t0 + 4, 3])
    if mode:
        for c in range(_U(a), _U(e)):
            m = bits[c]
            acc = wcols[w0 + c] * b[p0 + c]
            acc += (v1 if m & m1 else 0.0) * b[p1 + c]
            acc += (v2 if m & m2 else 0.0) * b[p2 + c]
            acc += (v3 if m & m3 else 0.0) * b[p3 + c]
            acc += (v4 if m & m4 else 0.0) * b[p4 + c]
            out[ob + c] = acc * lik[lb + c]
    else:
        for c in range(_U(a), _U(e)):
            m = bits[c]
            acc = wcols[w0 + c] * b[p0 + c]
            acc += (v1 if m & m1 else 0.0) * b[p1 + c]
            acc += (v2 if m & m2 else 0.0) * b[p2 + c]
            acc += (v3 if m & m3 else 0.0) * b[p3 + c]
            acc += (v4 if m & m4 else 0.0) * b[p4 + c]
            out[ob + c] = acc
    if lo < a:
        _cells(b, bits, wcols, vals, terms, t0, t1, hw, ob, lo, a, out, lik, lb, mode)
    if e < hi:
        _cells(b, bits, wcols, vals, terms, t0, t1, hw, ob, e, hi, out, lik, lb, mode)


@numba.njit(cache=True, nogil=True)
def fused_step(b, out, lik, layered, mode, spans, n_layers, hw, bits, wcols, vals, terms, bounds, ops):  # pragma: no cover - compiled
    """One belief's step with one action: ``out`` = ``T^T b`` (flat ``L*hw``), mode 0: nothing
    else, returns 1.0; 1: times the likelihood ``lik`` (``hw``, or ``L*hw`` when ``layered`` is 1),
    times ``1 / z`` when the sum ``z`` is positive and finite; 2: times the likelihood only.
    Returns ``z`` (modes 1, 2).  ``spans`` ``(L, 5)``: the action's terms of each destination
    layer (see :func:`_chunk`); ``terms`` ``(T, 4)``:
    source layer, flat shift (destination minus source cell), weight column (-1 for a bit term),
    bit (-1 for a weight term); ``vals`` the bit terms' values; ``bounds`` and ``ops`` the sum's
    :func:`pairwise_program` of ``L*hw`` values."""
    n = n_layers * hw
    sums = np.empty(bounds.size - 1)
    k = 0
    done = 0
    while done < n:
        layer = done // hw
        end = min(done + CHUNK, (layer + 1) * hw)
        base = layer * hw
        _chunk(b, bits, wcols, vals, terms, spans[layer], hw, _U(base), done - base, end - base, out, lik,
               _U(base * layered), mode)
        done = end
        while mode and k < sums.size and bounds[k + 1] <= done:
            sums[k] = _block(out, _U(bounds[k]), bounds[k + 1] - bounds[k])
            k += 1
    if mode == 0:
        return 1.0
    z = _run(sums, ops)
    if mode == 1 and z > 0.0 and np.isfinite(z):
        inv = 1.0 / z
        for i in range(_U(n)):
            out[i] *= inv
    return z
