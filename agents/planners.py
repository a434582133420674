"""Planners on the exact belief: what a good policy can do, to measure learned ones against.

Policies (the :class:`~gym_gridloc_agents.base.Policy` interface; ``belief`` is the exact
hidden-state belief ``(L, H, W)``):

- :class:`CentralPolicy` (``central``): ``argmin_a P(next reading = "nothing" | belief, a)``.
- :class:`ExpectimaxPolicy` (``expectimax``): depth-``d`` expectimax on the exact belief; the cost
  is the number of steps until the referee's test (largest POSITION probability >= threshold)
  holds; exact expectation over readings (readings below ``prune`` dropped, the rest
  renormalised); a leaf estimate of the steps still needed at depth ``d``; equal beliefs merged.
- :class:`MCTSPolicy` (``mcts``): Monte Carlo tree search on the belief MDP with the exact filter
  at every node.  ``readings="enumerate"`` (default): exact expectations over readings, an
  incremental selective expectimax valued by the leaf; ``readings="sample"``: classic UCT,
  readings sampled from the exact predictive distribution, rollouts with a fast policy.

:func:`lower_bound` computes a number no policy's expected steps can go below; :func:`fit_leaf`
fits the entropy leaf from rollouts on the belief MDP (:func:`belief_rollouts`).  Every belief
prediction goes through :func:`gym_gridloc.engine.predict` (batched).

This module is longer than 400 lines because it keeps the three planners, their leaves and the
bound that share :class:`BeliefOps` and the expectimax recursion in one place.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.model import GridModel
from gym_gridloc_agents.base import Policy

#: Where the fitted leaves shipped with the package live (``<env_id>-entropy.json``).
LEAF_DIR = Path(__file__).resolve().parent / "leaves"


def predict_batch(model: GridModel, beliefs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``b'_i = T_{a_i}^T b_i`` for ``beliefs`` ``(N, L, H, W)`` and ``actions`` ``(N,)`` (the engine's
    batched prediction; mass kept, kidnapping mixed in)."""
    return engine.predict(model, np.ascontiguousarray(beliefs, dtype=np.float64), np.asarray(actions, dtype=np.int64))


# =================================================================================================
# Model view: likelihoods, posteriors, the referee's test
# =================================================================================================
class BeliefOps:
    """What the planners need of a model, built once from the public interface."""

    def __init__(self, model, threshold: float = 0.9) -> None:
        self.model = model
        self.threshold = float(threshold)
        self.A = int(model.n_actions)
        self.Z = int(model.sensor.n_readings)
        self.shape = tuple(model.belief_shape)  # (L, H, W)
        L, H, W = self.shape
        if self.Z * L * H * W > 50_000_000:
            raise ValueError(f"{model!r}: a (readings x cells) likelihood table of {self.Z} x {L * H * W} is too large")
        table = engine.likelihoods(model, np.arange(self.Z))
        lik = np.empty((self.Z, L, H, W))
        lik[:] = table.reshape(self.Z, -1, H, W)  # broadcast over layers for position sensors
        self.lik = lik
        self.lik_flat_t = np.ascontiguousarray(lik.reshape(self.Z, -1).T)  # (LHW, Z)
        # Sensor entropy at each hidden state (bits), for features.
        p = lik.reshape(self.Z, -1)
        self.sensor_entropy = -(p * np.log2(np.where(p > 0, p, 1.0))).sum(axis=0).reshape(L, H, W)
        free = np.asarray(model.grid.free, dtype=bool)
        self.free = free
        self.n_free = int(free.sum())

    # -- basic quantities -------------------------------------------------------------------------
    def full(self, belief: np.ndarray) -> np.ndarray:
        b = np.asarray(belief, dtype=np.float64)
        if b.shape == self.shape:
            pass
        elif b.shape == self.shape[1:] and self.shape[0] == 1:
            b = b[None]
        else:
            raise ValueError(f"belief must have shape {self.shape}, got {b.shape} (use wrapper.filter.full_belief)")
        s = b.sum()
        if not s > 0:
            raise ValueError("belief has no mass")
        return b / s

    @staticmethod
    def position(beliefs: np.ndarray) -> np.ndarray:
        """(N, L, H, W) -> (N, H, W)."""
        return beliefs.sum(axis=1)

    def max_position(self, beliefs: np.ndarray) -> np.ndarray:
        n = beliefs.shape[0]
        return self.position(beliefs).reshape(n, -1).max(axis=1)

    def localised(self, beliefs: np.ndarray, slack: float = 0.0) -> np.ndarray:
        return self.max_position(beliefs) >= self.threshold - slack

    def predict_all(self, beliefs: np.ndarray) -> np.ndarray:
        """Every action for every belief: (N, L, H, W) -> (N * A, L, H, W), node-major."""
        n = beliefs.shape[0]
        return predict_batch(self.model, np.repeat(beliefs, self.A, axis=0), np.tile(np.arange(self.A), n))

    def reading_probs(self, preds: np.ndarray) -> np.ndarray:
        """P(z) (unnormalised by the predictions' mass) for (M, L, H, W) -> (M, Z)."""
        return preds.reshape(preds.shape[0], -1) @ self.lik_flat_t

    def posteriors(self, preds: np.ndarray, idx: np.ndarray, z: np.ndarray, pz: np.ndarray) -> np.ndarray:
        return preds[idx] * self.lik[z] / pz[:, None, None, None]

    def entropy(self, beliefs: np.ndarray) -> np.ndarray:
        p = self.position(beliefs).reshape(beliefs.shape[0], -1)
        return -(p * np.log2(np.where(p > 0, p, 1.0))).sum(axis=1)


def _dedupe(beliefs: np.ndarray, decimals: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Unique beliefs and the inverse index.  Two beliefs are merged when their projections on two
    fixed random directions agree after rounding to ``decimals`` (a hash of the rounded belief;
    unequal beliefs colliding on both is vanishingly unlikely, and equal ones always merge unless
    a projection falls on a rounding boundary, which only costs a repeated evaluation)."""
    n = beliefs.shape[0]
    if n <= 1:
        return beliefs, np.zeros(n, dtype=np.int64)
    flat = beliefs.reshape(n, -1)
    proj = _projections(flat.shape[1])
    keys = np.round(flat @ proj, decimals) + 0.0  # (n, 2)
    _, first, inv = np.unique(keys[:, 0] * np.pi + keys[:, 1], return_index=True, return_inverse=True)
    return beliefs[first], inv.reshape(-1)


_PROJ: dict = {}


def _projections(d: int) -> np.ndarray:
    p = _PROJ.get(d)
    if p is None:
        p = _PROJ[d] = np.random.default_rng(12345).uniform(0.5, 1.5, (d, 2))
    return p


# =================================================================================================
# Leaf estimates of the steps still needed (for beliefs that are not localised)
# =================================================================================================
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
        kx = np.array([np.mean(v) for v in xs_out])
        return cls(kx, np.array(vals))


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


# =================================================================================================
# Policies
# =================================================================================================
class PlannerPolicy(Policy):
    """A planner on the exact belief: ``reset(seed, model)``, ``act(observation, belief)``; the
    time spent deciding is kept (``seconds``, ``decisions``)."""

    name = "planner"

    def __init__(self, model: GridModel, *, threshold: float = 0.9, seed: int | None = None, **_: Any) -> None:
        super().__init__(model, seed=seed)
        self.threshold = float(threshold)
        self.ops = BeliefOps(model, self.threshold)
        self.decisions = 0
        self.seconds = 0.0

    def set_model(self, model: GridModel) -> None:
        super().set_model(model)
        self.ops = BeliefOps(model, self.threshold)

    def values(self, b: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """Each action's cost (lower is better) at the normalised belief ``b``."""
        raise NotImplementedError

    def act(self, observation: Any, belief: np.ndarray) -> int:
        return self.choose(self.probabilities(observation, belief))

    def probabilities(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        ties = self.best(self.values(self.ops.full(belief)))
        self.seconds += time.perf_counter() - t
        self.decisions += 1
        out = np.zeros(self.n_actions)
        out[ties] = 1.0 / len(ties)
        return out


def nothing_reading(model, nothing: int | None = None) -> int:
    """The sensor's "nothing" reading: ``nothing`` if given, else ``model.sensor.nothing``.
    Raises ``ValueError`` for sensors without one (colour and wall sensors)."""
    if nothing is None:
        nothing = getattr(model.sensor, "nothing", None)
    if nothing is None:
        raise ValueError(
            f"policy 'central' needs a sensor with a 'nothing' reading (RingSensor); {type(model.sensor).__name__} "
            "has none (pass nothing=<reading> to name one)"
        )
    nothing = int(nothing)
    if not 0 <= nothing < model.sensor.n_readings:
        raise ValueError(f"nothing reading {nothing} outside 0..{model.sensor.n_readings - 1}")
    return nothing


class CentralPolicy(PlannerPolicy):
    """``argmin_a P(z' = nothing | b, a) = sum_s (T_a^T b)(s) P(nothing | s)``: keep the robot
    where the sensor names a cell.  ``depth=2``: the expected number of "nothing" readings over two
    steps, the second action chosen after the first reading.  Sensors without a "nothing" reading
    are refused (pass ``nothing=<reading>`` to name one)."""

    name = "central"

    def __init__(self, model, *, nothing: int | None = None, depth: int = 1, **kw) -> None:
        if depth not in (1, 2):
            raise ValueError(f"central depth must be 1 or 2, got {depth!r}")
        self.nothing_arg, self.depth = nothing, int(depth)
        nothing_reading(model, nothing)  # refuse sensors without a "nothing" reading now, not at the first act
        super().__init__(model, **kw)

    @property
    def lik_nothing(self) -> np.ndarray:
        return self.ops.lik[nothing_reading(self.model, self.nothing_arg)].reshape(-1)

    def values(self, b: np.ndarray) -> np.ndarray:
        preds = self.ops.predict_all(b[None])
        lik_nothing = self.lik_nothing
        pn = preds.reshape(self.n_actions, -1) @ lik_nothing
        if self.depth == 2:  # + E_z1[ min_a2 P(nothing at step 2 | b_a1z1, a2) ], closed loop
            A, Z = self.n_actions, self.ops.Z
            joint = (preds[:, None] * self.ops.lik[None]).reshape(A * Z, *self.ops.shape)  # mass p(z1 | a1)
            pn2 = (self.ops.predict_all(joint).reshape(A * Z * A, -1) @ lik_nothing).reshape(A, Z, A)
            pn = pn + pn2.min(axis=2).sum(axis=1)
        return pn


# -- expectimax ------------------------------------------------------------------------------------
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
    q = _q_values(ops, root[None], depth, leaf, prune, renormalise, memo, slack, stats, max_pairs)
    return q[0]


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
    flat_preds = preds.reshape(n * A, -1)
    flat_lik = ops.lik.reshape(Z, -1)
    L, H, W = ops.shape
    opens, open_idx = [], []
    chunk = 8192
    for s in range(0, m, chunk):
        sl = slice(s, min(m, s + chunk))
        post = flat_preds[ii[sl]] * flat_lik[zz[sl]]
        post /= p[sl, None]
        pos = post.reshape(-1, L, H * W).sum(axis=1) if L > 1 else post
        op = np.flatnonzero(pos.max(axis=1) < ops.threshold - slack)
        if len(op) == 0:
            continue
        beliefs = post[op].reshape(-1, L, H, W)
        if depth == 1:
            v[s + op] = leaf(ops, beliefs)
        else:
            opens.append(beliefs)
            open_idx.append(s + op)
    if depth > 1 and opens:
        children = np.concatenate(opens)
        idx = np.concatenate(open_idx)
        if memo:
            uniq, inv = _dedupe(children)
        else:
            uniq, inv = children, np.arange(len(children))
        vals = _q_values(ops, uniq, depth - 1, leaf, prune, renormalise, memo, slack, stats, max_pairs).min(axis=1)
        v[idx] = vals[inv]
    return 1.0 + np.bincount(ii, weights=w * v, minlength=n * A).reshape(n, A)


class ExpectimaxPolicy(PlannerPolicy):
    """Depth-``depth`` expectimax on the expected number of steps to localise.

    ``leaf``: the estimate of the steps still needed at depth ``depth`` (see :func:`load_leaf`:
    ``"one"``, a number, an :class:`EntropyLeaf` or its JSON file).  ``prune``:
    readings with ``p(z | b, a) < prune`` are dropped and the rest renormalised.
    """

    name = "expectimax"

    def __init__(self, model, *, depth: int = 2, leaf: Any = "one", prune: float = 1e-3, memo: bool = True, **kw) -> None:
        super().__init__(model, **kw)
        if int(depth) < 1:
            raise ValueError(f"depth must be >= 1, got {depth!r}")
        self.depth = int(depth)
        self.leaf = load_leaf(leaf)
        self.prune = float(prune)
        self.memo = bool(memo)

    def q_values(self, belief: np.ndarray) -> np.ndarray:
        return expectimax_q(self.ops, self.ops.full(belief), self.depth, self.leaf, prune=self.prune, memo=self.memo)

    def values(self, b: np.ndarray) -> np.ndarray:
        return expectimax_q(self.ops, b, self.depth, self.leaf, prune=self.prune, memo=self.memo)


# -- MCTS ------------------------------------------------------------------------------------------
class _Node:
    __slots__ = ("belief", "n", "na", "qa", "preds", "pz", "children")

    def __init__(self, belief):
        self.belief = belief
        self.n = 0
        self.na = None
        self.qa = None
        self.preds = None
        self.pz = None
        self.children = {}


class MCTSPolicy(PlannerPolicy):
    """UCT on the exact belief MDP, minimising the expected number of steps to localise.

    Each simulation descends from the root choosing ``argmin_a Q(a) - c * scale * sqrt(ln N / n_a)``
    (untried actions first; ``scale`` = the root's mean cost so far, at least 1), samples the
    reading from the node's exact predictive distribution ``p(z | b, a)`` and moves to the exact
    posterior (created on first visit; a localised posterior is terminal with cost 0).  A new node
    is valued by a rollout of ``rollout`` (``"central"``, ``"greedy"`` (one-step expected
    entropy), ``"random"`` or ``"none"``) for at most ``rollout_steps`` steps, plus ``leaf`` if it
    has not localised by then.  Budget: ``simulations`` per decision, or ``time_ms`` if given.
    The action played is the most visited one (ties: lowest Q, then the seeded generator).
    """

    name = "mcts"

    def __init__(self, model, *, simulations: int = 200, time_ms: float | None = None, c: float = 1.0,
                 rollout: str = "greedy", rollout_steps: int = 20, leaf: Any = "one", max_depth: int = 50,
                 nothing: int | None = None, **kw) -> None:
        super().__init__(model, **kw)
        if rollout not in ("central", "greedy", "random", "none"):
            raise ValueError(f"rollout must be 'central', 'greedy', 'random' or 'none', got {rollout!r}")
        self.simulations = int(simulations)
        self.time_ms = None if time_ms is None else float(time_ms)
        self.c = float(c)
        self.rollout = rollout
        self.rollout_steps = int(rollout_steps)
        self.leaf = load_leaf(leaf)
        self.max_depth = int(max_depth)
        if rollout == "central":
            self.lik_nothing = self.ops.lik[nothing_reading(model, nothing)].reshape(-1)
        self.sims_done = 0

    # -- node helpers --
    def _expand(self, node: _Node) -> None:
        preds = self.ops.predict_all(node.belief[None])
        pz = self.ops.reading_probs(preds)
        pz /= pz.sum(axis=1, keepdims=True)
        node.preds, node.pz = preds, pz
        node.na = np.zeros(self.n_actions)
        node.qa = np.zeros(self.n_actions)

    def _sample(self, p: np.ndarray) -> int:
        return int(min(np.searchsorted(np.cumsum(p), self.rng.random() * p.sum(), side="right"), len(p) - 1))

    def _rollout_action(self, b: np.ndarray, preds: np.ndarray, pz: np.ndarray) -> int:
        A = self.n_actions
        if self.rollout == "random":
            return int(self.rng.integers(A))
        if self.rollout == "central":
            return self._break_ties(preds.reshape(A, -1) @ self.lik_nothing)
        # greedy: expected posterior position entropy E_z[H(b_az)] via H(joint) identity
        pos = preds.sum(axis=1).reshape(A, -1)  # (A, HW)
        joint = pos[:, None, :] * self.ops.lik[:, 0].reshape(1, self.ops.Z, -1) if self.ops.shape[0] == 1 else None
        if joint is None:  # layered: marginalise layers after weighting by the likelihood
            j = preds[:, None] * self.ops.lik[None]  # (A, Z, L, H, W)
            joint = j.sum(axis=2).reshape(A, self.ops.Z, -1)
        jl = joint * np.log2(np.where(joint > 0, joint, 1.0))
        pzl = pz * np.log2(np.where(pz > 0, pz, 1.0))
        eh = -jl.sum(axis=(1, 2)) + pzl.sum(axis=1)
        return self._break_ties(eh)

    def _evaluate(self, b: np.ndarray) -> float:
        """Rollout cost from a non-localised belief."""
        if self.rollout == "none" or self.rollout_steps <= 0:
            return float(self.leaf(self.ops, b[None])[0])
        cost = 0.0
        for _ in range(self.rollout_steps):
            preds = self.ops.predict_all(b[None])
            pz = self.ops.reading_probs(preds)
            a = self._rollout_action(b, preds, pz)
            z = self._sample(pz[a])
            post = preds[a] * self.ops.lik[z]
            b = post / post.sum()
            cost += 1.0
            if self.ops.max_position(b[None])[0] >= self.ops.threshold:
                return cost
        return cost + float(self.leaf(self.ops, b[None])[0])

    def _simulate(self, node: _Node, depth: int, root_scale: float) -> float:
        if node.preds is None:
            self._expand(node)
        untried = np.flatnonzero(node.na == 0)
        if len(untried):
            a = int(untried[0]) if len(untried) == 1 else int(self.rng.choice(untried))
        else:
            ucb = node.qa - self.c * root_scale * np.sqrt(math.log(node.n) / node.na)
            a = self._break_ties(ucb)
        z = self._sample(node.pz[a])
        key = (a, z)
        child = node.children.get(key)
        if child is None:
            post = node.preds[a] * self.ops.lik[z]
            post /= post.sum()
            if self.ops.max_position(post[None])[0] >= self.ops.threshold:
                child = node.children[key] = "done"
                cost = 1.0
            else:
                child = node.children[key] = _Node(post)
                cost = 1.0 + self._evaluate(post)
                child.n = 1  # the rollout counts as its first visit
        elif isinstance(child, str):
            cost = 1.0
        elif depth + 1 >= self.max_depth:
            cost = 1.0 + float(self.leaf(self.ops, child.belief[None])[0])
        else:
            cost = 1.0 + self._simulate(child, depth + 1, root_scale)
        node.n += 1
        node.na[a] += 1
        node.qa[a] += (cost - node.qa[a]) / node.na[a]
        return cost

    def search(self, b: np.ndarray) -> _Node:
        root = _Node(b)
        root.n = 1
        deadline = None if self.time_ms is None else time.perf_counter() + self.time_ms / 1000.0
        total, sims = 0.0, 0
        while True:
            scale = max(1.0, total / sims) if sims else 1.0
            total += self._simulate(root, 0, scale)
            sims += 1
            if deadline is not None:
                if time.perf_counter() >= deadline and sims >= self.n_actions:
                    break
            elif sims >= self.simulations:
                break
        self.sims_done += sims
        return root

    def values(self, b: np.ndarray) -> np.ndarray:
        """The most visited actions are best (ties: the lowest mean cost)."""
        root = self.search(b)
        return -root.na + 1e-6 * root.qa / max(1.0, float(np.abs(root.qa).max()))


class _ENode:
    __slots__ = ("belief", "q", "na", "n", "kids", "value")

    def __init__(self, belief, value):
        self.belief = belief
        self.value = value  # leaf estimate until expanded, then min_a q
        self.q = None
        self.na = None
        self.n = 0
        self.kids = None  # per action: (probs (k,), children list: _ENode or None for localised)


class ExpectedMCTSPolicy(PlannerPolicy):
    """Monte Carlo tree search with EXACT expectations over readings (an incremental, selective
    expectimax).  Expanding a node builds, for every action, the posterior of every reading
    (``p(z | b, a) >= prune``, renormalised) and values each non-localised one with ``leaf``;
    ``Q(a) = 1 + sum_z p(z) V(child_z)`` with ``V = 0`` for a localised child and ``V(child) =
    leaf(child)`` until the child is expanded, ``min_a Q(child, a)`` after.  A simulation descends
    by ``argmin_a Q(a) - c * sqrt(ln N / n_a)`` (untried first) and a reading drawn from
    ``p(z | b, a)`` among non-localised children, expands the node it reaches and backs the new
    values up the path.  Budget: ``simulations`` expansions or ``time_ms``.  The action played is
    ``argmin_a Q(a)`` at the root (ties: seeded generator)."""

    name = "mcts"

    def __init__(self, model, *, simulations: int = 100, time_ms: float | None = None, c: float = 0.3,
                 leaf: Any = "one", prune: float = 1e-3, max_depth: int = 30, **kw) -> None:
        """``max_depth``: the deepest level (root = 0) whose nodes may be expanded."""
        super().__init__(model, **kw)
        self.simulations = int(simulations)
        self.time_ms = None if time_ms is None else float(time_ms)
        self.c = float(c)
        self.leaf = load_leaf(leaf)
        self.prune = float(prune)
        self.max_depth = int(max_depth)
        self.sims_done = 0

    def _expand(self, node: _ENode) -> None:
        ops = self.ops
        preds = ops.predict_all(node.belief[None])
        pz = ops.reading_probs(preds)
        keep = pz > 0
        if self.prune > 0:
            keep &= pz >= self.prune * pz.sum(axis=1, keepdims=True)
        ai, zz = np.nonzero(keep)
        p = pz[ai, zz]
        post = ops.posteriors(preds, ai, zz, p)
        loc = ops.localised(post)
        vals = np.zeros(len(ai))
        op = np.flatnonzero(~loc)
        if len(op):
            vals[op] = self.leaf(ops, post[op])
        mass = np.bincount(ai, weights=p, minlength=self.n_actions)
        node.kids = []
        q = np.empty(self.n_actions)
        for a in range(self.n_actions):
            sel = np.flatnonzero(ai == a)
            w = p[sel] / mass[a]
            kids = [None if loc[j] else _ENode(post[j], vals[j]) for j in sel]
            node.kids.append((w, kids))
            q[a] = 1.0 + float(w @ vals[sel])
        node.q = q
        node.na = np.zeros(self.n_actions)
        node.value = float(q.min())

    def _q(self, node: _ENode, a: int) -> float:
        w, kids = node.kids[a]
        return 1.0 + sum(wi * k.value for wi, k in zip(w, kids) if k is not None)

    def search(self, b: np.ndarray) -> _ENode:
        root = _ENode(b, 0.0)
        self._expand(root)
        deadline = None if self.time_ms is None else time.perf_counter() + self.time_ms / 1000.0
        sims = 0
        while True:
            path = []
            node = root
            for depth in range(self.max_depth + 1):
                if node.kids is None:
                    self._expand(node)
                    break
                if depth == self.max_depth:
                    break
                untried = np.flatnonzero(node.na == 0)
                if len(untried):
                    a = int(untried[0]) if len(untried) == 1 else int(self.rng.choice(untried))
                else:
                    a = self._break_ties(node.q - self.c * np.sqrt(math.log(node.n) / node.na))
                w, kids = node.kids[a]
                open_ = [i for i, k in enumerate(kids) if k is not None]
                path.append((node, a))
                if not open_:
                    break
                pw = w[open_]
                i = open_[self._sample(pw)]
                node = kids[i]
            for nd, a in reversed(path):
                nd.n += 1
                nd.na[a] += 1
                nd.q[a] = self._q(nd, a)
                nd.value = float(nd.q.min())
            sims += 1
            if deadline is not None:
                if time.perf_counter() >= deadline:
                    break
            elif sims >= self.simulations:
                break
        self.sims_done += sims
        return root

    def _sample(self, p: np.ndarray) -> int:
        return int(min(np.searchsorted(np.cumsum(p), self.rng.random() * p.sum(), side="right"), len(p) - 1))

    def values(self, b: np.ndarray) -> np.ndarray:
        return self.search(b).q


#: The planners :func:`make_planner` builds.
PLANNER_NAMES = ("central", "expectimax", "mcts")


def make_planner(name: str, model: GridModel, *, env_id: str | None = None, **kw: Any) -> PlannerPolicy:
    """``central``, ``expectimax`` or ``mcts`` with keyword options (see the classes); ``leaf``
    defaults to ``"shipped"`` (the entropy leaf fitted for ``env_id``, if one ships)."""
    if "leaf" in kw or name in ("expectimax", "mcts"):
        kw["leaf"] = load_leaf(kw.get("leaf", "shipped"), env_id)
    if name == "central":
        kw.pop("leaf", None)
        return CentralPolicy(model, **kw)
    if name == "expectimax":
        return ExpectimaxPolicy(model, **kw)
    if name == "mcts":
        readings = kw.pop("readings", "enumerate")
        if readings not in ("enumerate", "sample"):
            raise ValueError(f"mcts readings must be 'enumerate' or 'sample', got {readings!r}")
        return (ExpectedMCTSPolicy if readings == "enumerate" else MCTSPolicy)(model, **kw)
    raise ValueError(f"unknown planner {name!r}; allowed: {', '.join(PLANNER_NAMES)}")


# =================================================================================================
# Lower bound
# =================================================================================================
def initial_beliefs(ops: BeliefOps) -> tuple[np.ndarray, np.ndarray]:
    """The beliefs after the first reading from the uniform prior, and the readings' probabilities."""
    free = np.broadcast_to(ops.free, ops.shape).astype(np.float64)
    prior = free / free.sum()
    pz = ops.reading_probs(prior[None])[0]
    zs = np.flatnonzero(pz > 0)
    posts = prior[None] * ops.lik[zs] / pz[zs, None, None, None]
    return posts, pz[zs]


def lower_bound(model, depth: int, *, threshold: float = 0.9, prune: float = 0.0, progress: bool = False) -> dict:
    """``LB_k = E_{z0}[ W_k(b0(z0)) ]``, below which no policy's expected steps can go.

    ``W_k(b) = 1 + min_a sum_z p(z | b, a) W'_{k-1}(b_az)`` with ``W'_j(b) = 0`` if ``b`` is
    localised, ``W_j(b)`` otherwise, and ``W_0 = 1`` for a non-localised belief (it needs at least
    one more step).  By induction ``W_k(b) <= min_pi E[min(T, k + 1)] <= min_pi E[T]`` where ``T``
    counts steps from ``b`` to the referee's test: each level is the exact Bellman operator of the
    belief MDP (cost 1 per step, 0 once localised) applied to a leaf that under-estimates the
    true cost-to-go.  Readings with probability below ``prune`` are dropped *without*
    renormalising (they count 0, less than their true cost), the localisation test is made with a
    1e-9 slack (counting borderline beliefs as localised), so both only lower the number.  As the
    benchmark counts truncated episodes at ``max_episode_steps`` (>= ``k + 1``), the bound also holds
    for the benchmark's mean steps.
    """
    ops = BeliefOps(model, threshold)
    b0, p0 = initial_beliefs(ops)
    one = ConstantLeaf(1.0)
    t = time.perf_counter()
    vals = np.zeros(len(b0))
    for i, b in enumerate(b0):
        vals[i] = expectimax_q(ops, b, depth, one, prune=prune, renormalise=False, memo=True, slack=1e-9).min()
        if progress:
            print(f"  reading {i}: p {p0[i]:.4f} W {vals[i]:.4f} ({time.perf_counter() - t:.0f} s)", flush=True)
    return {"depth": depth, "prune": prune, "bound": float(p0 @ vals), "per_reading": vals.tolist(),
            "reading_probs": p0.tolist(), "seconds": time.perf_counter() - t}


# =================================================================================================
# Rollouts on the belief MDP and leaf fitting
# =================================================================================================
def belief_rollouts(model, policy, episodes: int, *, seed: int = 1_000_000, max_steps: int = 100,
                    threshold: float = 0.9, record: bool = True) -> dict:
    """Episodes of ``policy`` simulated on the belief MDP itself: the first reading and every later
    one drawn from the exact predictive distribution of the current belief (the same law as the
    environment's readings seen through its filter).  Returns the steps of each episode and, with
    ``record``, every belief at which the policy acted with the steps it still took (a truncated
    episode counts ``max_steps``).  Episode ``i`` seeds the policy and the reading draws with
    ``seed + i``."""
    ops = BeliefOps(model, threshold)
    b0, p0 = initial_beliefs(ops)
    steps = np.zeros(episodes, dtype=np.int64)
    beliefs, remaining = [], []
    for i in range(episodes):
        rng = np.random.default_rng(seed + i)
        policy.reset(seed=seed + i)
        b = b0[int(rng.choice(len(p0), p=p0))]
        seen = []
        t = 0
        while True:
            seen.append(b)
            a = policy.act(None, b)
            pred = predict_batch(model, b[None], np.array([a]))[0]
            pz = ops.reading_probs(pred[None])[0]
            z = int(rng.choice(len(pz), p=pz / pz.sum()))
            post = pred * ops.lik[z]
            b = post / post.sum()
            t += 1
            if ops.max_position(b[None])[0] >= threshold or t >= max_steps:
                break
        steps[i] = t
        if record:
            beliefs.extend(seen)
            remaining.extend(t - np.arange(len(seen)))
    out = {"steps": steps}
    if record:
        out["beliefs"] = np.array(beliefs)
        out["remaining"] = np.array(remaining, dtype=np.float64)
    return out


def fit_leaf(model, beliefs: np.ndarray, remaining: np.ndarray, *, threshold: float = 0.9, **kw) -> EntropyLeaf:
    """Fit an entropy leaf to (belief, steps still taken) pairs (:func:`belief_rollouts`)."""
    return EntropyLeaf.fit(BeliefOps(model, threshold).entropy(beliefs), remaining, **kw)
