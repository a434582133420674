"""What the engine derives from a model, cached per model object (never stored on the model: a
:class:`~gym_gridloc.GridModel` is frozen data; the cache holds the model weakly, so a redrawn map
is freed): the plan of its kernel (:mod:`gym_gridloc.kernels`), the average transition, the
sampler's tables of every action's terms, single readings' likelihoods, every reading's first
posterior, and the engine's bound functions.  With it, what the engine's modules
(:mod:`gym_gridloc.engine`, :mod:`gym_gridloc.sampling`, :mod:`gym_gridloc.bank`) share: the
model and action checks, the likelihoods of N readings and the impossible-observation error.
"""

from __future__ import annotations

import functools
import weakref
from typing import Any

import numpy as np

from gym_gridloc import kernels
from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.grid import read_only
from gym_gridloc.core.model import GridModel, Term, mean_transition
from gym_gridloc.core.validation import whole_numbers


class Derived:
    """What the engine derives from one model, built on first use.  It holds the model weakly (the
    model is the key it is cached under)."""

    #: At most this many bytes of single-reading likelihoods are kept per model.
    LIK_CACHE_BYTES = 8 * 2**20

    def __init__(self, model: GridModel) -> None:
        self.model = weakref.ref(model)
        #: The likelihoods of single readings kept so far (by reading).
        self.liks: dict[int, np.ndarray] = {}
        self._lik_bytes = 0
        self.layered = int(model.sensor.layered)
        #: The engine's bound functions of this model: steppers (by ``normalise``).
        self.steppers: dict[bool, Any] = {}
        self._first: tuple[np.ndarray, np.ndarray] | None = None
        self._first_asked = False  # a model used once (a map of one episode) never builds the table
        #: One state's outcomes under one action, keyed ``(action, layer, row, col)``:
        #: ``(cumulative probabilities, last possible outcome)`` (one-state draws).
        self.outcomes: dict[tuple[int, int, int, int], tuple[tuple[float, ...], int]] = {}

    def lik(self, reading: int) -> np.ndarray:
        """The flat likelihood of one reading (cached while the cache is small)."""
        lik = self.liks.get(reading)
        if lik is None:
            lik = read_only(np.ascontiguousarray(self.model().sensor.likelihood(reading), dtype=np.float64).reshape(-1))
            if self._lik_bytes + lik.nbytes <= self.LIK_CACHE_BYTES:
                self.liks[reading] = lik
                self._lik_bytes += lik.nbytes
        return lik

    @functools.cached_property
    def transitions(self) -> tuple[tuple[Term, ...], ...]:
        """Every action's terms; index n_actions is the unknown action: the average of the others
        (built on first use of the plan, as large as one action's terms on a 512 x 512 map)."""
        transitions = self.model().transitions
        return (*transitions, mean_transition(transitions))

    @functools.cached_property
    def moves(self) -> tuple[np.ndarray, np.ndarray]:
        """The sampler's tables, every action's terms in their order padded to ``K`` (zero weight):
        ``weights`` ``(A + 1, K, H*W)`` and ``keys`` ``(A + 1, 4, K)`` (source layer, destination
        layer, row shift, column shift; a padding term's source is -1): :func:`gym_gridloc.kernels.padded`.
        With the compiled filter they are its plan's (one copy: the filter's weights are these)."""
        model = self.model()
        if kernels.uses_numba(model.n_layers * model.shape[0] * model.shape[1]):
            plan = self.plan
            return plan.w, plan.keys
        weights, keys = kernels.padded(self.transitions, model.shape)
        return weights, np.ascontiguousarray(keys[:, :4])

    #: :func:`~gym_gridloc.engine.first_posterior` keeps every reading's posterior when (readings x cells) is at most this.
    FIRST_TABLE_MAX = 2**18

    def first_table(self, now: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
        """``(posteriors (R, L*H*W), possible (R,))`` of the prior and each reading, built on the
        second request (a model used once, e.g. a map of one episode, never builds it) or at once
        (``now``); None when too large."""
        if self._first is None:
            model = self.model()
            R, size = model.sensor.n_readings, int(np.prod(model.belief_shape))
            if R * size > self.FIRST_TABLE_MAX or not (self._first_asked or now):
                self._first_asked = True
                return None
            flat = np.broadcast_to(model.prior().reshape(1, -1), (R, size)).copy()
            post = weighted(model, flat, likelihoods(model, np.arange(R)))
            z = post.sum(axis=1)
            ok = (z > 0.0) & np.isfinite(z)
            np.divide(post, np.where(ok, z, 1.0)[:, None], out=post)
            self._first = (read_only(post), read_only(ok))
        return self._first

    @functools.cached_property
    def plan(self) -> kernels.NumbaPlan | kernels.NumpyPlan:
        model = self.model()
        return kernels.make_plan(self.transitions, model.n_layers, model.shape)


_DERIVED: "weakref.WeakKeyDictionary[GridModel, Derived]" = weakref.WeakKeyDictionary()


def of(model: GridModel) -> Derived:
    """What the engine derives from ``model`` (checked), made on first use and kept while the model lives."""
    d = _DERIVED.get(checked_model(model))  # checked before the lookup: a str cannot be a weak key
    if d is None:
        d = _DERIVED[model] = Derived(model)
    return d


def plan(model: GridModel) -> kernels.NumbaPlan | kernels.NumpyPlan:
    """The kernel plan of ``model`` (:mod:`gym_gridloc.kernels`), built once per model."""
    return of(model).plan


def path(model: GridModel) -> str:
    """``"numba"``, ``"numpy"`` or ``"fused"``: the kernel that filters ``model`` (:mod:`gym_gridloc.kernels`)."""
    return plan(model).path


def terms(model: GridModel, action: int | None) -> tuple[Term, ...]:
    """The terms of ``action``'s transition (``None``: the actions' average, cached)."""
    if action is None:
        return of(model).transitions[model.n_actions]
    return model.transitions[model.check_action(action)]


# -- actions and shapes ------------------------------------------------------------------------------
def action_indices(model: GridModel, actions: Any, n: int) -> np.ndarray:
    """``actions`` as ``n`` plan indices (int64): each an action in ``0..A-1``, or ``A`` for an
    unknown action (``None``, alone or as an element).  A scalar applies to all ``n``."""
    A = checked_model(model).n_actions
    if type(actions) is np.ndarray and actions.dtype == np.int64 and actions.shape == (n,) and (
            n == 0 or (actions.min() >= 0 and actions.max() < A)):
        return actions  # already N plan indices (the batched callers' common case)
    if actions is None:
        return np.full(n, A, dtype=np.int64)
    if np.ndim(actions) == 0:
        return np.full(n, model.check_action(actions), dtype=np.int64)
    arr = np.asarray(actions)
    if arr.dtype == object:
        return np.array([A if a is None else model.check_action(a) for a in arr.reshape(-1)], dtype=np.int64).reshape(arr.shape)
    if arr.shape != (n,):
        raise ValueError(f"actions must be {n} actions (one per belief), got shape {arr.shape}")
    if not whole_numbers(arr):
        raise ValueError(f"actions must be integers in 0..{A - 1}, got {arr!r}")
    out = arr.astype(np.int64)
    bad = (out < 0) | (out >= A)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"action {arr[i].item()!r} of belief {i} is outside 0..{A - 1}")
    return out


def checked_model(model: Any, expected: str = "expected a GridModel") -> GridModel:
    """``model``, or a TypeError ``"<expected>, got <its type>"`` (each caller's own wording)."""
    if not isinstance(model, GridModel):
        raise TypeError(f"{expected}, got {type(model).__name__}")
    return model


def likelihoods(model: GridModel, readings: Any, out: np.ndarray | None = None) -> np.ndarray:
    """P(reading_i | state) for N readings as ``(N, H*W)`` (position sensors) or ``(N, L*H*W)``
    (sensors whose reading depends on the layer), zero on obstacles."""
    return checked_model(model).sensor.likelihoods(np.asarray(readings, dtype=np.int64).reshape(-1), out=out)


def impossible(model: GridModel, reading: int, *, label: str | None = None,
               given: str = "the belief so far") -> ImpossibleObservationError:
    """The one error for a reading of probability zero in every state the belief allows.
    ``label`` names it (default ``observation <obs> (<what it reads>)``)."""
    if label is None:
        label = f"observation {model.sensor.observation_text(int(reading))}"
    return ImpossibleObservationError(
        f"{label} is impossible under the filter's model ({model!r}) given {given}: every state "
        "that could be reached gives it probability 0 (model mismatch?)"
    )


def check_z(model: GridModel, z: np.ndarray, readings: np.ndarray) -> None:
    """Raise for the first belief of a batch whose normaliser ``z`` is not positive (1.0 where masked out)."""
    ok = (z > 0.0) & np.isfinite(z)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        text = model.sensor.observation_text(int(readings[i]))
        raise impossible(model, int(readings[i]), label=f"observation {text} of belief {i}")


def weighted(model: GridModel, flat: np.ndarray, lik: np.ndarray) -> np.ndarray:
    """Flat beliefs ``(N, L*H*W)`` times their likelihoods (``(N, H*W)``, or ``(N, L*H*W)`` layered)."""
    if lik.shape[1] == flat.shape[1]:
        return flat * lik
    return (flat.reshape(flat.shape[0], model.n_layers, -1) * lik[:, None, :]).reshape(flat.shape[0], -1)
