"""Filter kernels: how a transition (a tuple of stencil terms per action) is applied to flat beliefs.

Only :mod:`gym_gridloc.engine` uses this module; it builds one plan per model and caches it.  A
plan covers every action and, as one more action, their average (an unknown action).  Two paths
give the same numbers (within rounding; the tests compare both with a dense reference within 1e-12):

* **numba** (the optional ``fast`` extra), for models whose belief has fewer than
  :data:`NUMBA_MAX_CELLS` cells, where numpy's per-call overhead dominates: one compiled pass per
  step (predict, likelihood, sum) over cache-sized chunks (:mod:`gym_gridloc._numba_kernels`), for
  one belief or a batch.  numba is imported the first time such a model is filtered, never at
  import: it costs about 100 MiB of resident memory, so a process that only builds large grids
  never loads it.
* **numpy** (every larger model, and every model without numba or with ``GYM_GRIDLOC_NO_NUMBA=1``):
  for one belief, a stencil term ``(dr, dc)`` is one diagonal of ``T^T`` over the flat belief, at
  offset ``-(dr*W + dc)``, whose values are the term's own weight array (the cells where a shift
  wraps round a row edge have weight 0).  :func:`diagonal_add` adds ``w * x`` for each diagonal
  straight into the output buffer (the loop of scipy's DIA matrix-vector product, in numpy, chunk
  by chunk so that the products are added while in cache), reading the model's weights in place
  (no copy); a ``(0, 0)`` term is written first with one multiply.  For a batch, each distinct
  shift is one multiply-add over all N beliefs, with the N actions' weights gathered (or shared).
* **fused** (larger models with :data:`NUMBA_LARGE`, ``GYM_GRIDLOC_NUMBA=all``): the numpy plan
  whose one-belief step is one compiled pass (:mod:`gym_gridloc._numba_filter`: each cell's terms
  in the numpy plan's order, times the likelihood, written once; the sum in numpy's pairwise
  order): the numpy plan's numbers, bit for bit, with a single pass over the belief and no
  temporaries.  It loads numba for a large model (about 110 MiB resident), so it is asked for.

Flat arrays: a belief is ``L*H*W`` float64 (layer-major), a likelihood ``H*W`` (position sensors)
or ``L*H*W`` (``layered``: a reading that depends on the layer, e.g. a heading).  ``mode`` 0 only
predicts; 1 multiplies by the likelihood and normalises; 2 multiplies and leaves the sum unapplied.
Every ``run`` returns the sums (1.0 where nothing was summed).
"""

from __future__ import annotations

import functools
import importlib.util
import os
import threading
from typing import Any

import numpy as np

#: numba is installed and not switched off by ``GYM_GRIDLOC_NO_NUMBA`` (it is not imported here).
AVAILABLE = (
    os.environ.get("GYM_GRIDLOC_NO_NUMBA", "") not in ("1", "true", "yes")
    and importlib.util.find_spec("numba") is not None
)
#: Models whose belief (layers x rows x columns) has fewer cells use the numba kernels.
NUMBA_MAX_CELLS = 128 * 128
#: Elements per chunk of :func:`diagonal_add` (128 KiB of products, added while in cache).
DIAGONAL_CHUNK = 16384
#: The fused plan reads the weights of each layer's first term as one-byte codes of at most 8 values
#: (a select among them) when the actions' arrays of such weights exceed this many bytes: they no
#: longer stay in cache from one step to the next, and the codes take an eighth of the memory.
CODED_BYTES = 4 * 2**20
#: Models with :data:`NUMBA_MAX_CELLS` cells or more step one belief with the fused compiled pass
#: (:class:`FusedPlan`) when numba is available: ``GYM_GRIDLOC_NUMBA=all``.
NUMBA_LARGE = os.environ.get("GYM_GRIDLOC_NUMBA", "") == "all"

_COMPILED = None


def uses_numba(n_cells: int) -> bool:
    """Whether a belief of ``n_cells`` (L*H*W) is filtered by the compiled kernels.  When it is
    small enough, this imports numba (once)."""
    return AVAILABLE and n_cells < NUMBA_MAX_CELLS and _compiled() is not None


def compiled(n_cells: int):
    """:mod:`gym_gridloc._numba_kernels` when a belief of ``n_cells`` (L*H*W) is small enough for
    the compiled kernels (:func:`uses_numba`), else None.  Besides the filter's plan, the referee's
    and the observation's readout of one belief use them (the same numbers as their numpy code)."""
    return _COMPILED if _COMPILED is not None and AVAILABLE and n_cells < NUMBA_MAX_CELLS else (
        _compiled() if uses_numba(n_cells) else None)


def bit_functions(bit_generator: np.random.BitGenerator) -> np.ndarray:
    """The addresses the compiled kernels draw from ``bit_generator`` with (its C interface:
    ``next_uint32``, ``next_double``, its state), as a ``uint64`` array of 3 (the caller holds
    the bit generator's lock while drawing).  Made once per bit generator: the last 64 are kept,
    each with the ``ctypes`` interface it was read from (a bit generator makes that once, so a
    new one at the same ``id`` is told apart)."""
    c = bit_generator.ctypes
    known = _BIT_FUNCTIONS.get(id(bit_generator))
    if known is None or known[0] is not c:
        import ctypes

        addresses = np.array([ctypes.cast(c.next_uint32, ctypes.c_void_p).value, ctypes.cast(c.next_double, ctypes.c_void_p).value,
                              c.state_address], dtype=np.uint64)
        addresses.flags.writeable = False
        if len(_BIT_FUNCTIONS) >= 64:
            _BIT_FUNCTIONS.clear()
        known = _BIT_FUNCTIONS[id(bit_generator)] = (c, addresses)
    return known[1]


_BIT_FUNCTIONS: dict[int, tuple[Any, np.ndarray]] = {}


def make_plan(transitions, n_layers: int, shape: tuple[int, int]):
    """The plan for ``transitions`` (one tuple of terms per action, the unknown action last)."""
    if uses_numba(n_layers * shape[0] * shape[1]):
        return NumbaPlan(transitions, n_layers, shape)
    fused = NUMBA_LARGE and AVAILABLE and _compiled() is not None and _sums_in_one_piece()
    return (FusedPlan if fused else NumpyPlan)(transitions, n_layers, shape)


@functools.cache
def _sums_in_one_piece() -> bool:
    """Whether numpy sums a long array in one pairwise piece, as :class:`FusedPlan` does (numpy 2.4
    does; numpy 2.0 and older sum it buffer by buffer, and then the fused plan is not used):
    numpy 2.4 or newer, and the same sums on a few long arrays."""
    if np.lib.NumpyVersion(np.__version__) < "2.4.0":
        return False
    rng = np.random.default_rng(0)
    for n in (17161, 3 * 8192 + 77, 65537):  # (one length can agree by chance)
        x = rng.random(n) ** 3
        if _compiled().pairwise_sum(x, *_compiled().pairwise_program(x.size)) != np.add.reduce(x):
            return False
    return True


def weigh(out, liks, layered: int, n_layers: int, mode: int) -> np.ndarray:
    """Multiply N predicted flat beliefs ``out`` ``(N, L*H*W)`` by their likelihoods ``liks``, in
    place (mode 1: and normalise each whose sum is positive and finite, times ``1 / z`` as every
    kernel normalises); returns the sums."""
    view = out if layered else out.reshape(out.shape[0], n_layers, -1)
    view *= liks if layered else liks[:, None, :]
    z = out.sum(axis=1)
    if mode == 1:
        out *= (1.0 / np.where((z > 0.0) & np.isfinite(z), z, 1.0))[:, None]
    return z


def padded(transitions, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Every action's terms padded to ``K`` (a padding term has zero weight and every key -1):
    weights ``(A, K, H*W)`` (a copy) and keys ``(A, 5, K)``: source layer, destination layer,
    row shift, column shift, flat offset."""
    h, w = shape
    weights = np.zeros((len(transitions), max(1, max(len(terms) for terms in transitions)), h * w))
    keys = np.full((len(transitions), 5, weights.shape[1]), -1, dtype=np.int64)
    for a, terms in enumerate(transitions):
        for i, t in enumerate(terms):
            weights[a, i] = t.weight.reshape(-1)
            keys[a, :, i] = (t.src, t.dst, t.dr, t.dc, t.dr * w + t.dc)
    return weights, keys


def _compiled():
    """:mod:`gym_gridloc._numba_kernels`, imported (with numba) on first use; None (with a
    warning, and :data:`AVAILABLE` set to False) if numba is installed but fails to import."""
    global _COMPILED, AVAILABLE
    if _COMPILED is None and AVAILABLE:
        try:
            from gym_gridloc import _numba_kernels as _COMPILED  # binds the global
        except ImportError as exc:  # pragma: no cover - a broken numba install
            import warnings

            warnings.warn(f"numba failed to import ({exc}); the filter runs on numpy", RuntimeWarning, stacklevel=2)
            AVAILABLE = False
    return _COMPILED


def diagonal_add(w, x, y, offset: int, tmp) -> None:
    """``y[i] += w[j] * x[j]`` for ``j = i + offset``: one diagonal of ``T^T`` added to ``y``
    (the loop of scipy's DIA matrix-vector product, in public numpy: the same products and sums
    in the same order), chunk by chunk through the buffer ``tmp``, so that each chunk's products
    are still in cache when they are added."""
    i0, j0 = max(0, -offset), max(0, offset)
    n = min(y.shape[0] + offset, x.shape[0]) - j0
    c = tmp.shape[0]
    for s in range(0, n, c):
        m = min(c, n - s)
        t = np.multiply(w[j0 + s : j0 + s + m], x[j0 + s : j0 + s + m], out=tmp[:m])
        ys = y[i0 + s : i0 + s + m]
        np.add(ys, t, out=ys)


class NumbaPlan:
    """Every action's terms padded to one ``(A, K, H*W)`` weight array ``w`` and ``(A, 5, K)``
    table ``meta`` of (source layer, destination layer, flat offset, first and end destination
    cell): one compiled call steps one belief or N beliefs, each with its own action."""

    path = "numba"

    def __init__(self, transitions, n_layers: int, shape: tuple[int, int]) -> None:
        hw = shape[0] * shape[1]
        self.n_layers = n_layers
        self.w, keys = padded(transitions, shape)  # a copy: this path is for small models only
        #: The sampler's keys (source layer, destination layer, row shift, column shift) ``(A, 4, K)``
        #: beside ``w``: the engine draws moves from these same tables.
        self.keys = np.ascontiguousarray(keys[:, :4])
        off = keys[:, 4]  # padding terms feed no layer (destination -1)
        self.meta = np.stack((keys[:, 0], keys[:, 1], off, np.maximum(off, 0), np.minimum(hw + off, hw)), axis=1)
        kernels = _compiled()
        self.batch = kernels.batch_update
        one, n = kernels.stencil_update, n_layers
        per_action = [(self.w[a].reshape(-1), self.meta[a].reshape(-1)) for a in range(len(transitions))]  # (flat views)

        def run_one(belief, action: int, lik, layered: int, out, mode: int) -> float:
            """One belief (flat, or C-contiguous (L, H, W)) with one action (see the module docstring)."""
            w, meta = per_action[action]
            return one(belief, w, meta, lik, layered, out, n, mode)

        self.run_one = run_one

    def run(self, beliefs, actions, liks, layered: int, out, mode: int, sel) -> np.ndarray:
        """N flat beliefs ``(N, L*H*W)`` with N actions; rows where ``sel`` is False untouched."""
        z = np.empty(beliefs.shape[0])
        self.batch(beliefs, self.w, self.meta, actions, np.ascontiguousarray(liks), layered, out, self.n_layers, mode, sel, z)
        return z


class NumpyPlan:
    """Diagonals of ``T^T`` for one belief; shared shifts with gathered weights for a batch."""

    path = "numpy"

    def __init__(self, transitions, n_layers: int, shape: tuple[int, int]) -> None:
        h, w = shape
        self.hw = h * w
        self.n_layers = n_layers
        self.single = [self._diagonals(terms, w) for terms in transitions]
        self._transitions = transitions
        self._width = w
        self._local = threading.local()  # diagonal_add's buffer, one per thread (numpy drops the GIL)

    def _diagonals(self, terms, width: int):
        """``(zero, writes, adds)``: layers to clear, ``(src, dst, weight)`` of the ``(0, 0)``
        terms written first (one per destination layer), ``(src, dst, offsets, weights)`` of the
        other terms, one diagonal each (the model's own weight arrays, not copied)."""
        hw = self.hw
        writes, adds, covered = [], [], set()
        for t in terms:
            if t.dr == 0 and t.dc == 0 and t.dst not in covered:
                covered.add(t.dst)
                writes.append((t.src, t.dst, t.weight.reshape(hw)))
            else:
                adds.append((t.src, t.dst, -(t.dr * width + t.dc), t.weight.reshape(hw)))
        zero = tuple(layer for layer in range(self.n_layers) if layer not in covered)
        return zero, tuple(writes), tuple(adds)

    def predict_one(self, b, action: int, out) -> None:
        hw = self.hw
        zero, writes, adds = self.single[action]
        tmp = getattr(self._local, "tmp", None)
        if tmp is None:
            tmp = self._local.tmp = np.empty(min(hw, DIAGONAL_CHUNK))
        for layer in zero:
            out[layer * hw : (layer + 1) * hw] = 0.0
        for src, dst, wt in writes:
            np.multiply(wt, b[src * hw : (src + 1) * hw], out=out[dst * hw : (dst + 1) * hw])
        for src, dst, offset, wt in adds:
            diagonal_add(wt, b[src * hw : (src + 1) * hw], out[dst * hw : (dst + 1) * hw], offset, tmp)

    def run_one(self, belief, action: int, lik, layered: int, out, mode: int) -> float:
        """One belief (flat, or C-contiguous (L, H, W)) with one action (see the module docstring)."""
        belief, out = belief.reshape(-1), out.reshape(-1)
        self.predict_one(belief, action, out)
        if mode == 0:
            return 1.0
        view = out if layered else out.reshape(self.n_layers, self.hw)
        np.multiply(view, lik, out=view)
        z = float(np.add.reduce(out))
        if mode == 1 and z > 0.0 and np.isfinite(z):
            out *= 1.0 / z
        return z

    @functools.cached_property
    def _batch_plan(self):
        """Built on first batched use: one entry per distinct flat shift over all actions: ``(first, src_lo, dst_lo, n,
        weights)`` with ``weights`` an (A, n) stack of the actions' weight slices, or (1, n) when
        every action has the same weight; "first" entries write their destination layer."""
        hw, width = self.hw, self._width
        entries: dict[tuple[int, int, int], list] = {}
        firsts: dict[tuple[int, int, int], bool] = {}
        for a, terms in enumerate(self._transitions):
            covered: set[int] = set()
            for t in terms:
                off = t.dr * width + t.dc
                s0, d0 = (0, off) if off >= 0 else (-off, 0)
                n = hw - abs(off)
                key = (t.src * hw + s0, t.dst * hw + d0, n)
                first = off == 0 and t.dst not in covered
                if off == 0:
                    covered.add(t.dst)
                rows = entries.setdefault(key, [None] * len(self._transitions))
                rows[a] = t.weight.reshape(-1)[s0 : s0 + n]
                firsts[key] = firsts.get(key, True) and first
        covered = set()
        first_keys = []
        for key in entries:
            if firsts[key] and key[1] // hw not in covered and all(r is not None for r in entries[key]):
                covered.add(key[1] // hw)
                first_keys.append(key)
        zero = tuple(layer for layer in range(self.n_layers) if layer not in covered)
        plan = []
        for key in first_keys + [key for key in entries if key not in first_keys]:
            n = key[2]
            rows = [np.zeros(n) if r is None else r for r in entries[key]]
            same = all(r is rows[0] or np.array_equal(r, rows[0]) for r in rows[1:])
            plan.append((key in first_keys, key[0], key[1], n, rows[0].reshape(1, n) if same else np.stack(rows)))
        return zero, tuple(plan)

    def run(self, beliefs, actions, liks, layered: int, out, mode: int, sel) -> np.ndarray:
        """N flat beliefs ``(N, L*H*W)`` with N actions (all N computed; rows where ``sel`` is
        False are written back unchanged)."""
        zero, plan = self._batch_plan
        hw, n_rows = self.hw, beliefs.shape[0]
        keep = None if sel.all() else out[~sel].copy()
        for layer in zero:
            out[:, layer * hw : (layer + 1) * hw] = 0.0
        for first, s0, d0, n, weights in plan:
            wv = weights if weights.shape[0] == 1 else weights[actions]
            src, dst = beliefs[:, s0 : s0 + n], out[:, d0 : d0 + n]
            if first:
                np.multiply(wv, src, out=dst)
            else:
                dst += wv * src
        z = weigh(out, liks, layered, self.n_layers, mode) if mode > 0 else np.ones(n_rows)
        if keep is not None:
            out[~sel] = keep
            z[~sel] = 1.0
        return z


class FusedPlan(NumpyPlan):
    """The numpy plan, whose one-belief step (``run_one``) is one compiled pass with the same numbers
    (:mod:`gym_gridloc._numba_filter`); batches are the numpy plan's.  Each action's terms of each
    destination layer in the numpy plan's order: the first (the written ``(0, 0)`` term, or the
    first added) and those whose nonzero weights vary read their weight arrays (copied into one
    array, each once), the others (one value where not zero: a move's weight on a grid) a bit of
    a byte per destination cell (up to 7 such patterns of cells).  Beyond :data:`CODED_BYTES`, a
    first term of at most 8 values (a blocked move's stay on a grid) reads a byte per cell too."""

    path = "fused"

    def __init__(self, transitions, n_layers: int, shape: tuple[int, int]) -> None:
        super().__init__(transitions, n_layers, shape)
        hw, fast = self.hw, _compiled()
        masks: dict[bytes, int] = {}
        columns: dict[int, tuple[int, np.ndarray]] = {}  # the weights' address -> (column, weights)
        terms, vals = [], []
        self.spans = np.zeros((len(transitions), n_layers, 6), dtype=np.int64)
        codes, tables = [np.zeros(hw, dtype=np.uint8)], [np.zeros(8)]
        for a, (_, writes, adds) in enumerate(self.single):
            layers: list[list] = [[] for _ in range(n_layers)]
            for src, dst, wt in writes:
                layers[dst].append((src, 0, wt))
            for src, dst, offset, wt in adds:
                layers[dst].append((src, -offset, wt))
            for layer, group in enumerate(layers):
                first = len(terms)
                for i, (src, s, wt) in enumerate(group):
                    lo, hi = max(0, -s), min(hw, hw - s)  # the sources inside the layer
                    used = wt[lo:hi]
                    nonzero = used[used != 0.0]
                    bit = -1
                    if i > 0 and (nonzero.size == 0 or np.all(nonzero == nonzero[0])):
                        cells = np.zeros(hw, dtype=bool)
                        cells[lo + s : hi + s] = used != 0.0
                        key = cells.tobytes()
                        if key in masks or len(masks) < 7:
                            bit = masks.setdefault(key, len(masks))
                    column = -1 if bit >= 0 else columns.setdefault(wt.ctypes.data, (len(columns), wt))[0]
                    terms.append((src, s, column, bit))
                    vals.append(float(nonzero[0]) if bit >= 0 and nonzero.size else 0.0)
                    if i == 0:  # its weights by destination cell
                        first_weights = np.zeros(hw)
                        first_weights[lo + s : hi + s] = used
                shifts = [s for _, s, _ in group] + [0]
                bits_only = all(t[3] >= 0 for t in terms[first + 1 :])
                self.spans[a, layer, :5] = (first, len(terms), max(shifts), hw + min(shifts), 0 < len(group) <= 5 and bits_only)
                lo, hi = self.spans[a, layer, 2:4]
                coded = self.spans[a, layer, 4] and hi > lo and hw * 8 * len(transitions) * n_layers > CODED_BYTES
                values = np.unique(first_weights[lo:hi]) if coded else np.zeros(9)
                if values.size <= 8:  # the first term's weights as codes of at most 8 values
                    code = np.zeros(hw, dtype=np.uint8)
                    code[lo:hi] = np.searchsorted(values, first_weights[lo:hi])
                    self.spans[a, layer, 4:] = (2, len(codes))
                    codes.append(code)
                    tables.append(np.concatenate([values, np.zeros(8 - values.size)]))
        self.terms = np.array(terms, dtype=np.int64).reshape(-1, 4)
        self.vals = np.array(vals)
        self.codes, self.tables = np.concatenate(codes), np.concatenate(tables)
        self.bits = np.zeros(hw, dtype=np.uint8)
        for cells, bit in masks.items():
            self.bits |= np.frombuffer(cells, dtype=bool).astype(np.uint8) << bit
        self.wcols = np.concatenate([wt for _, wt in sorted(columns.values(), key=lambda c: c[0])] or [np.zeros(0)])
        self.bounds, self.ops = fast.pairwise_program(n_layers * hw)
        step, spans = fast.fused_step, list(self.spans)
        model = (n_layers, hw, self.bits, self.wcols, self.vals, self.codes, self.tables, self.terms, self.bounds, self.ops)

        def run_one(belief, action: int, lik, layered: int, out, mode: int) -> float:
            """One belief (flat, or C-contiguous (L, H, W)) with one action (see the module docstring)."""
            return step(belief, out, lik, layered, mode, spans[action], *model)

        self.run_one = run_one
