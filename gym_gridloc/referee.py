"""The referee: what an episode reports, and when it ends, from the exact posterior.

The step of N robots (:mod:`gym_gridloc.batch`: the single environment is its N = 1 view, the
native vector environment its N view) builds ``info``, the reward and the termination with these
functions, :func:`readout` (:func:`summarise`) and :func:`outcomes`, or has the compiled step fill
the same numbers in its call (:class:`Blocks`); :func:`scalars` gives one row as the single
environment reports it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gym_gridloc import kernels
from gym_gridloc.core.sensors import xlogx

#: The compiled readout sums the entropy of a position belief of at most this many cells itself
#: (numpy's pairwise summation); a longer one is summed by numpy: numpy 2.0 and older reduce a row
#: longer than their buffer (8192 values by default) buffer by buffer, numpy 2.4 in one piece, and
#: only numpy's own sum is the same number in every version.
COMPILED_ENTROPY_CELLS = 8192

#: The confidence at which the referee says the robot is localised, by default (the environments'
#: ``localise_threshold``, the planners' ``threshold``): :func:`localised`.
LOCALISE_THRESHOLD = 0.9

#: Reward kinds: ``"step"`` is -1 per step; ``"belief"`` is the referee's confidence (the largest
#: posterior probability it tests: the research protocol's reward).
REWARDS = ("step", "belief")


def entropy(p: np.ndarray) -> np.ndarray:
    """Entropy in bits along the last axis of probabilities ``p`` (``0 log 0 = 0``); the same
    sums for one row or N: a float64 array of ``p.shape[:-1]`` (a 0-d array for one row).  The one
    belief entropy: the environments' ``info``, the planners' entropy leaf (its terms are
    ``gym_gridloc.core.sensors.xlogx``, as the lookahead's expected entropies)."""
    return -np.add.reduce(xlogx(p), axis=-1) + 0.0  # + 0.0: no -0.0 for a sure belief


def confidences(beliefs: np.ndarray, *, pose: bool = False) -> np.ndarray:
    """What the referee tests in N hidden-state beliefs ``(N, L, H, W)``: the largest position
    probability (``pose=True``: the largest hidden-state probability), ``(N,)``."""
    n, L = beliefs.shape[:2]
    flat = beliefs.reshape(n, -1) if pose or L == 1 else beliefs.sum(axis=1).reshape(n, -1)
    return flat.max(axis=1)


def localised(beliefs: np.ndarray, threshold: float, *, pose: bool = False, slack: float = 0.0) -> np.ndarray:
    """The referee's test on N hidden-state beliefs ``(N, L, H, W)``: the confidence
    (:func:`confidences`) reaches ``threshold - slack``, ``(N,)`` booleans.  The environments end
    an episode on it; the planners stop planning on it."""
    return confidences(beliefs, pose=pose) >= threshold - slack


def summarise(beliefs: np.ndarray, states: np.ndarray, threshold: float, *, pose: bool = False) -> dict[str, np.ndarray]:
    """The referee's view of N exact hidden-state beliefs ``(N, L, H, W)`` and the true states
    ``(N, 3)`` (layer, row, col), as arrays with N rows.

    ``estimate`` is the most probable position (``pose=True``: the most probable hidden state,
    whose layer is ``estimate_layer``), ``confidence`` its probability; ``localised`` when that
    reaches ``threshold``; ``error`` the Manhattan distance from the estimate to the true position;
    ``success`` when localised on the truth (the true state, with ``pose``); ``entropy`` of the
    position belief in bits.
    """
    return readout(beliefs, states, threshold, pose=pose)[0]


def readout(beliefs: np.ndarray, states: np.ndarray, threshold: float, *, pose: bool = False) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`summarise` and the position beliefs ``(N, H*W)`` float64 it read (the layers summed
    in order, as ``beliefs.sum(axis=1)``; one layer: the beliefs themselves), for a caller that
    needs them too (the native vector env's observation): one pass over the beliefs, not two."""
    n, L, h, w = beliefs.shape
    fast = kernels.compiled(L * h * w) if beliefs.dtype.char == "d" and beliefs.flags.c_contiguous else None
    if fast is not None and n > 0:
        return _summarise_compiled(fast, beliefs, states, threshold, pose)
    flat = beliefs.reshape(n, -1)
    pflat = flat if L == 1 else beliefs.sum(axis=1).reshape(n, -1)
    tested = flat if pose else pflat
    k = tested.argmax(axis=1)
    confidence = tested[np.arange(n), k]
    cell = k % (h * w) if pose and L > 1 else k
    estimate = np.empty((n, 2), dtype=k.dtype)
    np.divmod(cell, w, out=(estimate[:, 0], estimate[:, 1]))
    truth = states[:, 1:3]
    error = np.abs(estimate - truth).sum(axis=1)
    localised = confidence >= threshold
    right = error == 0
    if pose:
        layer = k // (h * w)
        right &= layer == states[:, 0]
    info = {
        "position": truth.copy(),
        "estimate": estimate,
        "confidence": confidence,
        "error": error,
        "localised": localised,
        "success": localised & right,
        "entropy": entropy(pflat),
    }
    if L > 1:
        info["heading"] = states[:, 0].copy()
    if pose:
        info["estimate_heading"] = layer
    return info, pflat


def _summarise_compiled(fast, beliefs: np.ndarray, states: np.ndarray, threshold: float, pose: bool) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`summarise` on small float64 beliefs: one compiled pass for the readout, numpy's
    log2, one compiled pass for the entropies (of at most :data:`COMPILED_ENTROPY_CELLS` cells;
    numpy sums longer ones): the same numbers (``tests/test_readout.py``)."""
    n, L, h, w = beliefs.shape
    st = np.ascontiguousarray(states, dtype=np.int64)
    b = Blocks(n, h * w, threshold, pose)
    fast.batch_readout(beliefs.reshape(n, -1), L, b.pose, w, st, b.threshold, b.scratch, b.kept, b.ints, b.confidence,
                       b.estimate, b.flags, b.observed, b.support, b.spans)
    return b.infos(L)


class Blocks:
    """What the compiled step fills for the referee (``_numba_vector.vector_advance``), for N
    rows of beliefs of ``cells`` positions, with the rules it follows: the readout of
    :func:`readout` and how each step ends (:func:`outcomes`).  Rules: ``threshold`` and
    ``pose`` (as :func:`summarise`'s), ``kind`` (the reward, :data:`REWARDS`), ``limit`` (the step
    count that truncates; None: never), ``fixed_length`` (episodes end by truncation only).
    Blocks: ``scratch`` (2, N, cells) the position beliefs and the entropy's log2 arguments,
    ``kept`` the cells of those arguments, ``ints`` (5, N) the tested index, the estimated layer,
    the error, where each row's arguments end and the true layer, ``confidence``, ``estimate``
    (2, N, 2) the estimated and true positions, ``flags`` (2, N) localised and success,
    ``observed`` (float32 (N, cells) with ``observed``: the observation's position beliefs, as
    ``observation.observed_belief`` makes them; else no rows), ``rewards`` and ``ends`` (3, N)
    terminated, truncated and their or; ``support`` (N * ``states``) and ``spans`` (N) what the
    compiled step knows of each row's belief of ``states`` hidden states: its states with mass,
    ascending, at ``support[i * states:]``, and how many (``spans[i]`` >= 0), or -1 (unknown) or
    -2 (too many to filter sparsely: ``gym_gridloc._numba_sparse``); ``states`` 0 (the default:
    blocks for a readout only) leaves no room, and the step then never filters sparsely.
    :meth:`infos` and :meth:`outcomes` read them (copied
    for a caller that keeps them: a vector env's infos are its caller's).  Few allocations (blocks
    whose rows are the arrays); the compiled structure of the blocks is made once."""

    __slots__ = ("pose", "threshold", "limit", "fixed_length", "belief_reward", "scratch", "kept", "ints", "confidence",
                 "estimate", "flags", "observed", "rewards", "ends", "support", "spans", "_compiled", "_views")

    def __init__(self, n: int, cells: int, threshold: float, pose: bool, *, kind: str = "step", limit: int | None = None,
                 fixed_length: bool = False, observed: bool = False, states: int = 0) -> None:
        self.pose, self.threshold, self.limit = bool(pose), float(threshold), int(limit or 0)
        self.fixed_length, self.belief_reward = bool(fixed_length), kind == "belief"
        self.scratch, self.kept = np.empty((2, n, cells)), np.empty(n * cells, dtype=np.int64)
        self.ints, self.confidence = np.empty((5, n), dtype=np.int64), np.empty(n)
        self.estimate, self.flags = np.empty((2, n, 2), dtype=np.int64), np.empty((2, n), dtype=bool)
        self.observed = np.empty((n if observed else 0, cells), dtype=np.float32)
        self.rewards, self.ends = np.empty(n), np.empty((3, n), dtype=bool)
        self.support, self.spans = np.empty(n * states, dtype=np.int64), np.full(n, -1, dtype=np.int64)
        self._compiled = self._views = None

    @property
    def compiled(self):
        """The compiled structure of these blocks (``_numba_structs.BLOCKS``), made once."""
        if self._compiled is None:
            self._compiled = kernels.compiled(1).referee_blocks(
                self.pose, self.threshold, self.limit, self.fixed_length, self.belief_reward, self.scratch, self.kept,
                self.ints, self.confidence, self.estimate, self.flags, self.observed, self.rewards, self.ends, self.support,
                self.spans)
        return self._compiled

    def __getstate__(self) -> dict:
        return {k: getattr(self, k) for k in self.__slots__ if k not in ("_compiled", "_views")}

    def __setstate__(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)
        self._compiled = self._views = None

    def infos(self, n_layers: int, *, copy: bool = False) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """:func:`readout`'s infos and position beliefs from the filled blocks of beliefs of
        ``n_layers`` layers (the readout copied the true positions and headings): numpy's log2 (of
        the positive probabilities only: the others' terms are zeros), then the entropies.
        ``copy``: the infos are copies, the caller's to keep (the blocks are filled again)."""
        pos, q = self.scratch
        n, cells = pos.shape
        ints = self.ints.copy() if copy else self.ints
        _, layer, error, _, heading = ints
        ends = self.ints[3]
        if cells <= COMPILED_ENTROPY_CELLS:
            ent = np.empty(n)
            q = q.reshape(-1)[:ends[-1]]
            kernels.compiled(1).batch_entropy(pos, np.log2(q, out=q), self.kept, ends, ent)
        else:
            ent = entropy(pos)
        localised, success = self.flags.copy() if copy else self.flags
        estimate, position = self.estimate.copy() if copy else self.estimate
        confidence = self.confidence.copy() if copy else self.confidence
        info = {"position": position, "estimate": estimate, "confidence": confidence, "error": error,
                "localised": localised, "success": success, "entropy": ent}
        if n_layers > 1:
            info["heading"] = heading
        if self.pose:
            info["estimate_heading"] = layer
        return info, pos

    def outcomes(self, *, copy: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(rewards, terminated, truncated, done)`` of the filled blocks (``copy``: copies)."""
        ends = self.ends.copy() if copy else self.ends
        return self.rewards.copy() if copy else self.rewards, ends[0], ends[1], ends[2]

    def one(self, n_layers: int) -> dict[str, Any]:
        """:meth:`infos` of blocks of ONE row as the single environment reports them
        (:func:`scalars`: the same numbers), read from the blocks directly (no arrays of rows:
        the single environment pays this at every step)."""
        if self._views is None:  # (the blocks are filled again at every step: their views are kept)
            self._views = (self.scratch[0], self.scratch[1].reshape(-1), self.ints[3], np.empty(1))
        pos, q, ends, ent = self._views
        cells = pos.shape[1]
        if cells <= COMPILED_ENTROPY_CELLS:
            q = q[:ends.item(0)]
            kernels.compiled(1).batch_entropy(pos, np.log2(q, out=q), self.kept, ends, ent)
            h = ent.item(0)
        else:
            h = entropy(pos).item(0)
        ints, est, flags = self.ints, self.estimate, self.flags
        info = {"position": (est.item(1, 0, 0), est.item(1, 0, 1)), "estimate": (est.item(0, 0, 0), est.item(0, 0, 1)),
                "confidence": self.confidence.item(0), "error": ints.item(2, 0), "localised": flags.item(0, 0),
                "success": flags.item(1, 0), "entropy": h}
        if n_layers > 1:
            info["heading"] = ints.item(4, 0)
        if self.pose:
            info["estimate_heading"] = ints.item(1, 0)
        return info


def scalars(info: dict[str, np.ndarray], i: int) -> dict[str, Any]:
    """Row ``i`` of N environments' infos (:func:`summarise`) as the single environment reports
    it: tuples for positions, Python ``int``/``float``/``bool`` for the rest (the same numbers)."""
    est, pos = info["estimate"], info["position"]
    out = {
        "position": (pos.item(i, 0), pos.item(i, 1)),
        "estimate": (est.item(i, 0), est.item(i, 1)),
        "confidence": info["confidence"].item(i),
        "error": info["error"].item(i),
        "localised": info["localised"].item(i),
        "success": info["success"].item(i),
        "entropy": info["entropy"].item(i),
    }
    if "heading" in info:
        out["heading"] = info["heading"].item(i)
    if "estimate_heading" in info:
        out["estimate_heading"] = info["estimate_heading"].item(i)
    return out


def summary(belief: np.ndarray, state: np.ndarray, threshold: float, *, pose: bool = False) -> dict[str, Any]:
    """:func:`summarise` for one belief ``(L, H, W)`` and its true state ``(3,)``, as the single
    environment reports it (:func:`scalars`)."""
    b = np.ascontiguousarray(belief, dtype=np.float64)
    st = np.asarray(state, dtype=np.int64).reshape(1, 3)
    return scalars(summarise(b[None], st, threshold, pose=pose), 0)


_MASK_NAMES: dict[tuple, tuple[tuple[str, ...], np.ndarray]] = {}  # (info's keys, N) -> the mask keys, a block of ones


def masked(info: dict[str, np.ndarray], mask: np.ndarray | None) -> dict[str, np.ndarray]:
    """The infos of N environments as a Gymnasium vector env reports them: ``info`` (arrays of N
    rows) with a ``_key`` mask beside each key, ``mask`` (N booleans; None: all True), each its own
    array (the rows of one block)."""
    if (kept := _MASK_NAMES.get(keys := (tuple(info), info["confidence"].shape[0]))) is None:
        names = tuple(f"_{k}" for k in keys[0] if not k.startswith("_") and f"_{k}" not in info)
        kept = _MASK_NAMES[keys] = names, np.ones((len(names), keys[1]), dtype=bool)
    (out := dict(info)).update(zip(kept[0], kept[1].copy() if mask is None else np.repeat(mask[None], len(kept[0]), axis=0)))
    return out


def outcomes(kind: str, info: dict[str, np.ndarray], restarted: np.ndarray, elapsed: np.ndarray, limit: int | None,
             fixed_length: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How N steps end, from the referee's ``info`` (:func:`summarise`): ``(rewards, terminated,
    truncated, done)``.  ``restarted`` (N booleans): the environments that started an episode
    instead of stepping (reward 0.0, never terminated); ``elapsed`` (N,) int64 the episodes'
    step counts, advanced here (+1, or 0 where restarted); ``limit``: the count
    that truncates (None: never); ``fixed_length``: episodes end by truncation only.  The
    compiled step computes the same in its call (:class:`Blocks`)."""
    stepped = ~restarted
    elapsed += 1
    elapsed *= stepped  # +1, or 0 when restarted
    terminated = np.zeros(elapsed.shape[0], dtype=bool) if fixed_length else info["localised"] & stepped
    truncated = elapsed >= limit if limit else np.zeros(elapsed.shape[0], dtype=bool)
    return rewards(kind, info, stepped), terminated, truncated, terminated | truncated


def rewards(kind: str, info: dict[str, np.ndarray], stepped: np.ndarray | None = None) -> np.ndarray:
    """The reward of each of N steps: -1 (``"step"``), or the referee's confidence (``"belief"``);
    0.0 where ``stepped`` (N booleans, if given) is False (an environment that was reset)."""
    if kind == "belief":
        conf = info["confidence"].astype(np.float64)
        return conf if stepped is None else np.where(stepped, conf, 0.0)
    if stepped is None:
        return np.full(info["confidence"].shape[0], -1.0)
    return np.where(stepped, -1.0, 0.0)
