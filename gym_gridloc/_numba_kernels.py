"""The compiled (numba) filter kernels.  Imported only by :mod:`gym_gridloc.kernels`, and only
when a model small enough for them is first filtered: importing numba costs about 100 MiB of
resident memory, so a process that only works on large grids never pays it."""

from __future__ import annotations

import numba
import numpy as np

_CHUNK = 2048


@numba.njit(cache=True, nogil=True)
def stencil_update(b, w, meta, lik, layered, out, n_layers, mode):  # pragma: no cover - compiled
    """``out = T^T b`` over flat arrays in cache-sized chunks (one pass over memory); mode 0:
    predict only; 1: times ``lik``, normalised; 2: times ``lik``.  Returns the sum (modes 1, 2).
    ``lik`` holds one (H*W) likelihood, or one per layer when ``layered`` is 1.  ``b`` and ``out``
    may be (L, H, W): C-contiguous arrays are read flat (no reshape in Python)."""
    b = b.reshape(b.size)
    out = out.reshape(out.size)
    K = w.shape[0]
    hw = out.shape[0] // n_layers
    src, dst, off, lo, hi = meta[0], meta[1], meta[2], meta[3], meta[4]
    z0 = z1 = z2 = z3 = 0.0
    for layer in range(n_layers):
        base = layer * hw
        lbase = base * layered
        for c0 in range(0, hw, _CHUNK):
            c1 = min(hw, c0 + _CHUNK)
            oc = out[base + c0 : base + c1]
            for i in range(c1 - c0):
                oc[i] = 0.0
            for k in range(K):
                if dst[k] != layer:
                    continue
                a = max(c0, lo[k])
                e = min(c1, hi[k])
                if e <= a:
                    continue
                o = off[k]
                # Slices indexed from 0: no negative-index checks, so the loop vectorises.
                wv = w[k, a - o : e - o]
                bv = b[src[k] * hw + a - o : src[k] * hw + e - o]
                ov = out[base + a : base + e]
                for i in range(e - a):
                    ov[i] += wv[i] * bv[i]
            if mode > 0:
                lv = lik[lbase + c0 : lbase + c1]
                n = c1 - c0
                for i in range(n):
                    oc[i] *= lv[i]
                # Four running sums: the additions overlap instead of waiting on each other.
                n4 = n - n % 4
                for i in range(0, n4, 4):
                    z0 += oc[i]
                    z1 += oc[i + 1]
                    z2 += oc[i + 2]
                    z3 += oc[i + 3]
                for i in range(n4, n):
                    z0 += oc[i]
    z = (z0 + z1) + (z2 + z3)
    if mode == 1 and z > 0.0 and np.isfinite(z):
        inv = 1.0 / z
        for i in range(n_layers * hw):
            out[i] *= inv
    return z


@numba.njit(cache=True, nogil=True)
def batch_update(beliefs, w, meta, actions, lik, layered, out, n_layers, mode, sel, z):  # pragma: no cover - compiled
    """:func:`stencil_update` on each selected row of ``beliefs`` with its action (row ``i`` of
    ``lik`` is its likelihood; unused in mode 0)."""
    for i in range(beliefs.shape[0]):
        if sel[i]:
            a = actions[i]
            z[i] = stencil_update(beliefs[i], w[a], meta[a], lik[i], layered, out[i], n_layers, mode)
        else:
            z[i] = 1.0


# -- one belief's readout: what the referee and the observation read after each step ------------------
# Bit for bit what numpy computes (the callers' numpy paths are the reference; tests hold them equal):
# layers are summed in order (numpy's sum over the layer axis), float32 casts round to nearest, and
# the entropy's sum is numpy's pairwise summation.  log2 itself stays numpy's (its SIMD log2 may
# differ in the last bit from libm's).

@numba.njit(cache=True, nogil=True)
def readout(flat, n_layers, pose, pos, q):  # pragma: no cover - compiled
    """For one hidden-state belief ``flat`` (L*H*W, layer-major): ``pos`` (H*W) = the position
    belief (the layers summed in order), ``q`` (H*W) = ``pos + (pos <= 0)`` (the entropy's log2
    argument); returns the index of the first largest value (the first NaN, as numpy's argmax)
    of ``flat`` (``pose``) or of ``pos``."""
    hw = flat.size // n_layers
    for i in range(hw):
        x = flat[i]
        for layer in range(1, n_layers):
            x += flat[layer * hw + i]
        pos[i] = x
        q[i] = x + 1.0 if x <= 0.0 else x + 0.0
    tested = flat if pose else pos
    k = 0
    best = tested[0]
    if best != best:
        return 0
    for i in range(1, tested.size):
        x = tested[i]
        if x != x:
            return i
        if x > best:
            best = x
            k = i
    return k


@numba.njit(cache=True, nogil=True)
def _block_product(p, q, lo, n):  # pragma: no cover - compiled
    """numpy's pairwise sum of ``p[lo:lo+n] * q[lo:lo+n]`` for ``n <= 128`` (one block: eight
    running sums, then the rest in order)."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += p[i] * q[i]
        return res
    r0 = p[lo] * q[lo]
    r1 = p[lo + 1] * q[lo + 1]
    r2 = p[lo + 2] * q[lo + 2]
    r3 = p[lo + 3] * q[lo + 3]
    r4 = p[lo + 4] * q[lo + 4]
    r5 = p[lo + 5] * q[lo + 5]
    r6 = p[lo + 6] * q[lo + 6]
    r7 = p[lo + 7] * q[lo + 7]
    i = 8
    end = n - n % 8
    while i < end:
        j = lo + i
        r0 += p[j] * q[j]
        r1 += p[j + 1] * q[j + 1]
        r2 += p[j + 2] * q[j + 2]
        r3 += p[j + 3] * q[j + 3]
        r4 += p[j + 4] * q[j + 4]
        r5 += p[j + 5] * q[j + 5]
        r6 += p[j + 6] * q[j + 6]
        r7 += p[j + 7] * q[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += p[lo + i] * q[lo + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def _pairwise_product(p, q, lo, n):  # pragma: no cover - compiled
    """numpy's pairwise sum (``DOUBLE_pairwise_sum``) of ``p[lo:lo+n] * q[lo:lo+n]``: blocks of
    at most 128, larger ranges split in two halves (the first a multiple of 8) and the halves'
    sums added.  The recursion is unrolled on a stack (numba's cache cannot hold a recursive
    function)."""
    if n <= 128:
        return _block_product(p, q, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    stage = np.zeros(64, dtype=np.int64)
    left = np.empty(64)
    top = 0
    los[0], ns[0] = lo, n
    ret = 0.0
    while True:
        m = ns[top]
        if m <= 128:
            ret = _block_product(p, q, los[top], m)
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
            return ret


@numba.njit(cache=True, nogil=True)
def entropy_sum(p, log2q):  # pragma: no cover - compiled
    """``-np.add.reduce(p * log2q) + 0.0`` (the referee's entropy, ``log2q`` = log2 of
    :func:`readout`'s ``q``), with numpy's order of additions."""
    return -(0.0 + _pairwise_product(p, log2q, 0, p.size)) + 0.0


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


# -- a batch of N: the native vector environment's step ---------------------------------------------
@numba.njit(cache=True, nogil=True)
def sample_moves(weights, keys, actions, states, u, width, out):  # pragma: no cover - compiled
    """The engine's draw of N next states (``engine.sample_next`` without kidnapping), with the
    same arithmetic: state ``i`` under action ``actions[i]`` takes the first term whose running
    sum (left to right, as ``np.cumsum``) exceeds ``u[i]`` times the total, or, when the product
    rounds up to the total, the last term of positive weight.  ``weights`` ``(A + 1, K, H*W)`` and
    ``keys`` ``(A + 1, 4, K)`` are the engine's padded tables; ``states``/``out`` ``(N, 3)``."""
    K = weights.shape[1]
    cum = np.empty(K)
    for i in range(states.shape[0]):
        a = actions[i]
        layer, r, c = states[i, 0], states[i, 1], states[i, 2]
        cell = r * width + c
        total = 0.0
        last = K - 1
        for k in range(K):
            p = weights[a, k, cell] if keys[a, 0, k] == layer else 0.0
            total += p
            cum[k] = total
            if p > 0.0:
                last = k
        target = u[i] * total
        chosen = last
        for k in range(K):
            if target < cum[k]:
                chosen = k
                break
        out[i, 0] = keys[a, 1, chosen]
        out[i, 1] = r + keys[a, 2, chosen]
        out[i, 2] = c + keys[a, 3, chosen]


@numba.njit(cache=True, nogil=True)
def batch_readout(flat, n_layers, pose, width, states, threshold, pos, q, k, confidence, estimate, error, localised, success, layer):  # pragma: no cover - compiled
    """:func:`readout` of N hidden-state beliefs ``flat`` (N, L*H*W) and the referee's arrays of
    ``referee.summarise`` (the same numbers): ``pos``/``q`` (N, H*W) as :func:`readout` fills
    them, then per row the index ``k`` of the largest tested value, its ``confidence``, the
    ``estimate`` (row, column), the Manhattan ``error`` to the true ``states`` (layer, row, col),
    ``localised`` (confidence >= threshold), ``success`` and the estimated ``layer`` (pose)."""
    hw = pos.shape[1]
    for i in range(flat.shape[0]):
        j = readout(flat[i], n_layers, pose, pos[i], q[i])
        conf = flat[i, j] if pose else pos[i, j]
        cell = j % hw if pose and n_layers > 1 else j
        er, ec = cell // width, cell % width
        lay = j // hw
        e = abs(er - states[i, 1]) + abs(ec - states[i, 2])
        k[i] = j
        confidence[i] = conf
        estimate[i, 0] = er
        estimate[i, 1] = ec
        error[i] = e
        localised[i] = conf >= threshold
        right = e == 0
        if pose:
            right = right and lay == states[i, 0]
        success[i] = localised[i] and right
        layer[i] = lay


@numba.njit(cache=True, nogil=True)
def batch_entropy(pos, log2q, out):  # pragma: no cover - compiled
    """:func:`entropy_sum` of each row: ``out[i] = -np.add.reduce(pos[i] * log2q[i]) + 0.0``."""
    for i in range(pos.shape[0]):
        out[i] = entropy_sum(pos[i], log2q[i])
