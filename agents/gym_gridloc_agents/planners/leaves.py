"""Leaf estimates of the steps still needed (for beliefs that are not localised), episodes on
the belief MDP, and fitting an entropy leaf to them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc.referee import LOCALISE_THRESHOLD
from gym_gridloc_agents.planners.ops import BeliefOps, initial_beliefs, predict_batch

#: Where the fitted leaves shipped with the package live (``<env_id>-entropy.json``).
LEAF_DIR = Path(__file__).resolve().parent / "fitted_leaves"


class Leaf:
    """``leaf(ops, beliefs (N, L, H, W)) -> (N,)`` estimated steps still needed."""

    kind = "leaf"

    def __call__(self, ops: BeliefOps, beliefs: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def to_dict(self) -> dict:
        raise NotImplementedError

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict()))


class ConstantLeaf(Leaf):
    """A constant (``1.0``: a non-localised belief needs at least one more step; a lower bound)."""

    kind = "constant"

    def __init__(self, value: float = 1.0) -> None:
        self.value = float(value)

    def __call__(self, ops, beliefs):
        return np.full(beliefs.shape[0], self.value)

    def to_dict(self):
        return {"kind": self.kind, "value": self.value}


class EntropyLeaf(Leaf):
    """A non-decreasing piecewise-linear function of the position entropy (bits), fitted as binned
    means of a base policy's remaining steps (pool-adjacent-violators for monotonicity)."""

    kind = "entropy"

    def __init__(self, knots_x: Sequence[float], knots_y: Sequence[float]) -> None:
        self.x = np.asarray(knots_x, dtype=np.float64)
        self.y = np.asarray(knots_y, dtype=np.float64)

    def __call__(self, ops, beliefs):
        return np.interp(ops.entropy(beliefs), self.x, self.y)

    def to_dict(self):
        return {"kind": self.kind, "x": self.x.tolist(), "y": self.y.tolist()}

    @classmethod
    def fit(cls, entropies: np.ndarray, targets: np.ndarray, n_bins: int = 40) -> "EntropyLeaf":
        order = np.argsort(entropies)
        e, t = entropies[order], targets[order]
        chunks = np.array_split(np.arange(len(e)), min(n_bins, max(1, len(e) // 20)))
        xs = np.array([e[c].mean() for c in chunks])
        ys = np.array([t[c].mean() for c in chunks])
        ws = np.array([len(c) for c in chunks], dtype=np.float64)
        # pool adjacent violators: non-decreasing y
        vals, wts, xs_out = [], [], []
        for x, y, w in zip(xs, ys, ws):
            vals.append(y); wts.append(w); xs_out.append([x])
            while len(vals) > 1 and vals[-2] > vals[-1]:
                y2, w2, x2 = vals.pop(), wts.pop(), xs_out.pop()
                vals[-1] = (vals[-1] * wts[-1] + y2 * w2) / (wts[-1] + w2)
                wts[-1] += w2
                xs_out[-1] += x2
        return cls(np.array([np.mean(v) for v in xs_out]), np.array(vals))


def load_leaf(spec: Any, env_id: str | None = None) -> Leaf:
    """A leaf from a :class:`Leaf`, a number (constant), ``"one"``/``"zero"``, ``"shipped"`` (the
    entropy leaf fitted for ``env_id``, :data:`LEAF_DIR`; ``"one"`` where none is shipped), a
    dict or a JSON path."""
    if isinstance(spec, Leaf):
        return spec
    if spec == "shipped":
        path = LEAF_DIR / f"{env_id}-entropy.json"
        spec = path if env_id is not None and path.is_file() else "one"
    if spec is None or spec == "one":
        return ConstantLeaf(1.0)
    if spec == "zero":
        return ConstantLeaf(0.0)
    if isinstance(spec, (int, float)):
        return ConstantLeaf(float(spec))
    if isinstance(spec, (str, Path)):
        spec = json.loads(Path(spec).read_text())
    if isinstance(spec, dict):
        kind = spec["kind"]
        if kind == "constant":
            return ConstantLeaf(spec["value"])
        if kind == "entropy":
            return EntropyLeaf(spec["x"], spec["y"])
    raise ValueError(f"unknown leaf {spec!r}: a Leaf, a number, 'one', 'zero', 'shipped', a dict or a JSON file")


def belief_rollouts(model, policy, episodes: int, *, seed: int = 1_000_000, max_steps: int = 100,
                    threshold: float = LOCALISE_THRESHOLD, pose: bool = False, record: bool = True) -> dict:
    """Episodes of ``policy`` simulated on the belief MDP itself: the first reading and every later
    one drawn from the exact predictive distribution of the current belief (the same law as the
    environment's readings seen through its filter), each ended by the referee's test
    (``threshold``; on the pose with ``pose``, the environment's ``referee_pose``).  Returns the
    steps of each episode and, with ``record``, every belief at which the policy acted with the
    steps it still took (a truncated episode counts ``max_steps``).  Episode ``i`` seeds the policy
    and the reading draws with ``seed + i``."""
    ops = BeliefOps(model, threshold, pose=pose)
    b0, p0 = initial_beliefs(ops)
    steps = np.zeros(episodes, dtype=np.int64)
    beliefs, remaining = [], []
    for i in range(episodes):
        rng = np.random.default_rng(seed + i)
        policy.reset(seed=seed + i)
        b = b0[int(rng.choice(len(p0), p=p0))]
        seen = []
        while True:
            seen.append(b)
            a = policy.act(None, b)
            pred = predict_batch(model, b[None], np.array([a]))[0]
            pz = ops.reading_probs(pred[None])[0]
            z = int(rng.choice(len(pz), p=pz / pz.sum()))
            b = ops.update(pred, z)
            if ops.localised(b[None])[0] or len(seen) >= max_steps:
                break
        steps[i] = len(seen)
        if record:
            beliefs.extend(seen)
            remaining.extend(len(seen) - np.arange(len(seen)))
    out = {"steps": steps}
    if record:
        out["beliefs"] = np.array(beliefs)
        out["remaining"] = np.array(remaining, dtype=np.float64)
    return out


def fit_leaf(model, beliefs: np.ndarray, remaining: np.ndarray, *, threshold: float = LOCALISE_THRESHOLD, **kw) -> EntropyLeaf:
    """Fit an entropy leaf to (belief, steps still taken) pairs (:func:`belief_rollouts`)."""
    return EntropyLeaf.fit(BeliefOps(model, threshold).entropy(beliefs), remaining, **kw)
