"""The engine: the one place where a :class:`~gym_gridloc.GridModel`'s numbers are applied.

Everything that moves a belief or a robot calls these functions: the environments, the native
vector environment, :class:`~gym_gridloc.ForwardFilter` and :class:`~gym_gridloc.BatchFilter`,
the particle filter, smoothing and Viterbi, and the lookahead policies.

* :func:`predict` -- one transition step of a belief ``(L, H, W)`` or of a batch ``(N, L, H, W)``,
  each with its own action (``None``: the action is unknown, the actions' average).  The kernel
  (numba or numpy/scipy, :mod:`gym_gridloc.kernels`) is chosen inside, for N = 1 too.
* :func:`update` and :func:`step` -- condition on readings (after predicting, for ``step``),
  normalise, and raise one :class:`~gym_gridloc.ImpossibleObservationError` when a reading has
  probability zero.
* :func:`backward` -- the transpose of :func:`predict` (the backward pass of smoothing).
* :func:`first_posterior` -- an episode's first beliefs: the prior conditioned on N readings.
* :func:`sample_initial`, :func:`sample_next`, :func:`sample_readings` -- the simulator's side,
  batched: states are ``(N, 3)`` int64 arrays of ``(layer, row, col)``.
* :func:`stepper`, :func:`sampler`, :func:`advancer`, :func:`vector_advancer` -- bound functions
  for hot loops: one belief's step, one robot's move and reading, N robots moved, read and
  filtered at once, and a vector step of N robots (moves, new episodes, readings, beliefs) as
  one compiled call; :class:`VectorBank`, the same step with each robot on its own model.

Kidnapping (``model.kidnap_prob``: after a move, the robot is teleported to a uniformly chosen free
state) is mixed in here and nowhere else: :func:`predict` and :func:`backward` mix it into the
beliefs, :func:`kidnapped` into transition probabilities (Viterbi, pomdp_py's transition model,
:func:`transition_matrix`), :func:`sample_next` draws it.

What the engine derives from a model (the plan of its kernel, the average transition, the batched
sampler's table of every action's terms) is cached here, per model object, never stored on the
model: a :class:`GridModel` is frozen data.

This module is longer than 400 lines on purpose: it is the one place where a model's numbers are
applied, so that no caller writes a prediction, an update or a sampler again.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
import weakref
from typing import Any, Callable

import numpy as np

from gym_gridloc import kernels
from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.grid import read_only
from gym_gridloc.core.model import GridModel, Term, mean_transition
from gym_gridloc.core.validation import whole_numbers

__all__ = [
    "predict", "update", "step", "backward", "kidnapped", "transition_matrix", "likelihood", "likelihoods", "impossible", "plan",
    "first_posterior", "sample_initial", "sample_next", "sample_readings", "sampler", "stepper", "advancer", "vector_advancer", "vector_bank", "VectorBank", "states_of", "simulate", "action_indices", "path", "terms",
    "checked_model",
]


class _Derived:
    """What the engine derives from one model, built on first use.  It holds the model weakly (the
    model is the key it is cached under)."""

    #: At most this many bytes of single-reading likelihoods are kept per model.
    LIK_CACHE_BYTES = 8 * 2**20

    def __init__(self, model: GridModel) -> None:
        self.model = weakref.ref(model)
        self._liks: dict[int, np.ndarray] = {}
        self._lik_bytes = 0
        self.layered = int(model.sensor.layered)
        self._steppers: dict[bool, Any] = {}
        self._sampler: Any = None
        self._first: tuple[np.ndarray, np.ndarray] | None = None
        self._first_asked = False  # a model used once (a map of one episode) never builds the table
        self._advancer: Any = None
        #: One state's outcomes under one action, keyed ``(action, layer, row, col)``:
        #: ``(cumulative probabilities, last possible outcome)`` (one-state draws).
        self.outcomes: dict[tuple[int, int, int, int], tuple[tuple[float, ...], int]] = {}

    def lik(self, reading: int) -> np.ndarray:
        """The flat likelihood of one reading (cached while the cache is small)."""
        lik = self._liks.get(reading)
        if lik is None:
            lik = read_only(np.ascontiguousarray(self.model().sensor.likelihood(reading), dtype=np.float64).reshape(-1))
            if self._lik_bytes + lik.nbytes <= self.LIK_CACHE_BYTES:
                self._liks[reading] = lik
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
        layer, row shift, column shift; a padding term's source is -1): :func:`kernels.padded`.
        With the compiled filter they are its plan's (one copy: the filter's weights are these)."""
        model = self.model()
        if kernels.uses_numba(model.n_layers * model.shape[0] * model.shape[1]):
            plan = self.plan
            return plan.w, plan.keys
        weights, keys = kernels.padded(self.transitions, model.shape)
        return weights, np.ascontiguousarray(keys[:, :4])

    #: :func:`first_posterior` keeps every reading's posterior when (readings x cells) is at most this.
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
            post = _weighted(model, flat, likelihoods(model, np.arange(R)))
            z = post.sum(axis=1)
            ok = (z > 0.0) & np.isfinite(z)
            np.divide(post, np.where(ok, z, 1.0)[:, None], out=post)
            self._first = (read_only(post), read_only(ok))
        return self._first

    @functools.cached_property
    def plan(self) -> kernels.NumbaPlan | kernels.NumpyPlan:
        model = self.model()
        return kernels.make_plan(self.transitions, model.n_layers, model.shape)


_DERIVED: "weakref.WeakKeyDictionary[GridModel, _Derived]" = weakref.WeakKeyDictionary()


def _derived(model: GridModel) -> _Derived:
    d = _DERIVED.get(checked_model(model))  # checked before the lookup: a str cannot be a weak key
    if d is None:
        d = _DERIVED[model] = _Derived(model)
    return d


def plan(model: GridModel) -> kernels.NumbaPlan | kernels.NumpyPlan:
    """The kernel plan of ``model`` (:mod:`gym_gridloc.kernels`), built once per model."""
    return _derived(model).plan


def path(model: GridModel) -> str:
    """``"numba"`` or ``"numpy"``: the kernel that filters ``model``."""
    return plan(model).path


def terms(model: GridModel, action: int | None) -> tuple[Term, ...]:
    """The terms of ``action``'s transition (``None``: the actions' average, cached)."""
    if action is None:
        return _derived(model).transitions[model.n_actions]
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


def _flat(model: GridModel, beliefs: np.ndarray, name: str = "belief") -> tuple[np.ndarray, bool]:
    """``(beliefs as (N, L*H*W) float64 C-contiguous, single)``."""
    shape = checked_model(model).belief_shape
    b = np.asarray(beliefs)
    if b.shape == shape:
        return np.ascontiguousarray(b, dtype=np.float64).reshape(1, -1), True
    if b.ndim == 4 and b.shape[1:] == shape:
        return np.ascontiguousarray(b, dtype=np.float64).reshape(b.shape[0], -1), False
    raise ValueError(f"{name} must have shape {shape} (one belief) or (N, *{shape}) (a batch), got {b.shape}")


def _out(out: np.ndarray | None, like: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    if out is None:
        return np.empty(shape)
    if out.dtype != np.float64 or not out.flags.c_contiguous or out.size != like.size or np.may_share_memory(out, like):
        raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}, apart from the beliefs")
    return out


# -- beliefs ------------------------------------------------------------------------------------------
def _kidnap(model: GridModel, mass: Any, after: np.ndarray) -> None:
    """Mix the kidnapped robot into predicted beliefs or backward messages, in place:
    ``after = (1-k) after + k/S * mass`` on the free states; ``after`` is flat ``(N, L*H*W)`` with
    masses ``(N, 1)``, or one ``(L, H, W)`` with a number."""
    k = model.kidnap_prob
    mask = model.state_mask if after.ndim == 3 else model.state_mask.reshape(1, -1)
    after *= 1.0 - k
    after += (k / model.n_states) * mass * mask


def kidnapped(model: GridModel, p: Any) -> Any:
    """Transition probabilities ``P(s' | s)`` (a number or an array, between free states) with
    the kidnapped robot mixed in: ``(1 - k) p + k / S`` (``k = model.kidnap_prob``; ``p`` as it
    is when ``k = 0``).  ``kidnapped(model, 0.0)`` is the probability of one teleport's target."""
    k = model.kidnap_prob
    return p if k == 0.0 else (1.0 - k) * p + k / model.n_states


def transition_matrix(model: GridModel, action: int | None = None):
    """The transition of ``action`` (None: the average over actions) as a ``scipy.sparse`` CSR
    matrix ``T[s, s'] = P(s' | s)`` over the free states (layer-major, as ``model.to_vector``),
    kidnapping included (:func:`kidnapped`: then every row is dense)."""
    from scipy import sparse

    checked_model(model)
    rows, cols, vals = [], [], []
    index, n, S = model.grid.cell_index, model.grid.n_free, model.n_states
    for t in terms(model, action):
        rr, cc = np.nonzero(t.weight)
        rows.append(t.src * n + index[rr, cc])
        cols.append(t.dst * n + index[rr + t.dr, cc + t.dc])
        vals.append(t.weight[rr, cc])
    m = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(S, S)).tocsr()
    if model.kidnap_prob > 0.0:  # teleporting makes every row dense
        m = sparse.csr_matrix(kidnapped(model, m.toarray()))
    return m


def predict(model: GridModel, beliefs: np.ndarray, actions: Any = None, out: np.ndarray | None = None) -> np.ndarray:
    """One transition step ``T_a^T b`` of a belief ``(L, H, W)`` or a batch ``(N, L, H, W)``.

    ``actions``: an action (or ``None``, unknown) for one belief; for a batch, N actions or one
    for all.  ``out`` (C-contiguous float64 of the same shape, not the beliefs) receives the
    result without a new allocation.  The mass of each belief is kept.
    """
    flat, single = _flat(model, beliefs)
    n = flat.shape[0]
    acts = action_indices(model, actions, n)
    res = _out(out, flat, np.shape(beliefs) if single else (n, *model.belief_shape))
    res2 = res.reshape(n, -1)
    p = plan(model)
    if single:
        p.run_one(flat[0], int(acts[0]), _NO_LIK, 0, res2[0], 0)
    else:
        p.run(flat, acts, _no_liks(n), 0, res2, 0, _all(n))
    if model.kidnap_prob > 0.0:
        _kidnap(model, flat.sum(axis=1, keepdims=True), res2)
    return res


def backward(model: GridModel, messages: np.ndarray, action: int | None) -> np.ndarray:
    """The transpose of :func:`predict` for one ``(L, H, W)`` message:
    ``out[s] = sum_s' T[s, s'] * message[s']`` (the backward pass of smoothing; kidnapping
    included)."""
    checked_model(model)
    msg = np.asarray(messages, dtype=np.float64)
    out = np.zeros_like(msg)
    for t in terms(model, action):
        src, dst = t.slices
        out[t.src][src] += t.weight[src] * msg[t.dst][dst]
    if model.kidnap_prob > 0.0:
        _kidnap(model, float(msg[model.state_mask].sum()), out)
    return out


def likelihood(model: GridModel, reading: int) -> np.ndarray:
    """P(reading | state) of one reading as ``(H, W)`` (position sensors) or ``(L, H, W)``
    (layered), cached per model while the cache is small (read-only: do not write into it)."""
    d = _derived(model)
    return d.lik(int(reading)).reshape(model.belief_shape if d.layered else model.shape)


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


def _check_z(model: GridModel, z: np.ndarray, readings: np.ndarray) -> None:
    """Raise for the first belief of a batch whose normaliser ``z`` is not positive (1.0 where masked out)."""
    ok = (z > 0.0) & np.isfinite(z)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        text = model.sensor.observation_text(int(readings[i]))
        raise impossible(model, int(readings[i]), label=f"observation {text} of belief {i}")


def update(model: GridModel, beliefs: np.ndarray, readings: Any) -> np.ndarray:
    """Condition beliefs ``(L, H, W)`` or ``(N, L, H, W)`` on readings (one per belief), in place,
    normalised; returns the normalisers ``P(reading | belief)`` (N,).  On a reading of probability
    zero the beliefs are left as they were and :class:`ImpossibleObservationError` names it."""
    b = np.asarray(beliefs)
    if b.dtype != np.float64 or not b.flags.c_contiguous:
        raise ValueError("update() works in place: beliefs must be a C-contiguous float64 array")
    flat, single = _flat(model, b)
    n = flat.shape[0]
    rs = np.asarray(readings, dtype=np.int64).reshape(-1)
    if rs.size != n:
        raise ValueError(f"update() needs one reading per belief: {n} beliefs, {rs.size} readings")
    if single:  # one belief: the same numbers, with fewer array operations
        lik = _derived(model).lik(int(rs[0]))
        post = flat[0] * lik if lik.size == flat.shape[1] else (flat.reshape(model.n_layers, -1) * lik).reshape(-1)
        z1 = float(post.sum())
        if not (z1 > 0.0 and z1 < math.inf):
            raise impossible(model, int(rs[0]))
        np.divide(post, z1, out=flat[0])
        return np.array([z1])
    post = _weighted(model, flat, likelihoods(model, rs))
    z = post.sum(axis=1)
    _check_z(model, z, rs)
    np.divide(post, z[:, None], out=flat)
    return z


def _weighted(model: GridModel, flat: np.ndarray, lik: np.ndarray) -> np.ndarray:
    """Flat beliefs ``(N, L*H*W)`` times their likelihoods (``(N, H*W)``, or ``(N, L*H*W)`` layered)."""
    if lik.shape[1] == flat.shape[1]:
        return flat * lik
    return (flat.reshape(flat.shape[0], model.n_layers, -1) * lik[:, None, :]).reshape(flat.shape[0], -1)


def first_posterior(model: GridModel, readings: Any) -> np.ndarray:
    """The beliefs after the first reading of an episode: the prior conditioned on each of N
    ``readings``, ``(N, L, H, W)`` (what :func:`update` gives on N copies of ``model.prior()``,
    the same numbers).  From the second call on a model, while (readings x cells) is small, the
    posterior of every reading is computed once and each call is a gather."""
    d = _derived(model)
    rs = np.asarray(readings, dtype=np.int64).reshape(-1)
    table = d.first_table()
    if table is None:
        post = np.broadcast_to(model.prior(), (rs.size, *model.belief_shape)).copy()
        update(model, post, rs)
        return post
    posts, ok = table
    bad = ~ok.take(rs, mode="clip") | (rs < 0) | (rs >= ok.size)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if not 0 <= rs[i] < ok.size:
            raise ValueError(f"reading {rs[i]} of belief {i} is outside 0..{ok.size - 1}")
        raise impossible(model, int(rs[i]), label=f"observation {model.sensor.observation_text(int(rs[i]))} of belief {i}")
    return posts.take(rs, axis=0).reshape(rs.size, *model.belief_shape)


def step(model: GridModel, beliefs: np.ndarray, actions: Any, readings: Any, out: np.ndarray | None = None,
         *, normalise: bool = True, mask: np.ndarray | None = None):
    """Predict each belief with its action, then condition it on its reading: ``(out, z)``.

    ``beliefs`` ``(L, H, W)`` (then ``z`` is a float) or ``(N, L, H, W)`` (then ``z`` is (N,));
    ``z`` is ``P(reading | belief, action)``.  With ``normalise=False`` the result is left
    multiplied by ``z`` (the caller divides later).  ``mask`` (N booleans) limits the step to
    some beliefs (the other rows of ``out`` are left as they were).  On an impossible reading
    nothing the caller holds changes (``out`` may be overwritten) and
    :class:`ImpossibleObservationError` names it.
    """
    flat, single = _flat(model, beliefs)
    if single:
        res = _out(out, flat, model.belief_shape)
        return res, stepper(model, normalise=normalise)(flat, actions, int(readings), res)
    d, n = _derived(model), flat.shape[0]
    acts = action_indices(model, actions, n)
    rs = np.asarray(readings, dtype=np.int64).reshape(-1)
    if rs.size != n:
        raise ValueError(f"step() needs one reading per belief: {n} beliefs, {rs.size} readings")
    sel = _all(n) if mask is None else np.asarray(mask, dtype=bool)
    if mask is not None:
        acts, rs = np.where(sel, acts, 0), np.where(sel, rs, 0)
    res = _out(out, flat, (n, *model.belief_shape))
    res2 = res.reshape(n, -1)
    lik = likelihoods(model, rs)
    if model.kidnap_prob > 0.0:
        z = _mixed_step(model, d, flat, acts, lik, res2, normalise, sel)
    else:
        z = d.plan.run(flat, acts, lik, d.layered, res2, 1 if normalise else 2, sel)
    _check_z(model, z, rs)
    return res, z


def _mixed_step(model: GridModel, d: _Derived, flat: np.ndarray, acts: np.ndarray, lik: np.ndarray,
                out: np.ndarray, normalise: bool, sel: np.ndarray) -> np.ndarray:
    """:func:`step` with kidnapping: predict, mix, then weigh (the kernels' fused pass cannot mix)."""
    keep = None if sel.all() else out[~sel].copy()
    d.plan.run(flat, acts, _no_liks(flat.shape[0]), 0, out, 0, sel)
    _kidnap(model, flat.sum(axis=1, keepdims=True), out)
    z = kernels.weigh(out, lik, d.layered, model.n_layers, 1 if normalise else 2)
    if keep is not None:
        out[~sel] = keep
        z[~sel] = 1.0
    return z


def stepper(model: GridModel, *, normalise: bool = True) -> Callable[[np.ndarray, Any, int, np.ndarray], float]:
    """:func:`step` for one belief as a bound function ``(belief, action, reading, out) -> z``,
    for hot loops (the single filter): ``belief`` and ``out`` C-contiguous float64 arrays of the
    belief's ``L*H*W`` values, ``(L, H, W)`` or flat (not checked), ``action`` an int or None,
    ``reading`` an int.  Normalising multiplies by ``1.0 / z`` (both kernels), except with
    kidnapping, which divides by ``z``; :class:`~gym_gridloc.ForwardFilter` relies on it."""
    d = _derived(model)
    if normalise not in d._steppers:
        d._steppers[normalise] = _make_stepper(model, d, normalise)
    return d._steppers[normalise]


def _make_stepper(model: GridModel, d: _Derived, normalise: bool):
    n_actions, layered, mode = model.n_actions, d.layered, 1 if normalise else 2
    lik_of, liks = d.lik, d._liks
    # The model's cache keeps this stepper: holding the model strongly here would keep it forever.
    run_one = d.plan.run_one
    mixed = model.kidnap_prob > 0.0
    model_ref = weakref.ref(model)
    del model

    def step_one(belief: np.ndarray, action: Any, reading: int, out: np.ndarray) -> float:
        if type(action) is int and 0 <= action < n_actions:
            a = action
        elif action is None:
            a = n_actions
        else:
            a = model_ref().check_action(action)
        lik = liks.get(reading)
        if lik is None:
            lik = lik_of(int(reading))
        if mixed:
            z = float(_mixed_step(model_ref(), d, belief.reshape(1, -1), np.array([a]), lik[None], out.reshape(1, -1),
                                  normalise, _all(1))[0])
        else:
            z = run_one(belief, a, lik, layered, out, mode)
        if not (z > 0.0 and z < math.inf):
            raise impossible(model_ref(), int(reading))
        return z

    return step_one


_NO_LIK = np.zeros(1)


@functools.cache
def _no_liks(n: int) -> np.ndarray:
    return np.zeros((n, 1))


@functools.cache
def _all(n: int) -> np.ndarray:
    return read_only(np.ones(n, dtype=bool))


# -- the simulator's side -----------------------------------------------------------------------------
def states_of(model: GridModel, indices: np.ndarray) -> np.ndarray:
    """State indices (layer-major over free cells, as :meth:`GridModel.to_vector` orders them)
    as ``(N, 3)`` states (layer, row, col)."""
    layer, cell = np.divmod(np.asarray(indices, dtype=np.int64).reshape(-1), model.grid.n_free)
    out = np.empty((layer.size, 3), dtype=np.int64)
    out[:, 0] = layer
    out[:, 1:] = model.grid.free_cells[cell]
    return out


def sample_initial(model: GridModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` hidden states drawn uniformly over the free states, ``(n, 3)`` (layer, row, col)."""
    return states_of(checked_model(model), rng.integers(model.n_states, size=n))


def sample_next(model: GridModel, states: np.ndarray, actions: Any, rng: np.random.Generator) -> np.ndarray:
    """The next hidden states of ``states`` ``(N, 3)`` under ``actions`` (N, or one for all;
    ``None``: unknown), drawn from the model's transition (kidnapping included).

    Random numbers, in this order: with kidnapping, one uniform per state (kidnapped if below
    ``kidnap_prob``) and a uniform state for each kidnapped one; then one uniform per moving
    state, which picks the next state by the cumulative probabilities of the action's terms in
    their order.
    """
    d = _derived(model)  # checks the model
    transitions = d.transitions
    st = np.asarray(states, dtype=np.int64).reshape(-1, 3)
    n = st.shape[0]
    if n == 1 and model.kidnap_prob == 0.0 and type(actions) is int and 0 <= actions < model.n_actions:
        # one state: the same draw, without array overheads
        return np.array([_next_one(transitions[actions], st[0], rng, d.outcomes, actions)], dtype=np.int64)
    acts = action_indices(model, actions, n)
    out = st.copy()
    moving = np.arange(n)
    if model.kidnap_prob > 0.0:
        kidnapped = rng.random(n) < model.kidnap_prob
        if kidnapped.any():
            out[kidnapped] = sample_initial(model, int(kidnapped.sum()), rng)
            moving = np.flatnonzero(~kidnapped)
    if moving.size == 1:
        i = int(moving[0])
        a = int(acts[i])
        out[i] = _next_one(transitions[a], st[i], rng, d.outcomes, a)
        return out
    if moving.size == 0:
        return out
    u = rng.random(moving.size)
    weights, keys = d.moves
    fast = kernels.compiled(model.n_layers * model.shape[0] * model.shape[1])
    if fast is not None:  # one compiled pass, the same arithmetic (tests/test_readout.py)
        if moving.size == n:
            fast.sample_moves(weights, keys, acts, st, u, model.shape[1], out)
        else:
            moved = np.empty((moving.size, 3), dtype=np.int64)
            fast.sample_moves(weights, keys, acts[moving], st[moving], u, model.shape[1], moved)
            out[moving] = moved
        return out
    acts, st_m = acts[moving], st[moving]
    p = weights[acts, :, st_m[:, 1] * model.shape[1] + st_m[:, 2]]  # (n, K): each state's action's terms
    key = keys[acts]  # (n, 4, K)
    p[key[:, 0] != st_m[:, :1]] = 0.0  # terms of another source layer
    cum = np.cumsum(p, axis=1)
    below = (u * cum[:, -1])[:, None] < cum
    k = np.argmax(below, axis=1)
    none = ~below.any(axis=1)
    if none.any():  # u * total rounded up to the total: the last possible outcome
        k[none] = p.shape[1] - 1 - np.argmax((p[none] > 0)[:, ::-1], axis=1)
    chosen = np.take_along_axis(key, k[:, None, None], axis=2)[:, :, 0]  # (n, 4)
    out[moving] = chosen[:, 1:] + st_m * (0, 1, 1)  # (destination layer, row + dr, col + dc)
    return out


#: At most this many single states' outcomes are kept per model (for one-state draws).
OUTCOMES_CACHED = 1 << 16


def _next_one(ts: tuple[Term, ...], state: np.ndarray, rng: np.random.Generator,
              cache: dict | None = None, action: int = -1) -> tuple[int, int, int]:
    """:func:`sample_next` for one moving state ``(3,)`` (an array, or a tuple of ints) (the same
    uniform and arithmetic, on scalars).  ``cache`` (keyed by ``action`` and the state) keeps each
    state's cumulative sums."""
    layer, r, c = state.tolist() if type(state) is np.ndarray else state
    x = rng.random()
    key = (action, layer, r, c)
    found = None if cache is None else cache.get(key)
    if found is None:
        p = [float(t.weight[r, c]) if t.src == layer else 0.0 for t in ts]
        cum = tuple(itertools.accumulate(p))  # summed left to right, as np.cumsum does (a tuple of floats: not tracked by the GC)
        found = cum, max(j for j, q in enumerate(p) if q > 0.0)
        if cache is not None and len(cache) < OUTCOMES_CACHED:
            cache[key] = found
    cum, last = found
    k = bisect.bisect_right(cum, x * cum[-1])  # the first term whose cumulative sum exceeds x * total
    if k == len(cum):  # x rounded up to the total: the last possible outcome
        k = last
    t = ts[k]
    return t.dst, r + t.dr, c + t.dc


def sampler(model: GridModel) -> Callable[[tuple[int, int, int], Any, np.random.Generator], tuple[tuple[int, int, int], int]]:
    """:func:`sample_next` then :func:`sample_readings` for ONE state as a bound function
    ``(state, action, rng) -> (next state, reading)``, for hot loops (the single environment):
    ``state`` a tuple ``(layer, row, col)`` of ints, the result a tuple and an ``int``; the same
    random draws and numbers as the batched functions with N = 1."""
    d = _derived(model)
    if d._sampler is None:
        d._sampler = _make_sampler(model, d)
    return d._sampler


def _make_sampler(model: GridModel, d: _Derived):
    transitions, outcomes, n_actions = d.transitions, d.outcomes, model.n_actions
    read = model.sensor.sample_one
    scalar = model.kidnap_prob == 0.0
    model_ref = weakref.ref(model)  # (the model's cache keeps this function)
    del model

    def sample_one(state: tuple[int, int, int], action: Any, rng: np.random.Generator):
        if scalar and type(action) is int and 0 <= action < n_actions:
            nxt = _next_one(transitions[action], state, rng, outcomes, action)
        else:  # kidnapping, or an action to check: the batched draw of one
            nxt = tuple(sample_next(model_ref(), np.array([state], dtype=np.int64), action, rng)[0].tolist())
        return nxt, read(nxt, rng)

    return sample_one


def advancer(model: GridModel) -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """:func:`sample_next`, :func:`sample_readings` and :func:`step` for N robots and their
    beliefs as one bound function, for hot loops (the native vector environment):
    ``(states, actions, beliefs, out, rng) -> (next states, readings)``.  ``states`` ``(N, 3)``
    int64, ``actions`` N int64 actions in ``0..A-1`` (not checked: the caller has), ``beliefs``
    and ``out`` C-contiguous float64 ``(N, L*H*W)``, apart; ``out`` receives the normalised
    posteriors.  The same random draws and numbers as the three functions; an impossible reading
    raises as :func:`step` does (it cannot happen to readings drawn from the model)."""
    d = _derived(model)
    if d._advancer is None:
        d._advancer = _make_advancer(model, d)
    return d._advancer


def _make_advancer(model: GridModel, d: _Derived):
    fast = kernels.compiled(model.n_layers * model.shape[0] * model.shape[1])
    plan_ = d.plan
    model_ref = weakref.ref(model)  # (the model's cache keeps this function)
    if fast is None or model.kidnap_prob > 0.0 or not isinstance(plan_, kernels.NumbaPlan):
        del model

        def advance_generic(states, actions, beliefs, out, rng):
            m = model_ref()
            nxt = sample_next(m, states, actions, rng)
            readings = sample_readings(m, nxt, rng)
            shape = (-1, *m.belief_shape)
            step(m, beliefs.reshape(shape), actions, readings, out=out.reshape(shape))
            return nxt, readings

        return advance_generic
    weights, keys = d.moves
    width, layered, n_layers = model.shape[1], d.layered, model.n_layers
    sample, liks_of = model.sensor.sample, model.sensor.likelihoods
    w, meta, batch, moves = plan_.w, plan_.meta, fast.batch_update, fast.sample_moves
    del model

    def advance(states, actions, beliefs, out, rng):
        n = states.shape[0]
        nxt = np.empty((n, 3), dtype=np.int64)
        moves(weights, keys, actions, states, rng.random(n), width, nxt)
        readings = sample(nxt, rng)
        z = np.empty(n)
        batch(beliefs, w, meta, actions, liks_of(readings), layered, out, n_layers, 1, _all(n), z)
        if not ((z > 0.0) & (z < math.inf)).all():  # (NaN fails both)
            _check_z(model_ref(), z, readings)
        return nxt, readings

    return advance


def vector_advancer(model: GridModel) -> Callable[..., None] | None:
    """A vector step of N robots on ``model`` as one compiled call, for the native vector
    environment: ``(states, readings, actions, beliefs, out, modes, rng)``.  Row ``i``
    with ``modes[i]`` 0 moves under ``actions[i]``, reads, and ``out[i]`` receives its normalised
    posterior (:func:`sample_next`, :func:`sample_readings`, :func:`step`); 1 starts an episode
    (:func:`sample_initial`, :func:`sample_readings`, :func:`first_posterior`); 2 keeps its state,
    reading and belief.  ``states`` ``(N, 3)`` and ``readings`` (N,) int64 are updated in place
    (``out`` gets the kept beliefs too); ``actions`` N int64 in
    ``0..A-1`` (not checked: the caller has); ``modes`` N int8; ``beliefs`` and ``out``
    C-contiguous float64 ``(N, L*H*W)``, apart.  The same random draws and numbers as those
    functions called in that order (the moving rows, then the starting rows): a test holds them
    equal.  None when the model has no compiled path (a large grid, kidnapping, a sensor without
    :meth:`~gym_gridloc.core.sensors.Sensor.draw_table`, or too many readings for the tables).
    N robots each on its own model: :class:`VectorBank`."""
    bank = vector_bank(model, 1)
    if bank is None:
        return None

    def advance_one_model(states, readings, actions, beliefs, out, modes, rng):
        bank.advance(states, readings, actions, beliefs, out, modes, rng, np.zeros(modes.size, dtype=np.int64))

    return advance_one_model


def vector_bank(model: GridModel, n_rows: int) -> "VectorBank | None":
    """A :class:`VectorBank` for ``n_rows`` robots whose first model is ``model``, or None when
    ``model`` has no compiled vector step (see :func:`vector_advancer`)."""
    tables = _vector_tables(model)
    return None if tables is None else VectorBank(model, n_rows, tables)


def _vector_tables(model: GridModel) -> tuple[tuple[int, ...], tuple[np.ndarray, ...]] | None:
    """``(scalars, arrays)`` of :func:`_numba_vector.vector_advance` for one model, or None when
    it has no compiled path: ``scalars`` (width, layers, layered, the draw table's kind, uniforms
    per reading, states), ``arrays`` in the kernel's order (the moves' keys, the filter plan's
    weights, from which the moves are drawn too, and meta, every reading's likelihood, the
    sensor's draw table, the free cells, every reading's first posterior and whether it is
    possible), C-contiguous (a bank copies them; they are not kept: a bank of maps that never
    come again keeps one copy)."""
    d = _derived(model)
    fast = kernels.compiled(model.n_layers * model.shape[0] * model.shape[1])
    if fast is None or model.kidnap_prob > 0.0 or not isinstance(d.plan, kernels.NumbaPlan):
        return None
    draw = model.sensor.draw_table()
    first = d.first_table(now=True)
    if draw is None or first is None:
        return None
    kind, cum, total, values = draw
    posts, possible = first
    liks = likelihoods(model, np.arange(model.sensor.n_readings))
    arrays = (d.plan.keys, d.plan.w, d.plan.meta, liks, cum, total, values, model.grid.free_cells.astype(np.int64), posts, possible)
    scalars = (model.shape[1], model.n_layers, d.layered, kind, cum.shape[1] if kind == 1 else 1, model.n_states)
    return scalars, tuple(np.ascontiguousarray(a) for a in arrays)


def _vector_function(scalars: tuple[int, ...], stacked: tuple[np.ndarray, ...], model_at: Callable[[int], GridModel],
                     maze: tuple | None = None, place: Callable[[np.ndarray, np.ndarray, np.ndarray], Callable] | None = None):
    """The vector step over ``stacked`` tables (a leading slot axis):
    ``(states, readings, actions, beliefs, out, modes, rng, slots, readout=None, ending=None,
    maps=False)``; ``model_at(slot)`` names the model in an impossible reading's error.
    ``readout``: the referee's blocks (:func:`referee.readout_blocks`), which the same call fills
    for every row; ``ending`` (with ``readout``): the referee's :func:`referee.ending_blocks`,
    the same for how each row's step ends; ``maps`` (with ``maze``, a bank's ``(walls, rooms,
    code slots)``): the starting rows' maps are drawn first, in the same call, and
    ``place(codes, modes, slots)`` places the models of codes without a slot and returns the
    bank's step (its tables may have grown), which goes on (:meth:`VectorBank.draw_maps`)."""
    width, n_layers, layered, kind, per_draw, n_states = scalars
    keys, w, meta, liks, cum, total, values, free_cells, posts, possible = stacked
    kernel = kernels.compiled(1).vector_advance

    def advance(states, readings, actions, beliefs, out, modes, rng, slots, readout=None, ending=None, maps=False):
        bits = rng.bit_generator
        functions = kernels.bit_functions(bits)
        pose, threshold, scratch, kept, ints, confidence, estimate, flags, observed = _NO_READOUT if readout is None else readout
        restarted, elapsed, limit, fixed, belief, rewards, ends = _NO_ENDING if ending is None else ending
        walls, rooms, code_slots, codes = _NO_MAZE if not maps else (*maze, np.empty(modes.shape[0], dtype=np.int64))
        with bits.lock:  # (the draws are the generator's: as its own methods, under its lock)
            bad = kernel(keys, w, meta, width, n_layers, layered, liks, kind, cum, total, values, per_draw,
                         free_cells, posts, possible, slots, modes, states, actions, beliefs, out, readings, functions, n_states,
                         walls, rooms, code_slots, codes, readout is not None, pose, threshold, scratch, kept, ints,
                         confidence, estimate, flags, observed, ending is not None, restarted, elapsed, limit, fixed, belief,
                         rewards, ends)
        if bad == -2:  # new maps: their models placed, the rows' slots set; then the rest of the step
            return place(codes, modes, slots)(states, readings, actions, beliefs, out, modes, rng, slots, readout, ending)
        if bad >= 0:
            model = model_at(int(slots[bad]))
            text = model.sensor.observation_text(int(readings[bad]))
            raise impossible(model, int(readings[bad]), label=f"observation {text} of belief {bad}")

    return advance


#: The ending arguments of a vector step that computes none (the types of the real blocks).
_NO_ENDING = (np.empty(0, dtype=bool), np.empty(0, dtype=np.int64), 0, False, False, np.empty(0), np.empty((3, 0), dtype=bool))
#: The map arguments of a vector step that draws no maps (the types of the real ones).
_NO_MAZE = (np.empty((2, 0), dtype=np.int64), 1, np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))
#: The readout arguments of a vector step that reads nothing (the types of the real blocks).
_NO_READOUT = (False, 0.0, np.empty((2, 0, 1)), np.empty(0, dtype=np.int64), np.empty((5, 0), dtype=np.int64), np.empty(0), np.empty((2, 0, 2), dtype=np.int64),
               np.empty((2, 0), dtype=bool), np.empty((0, 1), dtype=np.float32))


class VectorBank:
    """The vector step of N robots each on its own model, in one compiled call: the tables of
    models of the same sizes (the first model's) stacked, one slot per model (the native vector
    environment with maps redrawn at reset); :func:`vector_bank` makes one.  :meth:`slot` places a model (its tables are copied
    once; a model already placed keeps its slot); ``advance`` is :func:`vector_advancer`'s
    step with the row's slots last: ``(states, readings, actions, beliefs, out, modes, rng,
    slots, readout=None, ending=None, maps=False)``, the same draws and numbers as
    :func:`vector_advancer` of each row's model (``readout``, ``ending``, ``maps``: see
    :meth:`draw_maps` and ``_vector_function``).

    The bank holds at most ``max(N + 1, BYTES / one model's tables)`` models; when it is full, a
    new model takes the least recently placed slot that no row uses (N rows use at most N).  It
    holds its models (strongly: the bank belongs to one vector environment).

    A bank can also draw the maps of the rows that start an episode, in the step's own call
    (:meth:`draw_maps`: mazes, by their codes, a table from each code to its slot)."""

    #: The bank's tables grow to this many bytes before slots are reused (and beyond, to N + 1 slots).
    BYTES = 32 * 2**20
    #: The most walls of the mazes whose codes :meth:`draw_maps` keeps a table of slots for (2**16 codes: 512 KiB).
    CODE_WALLS = 16

    def __init__(self, model: GridModel, n_rows: int, tables: tuple[tuple[int, ...], tuple[np.ndarray, ...]]) -> None:
        self.scalars, arrays = tables
        self.signature = self._signature(tables)
        per_model = sum(a.nbytes for a in arrays)
        self.limit = max(n_rows + 1, min(self.BYTES // max(per_model, 1), 4096))
        self.models: list[GridModel | None] = []
        self._slot_of: dict[int, int] = {}
        self._placed = np.zeros(0, dtype=np.int64)  # when each slot was last placed (its model asked for)
        self._clock = 0
        self._stacked = tuple(np.empty((0, *a.shape), dtype=a.dtype) for a in arrays)
        self._maze: tuple | None = None  # (walls, rooms, code -> slot) of draw_maps
        self._model_of_code: Callable[[int], GridModel] | None = None
        self._slot_codes: dict[int, int] = {}  # slot -> the code its model was placed for
        self._place(model, tables, np.zeros(0, dtype=np.int64))

    def draw_maps(self, walls: np.ndarray, rooms: int, model_of_code: Callable[[int], GridModel]) -> bool:
        """Let ``advance(..., maps=True)`` draw the starting rows' maps in the step's own call:
        perfect mazes on the graph of ``rooms`` rooms and ``walls`` ((2, W) int64: each wall's two
        rooms), drawn as :func:`gym_gridloc.generators.perfect_maze_codes` draws their codes (from
        the step's generator, before the step's other draws), each code's model
        ``model_of_code(code)``, placed when its code first comes (its slot then kept in a table
        of every code).  False, and nothing changes, when the table would be too large (more than
        :data:`CODE_WALLS` walls)."""
        walls = np.ascontiguousarray(walls, dtype=np.int64)
        if walls.ndim != 2 or walls.shape[0] != 2 or walls.shape[1] > self.CODE_WALLS:
            return False
        self._maze = (walls, int(rooms), np.full(1 << walls.shape[1], -1, dtype=np.int64))
        self._model_of_code = model_of_code
        self._bind()
        return True

    def _place_codes(self, codes: np.ndarray, modes: np.ndarray, slots: np.ndarray) -> Callable:
        """The slots of the starting rows (``modes`` 1, in order) for their maps' ``codes``:
        each code's model placed if its code has no slot yet (the other rows' slots kept).
        Returns the bank's step (bound again if the tables grew)."""
        table = self._maze[2]
        for i, code in zip(np.flatnonzero(modes == 1).tolist(), codes.tolist()):
            s = int(table[code])
            if s < 0:
                s = self.slot(self._model_of_code(code), slots)
                if s is None:
                    raise ValueError(f"the map of code {code} has a model of other sizes than the bank's")
                table[code] = s
                self._slot_codes[s] = code
            slots[i] = s
        return self.advance

    @staticmethod
    def _signature(tables) -> tuple:
        scalars, arrays = tables
        return scalars, tuple((a.shape, a.dtype.str) for a in arrays)

    def slot(self, model: GridModel, in_use: np.ndarray) -> int | None:
        """The slot of ``model`` (placed now if new), or None when the bank cannot hold it (no
        compiled path, or other sizes).  ``in_use``: the rows' slots, which are not reused."""
        self._clock += 1
        s = self._slot_of.get(id(model))
        if s is not None and self.models[s] is model:
            self._placed[s] = self._clock
            return s
        tables = _vector_tables(model)
        if tables is None or self._signature(tables) != self.signature:
            return None
        return self._place(model, tables, in_use)

    def _place(self, model: GridModel, tables, in_use: np.ndarray) -> int:
        s = self._free_slot(in_use)
        old = self.models[s]
        if old is not None:
            del self._slot_of[id(old)]
            code = self._slot_codes.pop(s, None)
            if code is not None:  # (its code has no slot any more)
                self._maze[2][code] = -1
        self.models[s] = model
        self._slot_of[id(model)] = s
        self._placed[s] = self._clock
        for bank, a in zip(self._stacked, tables[1]):
            bank[s] = a
        return s

    def _free_slot(self, in_use: np.ndarray) -> int:
        size = len(self.models)
        if size < self.limit:  # grow (doubling: copies amortised)
            if size == self._stacked[0].shape[0]:
                grown = min(self.limit, max(1, 2 * size))
                self._stacked = tuple(np.concatenate([a, np.empty((grown - size, *a.shape[1:]), dtype=a.dtype)]) for a in self._stacked)
                self._placed = np.concatenate([self._placed, np.zeros(grown - size, dtype=np.int64)])
                self._bind()
            self.models.append(None)
            return size
        placed = self._placed.copy()
        placed[in_use] = np.iinfo(np.int64).max  # (never a slot a row is on: N rows leave one free)
        return int(np.argmin(placed))

    def _bind(self) -> None:
        self.advance = _vector_function(self.scalars, self._stacked, lambda s: self.models[s], self._maze, self._place_codes)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("advance", "_slot_of")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._slot_of = {id(m): s for s, m in enumerate(self.models) if m is not None}
        self._bind()


def sample_readings(model: GridModel, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One reading per state ``(N, 3)``, drawn from the sensor (N,) int64."""
    return checked_model(model).sensor.sample(np.asarray(states, dtype=np.int64).reshape(-1, 3), rng)


def simulate(model: GridModel, steps: int, rng: np.random.Generator, actions: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A trajectory of one robot: ``(states (T+1, 3), actions (T,), readings (T+1,))`` with
    ``T = steps``.  ``actions`` (T of them) are taken as given; by default each is drawn uniformly
    just before its move (the same generator draws, in this order: start, first reading, then per
    step: action, move, reading)."""
    checked_model(model)
    states = np.empty((steps + 1, 3), dtype=np.int64)
    readings = np.empty(steps + 1, dtype=np.int64)
    acts = np.empty(steps, dtype=np.int64)
    st = sample_initial(model, 1, rng)
    states[0], readings[0] = st[0], sample_readings(model, st, rng)[0]
    for k in range(steps):
        a = int(rng.integers(model.n_actions)) if actions is None else model.check_action(actions[k])
        st = sample_next(model, st, a, rng)
        states[k + 1], readings[k + 1], acts[k] = st[0], sample_readings(model, st, rng)[0], a
    return states, acts, readings
