"""The model as data: free cells, a sparse transition per action, a likelihood per reading.

A hidden state is ``(layer, row, col)``: ``layer`` is 0 for position-only models and the heading
for models whose hidden state includes one.  A belief is held as an ``(L, H, W)`` array that is
zero on obstacles.

A transition is a tuple of :class:`Term`: "from a state in layer ``src`` at ``(r, c)``, go to
layer ``dst`` at ``(r + dr, c + dc)`` with probability ``weight[r, c]``".  This is a sparse
matrix written as a stencil: the filter's prediction is a few multiply-adds over shifted arrays,
the simulator samples the same numbers, and :meth:`GridModel.transition_matrix` writes them out
as a ``scipy.sparse`` matrix for anyone who wants one.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from gym_gridloc.core.grid import DIRECTIONS, GridMap
from gym_gridloc.core.sensors import Sensor

_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class Term:
    """One stencil term of a transition (see the module docstring)."""

    src: int
    dst: int
    dr: int
    dc: int
    weight: np.ndarray

    @functools.cached_property
    def slices(self) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
        """``(source, destination)`` slices of an (H, W) array (the weight's shape) for this shift."""
        h, w = self.weight.shape
        dr, dc = self.dr, self.dc
        src = (slice(max(0, -dr), h - max(0, dr)), slice(max(0, -dc), w - max(0, dc)))
        dst = (slice(max(0, dr), h - max(0, -dr)), slice(max(0, dc), w - max(0, -dc)))
        return src, dst


def merge_terms(terms: Sequence[Term], scale: float = 1.0) -> tuple[Term, ...]:
    """Add up terms with the same (src, dst, dr, dc) and drop those that are zero everywhere."""
    merged: dict[tuple[int, int, int, int], np.ndarray] = {}
    for t in terms:
        key = (t.src, t.dst, t.dr, t.dc)
        if key in merged:
            merged[key] = merged[key] + t.weight * scale
        else:  # no copy at scale 1 (the weights are made read-only below)
            merged[key] = t.weight if scale == 1.0 else t.weight * scale
    out = []
    for (src, dst, dr, dc), weight in merged.items():
        if np.any(weight):
            weight = np.ascontiguousarray(weight, dtype=np.float64)
            weight.setflags(write=False)
            out.append(Term(src, dst, dr, dc, weight))
    return tuple(out)


_KERNELS = None


def _kernels():
    """:mod:`gym_gridloc.kernels`, imported on first use (it imports numba only when a small
    model is first filtered; see :func:`gym_gridloc.kernels.uses_numba`)."""
    global _KERNELS
    if _KERNELS is None:
        from gym_gridloc import kernels

        _KERNELS = kernels
    return _KERNELS


def _share_equal(transitions: tuple[tuple[Term, ...], ...]) -> tuple[tuple[Term, ...], ...]:
    """The actions' terms with every weight array equal to an earlier action's weight of the
    same ``(src, dst, dr, dc)`` replaced by that array (held once: e.g. on a colour grid the
    three actions that slip north share one north weight)."""
    seen: dict[tuple[int, int, int, int], list[np.ndarray]] = {}
    out = []
    for terms in transitions:
        shared = []
        for t in terms:
            key = (t.src, t.dst, t.dr, t.dc)
            same = next((w for w in seen.get(key, ()) if np.array_equal(w, t.weight)), None)
            if same is None:
                seen.setdefault(key, []).append(t.weight)
                shared.append(t)
            else:
                shared.append(Term(t.src, t.dst, t.dr, t.dc, same))
        out.append(tuple(shared))
    return tuple(out)


def move_terms(grid: GridMap, direction_probs: np.ndarray, layer: int = 0, dst_layer: int | None = None) -> list[Term]:
    """Terms for "try direction d with probability ``direction_probs[d]``; a blocked move stays".

    ``direction_probs`` is a length-4 vector or a (4, H, W) array (a probability per cell).
    """
    dst_layer = layer if dst_layer is None else dst_layer
    h, w = grid.shape
    probs = np.broadcast_to(np.asarray(direction_probs, dtype=np.float64).reshape(4, -1, 1) if np.ndim(direction_probs) == 1 else direction_probs, (4, h, w))
    blocked = grid.blocked()
    free = grid.free
    terms = []
    stay = np.zeros((h, w))
    for d, (dr, dc) in enumerate(DIRECTIONS):
        p = np.where(free, probs[d], 0.0)
        terms.append(Term(layer, dst_layer, int(dr), int(dc), np.where(blocked[d], 0.0, p)))
        stay += np.where(blocked[d], p, 0.0)
    terms.append(Term(layer, dst_layer, 0, 0, stay))
    return terms


class GridModel:
    """A hidden-Markov model on a grid: what the simulator samples and the filter multiplies.

    Parameters
    ----------
    grid:
        The map.
    transitions:
        One tuple of :class:`Term` per action (the same tuple for every action when the action
        plays no part).  Every free state's outgoing probabilities must sum to 1.
    sensor:
        P(reading | position) and how readings map to observations.
    n_layers:
        Number of hidden states per cell (1, or 4 for a heading).
    name:
        A short name for messages and rendering.
    """

    def __init__(
        self,
        grid: GridMap,
        transitions: Sequence[Sequence[Term]],
        sensor: Sensor,
        *,
        n_layers: int = 1,
        name: str = "GridModel",
        action_dependent: bool = True,
        layer_names: Sequence[str] | None = None,
        params: dict[str, Any] | None = None,
        kidnap_prob: float = 0.0,
    ) -> None:
        from gym_gridloc.core.validation import check_probability

        self.kidnap_prob = check_probability("kidnap_prob", kidnap_prob)
        self.grid = grid
        self.sensor = sensor
        self.n_layers = int(n_layers)
        self.name = name
        self.action_dependent = bool(action_dependent)
        self.layer_names = tuple(layer_names) if layer_names else tuple(str(i) for i in range(self.n_layers))
        self.params = dict(params or {})
        # No copies: merge_terms keeps the given arrays (read-only) where nothing merges.
        self.transitions = _share_equal(tuple(merge_terms(t) for t in transitions))
        if not self.transitions:
            raise ValueError("a model needs at least one action")
        self._check()

    @property
    def mean_transition(self) -> tuple[Term, ...]:
        """The actions' average transition (for an unknown action), built on first use: on a
        512 x 512 map it is as large as one action's."""
        mean = self.__dict__.get("_mean_transition")
        if mean is None:
            if len(self.transitions) == 1:
                mean = self.transitions[0]
            else:
                mean = merge_terms([t for terms in self.transitions for t in terms], 1.0 / len(self.transitions))
            self.__dict__["_mean_transition"] = mean
        return mean

    def with_kidnapping(self, kidnap_prob: float) -> "GridModel":
        """A copy of this model in which, after every move, the robot is teleported with
        probability ``kidnap_prob`` to a uniformly chosen free state (the kidnapped robot)."""
        import copy

        from gym_gridloc.core.validation import check_probability

        other = copy.copy(self)
        other.kidnap_prob = check_probability("kidnap_prob", kidnap_prob)
        return other

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape

    @property
    def belief_shape(self) -> tuple[int, int, int]:
        return (self.n_layers, *self.grid.shape)

    @property
    def n_actions(self) -> int:
        return len(self.transitions)

    @property
    def n_states(self) -> int:
        return self.n_layers * self.grid.n_free

    @property
    def state_mask(self) -> np.ndarray:
        return np.broadcast_to(self.grid.free, self.belief_shape)

    def __repr__(self) -> str:
        h, w = self.shape
        return f"<{self.name} {h}x{w}, {self.grid.n_free} free cells, {self.n_states} states>"

    # -- checks --------------------------------------------------------------------------------
    def _check(self) -> None:
        h, w = self.shape
        free = self.grid.free
        for a, terms in enumerate(self.transitions):
            out = np.zeros(self.belief_shape)
            for t in terms:
                if not (0 <= t.src < self.n_layers and 0 <= t.dst < self.n_layers):
                    raise ValueError(f"action {a}: a term names layer {t.src}->{t.dst}, outside 0..{self.n_layers - 1}")
                if np.any(t.weight < 0) or not np.all(np.isfinite(t.weight)):
                    raise ValueError(f"action {a}: a transition probability is negative or not finite")
                src, dst = t.slices
                inside = np.zeros((h, w), dtype=bool)
                inside[src] = free[dst]
                if np.any(t.weight[~(inside & free)] != 0):
                    raise ValueError(f"action {a}: a transition leaves the free cells (shift {t.dr},{t.dc})")
                out[t.src] += t.weight
            bad = np.abs(out[:, free] - 1.0) > _TOL
            if np.any(bad):
                raise ValueError(f"action {a}: transition rows do not sum to 1 (largest error {np.abs(out[:, free] - 1).max():.3g})")

    # -- state vectors ---------------------------------------------------------------------------
    def to_vector(self, belief: np.ndarray) -> np.ndarray:
        """(L, H, W) array -> (S,) vector over free states, ordered layer-major."""
        return np.asarray(belief).reshape(self.belief_shape)[:, self.grid.free].reshape(-1)

    def from_vector(self, vector: np.ndarray) -> np.ndarray:
        """(S,) vector -> (L, H, W) array, zero on obstacles."""
        out = np.zeros(self.belief_shape)
        out[:, self.grid.free] = np.asarray(vector, dtype=np.float64).reshape(self.n_layers, -1)
        return out

    def state_index(self, state: tuple[int, int, int]) -> int:
        layer, r, c = state
        return int(layer * self.grid.n_free + self.grid.cell_index[r, c])

    def state_of_index(self, s: int) -> tuple[int, int, int]:
        layer, i = divmod(int(s), self.grid.n_free)
        r, c = self.grid.free_cells[i]
        return int(layer), int(r), int(c)

    def prior(self) -> np.ndarray:
        """Uniform over free states, (L, H, W)."""
        return np.where(self.state_mask, 1.0 / self.n_states, 0.0)

    # -- the filter's side -----------------------------------------------------------------------
    def terms(self, action: int | None) -> tuple[Term, ...]:
        if action is None:
            return self.mean_transition
        return self.transitions[self.check_action(action)]

    def check_action(self, action: Any) -> int:
        try:
            a = int(action)
        except (TypeError, ValueError):
            raise TypeError(f"action must be an integer in 0..{self.n_actions - 1}, got {action!r}") from None
        if a != action or not 0 <= a < self.n_actions:
            raise ValueError(f"action must be an integer in 0..{self.n_actions - 1} (0=N, 1=E, 2=S, 3=W), got {action!r}")
        return a

    def flat_plan(self, action: int | None) -> tuple[tuple[bool, int, int, int, int, np.ndarray], ...]:
        """The stencil of ``action`` as shifts of the flattened (L*H*W) belief, cached.

        A shift (dr, dc) is the flat offset ``dr*W + dc``: the cells where that wraps round a
        row edge have weight 0 (a term never leaves the grid, see :meth:`_check`), so one
        contiguous slice per term gives exactly the 2-D result while reading contiguous memory.
        Returns ``(zero_layers, entries)``; an entry is ``(first, src_lo, dst_lo, n, weight_slice)``
        over flat indices: ``first`` marks a (0, 0) term that covers its whole destination layer
        and is written rather than added (such terms come first); ``zero_layers`` are the layers
        no such term covers, cleared first.  Used by :class:`BatchFilter`'s batched numpy path.
        """
        key = -1 if action is None else self.check_action(action)
        cache = self.__dict__.setdefault("_flat_plans", {})
        plan = cache.get(key)
        if plan is not None:
            return plan
        h, w = self.shape
        hw = h * w
        firsts, rest, covered = [], [], set()
        for t in self.terms(action):
            off = t.dr * w + t.dc
            wf = t.weight.reshape(-1)
            s0, d0 = (0, off) if off >= 0 else (-off, 0)
            n = hw - abs(off)
            entry = (t.src * hw + s0, t.dst * hw + d0, n, wf[s0 : s0 + n])
            if off == 0 and t.dst not in covered:
                covered.add(t.dst)
                firsts.append((True, *entry))
            else:
                rest.append((False, *entry))
        zero = tuple(layer for layer in range(self.n_layers) if layer not in covered)
        plan = (zero, tuple(firsts) + tuple(rest))
        cache[key] = plan
        return plan

    def stencil_plan(self, action: int | None):
        """The plan that applies ``action``'s transition (None: the average) to a flat belief,
        cached: compiled (numba) on small models, scipy's diagonal kernel on the others
        (:func:`gym_gridloc.kernels.uses_numba` decides; :mod:`gym_gridloc.kernels`)."""
        kernels = _kernels()
        cache = self.__dict__.get("_stencil_plans")
        if cache is None:
            cache = self.__dict__["_stencil_plans"] = {}
        numba = kernels.uses_numba(self)
        plan = cache.get((numba, action)) if action is None or type(action) is int else None
        if plan is None:
            key = (numba, None if action is None else self.check_action(action))
            plan = cache.get(key)
            if plan is None:
                plan = cache[key] = kernels.make_plan(self, self.terms(key[1]))
        return plan

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_flat_plans", None)  # views into the weights: rebuilt on demand
        state.pop("_stencil_plans", None)
        return state

    def predict(self, belief: np.ndarray, action: int | None, out: np.ndarray | None = None) -> np.ndarray:
        """One transition step of an (L, H, W) belief (sum over the stencil's shifted arrays).

        ``out`` (a C-contiguous (L, H, W) float64 array, not ``belief``) receives the result
        without a new allocation.  The plan of :meth:`stencil_plan` does the work.
        """
        belief = np.ascontiguousarray(belief, dtype=np.float64)
        if belief.size != self.n_layers * self.grid.free.size:
            raise ValueError(f"belief must have shape {self.belief_shape}, got {belief.shape}")
        if out is None:
            out = np.empty(self.belief_shape)
        elif out.dtype != np.float64 or not out.flags.c_contiguous or out.size != belief.size or np.may_share_memory(out, belief):
            raise ValueError(f"out must be a C-contiguous float64 array of shape {self.belief_shape}, apart from belief")
        self.stencil_plan(action).run(belief, out, None)
        if self.kidnap_prob > 0.0:
            out *= 1.0 - self.kidnap_prob
            out += (self.kidnap_prob / self.n_states) * belief.sum() * self.state_mask
        return out

    def backward(self, message: np.ndarray, action: int | None) -> np.ndarray:
        """The transpose of :meth:`predict`: ``out[s] = sum_s' T[s, s'] * message[s']`` for an
        (L, H, W) message (the backward pass of smoothing; kidnapping included)."""
        out = np.zeros_like(message)
        for t in self.terms(action):
            src, dst = t.slices
            out[t.src][src] += t.weight[src] * message[t.dst][dst]
        if self.kidnap_prob > 0.0:
            out *= 1.0 - self.kidnap_prob
            out += (self.kidnap_prob / self.n_states) * float(message[self.state_mask].sum()) * self.state_mask
        return out

    def likelihood(self, reading: int) -> np.ndarray:
        """P(reading | position) as an (H, W) array, zero on obstacles."""
        return self.sensor.likelihood(reading)

    def transition_matrix(self, action: int | None = None):
        """The transition of ``action`` (None: the average over actions) as a ``scipy.sparse``
        CSR matrix ``T[s, s'] = P(s' | s)`` over the free states."""
        from scipy import sparse

        rows, cols, vals = [], [], []
        index = self.grid.cell_index
        n = self.grid.n_free
        for t in self.terms(action):
            rr, cc = np.nonzero(t.weight)
            rows.append(t.src * n + index[rr, cc])
            cols.append(t.dst * n + index[rr + t.dr, cc + t.dc])
            vals.append(t.weight[rr, cc])
        S = self.n_states
        m = sparse.coo_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(S, S)
        ).tocsr()
        if self.kidnap_prob > 0.0:  # teleporting makes every row dense
            m = sparse.csr_matrix((1.0 - self.kidnap_prob) * m.toarray() + self.kidnap_prob / S)
        return m

    def likelihood_vector(self, reading: int) -> np.ndarray:
        """P(reading | state) for every free state, (S,)."""
        return np.tile(self.likelihood(reading)[self.grid.free], self.n_layers)

    # -- the simulator's side --------------------------------------------------------------------
    def sample_initial_state(self, rng: np.random.Generator) -> tuple[int, int, int]:
        s = int(rng.integers(self.n_states))
        return self.state_of_index(s)

    def outcomes(self, state: tuple[int, int, int], action: int | None) -> list[tuple[tuple[int, int, int], float]]:
        """The next states of ``state`` under ``action`` with their probabilities (non-zero only)."""
        layer, r, c = state
        out = []
        for t in self.terms(action):
            if t.src == layer:
                p = float(t.weight[r, c])
                if p > 0.0:
                    out.append(((t.dst, r + t.dr, c + t.dc), p))
        return out

    def sample_next_state(self, state: tuple[int, int, int], action: int, rng: np.random.Generator) -> tuple[int, int, int]:
        if self.kidnap_prob > 0.0 and rng.random() < self.kidnap_prob:
            return self.sample_initial_state(rng)
        outcomes = self.outcomes(state, action)
        u = rng.random() * sum(p for _, p in outcomes)
        acc = 0.0
        for nxt, p in outcomes:
            acc += p
            if u < acc:
                return nxt
        return outcomes[-1][0]

    def sample_reading(self, state: tuple[int, int, int], rng: np.random.Generator) -> int:
        _, r, c = state
        return self.sensor.sample(r, c, rng)
