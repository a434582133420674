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
* :func:`sample_initial`, :func:`sample_next`, :func:`sample_readings`, :func:`simulate` -- the
  simulator's side, batched: states are ``(N, 3)`` int64 arrays of ``(layer, row, col)``
  (:mod:`gym_gridloc.sampling`, re-exported here).
* :func:`stepper` -- a bound function for hot loops: one belief's step (the filter's).
* :class:`VectorBank` (:func:`vector_bank`) -- the compiled step of N robots (:class:`Rows`: moves,
  new episodes, readings, beliefs, the referee's readout) in one call, each robot on its own model
  (:mod:`gym_gridloc.bank`, re-exported here); :class:`gym_gridloc.batch.Batch` calls it, or these
  functions as its numpy reference.

Kidnapping (``model.kidnap_prob``: after a move, the robot is teleported to a uniformly chosen free
state) is mixed in here and nowhere else: :func:`predict` and :func:`backward` mix it into the
beliefs, :func:`kidnapped` into transition probabilities (Viterbi, pomdp_py's transition model,
:func:`transition_matrix`); :func:`sample_next` draws it.

What the engine derives from a model (the plan of its kernel, the average transition, the batched
sampler's table of every action's terms) is cached per model object by :mod:`gym_gridloc.derived`,
never stored on the model: a :class:`GridModel` is frozen data.
"""

from __future__ import annotations

import functools
import math
import weakref
from typing import Any, Callable

import numpy as np

from gym_gridloc import derived, kernels, sampling
from gym_gridloc.bank import Rows, VectorBank, vector_bank
from gym_gridloc.core.grid import read_only
from gym_gridloc.core.model import GridModel
from gym_gridloc.derived import action_indices, checked_model, impossible, likelihoods, path, plan, terms
from gym_gridloc.sampling import OUTCOMES_CACHED, sample_initial, sample_next, sample_readings, simulate, states_of

__all__ = [
    "predict", "update", "step", "backward", "kidnapped", "transition_matrix", "likelihood", "likelihoods", "impossible", "plan",
    "first_posterior", "sample_initial", "sample_next", "sample_readings", "stepper", "vector_bank", "VectorBank", "Rows", "states_of", "simulate", "action_indices", "path", "terms",
    "checked_model", "OUTCOMES_CACHED",
]


def _flat(model: GridModel, beliefs: np.ndarray, name: str = "belief") -> tuple[np.ndarray, bool]:
    """``(beliefs as (N, L*H*W) float64 C-contiguous, single)``."""
    shape = derived.checked_model(model).belief_shape
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

    derived.checked_model(model)
    rows, cols, vals = [], [], []
    index, n, S = model.grid.cell_index, model.grid.n_free, model.n_states
    for t in derived.terms(model, action):
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
    acts = derived.action_indices(model, actions, n)
    res = _out(out, flat, np.shape(beliefs) if single else (n, *model.belief_shape))
    res2 = res.reshape(n, -1)
    p = derived.plan(model)
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
    derived.checked_model(model)
    msg = np.asarray(messages, dtype=np.float64)
    out = np.zeros_like(msg)
    for t in derived.terms(model, action):
        src, dst = t.slices
        out[t.src][src] += t.weight[src] * msg[t.dst][dst]
    if model.kidnap_prob > 0.0:
        _kidnap(model, float(msg[model.state_mask].sum()), out)
    return out


def likelihood(model: GridModel, reading: int) -> np.ndarray:
    """P(reading | state) of one reading as ``(H, W)`` (position sensors) or ``(L, H, W)``
    (layered), cached per model while the cache is small (read-only: do not write into it)."""
    d = derived.of(model)
    return d.lik(int(reading)).reshape(model.belief_shape if d.layered else model.shape)


def update(model: GridModel, beliefs: np.ndarray, readings: Any) -> np.ndarray:
    """Condition beliefs ``(L, H, W)`` or ``(N, L, H, W)`` on readings (one per belief), in place,
    normalised; returns the normalisers ``P(reading | belief)`` (N,).  On a reading of probability
    zero the beliefs are left as they were and :class:`~gym_gridloc.ImpossibleObservationError` names it."""
    b = np.asarray(beliefs)
    if b.dtype != np.float64 or not b.flags.c_contiguous:
        raise ValueError("update() works in place: beliefs must be a C-contiguous float64 array")
    flat, single = _flat(model, b)
    n = flat.shape[0]
    rs = np.asarray(readings, dtype=np.int64).reshape(-1)
    if rs.size != n:
        raise ValueError(f"update() needs one reading per belief: {n} beliefs, {rs.size} readings")
    if single:  # one belief: the same numbers, with fewer array operations
        lik = derived.of(model).lik(int(rs[0]))
        post = flat[0] * lik if lik.size == flat.shape[1] else (flat.reshape(model.n_layers, -1) * lik).reshape(-1)
        z1 = float(post.sum())
        if not (z1 > 0.0 and z1 < math.inf):
            raise derived.impossible(model, int(rs[0]))
        np.divide(post, z1, out=flat[0])
        return np.array([z1])
    post = derived.weighted(model, flat, derived.likelihoods(model, rs))
    z = post.sum(axis=1)
    derived.check_z(model, z, rs)
    np.divide(post, z[:, None], out=flat)
    return z


def first_posterior(model: GridModel, readings: Any) -> np.ndarray:
    """The beliefs after the first reading of an episode: the prior conditioned on each of N
    ``readings``, ``(N, L, H, W)`` (what :func:`update` gives on N copies of ``model.prior()``,
    the same numbers).  From the second call on a model, while (readings x cells) is small, the
    posterior of every reading is computed once and each call is a gather."""
    d = derived.of(model)
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
        raise derived.impossible(model, int(rs[i]), label=f"observation {model.sensor.observation_text(int(rs[i]))} of belief {i}")
    return posts.take(rs, axis=0).reshape(rs.size, *model.belief_shape)


def step(model: GridModel, beliefs: np.ndarray, actions: Any, readings: Any, out: np.ndarray | None = None,
         *, normalise: bool = True, mask: np.ndarray | None = None):
    """Predict each belief with its action, then condition it on its reading: ``(out, z)``.

    ``beliefs`` ``(L, H, W)`` (then ``z`` is a float) or ``(N, L, H, W)`` (then ``z`` is (N,));
    ``z`` is ``P(reading | belief, action)``.  With ``normalise=False`` the result is left
    multiplied by ``z`` (the caller divides later).  ``mask`` (N booleans) limits the step to
    some beliefs (the other rows of ``out`` are left as they were).  On an impossible reading
    nothing the caller holds changes (``out`` may be overwritten) and
    :class:`~gym_gridloc.ImpossibleObservationError` names it.
    """
    flat, single = _flat(model, beliefs)
    if single:
        res = _out(out, flat, model.belief_shape)
        return res, stepper(model, normalise=normalise)(flat, actions, int(readings), res)
    d, n = derived.of(model), flat.shape[0]
    acts = derived.action_indices(model, actions, n)
    rs = np.asarray(readings, dtype=np.int64).reshape(-1)
    if rs.size != n:
        raise ValueError(f"step() needs one reading per belief: {n} beliefs, {rs.size} readings")
    sel = _all(n) if mask is None else np.asarray(mask, dtype=bool)
    if mask is not None:
        acts, rs = np.where(sel, acts, 0), np.where(sel, rs, 0)
    res = _out(out, flat, (n, *model.belief_shape))
    res2 = res.reshape(n, -1)
    lik = derived.likelihoods(model, rs)
    if model.kidnap_prob > 0.0:
        z = _mixed_step(model, d, flat, acts, lik, res2, normalise, sel)
    else:
        z = d.plan.run(flat, acts, lik, d.layered, res2, 1 if normalise else 2, sel)
    derived.check_z(model, z, rs)
    return res, z


def _mixed_step(model: GridModel, d: derived.Derived, flat: np.ndarray, acts: np.ndarray, lik: np.ndarray,
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
    ``reading`` an int.  Normalising multiplies by ``1.0 / z`` (every kernel, and the mixing of
    kidnapping): :class:`~gym_gridloc.ForwardFilter` relies on it."""
    d = derived.of(model)
    if normalise not in d.steppers:
        d.steppers[normalise] = _make_stepper(model, d, normalise)
    return d.steppers[normalise]


def _make_stepper(model: GridModel, d: derived.Derived, normalise: bool):
    n_actions, layered, mode = model.n_actions, d.layered, 1 if normalise else 2
    lik_of, liks = d.lik, d.liks
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
            raise derived.impossible(model_ref(), int(reading))
        return z

    return step_one


_NO_LIK = np.zeros(1)


@functools.cache
def _no_liks(n: int) -> np.ndarray:
    return np.zeros((n, 1))


@functools.cache
def _all(n: int) -> np.ndarray:
    return read_only(np.ones(n, dtype=bool))
