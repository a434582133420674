"""Compiled filter kernels (numba), with the numpy stencil as the fallback.

The numpy stencil in :meth:`GridModel.predict` makes one pass over memory per ufunc call (a
multiply and an add per term); a compiled loop makes one pass in all.  :func:`stencil_update`
walks the belief in cache-sized chunks: for each chunk it sums the terms' contributions
(contiguous, vectorisable loops), multiplies by the likelihood and adds up the normaliser, so each
weight, belief and likelihood value is read once per step.  Results equal the numpy path within
rounding (1e-15; tests/test_filter.py compares both against a dense reference within 1e-12).

``numba`` is optional (the ``fast`` extra).  Without it, or with the environment variable
``GYM_GRIDLOC_NO_NUMBA=1``, :data:`AVAILABLE` is False and the filter uses numpy.
"""

from __future__ import annotations

import os

import numpy as np

AVAILABLE = False
_CHUNK = 2048
#: Grids with at least this many cells read their weights as masks and codes (see StencilPlan).
CODES_MIN_CELLS = 1 << 14

if os.environ.get("GYM_GRIDLOC_NO_NUMBA", "") not in ("1", "true", "yes"):
    try:
        import numba

        AVAILABLE = True
    except ImportError:  # pragma: no cover - exercised where numba is absent
        AVAILABLE = False

if AVAILABLE:

    @numba.njit(cache=True, nogil=True)
    def _stencil_update(b, w, meta, lik, out, n_layers, mode):  # pragma: no cover
        K = w.shape[0]
        hw = out.shape[0] // n_layers
        src, dst, off, lo, hi = meta[0], meta[1], meta[2], meta[3], meta[4]
        z0 = 0.0
        z1 = 0.0
        z2 = 0.0
        z3 = 0.0
        for layer in range(n_layers):
            base = layer * hw
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
                    lv = lik[c0:c1]
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
    def _stencil_update_codes(b, w, meta, codes, table, lik, likc, likt, out, n_layers, mode):  # pragma: no cover
        # mode 0: predict only; 1: times lik, normalised; 2: times lik; 3: times likt[likc].
        K = codes.shape[0]
        hw = out.shape[0] // n_layers
        src, dst, off, lo, hi, kind = meta[0], meta[1], meta[2], meta[3], meta[4], meta[5]
        z0 = 0.0
        z1 = 0.0
        z2 = 0.0
        z3 = 0.0
        for layer in range(n_layers):
            base = layer * hw
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
                    bv = b[src[k] * hw + a - o : src[k] * hw + e - o]
                    ov = out[base + a : base + e]
                    if kind[k] == 1:  # weight c on a mask, 0 elsewhere
                        cv = codes[k, a - o : e - o]
                        c = table[k, 1]
                        for i in range(e - a):
                            ov[i] += (c * cv[i]) * bv[i]
                    elif kind[k] == 2:  # a few values: one-byte codes into the table
                        cv = codes[k, a - o : e - o]
                        tk = table[k]
                        for i in range(e - a):
                            ov[i] += tk[cv[i]] * bv[i]
                    else:
                        wv = w[k, a - o : e - o]
                        for i in range(e - a):
                            ov[i] += wv[i] * bv[i]
                if mode > 0:
                    n = c1 - c0
                    if mode == 3:  # a likelihood of few values, as one-byte codes
                        lc = likc[c0:c1]
                        for i in range(n):
                            oc[i] *= likt[lc[i]]
                    else:
                        lv = lik[c0:c1]
                        for i in range(n):
                            oc[i] *= lv[i]
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
    def _batch_update(beliefs, w, meta, actions, lik, out, n_layers, sel, z):  # pragma: no cover
        for i in range(beliefs.shape[0]):
            if sel[i]:
                a = actions[i]
                z[i] = _stencil_update(beliefs[i], w[a], meta[a], lik[i], out[i], n_layers, 1)
            else:
                z[i] = 1.0


class BatchPlan:
    """Every action's stencil, padded to one shape, for :class:`gym_gridloc.BatchFilter`: one
    compiled call updates N beliefs (predict with each one's action, update, normalise)."""

    def __init__(self, model) -> None:
        plans = [model.stencil_plan(a) for a in range(model.n_actions)]
        k = max(p.w.shape[0] for p in plans)
        hw = plans[0].hw
        self.n_layers = model.n_layers
        self.w = np.zeros((len(plans), k, hw))
        self.meta = np.zeros((len(plans), 6, k), dtype=np.int64)
        self.meta[:, 1, :] = -1  # padding terms feed no layer
        for a, p in enumerate(plans):
            n = p.w.shape[0]
            self.w[a, :n] = p.w
            self.meta[a, :, :n] = p.meta
        self.meta[:, 5, :] = 0  # the float64 loop

    def run(self, beliefs: np.ndarray, actions: np.ndarray, lik: np.ndarray, out: np.ndarray, sel: np.ndarray) -> np.ndarray:
        z = np.empty(beliefs.shape[0])
        _batch_update(beliefs, self.w, self.meta, actions, lik, out, self.n_layers, sel, z)
        return z


class StencilPlan:
    """The arrays a kernel call needs for one action's terms (built once per model and action)."""

    def __init__(self, model, terms) -> None:
        h, w = model.shape
        hw = h * w
        self.hw = hw
        self.n_layers = model.n_layers
        weights = [t.weight for t in terms]
        base = weights[0].base if weights else None
        if (
            isinstance(base, np.ndarray)
            and base.shape == (len(weights), h, w)
            and base.flags.c_contiguous
            and all(wt.base is base and wt.ctypes.data == base[k].ctypes.data for k, wt in enumerate(weights))
        ):
            self.w = base.reshape(len(weights), hw)  # the model's own stacked weights, no copy
        else:
            self.w = np.ascontiguousarray(np.stack(weights).reshape(len(weights), hw)) if weights else np.zeros((0, hw))
        # Weights read as 8-byte floats cost most of a large grid's memory traffic.  A term whose
        # weight is one value c on a mask (0 elsewhere) is read as a one-byte mask (kind 1); one
        # with at most 256 values as one-byte codes into a small table (kind 2); others as
        # float64 (kind 0).  On grids that fit in cache the float64 loop is fastest: there every
        # term is kind 0.  The numbers multiplied are the same float64s in every kind.
        k_terms = len(weights)
        self.kind = np.zeros(k_terms, dtype=np.int64)
        self.codes = np.zeros((k_terms, hw if hw >= CODES_MIN_CELLS else 1), dtype=np.uint8)
        self.table = np.zeros((k_terms, 256))
        if hw >= CODES_MIN_CELLS:
            for k, wt in enumerate(weights):
                vals, inv = np.unique(wt, return_inverse=True)
                if len(vals) == 2 and vals[0] == 0.0:
                    self.kind[k] = 1
                elif len(vals) <= 256:
                    self.kind[k] = 2
                else:
                    continue
                self.table[k, : len(vals)] = vals
                self.codes[k] = inv.reshape(-1)
        self.src = np.array([t.src for t in terms], dtype=np.int64)
        self.dst = np.array([t.dst for t in terms], dtype=np.int64)
        self.off = np.array([t.dr * w + t.dc for t in terms], dtype=np.int64)
        # Destination cells d (within a layer) whose source d - off lies in the layer.
        self.lo = np.maximum(self.off, 0)
        self.hi = np.minimum(hw + self.off, hw)
        # One int array for the kernel (fewer arguments: a numba call costs per argument).
        self.meta = np.ascontiguousarray(np.stack([self.src, self.dst, self.off, self.lo, self.hi, self.kind]))
        self.use_codes = bool(self.kind.any())

    @property
    def run_flat(self):
        """``(belief, out, lik) -> sum`` over flat arrays, unnormalised: the kernel with its
        plan bound (the fewest Python steps per call)."""
        w, meta, n_layers = self.w, self.meta, self.n_layers
        if self.use_codes:
            codes, table = self.codes, self.table

            def run(belief, out, lik):
                if type(lik) is tuple:
                    return _stencil_update_codes(belief, w, meta, codes, table, _EMPTY, lik[0], lik[1], out, n_layers, 3)
                return _stencil_update_codes(belief, w, meta, codes, table, lik, _NO_CODES, _EMPTY, out, n_layers, 2)
        else:
            def run(belief, out, lik):
                return _stencil_update(belief, w, meta, lik, out, n_layers, 2)
        return run

    def likelihood_form(self, lik: np.ndarray):
        """What :attr:`run_flat` takes for a likelihood: on grids read as codes, a likelihood of at
        most 256 values becomes ``(codes, table)`` (1 byte per cell); else the flat float64s."""
        flat = np.ascontiguousarray(lik, dtype=np.float64).ravel()
        if self.use_codes:
            vals, inv = np.unique(flat, return_inverse=True)
            if len(vals) <= 256:
                return inv.reshape(-1).astype(np.uint8), np.pad(vals, (0, 256 - len(vals)))
        return flat

    def run(self, belief: np.ndarray, out: np.ndarray, lik: np.ndarray | None, normalise: bool = True) -> float:
        """``out = T^T belief``; with ``lik``, times ``lik`` and (with ``normalise``) divided by the
        sum, which is returned (0.0 without ``lik``)."""
        mode = 0 if lik is None else 1 if normalise else 2
        lk = _EMPTY if lik is None else lik.ravel()
        if self.use_codes:
            return _stencil_update_codes(belief.ravel(), self.w, self.meta, self.codes, self.table, lk,
                                         _NO_CODES, _EMPTY, out.ravel(), self.n_layers, mode)
        return _stencil_update(belief.ravel(), self.w, self.meta, lk, out.ravel(), self.n_layers, mode)

_EMPTY = np.zeros(1)
_NO_CODES = np.zeros(1, dtype=np.uint8)
