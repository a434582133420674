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
