"""The referee: what an episode reports, and when it ends, from the exact posterior.

The single environment and the native vector environment build ``info``, the reward and the
termination with these functions, for a batch of N (the single environment's N is 1).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Reward kinds: ``"step"`` is -1 per step; ``"belief"`` is the referee's confidence (the largest
#: posterior probability it tests: the research protocol's reward).
REWARDS = ("step", "belief")


def summarise(beliefs: np.ndarray, states: np.ndarray, threshold: float, *, pose: bool = False) -> dict[str, np.ndarray]:
    """The referee's view of N exact hidden-state beliefs ``(N, L, H, W)`` and the true states
    ``(N, 3)`` (layer, row, col), as arrays with N rows.

    ``estimate`` is the most probable position (``pose=True``: the most probable hidden state,
    whose layer is ``estimate_layer``), ``confidence`` its probability; ``localised`` when that
    reaches ``threshold``; ``error`` the Manhattan distance from the estimate to the true position;
    ``success`` when localised on the truth (the true state, with ``pose``); ``entropy`` of the
    position belief in bits.
    """
    n, L, h, w = beliefs.shape
    flat = beliefs.reshape(n, -1)
    pflat = flat if L == 1 else beliefs.sum(axis=1).reshape(n, -1)
    tested = flat if pose else pflat
    k = tested.argmax(axis=1)
    confidence = tested[np.arange(n), k]
    layer, cell = np.divmod(k, h * w)
    estimate = np.empty((n, 2), dtype=k.dtype)
    np.divmod(cell, w, out=(estimate[:, 0], estimate[:, 1]))
    truth = states[:, 1:3]
    error = np.abs(estimate - truth).sum(axis=1)
    localised = confidence >= threshold
    right = error == 0
    if pose:
        right &= layer == states[:, 0]
    safe = pflat + (pflat <= 0.0)  # log2(1) = 0 where p = 0
    entropy = -np.einsum("ij,ij->i", pflat, np.log2(safe))
    info = {
        "position": truth.copy(),
        "estimate": estimate,
        "confidence": confidence,
        "error": error,
        "localised": localised,
        "success": localised & right,
        "entropy": np.maximum(entropy, 0.0),
    }
    if L > 1:
        info["heading"] = states[:, 0].copy()
    if pose:
        info["estimate_heading"] = layer
    return info


def single(info: dict[str, np.ndarray]) -> dict[str, Any]:
    """Row 0 of :func:`summarise`'s arrays as the single environment reports it: tuples for
    positions, Python ``int``/``float``/``bool`` for the rest."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        v = value[0].tolist()  # Python scalars (bool, int, float), or a list for a position
        out[key] = tuple(v) if isinstance(v, list) else v
    return out


def rewards(kind: str, info: dict[str, np.ndarray]) -> np.ndarray:
    """The reward of each of N steps: -1 (``"step"``), or the referee's confidence (``"belief"``)."""
    if kind == "belief":
        return info["confidence"].astype(np.float64)
    return np.full(info["confidence"].shape[0], -1.0)
