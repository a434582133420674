"""``mcts``: Monte Carlo tree search on the exact belief MDP, with readings sampled (UCT with
rollouts) or enumerated (an incremental, selective expectimax)."""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gym_gridloc_agents.planners.base import PlannerPolicy, keywords
from gym_gridloc_agents.planners.central import nothing_reading
from gym_gridloc_agents.planners.leaves import load_leaf


def _sample(rng: np.random.Generator, p: np.ndarray) -> int:
    """An index drawn with probability proportional to ``p`` (one uniform)."""
    return int(min(np.searchsorted(np.cumsum(p), rng.random() * p.sum(), side="right"), len(p) - 1))


class _TreeSearch(PlannerPolicy):
    """What both searches share: the budget (``simulations`` per decision, or ``time_ms``), the
    exploration constant ``c``, the ``leaf`` and the ``max_depth``."""

    takes_leaf = True

    def __init__(self, model, *, simulations: int, time_ms: float | None, c: float, leaf: Any, max_depth: int,
                 **kw) -> None:
        super().__init__(model, **kw)
        self.simulations = int(simulations)
        self.time_ms = None if time_ms is None else float(time_ms)
        self.c = float(c)
        self.leaf = load_leaf(leaf)
        self.max_depth = int(max_depth)
        self.sims_done = 0

    def _choose(self, n: int, na: np.ndarray, q: np.ndarray, c: float) -> int:
        """An untried action (drawn among several), else ``argmin_a q(a) - c * sqrt(ln n / na(a))``."""
        untried = np.flatnonzero(na == 0)
        if len(untried):
            return self._one_of(untried)
        return self._break_ties(q - c * np.sqrt(math.log(n) / na))

    def _budget(self, min_sims: int = 1):
        """Yields once per simulation, the number made before it, until the budget is spent (a time
        budget: at least ``min_sims`` simulations); counts them in ``sims_done``."""
        deadline = None if self.time_ms is None else time.perf_counter() + self.time_ms / 1000.0
        for sims in itertools.count(1):
            yield sims - 1
            self.sims_done += 1
            if sims >= self.simulations if deadline is None else time.perf_counter() >= deadline and sims >= min_sims:
                return


@dataclass(eq=False, slots=True)
class _Node:
    belief: np.ndarray
    n: int = 0
    na: np.ndarray | None = None
    qa: np.ndarray | None = None
    preds: np.ndarray | None = None
    pz: np.ndarray | None = None
    children: dict = field(default_factory=dict)


class MCTSPolicy(_TreeSearch):
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
        super().__init__(model, simulations=simulations, time_ms=time_ms, c=c, leaf=leaf, max_depth=max_depth, **kw)
        if rollout not in ("central", "greedy", "random", "none"):
            raise ValueError(f"rollout must be 'central', 'greedy', 'random' or 'none', got {rollout!r}")
        self.rollout = rollout
        self.rollout_steps = int(rollout_steps)
        if rollout == "central":
            self.lik_nothing = self.ops.lik[nothing_reading(model, nothing)].reshape(-1)

    # -- node helpers --
    def _expand(self, node: _Node) -> None:
        node.preds = self.ops.predict_all(node.belief[None])
        node.pz = self.ops.reading_probs(node.preds)
        node.pz /= node.pz.sum(axis=1, keepdims=True)
        node.na = np.zeros(self.n_actions)
        node.qa = np.zeros(self.n_actions)

    def _rollout_action(self, b: np.ndarray, preds: np.ndarray, pz: np.ndarray) -> int:
        A = self.n_actions
        if self.rollout == "random":
            return int(self.rng.integers(A))
        if self.rollout == "central":
            return self._break_ties(preds.reshape(A, -1) @ self.lik_nothing)
        # greedy: the expected entropy after each action's reading, as the greedy policy's (the belief
        # MDP's, on the predictions the node already holds)
        return self._break_ties(self.ops.mdp.weighted_entropy(preds))

    def _evaluate(self, b: np.ndarray) -> float:
        """Rollout cost from a non-localised belief."""
        if self.rollout == "none" or self.rollout_steps <= 0:
            return float(self.leaf(self.ops, b[None])[0])
        cost = 0.0
        for _ in range(self.rollout_steps):
            preds = self.ops.predict_all(b[None])
            pz = self.ops.reading_probs(preds)
            a = self._rollout_action(b, preds, pz)
            z = _sample(self.rng, pz[a])
            b = self.ops.update(preds[a], z)
            cost += 1.0
            if self.ops.localised(b[None])[0]:
                return cost
        return cost + float(self.leaf(self.ops, b[None])[0])

    def _simulate(self, node: _Node, depth: int, root_scale: float) -> float:
        if node.preds is None:
            self._expand(node)
        a = self._choose(node.n, node.na, node.qa, self.c * root_scale)
        z = _sample(self.rng, node.pz[a])
        key = (a, z)
        child = node.children.get(key)
        if child is None:
            post = self.ops.update(node.preds[a], z)
            if self.ops.localised(post[None])[0]:
                node.children[key] = "done"
                cost = 1.0
            else:
                node.children[key] = _Node(post, n=1)  # the rollout counts as its first visit
                cost = 1.0 + self._evaluate(post)
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
        root = _Node(b, n=1)
        total = 0.0
        for sims in self._budget(self.n_actions):
            total += self._simulate(root, 0, max(1.0, total / sims) if sims else 1.0)
        return root

    def values(self, b: np.ndarray) -> np.ndarray:
        """The most visited actions are best (ties: the lowest mean cost)."""
        root = self.search(b)
        return -root.na + 1e-6 * root.qa / max(1.0, float(np.abs(root.qa).max()))


@dataclass(eq=False, slots=True)
class _ENode:
    belief: np.ndarray
    value: float  # leaf estimate until expanded, then min_a q
    q: np.ndarray | None = None
    na: np.ndarray | None = None
    n: int = 0
    kids: list | None = None  # per action: (probs (k,), children list: _ENode or None for localised)


class ExpectedMCTSPolicy(_TreeSearch):
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
        super().__init__(model, simulations=simulations, time_ms=time_ms, c=c, leaf=leaf, max_depth=max_depth, **kw)
        self.prune = float(prune)

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
        node.q = np.empty(self.n_actions)
        for a in range(self.n_actions):
            sel = np.flatnonzero(ai == a)
            w = p[sel] / mass[a]
            kids = [None if loc[j] else _ENode(post[j], vals[j]) for j in sel]
            node.kids.append((w, kids))
            node.q[a] = 1.0 + float(w @ vals[sel])
        node.na = np.zeros(self.n_actions)
        node.value = float(node.q.min())

    def _q(self, node: _ENode, a: int) -> float:
        w, kids = node.kids[a]
        return 1.0 + sum(wi * k.value for wi, k in zip(w, kids) if k is not None)

    def search(self, b: np.ndarray) -> _ENode:
        root = _ENode(b, 0.0)
        self._expand(root)
        for _ in self._budget():
            path = []
            node = root
            for depth in range(self.max_depth + 1):
                if node.kids is None:
                    self._expand(node)
                    break
                if depth == self.max_depth:
                    break
                a = self._choose(node.n, node.na, node.q, self.c)
                w, kids = node.kids[a]
                open_ = [i for i, k in enumerate(kids) if k is not None]
                path.append((node, a))
                if not open_:
                    break
                node = kids[open_[_sample(self.rng, w[open_])]]
            for nd, a in reversed(path):
                nd.n += 1
                nd.na[a] += 1
                nd.q[a] = self._q(nd, a)
                nd.value = float(nd.q.min())
        return root

    def values(self, b: np.ndarray) -> np.ndarray:
        return self.search(b).q


#: How ``mcts`` handles readings (its option ``readings``): the class of each.
READINGS = {"enumerate": ExpectedMCTSPolicy, "sample": MCTSPolicy}


def mcts_policy(model, context, *, readings: str = "enumerate", **options: Any) -> PlannerPolicy:
    """``mcts`` as the policy table builds it: :class:`ExpectedMCTSPolicy` (``readings="enumerate"``,
    the default) or :class:`MCTSPolicy` (``"sample"``), each refusing the options only the other takes."""
    if readings not in READINGS:
        raise ValueError(f"mcts readings must be 'enumerate' or 'sample', got {readings!r}")
    cls = READINGS[readings]
    takes = sorted(keywords(cls) - {"seed", "pose"})
    if extra := sorted(set(options) - set(takes)):
        raise ValueError(f"policy 'mcts' with readings={readings!r} takes no option {', '.join(map(repr, extra))} "
                         f"(its options with readings={readings!r}: {', '.join(['readings', *takes])})")
    return cls.build(model, context, **options)
