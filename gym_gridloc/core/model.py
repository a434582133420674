"""The model as data: free cells, a sparse transition per action, a likelihood per reading.

A hidden state is ``(layer, row, col)``: ``layer`` is 0 for position-only models and the heading
for models whose hidden state includes one.  A belief is held as an ``(L, H, W)`` array that is
zero on obstacles.

A transition is a tuple of :class:`Term`: "from a state in layer ``src`` at ``(r, c)``, go to
layer ``dst`` at ``(r + dr, c + dc)`` with probability ``weight[r, c]``".  This is a sparse
matrix written as a stencil: the filter's prediction is a few multiply-adds over shifted arrays,
the simulator samples the same numbers, and :func:`gym_gridloc.engine.transition_matrix` writes
them out as a ``scipy.sparse`` matrix for anyone who wants one (kidnapping mixed in there).

A :class:`GridModel` is frozen data; :mod:`gym_gridloc.engine` applies it (predict, update, sample)
and keeps what it derives from it (kernel plans) apart from it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from gym_gridloc.core.grid import DIRECTIONS, GridMap, read_only
from gym_gridloc.core.sensors import Sensor
from gym_gridloc.core.validation import check_int, check_probability, is_int

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
    return tuple(Term(*key, read_only(np.ascontiguousarray(w, dtype=np.float64)))
                 for key, w in merged.items() if np.any(w))


def mean_transition(transitions: Sequence[Sequence[Term]]) -> tuple[Term, ...]:
    """The actions' average transition (for an unknown action)."""
    if len(transitions) == 1:
        return tuple(transitions[0])
    return merge_terms([t for terms in transitions for t in terms], 1.0 / len(transitions))


def _share_equal(transitions: tuple[tuple[Term, ...], ...]) -> tuple[tuple[Term, ...], ...]:
    """The actions' terms with every weight array equal to an earlier action's weight of the
    same ``(src, dst, dr, dc)`` replaced by that array (held once: e.g. on a colour grid the
    three actions that slip north share one north weight)."""
    seen: dict[tuple[int, int, int, int], list[np.ndarray]] = {}

    def share(t: Term) -> Term:
        key = (t.src, t.dst, t.dr, t.dc)
        same = next((w for w in seen.get(key, ()) if np.array_equal(w, t.weight)), None)
        if same is None:
            seen.setdefault(key, []).append(t.weight)
            return t
        return Term(*key, same)

    return tuple(tuple(share(t) for t in terms) for terms in transitions)


def move_terms(grid: GridMap, direction_probs: np.ndarray, layer: int = 0, dst_layer: int | None = None) -> list[Term]:
    """Terms for "try direction d with probability ``direction_probs[d]``; a blocked move stays".

    ``direction_probs`` is a length-4 vector or a (4, H, W) array (a probability per cell).
    """
    dst_layer = layer if dst_layer is None else dst_layer
    h, w = grid.shape
    probs = np.broadcast_to(np.asarray(direction_probs, dtype=np.float64).reshape(4, -1, 1) if np.ndim(direction_probs) == 1 else direction_probs, (4, h, w))
    blocked = grid.blocked()
    terms = []
    stay = np.zeros((h, w))
    # One direction at a time: (4, H, W) temporaries would raise the peak memory of a 512 x 512 map.
    for d, (dr, dc) in enumerate(DIRECTIONS):
        p = np.where(grid.free, probs[d], 0.0)
        terms.append(Term(layer, dst_layer, int(dr), int(dc), np.where(blocked[d], 0.0, p)))
        stay += np.where(blocked[d], p, 0.0)
    terms.append(Term(layer, dst_layer, 0, 0, stay))
    return terms


class GridModel:
    """A hidden-Markov model on a grid: what the simulator samples and the filter multiplies.

    Frozen data: the map, one tuple of stencil terms per action, the sensor and the kidnap
    probability (and the parameters it was built with, for display).  Nothing else lives on it;
    :mod:`gym_gridloc.engine` applies it.

    Parameters
    ----------
    grid:
        The map.
    transitions:
        One tuple of :class:`Term` per action (the same tuple for every action when the action
        plays no part).  Every free state's outgoing probabilities must sum to 1.
    sensor:
        P(reading | state) and how readings map to observations.
    n_layers:
        Number of hidden states per cell (1, or 4 for a heading).
    name:
        A short name for messages and rendering.
    params:
        The builder's parameters (slip, accuracy, ...), kept for display and metadata.
    action_names:
        A short name per action, for messages (default ``N, E, S, W`` for four actions).
    kidnap_prob:
        After every move, the robot is teleported to a uniformly chosen free state with this
        probability (the kidnapped robot); 0 by default.
    """

    def __init__(
        self,
        grid: GridMap,
        transitions: Sequence[Sequence[Term]],
        sensor: Sensor,
        *,
        n_layers: int = 1,
        name: str = "GridModel",
        params: dict[str, Any] | None = None,
        action_names: Sequence[str] | None = None,
        kidnap_prob: float = 0.0,
    ) -> None:
        self.__dict__.update(
            kidnap_prob=check_probability("kidnap_prob", kidnap_prob), grid=grid, sensor=sensor, n_layers=int(n_layers),
            name=name, params=dict(params or {}),
            # No copies: merge_terms keeps the given arrays (read-only) where nothing merges.
            transitions=_share_equal(tuple(merge_terms(t) for t in transitions)),
        )
        if not self.transitions:
            raise ValueError("a model needs at least one action")
        if action_names is None:
            action_names = ("N", "E", "S", "W") if len(self.transitions) == 4 else tuple(map(str, range(len(self.transitions))))
        if len(action_names) != len(self.transitions):
            raise ValueError(f"action_names needs one name per action ({len(self.transitions)}), got {list(action_names)}")
        self.__dict__["action_names"] = tuple(action_names)
        self._check()

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"a GridModel is frozen data; cannot set {name!r} (build another model, e.g. with_kidnapping)")

    def with_kidnapping(self, kidnap_prob: float) -> "GridModel":
        """A copy of this model in which, after every move, the robot is teleported with
        probability ``kidnap_prob`` to a uniformly chosen free state (the kidnapped robot)."""
        p = check_probability("kidnap_prob", kidnap_prob)
        if p == self.kidnap_prob:
            return self
        other = object.__new__(GridModel)
        other.__dict__.update(self.__dict__, kidnap_prob=p)
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
        free = self.grid.free
        if self.sensor.grid is not self.grid and not np.array_equal(self.sensor.grid.labels, self.grid.labels):
            raise ValueError("the sensor is built on another map than the model")
        allowed: dict[tuple[int, int], np.ndarray] = {}  # per shift: the cells a term may have weight on
        checked: set[int] = set()
        for a, terms in enumerate(self.transitions):
            out = np.zeros(self.belief_shape)
            for t in terms:
                if not (0 <= t.src < self.n_layers and 0 <= t.dst < self.n_layers):
                    raise ValueError(f"action {a}: a term names layer {t.src}->{t.dst}, outside 0..{self.n_layers - 1}")
                out[t.src] += t.weight
                if id(t.weight) in checked:  # a weight array shared by several terms is checked once
                    continue
                key = (t.dr, t.dc)
                if key not in allowed:
                    src, dst = t.slices
                    inside = np.zeros(free.shape, dtype=bool)
                    inside[src] = free[dst]
                    allowed[key] = inside & free
                if not (t.weight >= 0).all() or (t.weight[~allowed[key]] != 0).any():
                    if not np.isfinite(t.weight).all() or (t.weight < 0).any():
                        raise ValueError(f"action {a}: a transition probability is negative or not finite")
                    raise ValueError(f"action {a}: a transition leaves the free cells (shift {t.dr},{t.dc})")
                checked.add(id(t.weight))
            err = np.abs(out[:, free] - 1.0)
            if not (err <= _TOL).all():  # also catches infinities and NaN
                raise ValueError(f"action {a}: transition rows do not sum to 1 (largest error {np.nanmax(err):.3g})")

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
        layer = self.grid.free * (1.0 / self.n_states)
        return layer[None] if self.n_layers == 1 else np.repeat(layer[None], self.n_layers, axis=0)

    def check_action(self, action: Any) -> int:
        """``action`` as an int in ``0..n_actions-1`` (whole numbers such as ``2.0`` too), or a
        clear error."""
        n = self.n_actions
        if is_int(action) and 0 <= action < n:  # the common case (the message is built on errors only)
            return int(action)
        return check_int("action", action, 0, n - 1, whole=True, what=f"an integer in 0..{n - 1} ({self.action_legend})")

    @property
    def action_legend(self) -> str:
        """The actions' meanings for messages, e.g. ``0=N, 1=E, 2=S, 3=W``."""
        return ", ".join(f"{i}={n}" for i, n in enumerate(self.action_names))

    # -- the transition and the sensor as numbers --------------------------------------------------
    def terms(self, action: int | None) -> tuple[Term, ...]:
        """The terms of ``action``'s transition; ``None``: the actions' average (merged on each
        call; :func:`gym_gridloc.engine.terms` caches it)."""
        if action is None:
            return mean_transition(self.transitions)
        return self.transitions[self.check_action(action)]

    def outcomes(self, state: tuple[int, int, int], action: int | None) -> list[tuple[tuple[int, int, int], float]]:
        """The next states of ``state`` under ``action`` with their probabilities (non-zero only,
        kidnapping left out)."""
        layer, r, c = state
        terms = [t for t in self.terms(action) if t.src == layer]
        return [((t.dst, r + t.dr, c + t.dc), p) for t in terms if (p := float(t.weight[r, c])) > 0.0]

    def likelihood(self, reading: int) -> np.ndarray:
        """P(reading | state): an (H, W) array for sensors that see the position only, (L, H, W)
        for sensors whose reading depends on the layer; zero on obstacles."""
        return self.sensor.likelihood(reading)

    def likelihood_vector(self, reading: int) -> np.ndarray:
        """P(reading | state) for every free state, (S,) layer-major."""
        lik = self.likelihood(reading)
        if lik.ndim == 3:
            return lik[:, self.grid.free].reshape(-1)
        return np.tile(lik[self.grid.free], self.n_layers)

