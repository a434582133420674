"""``expectimax``: depth-d expectimax on the expected number of steps to localise, and the lower
bound computed by the same recursion."""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from gym_gridloc.core.validation import check_int
from gym_gridloc.referee import LOCALISE_THRESHOLD
from gym_gridloc_agents.planners.base import PlannerPolicy
from gym_gridloc_agents.planners.leaves import ConstantLeaf, Leaf, load_leaf
from gym_gridloc_agents.planners.ops import BeliefOps, dedupe, initial_beliefs


def expectimax_q(ops: BeliefOps, root: np.ndarray, depth: int, leaf: Leaf, *, prune: float = 0.0,
                 renormalise: bool = True, memo: bool = True, slack: float = 0.0,
                 stats: dict | None = None, max_pairs: int = 1 << 16) -> np.ndarray:
    """Q(a) for the root belief (L, H, W): expected steps to localise when taking ``a`` first.

    ``V(b) = 0`` if ``b`` is localised (largest position probability >= threshold - ``slack``),
    ``leaf(b)`` at depth ``depth`` otherwise, and ``1 + min_a sum_z p(z | b, a) V(b_az)`` above.
    The root is never treated as localised (the environment only tests after a step).  Readings
    with ``p(z | b, a) < prune`` are dropped; ``renormalise`` spreads their mass over the rest
    (planning) or not (they count 0: a lower bound).  Beliefs equal after rounding are expanded
    once per batch (``memo``).  Batched level by level, depth first over batches of nodes so that
    at most about ``max_pairs`` (node, action, reading) posteriors are held per level.
    """
    return _q_values(ops, root[None], depth, leaf, prune, renormalise, memo, slack, stats, max_pairs)[0]


def _q_values(ops, nodes, depth, leaf, prune, renormalise, memo, slack, stats, max_pairs):
    """(n, A) Q-values of ``nodes`` (n, L, H, W), none of them localised."""
    n = nodes.shape[0]
    A, Z = ops.A, ops.Z
    per_node = A * Z
    if n * per_node > max_pairs and n > 1:
        step = max(1, max_pairs // per_node)
        return np.concatenate([_q_values(ops, nodes[s : s + step], depth, leaf, prune, renormalise, memo, slack,
                                         stats, max_pairs) for s in range(0, n, step)])
    if stats is not None:
        lv = stats.setdefault("nodes", {})
        lv[depth] = lv.get(depth, 0) + n
    preds = ops.predict_all(nodes)  # (n*A, L, H, W)
    pz = ops.reading_probs(preds)  # (n*A, Z)
    total = pz.sum(axis=1)
    keep = pz > 0.0
    if prune > 0.0:
        keep &= pz >= prune * total[:, None]
    ii, zz = np.nonzero(keep)
    p = pz[ii, zz]
    mass = np.bincount(ii, weights=p, minlength=n * A) if renormalise else total
    w = p / mass[ii]
    m = len(ii)
    v = np.zeros(m)
    opens, open_idx = [], []
    chunk = 8192
    for s in range(0, m, chunk):
        sl = slice(s, min(m, s + chunk))
        post = ops.posteriors(preds, ii[sl], zz[sl], p[sl])
        op = np.flatnonzero(~ops.localised(post, slack))
        if len(op) == 0:
            continue
        beliefs = post[op]
        if depth == 1:
            v[s + op] = leaf(ops, beliefs)
        else:
            opens.append(beliefs)
            open_idx.append(s + op)
    if depth > 1 and opens:
        children = np.concatenate(opens)
        uniq, inv = dedupe(children) if memo else (children, np.arange(len(children)))
        vals = _q_values(ops, uniq, depth - 1, leaf, prune, renormalise, memo, slack, stats, max_pairs).min(axis=1)
        v[np.concatenate(open_idx)] = vals[inv]
    return 1.0 + np.bincount(ii, weights=w * v, minlength=n * A).reshape(n, A)


class ExpectimaxPolicy(PlannerPolicy):
    """Depth-``depth`` expectimax on the expected number of steps to localise.

    ``leaf``: the estimate of the steps still needed at depth ``depth`` (see :func:`load_leaf`:
    ``"one"``, a number, an :class:`EntropyLeaf` or its JSON file).  ``prune``:
    readings with ``p(z | b, a) < prune`` are dropped and the rest renormalised.
    """

    name = "expectimax"
    takes_leaf = True

    def __init__(self, model, *, depth: int = 2, leaf: Any = "one", prune: float = 1e-3, memo: bool = True, **kw) -> None:
        super().__init__(model, **kw)
        self.depth = check_int("depth", depth, whole=True)
        self.leaf = load_leaf(leaf)
        self.prune = float(prune)
        self.memo = bool(memo)

    def q_values(self, belief: np.ndarray) -> np.ndarray:
        return expectimax_q(self.ops, self.ops.full(belief), self.depth, self.leaf, prune=self.prune, memo=self.memo)

    def values(self, b: np.ndarray) -> np.ndarray:
        return expectimax_q(self.ops, b, self.depth, self.leaf, prune=self.prune, memo=self.memo)


#: The deepest :func:`lower_bound` search (beyond it the search cannot finish, nor its recursion fit the stack).
MAX_BOUND_DEPTH = 12


def lower_bound(model, depth: int, *, threshold: float = LOCALISE_THRESHOLD, pose: bool = False, prune: float = 0.0,
                progress: bool = False) -> dict:
    """``LB_k = E_{z0}[ W_k(b0(z0)) ]``, below which no policy's expected steps can go.

    ``W_k(b) = 1 + min_a sum_z p(z | b, a) W'_{k-1}(b_az)`` with ``W'_j(b) = 0`` if ``b`` is
    localised, ``W_j(b)`` otherwise, and ``W_0 = 1`` for a non-localised belief (it needs at least
    one more step).  By induction ``W_k(b) <= min_pi E[min(T, k + 1)] <= min_pi E[T]`` where ``T``
    counts steps from ``b`` to the referee's test (``threshold``; on the pose with ``pose``, the
    environment's ``referee_pose``): each level is the exact Bellman operator of the
    belief MDP (cost 1 per step, 0 once localised) applied to a leaf that under-estimates the
    true cost-to-go.  Readings with probability below ``prune`` are dropped *without*
    renormalising (they count 0, less than their true cost), the localisation test is made with a
    1e-9 slack (counting borderline beliefs as localised), so both only lower the number.  As the
    benchmark counts truncated episodes at ``max_episode_steps`` (>= ``k + 1``), the bound also holds
    for the benchmark's mean steps.
    """
    depth = check_int("depth", depth, 1, MAX_BOUND_DEPTH, error=ValueError,
                      what=f"a whole number in 1..{MAX_BOUND_DEPTH} (the search grows about |A x Z|^depth)")
    ops = BeliefOps(model, threshold, pose=pose)
    b0, p0 = initial_beliefs(ops)
    one = ConstantLeaf(1.0)
    t = time.perf_counter()
    vals = np.zeros(len(b0))
    for i, b in enumerate(b0):
        vals[i] = expectimax_q(ops, b, depth, one, prune=prune, renormalise=False, memo=True, slack=1e-9).min()
        if progress:  # W_k after this first reading: no policy localises from there in fewer mean steps
            print(f"  first reading {i + 1} of {len(b0)} (probability {p0[i]:.4f}): at least {vals[i]:.4f} mean steps "
                  f"from there ({time.perf_counter() - t:.0f} s)", file=sys.stderr, flush=True)
    return {"depth": depth, "prune": prune, "pose": ops.pose, "bound": float(p0 @ vals), "per_reading": vals.tolist(),
            "reading_probs": p0.tolist(), "seconds": time.perf_counter() - t}
