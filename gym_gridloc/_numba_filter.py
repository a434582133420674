"""The compiled filter steps: the stencil of small models (:class:`gym_gridloc.kernels.NumbaPlan`: one
belief or a batch, each with its action; the vector step's filter too) and the fused step of one
belief on a large model (:class:`gym_gridloc.kernels.FusedPlan`).

Small models: each term is added over its whole destination layer, the terms in order, then each
layer is weighed and summed in cache-sized chunks (:func:`stencil`).

Large models: the numpy plan's numbers, bit for bit, in one pass over the belief: each cell sums
its stencil terms in the plan's order (the ``(0, 0)`` term written first, then the others as
:func:`gym_gridloc.kernels.diagonal_add` adds them), is multiplied by its likelihood and written
once, and the sum is numpy's ``np.add.reduce`` of the result (its pairwise summation, whose blocks
are summed while in cache, in the order of a precomputed program).  A term whose weights are one
value ``v`` where they are not zero reads ``v`` and a bit of the cell's byte in ``bits`` (the
cells it feeds), not a weight array; a layer's first term reads its weights (``wcols``) or, on
grids too large for them to stay in cache, a one-byte code per cell of at most 8 values
(``codes``, ``tables``); the others read their weights.  Adding a zero
product (a bit not set) leaves a sum of non-negative numbers as it was, so the numbers are the
numpy plan's.  Imported by :mod:`gym_gridloc._numba_kernels` (numba is imported with it).
"""

from __future__ import annotations

import numba
import numpy as np

#: Cells of a layer weighed and summed at a time by the small models' stencil (kept in cache).
STENCIL_CHUNK = 2048
_U = np.uint64  # Offsets and indices are unsigned: numba then emits no negative-index checks, and
# flat arrays with offsets need no per-row views (a view, or a reshape, costs more than a small
# belief's arithmetic: tables and beliefs are flattened once per call and addressed by offset).


@numba.njit(cache=True, nogil=True)
def term(meta, mo, K, k):  # pragma: no cover - compiled
    """Term ``k`` of an action's ``(5, K)`` meta at ``meta[mo:]``: ``(source layer, destination
    layer, flat offset, first and end destination cell)``; a destination below 0 (padding) or an
    end at most the first cell: no term."""
    return (meta[mo + _U(k)], meta[mo + _U(K + k)], meta[mo + _U(2 * K + k)], meta[mo + _U(3 * K + k)],
            meta[mo + _U(4 * K + k)])


@numba.njit(cache=True, nogil=True)
def stencil(b, bo, w, wo, meta, mo, K, lik, lo, out, oo, n_layers, hw, layered, mode):  # pragma: no cover - compiled
    """``out = T^T b`` over flat arrays, the belief at ``b[bo:]`` into ``out[oo:]`` (``L*hw``
    values), the action's ``(K, hw)`` weights at ``w[wo:]`` and its ``(5, K)`` meta at
    ``meta[mo:]`` (see :func:`stencil_update`), the likelihood (``hw``, or ``L*hw`` when
    ``layered`` is 1) at ``lik[lo:]``.  Each term is added over its whole destination layer, the
    terms in order (each cell sums its terms in that order), then each layer is weighed and
    summed in cache-sized chunks."""
    for i in range(_U(n_layers * hw)):
        out[oo + i] = 0.0
    for k in range(K):
        src, dst, o, a, e = term(meta, mo, K, k)
        if dst < 0 or e <= a:
            continue
        wk = wo + _U(k * hw + a - o)
        bk = bo + _U(src * hw + a - o)
        ok = oo + _U(dst * hw + a)
        for i in range(_U(e - a)):
            out[ok + i] += w[wk + i] * b[bk + i]
    if mode == 0:
        return 0.0
    z0 = z1 = z2 = z3 = 0.0
    for layer in range(n_layers):
        base = oo + _U(layer * hw)
        lbase = lo + _U(layer * hw * layered)
        for c0 in range(0, hw, STENCIL_CHUNK):
            n = min(hw, c0 + STENCIL_CHUNK) - c0
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
    return stencil(b.reshape(b.size), _U(0), w, _U(0), meta, _U(0), K, lik, _U(0), out.reshape(out.size), _U(0),
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
            z[i] = stencil(bf, _U(i * size), wf, _U(a * K * hw), mf, _U(a * 5 * K), K, lf, _U(i * lik.shape[1]),
                            of, _U(i * size), n_layers, hw, layered, mode)
        else:
            z[i] = 1.0


# -- large models: the fused step ------------------------------------------------------------------
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
def _chunk(b, bits, wcols, vals, codes, tables, terms, span, hw, ob, lo, hi, out, lik, lb, mode):  # pragma: no cover - compiled
    """Cells ``lo..hi-1`` of one destination layer with its terms ``span`` (first term, end, the
    cells where every term's source is inside the layer, how, and the first term's codes): how 0,
    term by term (:func:`_cells`); 1 or 2, in one loop: one to five terms, the others bits, the
    first with its weights (1) or with at most 8 values, one per code (2: ``codes`` and ``tables``
    row ``span[5]``).  In one loop, a term of the five that the layer lacks adds a zero (bit 7,
    set nowhere)."""
    t0, t1, a, e, how = span[0], span[1], max(lo, span[2]), min(hi, span[3]), span[4]
    nt = t1 - t0
    if how == 0 or e <= a:
        _cells(b, bits, wcols, vals, terms, t0, t1, hw, ob, lo, hi, out, lik, lb, mode)
        return
    w0 = _U(terms[t0, 2] * hw - terms[t0, 1])
    kb = _U(span[5] * hw)
    tb = _U(span[5] * 8)
    u0, u1, u2, u3 = tables[tb], tables[tb + _U(1)], tables[tb + _U(2)], tables[tb + _U(3)]
    u4, u5, u6, u7 = tables[tb + _U(4)], tables[tb + _U(5)], tables[tb + _U(6)], tables[tb + _U(7)]
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
    if how == 1 and mode:
        for c in range(_U(a), _U(e)):
            m = bits[c]
            acc = wcols[w0 + c] * b[p0 + c]
            acc += (v1 if m & m1 else 0.0) * b[p1 + c]
            acc += (v2 if m & m2 else 0.0) * b[p2 + c]
            acc += (v3 if m & m3 else 0.0) * b[p3 + c]
            acc += (v4 if m & m4 else 0.0) * b[p4 + c]
            out[ob + c] = acc * lik[lb + c]
    elif how == 1 and not mode:
        for c in range(_U(a), _U(e)):
            m = bits[c]
            acc = wcols[w0 + c] * b[p0 + c]
            acc += (v1 if m & m1 else 0.0) * b[p1 + c]
            acc += (v2 if m & m2 else 0.0) * b[p2 + c]
            acc += (v3 if m & m3 else 0.0) * b[p3 + c]
            acc += (v4 if m & m4 else 0.0) * b[p4 + c]
            out[ob + c] = acc
    elif how == 2 and mode:
        for c in range(_U(a), _U(e)):
            k = codes[kb + c]
            w = u0
            w = u1 if k == 1 else w
            w = u2 if k == 2 else w
            w = u3 if k == 3 else w
            w = u4 if k == 4 else w
            w = u5 if k == 5 else w
            w = u6 if k == 6 else w
            w = u7 if k == 7 else w
            m = bits[c]
            acc = w * b[p0 + c]
            acc += (v1 if m & m1 else 0.0) * b[p1 + c]
            acc += (v2 if m & m2 else 0.0) * b[p2 + c]
            acc += (v3 if m & m3 else 0.0) * b[p3 + c]
            acc += (v4 if m & m4 else 0.0) * b[p4 + c]
            out[ob + c] = acc * lik[lb + c]
    elif how == 2 and not mode:
        for c in range(_U(a), _U(e)):
            k = codes[kb + c]
            w = u0
            w = u1 if k == 1 else w
            w = u2 if k == 2 else w
            w = u3 if k == 3 else w
            w = u4 if k == 4 else w
            w = u5 if k == 5 else w
            w = u6 if k == 6 else w
            w = u7 if k == 7 else w
            m = bits[c]
            acc = w * b[p0 + c]
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
def fused_step(b, out, lik, layered, mode, spans, n_layers, hw, bits, wcols, vals, codes, tables, terms, bounds, ops):  # pragma: no cover - compiled
    """One belief's step with one action: ``out`` = ``T^T b`` (flat ``L*hw``), mode 0: nothing
    else, returns 1.0; 1: times the likelihood ``lik`` (``hw``, or ``L*hw`` when ``layered`` is 1),
    times ``1 / z`` when the sum ``z`` is positive and finite; 2: times the likelihood only.
    Returns ``z`` (modes 1, 2).  ``spans`` ``(L, 6)``: the action's terms of each destination
    layer (see :func:`_chunk`); ``terms`` ``(T, 4)``:
    source layer, flat shift (destination minus source cell), weight column (-1 for a bit term),
    bit (-1 for a weight term); ``vals`` the bit terms' values; ``bounds`` and ``ops`` the sum's
    :func:`pairwise_program` of ``L*hw`` values.  ``b`` and ``out`` are read flat (C-contiguous)."""
    b, out = b.reshape(b.size), out.reshape(out.size)
    n = n_layers * hw
    sums = np.empty(bounds.size - 1)
    k = 0
    done = 0
    while done < n:
        layer = done // hw
        end = min(done + CHUNK, (layer + 1) * hw)
        base = layer * hw
        _chunk(b, bits, wcols, vals, codes, tables, terms, spans[layer], hw, _U(base), done - base, end - base, out, lik,
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
