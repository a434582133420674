"""The compiled step's sparse path: a belief with mass on few of its states (a maze's pose belief
after a few readings holds a handful of its hundreds) is filtered and read out over those states
only, with the dense kernels' numbers, bit for bit.

Why the numbers are the same: every skipped term of the dense kernels is a product with a zero
(a state without mass, a weight or likelihood times it), and adding ``+0.0`` leaves a sum of
non-negative numbers as it was; the terms that remain are added in the dense order (the stencil's
terms in order, each cell's running sums by its place in its chunk, the layers of a position in
order).  The states with mass are listed in ascending order (layer-major), as the dense loops
meet them."""

from __future__ import annotations

import numba
import numpy as np

from gym_gridloc._numba_filter import STENCIL_CHUNK, term

_U = np.uint64  # unsigned offsets and indices (see gym_gridloc._numba_filter)


#: A belief is filtered sparsely when at most one in ``SHARE`` of its states holds mass (the dense
#: kernels work on whole layers, several values per instruction: below that share the sparse
#: path is not faster; measured on DepthMaze-v0 and RingSensor8x8-v0, see docs/scale.md).
SHARE = 16


@numba.njit(cache=True, nogil=True)
def sparse_enough(count, size):  # pragma: no cover - compiled
    """Whether ``count`` states with mass of ``size`` are few enough for the sparse path."""
    return count * SHARE <= size


@numba.njit(cache=True, nogil=True)
def support(b, bo, size, out):  # pragma: no cover - compiled
    """The states of ``b[bo:bo+size]`` that are not zero (a NaN counts), ascending, into
    ``out[0:]``; returns how many."""
    k = 0
    for c in range(_U(size)):
        out[k] = c
        k += b[bo + c] != 0.0
    return k


@numba.njit(cache=True, nogil=True)
def sparse_stencil(b, bo, src, n_src, w, wo, meta, mo, K, lik, lo, out, oo, n_layers, hw, layered, marks, dst, do):  # pragma: no cover - compiled
    """:func:`gym_gridloc._numba_filter.stencil` in mode 1 (times the likelihood, normalised) for
    a belief whose states with mass are ``src[0:n_src]`` (ascending): the same numbers in ``out``
    and the same sum.  ``marks`` (one byte per state) is zero on entry and left zero.  Returns
    the sum and how many states of ``out`` have mass, listed ascending at ``dst[do:]``."""
    size = n_layers * hw
    for i in range(_U(size)):
        out[oo + i] = 0.0
    n_dst = 0
    for k in range(K):
        s_layer, d_layer, o, a, e = term(meta, mo, K, k)
        if d_layer < 0 or e <= a:
            continue
        s_lo = s_layer * hw
        for j in range(n_src):
            s = src[j]
            if s < s_lo:
                continue
            if s >= s_lo + hw:
                break
            cell = s - s_lo
            d = cell + o
            if d < a or d >= e:
                continue
            t = d_layer * hw + d
            out[oo + _U(t)] += w[wo + _U(k * hw + cell)] * b[bo + _U(s)]
            if marks[t] == 0:
                marks[t] = 1
                dst[do + _U(n_dst)] = t
                n_dst += 1
    # the destinations in ascending order (few: an insertion sort), their marks cleared
    for j in range(1, n_dst):
        t = dst[do + _U(j)]
        m = j
        while m > 0 and dst[do + _U(m - 1)] > t:
            dst[do + _U(m)] = dst[do + _U(m - 1)]
            m -= 1
        dst[do + _U(m)] = t
    # times the likelihood, each product added to the running sum its cell's place gives it
    z0 = z1 = z2 = z3 = 0.0
    for j in range(n_dst):
        t = dst[do + _U(j)]
        marks[t] = 0
        layer = t // hw
        cell = t - layer * hw
        v = out[oo + _U(t)] * lik[lo + _U(layer * hw * layered + cell)]
        out[oo + _U(t)] = v
        c0 = cell - cell % STENCIL_CHUNK
        i = cell - c0
        n = min(hw, c0 + STENCIL_CHUNK) - c0
        lane = i % 4 if i < n - n % 4 else 0  # (the dense loop's four running sums, the tail in the first)
        if lane == 0:
            z0 += v
        elif lane == 1:
            z1 += v
        elif lane == 2:
            z2 += v
        else:
            z3 += v
    z = (z0 + z1) + (z2 + z3)
    normalise = z > 0.0 and np.isfinite(z)
    inv = 1.0 / z if normalise else 1.0
    n_mass = 0
    for j in range(n_dst):
        t = dst[do + _U(j)]
        if normalise:
            out[oo + _U(t)] *= inv
        dst[do + _U(n_mass)] = t
        n_mass += out[oo + _U(t)] != 0.0
    return z, n_mass


@numba.njit(cache=True, nogil=True)
def sparse_positions(ff, fo, states, so, count, hw, sc, po):  # pragma: no cover - compiled
    """The position belief ``sc[po:po+hw]`` of a hidden-state belief ``ff[fo:]`` whose states
    with mass are ``states[so:so+count]`` (ascending): each position's layers added in order, as
    the dense readout adds them."""
    for c in range(_U(hw)):
        sc[po + c] = 0.0
    for j in range(count):
        t = states[so + _U(j)]
        sc[po + _U(t % hw)] += ff[fo + _U(t)]


@numba.njit(cache=True, nogil=True)
def sparse_argmax(ff, fo, states, so, count):  # pragma: no cover - compiled
    """numpy's argmax of a belief ``ff[fo:]`` whose states with mass are ``states[so:so+count]``
    (ascending; every other value zero): the first NaN, else the first largest value (0 when no
    state has mass)."""
    best = 0.0
    j = 0
    for k in range(count):
        t = states[so + _U(k)]
        x = ff[fo + _U(t)]
        if x != x:
            return t
        if x > best:
            best = x
            j = t
    return j
