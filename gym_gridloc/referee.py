"""The referee: what an episode reports, and when it ends, from the exact posterior.

The single environment and the native vector environment build ``info``, the reward and the
termination with these functions: :func:`summarise` for a batch of N, :func:`summary` for one
belief (the same numbers, on scalars; a test holds them equal).
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
    blocks = readout_blocks(n, h * w, threshold, pose)
    fast.batch_readout(beliefs.reshape(n, -1), L, blocks[0], w, st, *blocks[1:])
    return read_blocks(blocks, L)


def readout_blocks(n: int, cells: int, threshold: float, pose: bool, *, observed: bool = False) -> tuple:
    """What the compiled readout of N beliefs of ``cells`` positions fills, with its two
    parameters: ``(pose, threshold, scratch, kept, ints, confidence, estimate, flags, observed)``
    (``_numba_readout.batch_readout``'s, or the engine's vector step's with them); then
    :func:`read_blocks` gives the infos.  ``observed``: the readout also writes the observed
    position beliefs (float32 (N, cells), as ``observation.observed_belief`` makes them) in the
    last block (else it has no rows).  Few allocations: blocks whose rows are the arrays (a
    vector env pays them at every step)."""
    return (bool(pose), float(threshold), np.empty((2, n, cells)), np.empty(n * cells, dtype=np.int64),
            np.empty((5, n), dtype=np.int64), np.empty(n),
            np.empty((2, n, 2), dtype=np.int64), np.empty((2, n), dtype=bool),
            np.empty((n if observed else 0, cells), dtype=np.float32))


def read_blocks(blocks: tuple, n_layers: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`readout`'s infos and position beliefs from the filled :func:`readout_blocks` of
    beliefs of ``n_layers`` layers (the readout copied the true positions and headings): numpy's
    log2 (of the positive probabilities only: the others' terms are zeros), then the entropies."""
    pose, _, scratch, kept, ints, confidence, estimates, flags, _ = blocks
    pos, q = scratch
    n, cells = pos.shape
    _, layer, error, ends, heading = ints
    if cells <= COMPILED_ENTROPY_CELLS:
        ent = np.empty(n)
        q = q.reshape(-1)[:ends[-1]]
        kernels.compiled(1).batch_entropy(pos, np.log2(q, out=q), kept, ends, ent)
    else:
        ent = entropy(pos)
    localised, success = flags
    estimate, position = estimates
    info = {"position": position, "estimate": estimate, "confidence": confidence, "error": error,
            "localised": localised, "success": success, "entropy": ent}
    if n_layers > 1:
        info["heading"] = heading
    if pose:
        info["estimate_heading"] = layer
    return info, pos


def summary(belief: np.ndarray, state: np.ndarray, threshold: float, *, pose: bool = False) -> dict[str, Any]:
    """:func:`summarise` for one belief ``(L, H, W)`` and its true state ``(3,)``, as the single
    environment reports it: tuples for positions, Python ``int``/``float``/``bool`` for the rest.
    The same numbers as row 0 of :func:`summarise` (a test holds them equal), computed on scalars:
    the single environment pays this on every step."""
    L, h, w = belief.shape
    hw = h * w
    flat = belief.reshape(-1)
    fast = kernels.compiled(flat.size) if flat.dtype.char == "d" and flat.flags.c_contiguous else None
    if fast is not None:  # small beliefs: one compiled pass, numpy's log2 (the same numbers)
        q = np.empty(hw)
        pos = flat if L == 1 else np.empty(hw)  # (one layer: the kernel writes the same values back)
        k = fast.readout(flat, L, pose, pos, q)
        confidence = flat.item(k) if pose else pos.item(k)
        ent = fast.entropy_sum(pos, np.log2(q, out=q)) if hw <= COMPILED_ENTROPY_CELLS else float(entropy(pos))
    else:
        pos = flat if L == 1 else belief.sum(axis=0).reshape(-1)
        tested = flat if pose else pos
        k = int(tested.argmax())
        confidence = float(tested[k])
        ent = float(entropy(pos))
    layer, cell = divmod(k, hw)
    estimate = divmod(cell, w)
    truth_layer, row, col = state.tolist() if isinstance(state, np.ndarray) else state
    if not (type(truth_layer) is int and type(row) is int and type(col) is int):
        truth_layer, row, col = int(truth_layer), int(row), int(col)
    error = abs(estimate[0] - row) + abs(estimate[1] - col)
    localised = confidence >= threshold
    right = error == 0 and (not pose or layer == truth_layer)
    info = {
        "position": (row, col),
        "estimate": estimate,
        "confidence": confidence,
        "error": error,
        "localised": localised,
        "success": localised and right,
        "entropy": ent,
    }
    if L > 1:
        info["heading"] = truth_layer
    if pose:
        info["estimate_heading"] = layer
    return info


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


def ending_blocks(kind: str, restarted: np.ndarray, elapsed: np.ndarray, limit: int | None, fixed_length: bool) -> tuple:
    """:func:`outcomes`'s arguments and outputs as a compiled step takes them (the engine's vector
    step computes them beside its readout): ``(restarted, elapsed, limit, fixed_length,
    belief_reward, rewards, flags)``; :func:`ended` gives ``(rewards, terminated, truncated,
    done)`` from them."""
    n = elapsed.shape[0]
    return restarted, elapsed, int(limit or 0), bool(fixed_length), kind == "belief", np.empty(n), np.empty((3, n), dtype=bool)


def ended(blocks: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(rewards, terminated, truncated, done)`` of filled :func:`ending_blocks`."""
    rewards_, flags = blocks[5], blocks[6]
    return rewards_, flags[0], flags[1], flags[2]


def outcomes(kind: str, info: dict[str, np.ndarray], restarted: np.ndarray, elapsed: np.ndarray, limit: int | None,
             fixed_length: bool, *, cells: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How N steps end, from the referee's ``info`` (:func:`summarise`): ``(rewards, terminated,
    truncated, done)``.  ``restarted`` (N booleans): the environments that started an episode
    instead of stepping (reward 0.0, never terminated); ``elapsed`` (N,) int64 the episodes'
    step counts, advanced here (+1, or 0 where restarted); ``limit``: the count
    that truncates (None: never); ``fixed_length``: episodes end by truncation only.  ``cells``:
    the size of a belief (L*H*W), which decides, as for :func:`summarise`, whether one compiled
    pass does it (the same numbers)."""
    fast = None if cells is None else kernels.compiled(cells)
    if fast is not None:
        blocks = ending_blocks(kind, restarted, elapsed, limit, fixed_length)
        fast.batch_outcomes(info["localised"], info["confidence"], *blocks)
        return ended(blocks)
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
