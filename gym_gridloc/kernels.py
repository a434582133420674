"""Filter kernels: the one place that decides how a model's transition is applied to a belief.

Two paths give the same numbers (within rounding; tests compare both with each other and with a
dense reference within 1e-12):

* **numba** (the optional ``fast`` extra), for models whose belief has fewer than
  :data:`NUMBA_MAX_CELLS` cells, where numpy's per-call overhead dominates: one compiled pass per
  step (predict, likelihood, sum) over cache-sized chunks (:mod:`gym_gridloc._numba_kernels`).
  numba is imported the first time such a model is filtered, never at import: it costs about
  100 MiB of resident memory, so a process that only builds large grids never loads it.
* **diagonals** (every larger model, and every model without numba or with
  ``GYM_GRIDLOC_NO_NUMBA=1``): a stencil term ``(dr, dc)`` is one diagonal of ``T^T`` over the
  flat belief, at offset ``-(dr*W + dc)``, whose values are the term's own weight array (the cells
  where a shift wraps round a row edge have weight 0).  scipy's DIA matrix-vector loop adds
  ``w * x`` for each diagonal in one fused pass straight into the output buffer, reading the
  model's weights in place (no copy); a ``(0, 0)`` term is written first with one multiply.  Then
  one multiply by the likelihood and one sum.  Measured side by side at 512 x 512, this was
  faster than a cache-blocked numpy loop (two ufunc passes per term) and than itself run in
  blocks of 8K-32K cells (README, "Scale and speed").

:func:`uses_numba` decides; :meth:`GridModel.stencil_plan` builds and caches the plan.
"""

from __future__ import annotations

import importlib.util
import os

import numpy as np

#: numba is installed and not switched off by ``GYM_GRIDLOC_NO_NUMBA`` (it is not imported here).
AVAILABLE = (
    os.environ.get("GYM_GRIDLOC_NO_NUMBA", "") not in ("1", "true", "yes")
    and importlib.util.find_spec("numba") is not None
)
#: Models whose belief (layers x rows x columns) has fewer cells use the numba kernels.
NUMBA_MAX_CELLS = 128 * 128

_COMPILED = None


def uses_numba(model) -> bool:
    """Whether ``model`` is filtered by the compiled kernels (else by :class:`DiagonalPlan`).
    For a model small enough, this imports numba (once)."""
    h, w = model.shape
    return AVAILABLE and model.n_layers * h * w < NUMBA_MAX_CELLS and _compiled() is not None


def make_plan(model, terms):
    """The plan that applies ``terms`` (one action's transition of ``model``) on its path."""
    return StencilPlan(model, terms) if uses_numba(model) else DiagonalPlan(model, terms)


def _compiled():
    """:mod:`gym_gridloc._numba_kernels`, imported (with numba) on first use; None (with a
    warning, and :data:`AVAILABLE` set to False) if numba is installed but fails to import."""
    global _COMPILED, AVAILABLE
    if _COMPILED is None and AVAILABLE:
        try:
            from gym_gridloc import _numba_kernels
        except ImportError as exc:  # pragma: no cover - a broken numba install
            import warnings

            warnings.warn(f"numba failed to import ({exc}); the filter runs on numpy", RuntimeWarning, stacklevel=2)
            AVAILABLE = False
            return None
        _COMPILED = _numba_kernels
    return _COMPILED


def _dia_matvec_numpy(n_row, n_col, n_diags, length, offsets, data, x, y):
    """``y[i] += data[k, j] * x[j]`` for ``j = i + offsets[k]``: scipy's ``dia_matvec`` in numpy
    (used only if a scipy release drops that function)."""
    for k in range(n_diags):
        o = int(offsets[k])
        i0, j0 = max(0, -o), max(0, o)
        j1 = min(n_row + o, n_col, length)
        if j1 > j0:
            y[i0 : i0 + j1 - j0] += data[k, j0:j1] * x[j0:j1]


try:  # the loop behind scipy.sparse.dia_array @ x, called on our own buffers (no allocation)
    from scipy.sparse._sparsetools import dia_matvec as _dia_matvec
except ImportError:  # pragma: no cover - depends on the scipy release
    _dia_matvec = _dia_matvec_numpy


class DiagonalPlan:
    """One action's transition as diagonals of ``T^T`` (see the module docstring): ``writes``
    are ``(src, dst, weight)`` for the ``(0, 0)`` terms written first (one per destination
    layer), ``adds`` are ``(src, dst, offsets, weights)``, one diagonal each; ``zero`` are the
    layers no written term covers (cleared first)."""

    path = "numpy"

    def __init__(self, model, terms) -> None:
        h, w = model.shape
        self.hw = hw = h * w
        self.n_layers = model.n_layers
        writes, adds, covered = [], [], set()
        for t in terms:
            if t.dr == 0 and t.dc == 0 and t.dst not in covered:
                covered.add(t.dst)
                writes.append((t.src, t.dst, t.weight.reshape(hw)))
            else:  # one diagonal; the weights are the model's own (H, W) arrays, not copied
                adds.append((t.src, t.dst, np.array([-(t.dr * w + t.dc)], dtype=np.int32), t.weight.reshape(1, hw)))
        self.writes = tuple(writes)
        self.adds = tuple(adds)
        self.zero = tuple(layer for layer in range(self.n_layers) if layer not in covered)

    def predict(self, b: np.ndarray, out: np.ndarray) -> None:
        """``out = T^T b`` over flat (L*H*W,) float64 arrays (``out`` not ``b``)."""
        hw = self.hw
        for layer in self.zero:
            out[layer * hw : (layer + 1) * hw] = 0.0
        for src, dst, wt in self.writes:
            np.multiply(wt, b[src * hw : (src + 1) * hw], out=out[dst * hw : (dst + 1) * hw])
        for src, dst, offsets, rows in self.adds:
            _dia_matvec(hw, hw, len(offsets), hw, offsets, rows, b[src * hw : (src + 1) * hw], out[dst * hw : (dst + 1) * hw])

    @property
    def run_flat(self):
        """``(belief, out, lik) -> sum`` over flat arrays: predict, times ``lik``, unnormalised."""
        layers = (self.n_layers, self.hw)
        predict = self.predict

        def run(belief, out, lik):
            predict(belief, out)
            view = out.reshape(layers)
            np.multiply(view, lik, out=view)
            return float(np.add.reduce(out))

        return run

    def likelihood_form(self, lik: np.ndarray) -> np.ndarray:
        """What :attr:`run_flat` takes for a likelihood: the flat float64 array."""
        return np.ascontiguousarray(lik, dtype=np.float64).ravel()

    def run(self, belief: np.ndarray, out: np.ndarray, lik: np.ndarray | None, normalise: bool = True) -> float:
        """``out = T^T belief``; with ``lik``, times ``lik`` and (with ``normalise``) divided by the
        sum, which is returned (0.0 without ``lik``)."""
        b, o = belief.reshape(-1), out.reshape(-1)
        if lik is None:
            self.predict(b, o)
            return 0.0
        z = self.run_flat(b, o, self.likelihood_form(lik))
        if normalise and z > 0.0 and np.isfinite(z):
            o *= 1.0 / z
        return z


class StencilPlan:
    """The arrays a compiled kernel call needs for one action's terms (built once per model and
    action)."""

    path = "numba"

    def __init__(self, model, terms) -> None:
        h, w = model.shape
        hw = h * w
        self.hw = hw
        self.n_layers = model.n_layers
        weights = [t.weight for t in terms]
        # A copy as one (K, H*W) array: this path is for small models only.
        self.w = np.stack([wt.reshape(hw) for wt in weights]) if weights else np.zeros((0, hw))
        self.src = np.array([t.src for t in terms], dtype=np.int64)
        self.dst = np.array([t.dst for t in terms], dtype=np.int64)
        self.off = np.array([t.dr * w + t.dc for t in terms], dtype=np.int64)
        # Destination cells d (within a layer) whose source d - off lies in the layer.
        self.lo = np.maximum(self.off, 0)
        self.hi = np.minimum(hw + self.off, hw)
        # One int array for the kernel (fewer arguments: a numba call costs per argument).
        self.meta = np.ascontiguousarray(np.stack([self.src, self.dst, self.off, self.lo, self.hi]))
        self._kernel = _compiled().stencil_update

    @property
    def run_flat(self):
        """``(belief, out, lik) -> sum`` over flat arrays, unnormalised: the kernel with its
        plan bound (the fewest Python steps per call)."""
        w, meta, n_layers, kernel = self.w, self.meta, self.n_layers, self._kernel

        def run(belief, out, lik):
            return kernel(belief, w, meta, lik, out, n_layers, 2)

        return run

    def likelihood_form(self, lik: np.ndarray) -> np.ndarray:
        """What :attr:`run_flat` takes for a likelihood: the flat float64 array."""
        return np.ascontiguousarray(lik, dtype=np.float64).ravel()

    def run(self, belief: np.ndarray, out: np.ndarray, lik: np.ndarray | None, normalise: bool = True) -> float:
        """``out = T^T belief``; with ``lik``, times ``lik`` and (with ``normalise``) divided by the
        sum, which is returned (0.0 without ``lik``)."""
        mode = 0 if lik is None else 1 if normalise else 2
        lk = _EMPTY if lik is None else lik.ravel()
        return self._kernel(belief.reshape(-1), self.w, self.meta, lk, out.reshape(-1), self.n_layers, mode)


class BatchPlan:
    """Every action's stencil, padded to one shape, for :class:`gym_gridloc.BatchFilter`: one
    compiled call updates N beliefs (predict with each one's action, update, normalise).  Only
    for models on the numba path (:func:`uses_numba`)."""

    def __init__(self, model) -> None:
        plans = [model.stencil_plan(a) for a in range(model.n_actions)]
        if not all(isinstance(p, StencilPlan) for p in plans):
            raise ValueError(f"{model!r} is not filtered by the compiled kernels (see kernels.uses_numba)")
        k = max(p.w.shape[0] for p in plans)
        hw = plans[0].hw
        self.n_layers = model.n_layers
        self.w = np.zeros((len(plans), k, hw))
        self.meta = np.zeros((len(plans), 5, k), dtype=np.int64)
        self.meta[:, 1, :] = -1  # padding terms feed no layer
        for a, p in enumerate(plans):
            n = p.w.shape[0]
            self.w[a, :n] = p.w
            self.meta[a, :, :n] = p.meta
        self._kernel = _compiled().batch_update

    def run(self, beliefs: np.ndarray, actions: np.ndarray, lik: np.ndarray, out: np.ndarray, sel: np.ndarray) -> np.ndarray:
        z = np.empty(beliefs.shape[0])
        self._kernel(beliefs, self.w, self.meta, actions, lik, out, self.n_layers, sel, z)
        return z


_EMPTY = np.zeros(1)
