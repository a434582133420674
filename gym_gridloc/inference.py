"""Inference over a recorded episode: smoothing, fixed-lag smoothing and the most likely path.

An episode is ``observations`` (the reset reading first, exactly as the environment emits them)
and ``actions`` (``actions[k]`` is taken between ``observations[k]`` and ``observations[k+1]``; an
action may be ``None`` when it is unknown, and ``actions=None`` means every action is unknown).
Every computation is exact and runs on the model's sparse stencil (never a dense S x S product):

* :func:`smooth` -- forward-backward posteriors ``P(X_k | e_0:t)`` for every k, with scaled
  messages (each forward and backward message is normalised), stable for any episode length.
* :class:`FixedLagSmoother` / :func:`fixed_lag_smooth` -- online ``P(X_{t-d} | e_0:t)``.
* :func:`viterbi` -- the most likely state sequence and its log probability, max-product in log
  space.

The start distribution is the model's prior (uniform over free states) and kidnapping
(``model.kidnap_prob``) is part of the transition wherever it is set.
"""

from __future__ import annotations

import functools
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_int

__all__ = [
    "ForwardBackwardResult",
    "FixedLagSmoother",
    "fixed_lag_smooth",
    "forward_backward",
    "smooth",
    "viterbi",
]


# -- reading an episode ----------------------------------------------------------------------------
def _episode(model: GridModel, actions: Sequence[Any] | None, observations: Sequence[Any]) -> tuple[list[int | None], list[int]]:
    """Checked ``(actions, readings)`` of an episode."""
    engine.checked_model(model, "model must be a GridModel")
    obs = list(observations)
    if not obs:
        raise ValueError("observations must hold at least one observation (the reading at reset)")
    acts: list[Any] = [None] * (len(obs) - 1) if actions is None else list(actions)
    if len(acts) != len(obs) - 1:
        raise ValueError(
            "actions must have exactly one element fewer than observations (actions[k] is taken "
            f"between observations[k] and observations[k+1]); got {len(acts)} actions and {len(obs)} observations"
        )
    acts = [None if a is None else model.check_action(a) for a in acts]
    readings = [model.sensor.to_reading(o) for o in obs]
    return acts, readings


def _impossible(model: GridModel, k: int, reading: int) -> ImpossibleObservationError:
    return engine.impossible(model, reading, label=f"observation {k} (reading {model.sensor.describe(reading)})",
                             given="the observations and actions before it")


def _condition(model: GridModel, belief: np.ndarray, reading: int, k: int) -> float:
    """Condition ``belief`` (L, H, W) on observation ``k``'s reading, in place; its probability."""
    try:
        return float(engine.update(model, belief, reading)[0])
    except ImpossibleObservationError:
        raise _impossible(model, k, reading) from None


def _positions(beliefs: np.ndarray) -> np.ndarray:
    """(..., L, H, W) -> (..., H, W)."""
    return beliefs.sum(axis=-3)


# -- forward-backward ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ForwardBackwardResult:
    """What :func:`forward_backward` computes.

    ``filtered[k]`` is ``P(X_k | e_0:k)`` and ``smoothed[k]`` is ``P(X_k | e_0:t)``, both over the
    full hidden state as (t+1, L, H, W) arrays; ``log_likelihood`` is ``log P(e_0:t)`` (given the
    actions).
    """

    filtered: np.ndarray
    smoothed: np.ndarray
    log_likelihood: float

    @property
    def filtered_positions(self) -> np.ndarray:
        """``P(position_k | e_0:k)``, (t+1, H, W)."""
        return _positions(self.filtered)

    @property
    def smoothed_positions(self) -> np.ndarray:
        """``P(position_k | e_0:t)``, (t+1, H, W)."""
        return _positions(self.smoothed)


def forward_backward(model: GridModel, actions: Sequence[Any] | None, observations: Sequence[Any]) -> ForwardBackwardResult:
    """Filtered and smoothed beliefs of a recorded episode and its log likelihood.

    Both passes keep normalised messages (the forward message is the filtered belief; the backward
    message is rescaled to sum to 1 at every step), so nothing under- or overflows however long
    the episode is.  Raises :class:`ImpossibleObservationError` when an observation has probability
    zero under the model given what came before.
    """
    acts, readings = _episode(model, actions, observations)
    f = np.empty((len(readings), *model.belief_shape))  # the forward pass: filtered beliefs
    f[0], loglik = model.prior(), 0.0
    for k in range(len(readings)):
        if k > 0:
            engine.predict(model, f[k - 1], acts[k - 1], out=f[k])
        loglik += float(np.log(_condition(model, f[k], readings[k], k)))
    smoothed = np.empty_like(f)
    mask = model.state_mask
    b = mask / float(mask.sum())
    smoothed[-1] = f[-1]
    for k in range(len(readings) - 2, -1, -1):
        b = engine.backward(model, engine.likelihood(model, readings[k + 1]) * b, acts[k])
        b /= b.sum()  # positive: observation k+1 is possible (the forward pass checked it)
        g = f[k] * b
        smoothed[k] = g / g.sum()
    return ForwardBackwardResult(filtered=f, smoothed=smoothed, log_likelihood=loglik)


def smooth(model: GridModel, actions: Sequence[Any] | None, observations: Sequence[Any], *, full_state: bool = False) -> np.ndarray:
    """Smoothed position posteriors ``P(X_k | e_0:t)`` for k = 0..t, as a (t+1, H, W) array.

    ``observations[0]`` is the reading at reset; ``actions[k]`` is taken between ``observations[k]``
    and ``observations[k+1]`` (``None``: unknown).  ``full_state=True`` returns the full hidden
    state, (t+1, L, H, W).  The last row equals the filtered belief after the last observation.

    >>> import gym_gridloc
    >>> m = gym_gridloc.windy_maze_model()
    >>> post = gym_gridloc.smooth(m, [0], [[0, 0, 0, 1], [0, 1, 0, 0]])
    >>> post.shape, round(float(post[1].max()), 4)
    ((2, 6, 7), 0.425)
    """
    result = forward_backward(model, actions, observations)
    return result.smoothed if full_state else result.smoothed_positions


# -- fixed-lag smoothing ---------------------------------------------------------------------------
class FixedLagSmoother:
    """Online fixed-lag smoothing: after observation t, the belief ``P(X_{t-d} | e_0:t)``.

    The smoother keeps the last ``d + 1`` filtered beliefs and the actions and readings between
    them; each step runs the forward filter one step and a backward pass of ``d`` steps over that
    window, so a step costs ``d + 1`` sparse stencil passes (the dense-matrix form of the textbook
    algorithm would cost ``O(S^2)`` per step).  ``lag = 0`` is the forward filter.

    Parameters
    ----------
    model:
        The model (kidnapping included if the model has it).
    lag:
        The lag ``d >= 0``.
    full_state:
        Return (L, H, W) hidden-state beliefs instead of (H, W) position beliefs.
    """

    def __init__(self, model: GridModel, lag: int, *, full_state: bool = False) -> None:
        self.model = engine.checked_model(model, "FixedLagSmoother needs a GridModel")
        self.lag = check_int("lag", lag, minimum=0)
        self.full_state = bool(full_state)
        self.t = -1
        self._f: deque[np.ndarray] = deque(maxlen=self.lag + 1)  # f_{t-d} .. f_t
        self._links: deque[tuple[int | None, int]] = deque(maxlen=self.lag)  # (a_{j-1}, z_j) for j = t-d+1 .. t

    def _out(self, belief: np.ndarray) -> np.ndarray:
        return belief if self.full_state else _positions(belief)

    def _smoothed(self, k: int) -> np.ndarray:
        """``P(X_k | e_0:t)`` for k in the window (t-d .. t)."""
        first_f = self.t - len(self._f) + 1  # time of self._f[0]
        first_link = self.t - len(self._links) + 1  # time j of self._links[0] = (a_{j-1}, z_j)
        mask = self.model.state_mask
        b = mask / float(mask.sum())
        for j in range(self.t, k, -1):  # backward from t to k + 1
            action, reading = self._links[j - first_link]
            b = engine.backward(self.model, engine.likelihood(self.model, reading) * b, action)
            b /= b.sum()
        g = self._f[k - first_f] * b
        return self._out(g / g.sum())

    def reset(self, observation: Any) -> np.ndarray | None:
        """Start an episode with the reading at reset.  Returns ``P(X_0 | e_0)`` when the lag is 0,
        otherwise None (no belief is ``d`` steps old yet)."""
        reading = self.model.sensor.to_reading(observation)
        self.t = -1
        self._f.clear()
        self._links.clear()
        f = self.model.prior()
        _condition(self.model, f, reading, 0)
        self.t = 0
        self._f.append(f)
        return self._smoothed(0) if self.lag == 0 else None

    def step(self, action: int | None, observation: Any) -> np.ndarray | None:
        """Take in the action and the next observation; return ``P(X_{t-d} | e_0:t)`` for the new
        t, or None while ``t < d``.  On an impossible observation the state is left unchanged."""
        if self.t < 0:
            raise RuntimeError("call FixedLagSmoother.reset(observation) before step()")
        a = None if action is None else self.model.check_action(action)
        reading = self.model.sensor.to_reading(observation)
        f = engine.predict(self.model, self._f[-1], a)
        _condition(self.model, f, reading, self.t + 1)
        self.t += 1
        self._f.append(f)
        self._links.append((a, reading))  # nothing is kept at lag 0 (maxlen 0)
        k = self.t - self.lag
        return self._smoothed(k) if k >= 0 else None

    @property
    def filtered(self) -> np.ndarray:
        """The filtered belief ``P(X_t | e_0:t)``."""
        if self.t < 0:
            raise RuntimeError("call FixedLagSmoother.reset(observation) first")
        return self._out(self._f[-1].copy())

    def flush(self) -> list[np.ndarray]:
        """The beliefs still owed at the end of an episode: ``P(X_k | e_0:t)`` for
        k = max(0, t-d+1) .. t (empty for lag 0)."""
        if self.t < 0:
            raise RuntimeError("call FixedLagSmoother.reset(observation) first")
        return [self._smoothed(k) for k in range(max(0, self.t - self.lag + 1), self.t + 1)]


def fixed_lag_smooth(model: GridModel, actions: Sequence[Any] | None, observations: Sequence[Any], lag: int, *, full_state: bool = False) -> np.ndarray:
    """What an online fixed-lag smoother reports over a recorded episode: row k is
    ``P(X_k | e_0:min(k+d, t))``, (t+1, H, W) (or (t+1, L, H, W) with ``full_state``).  Lag 0 gives
    the filtered beliefs; a lag of at least t gives :func:`smooth`."""
    acts, _ = _episode(model, actions, observations)
    obs = list(observations)
    s = FixedLagSmoother(model, lag, full_state=full_state)
    # reset and step give None while no belief is d steps old; flush gives the ones still owed
    out = [s.reset(obs[0]), *(s.step(a, o) for a, o in zip(acts, obs[1:])), *s.flush()]
    return np.stack([b for b in out if b is not None])


# -- Viterbi ---------------------------------------------------------------------------------------
def viterbi(
    model: GridModel,
    actions: Sequence[Any] | None,
    observations: Sequence[Any],
    *,
    full_state: bool = False,
) -> tuple[list[tuple[int, ...]], float]:
    """The most likely state sequence of a recorded episode and its log probability.

    Max-product in log space over the model's stencil, with back-pointers (one small integer per
    state and step).  Returns ``(path, log_prob)``: ``path`` is ``[(row, col), ...]`` of length
    t+1 (with ``full_state=True``, ``[(layer, row, col), ...]``: for models with a heading the best
    sequence is over full states, reported as positions by default), and ``log_prob`` is
    ``log P(x_0:t, e_0:t)``, the joint log probability of that sequence and the observations
    (given the actions; the start is uniform over free states).  Ties go to the state and the term
    listed first.
    """
    acts, readings = _episode(model, actions, observations)
    n = len(readings)
    mask = model.state_mask
    n_states = model.n_states
    p_kid = model.kidnap_prob

    def observe(scores: np.ndarray, k: int) -> np.ndarray:
        """``scores`` plus the log likelihood of observation ``k``'s reading (an error if impossible)."""
        with np.errstate(divide="ignore"):
            scores = scores + np.log(engine.likelihood(model, readings[k]))
        if not np.isfinite(scores.max()):
            raise _impossible(model, k, readings[k])
        return scores

    @functools.cache
    def log_terms(a: int | None) -> list[tuple]:
        """``(term, source slices, destination slices, log weight)`` for each term of ``a``."""
        with np.errstate(divide="ignore"):
            return [
                (t, *t.slices, np.log(engine.kidnapped(model, t.weight)))
                for t in engine.terms(model, a)
            ]

    delta = observe(np.where(mask, -np.log(n_states), -np.inf), 0)
    pointers = np.empty((max(n - 1, 0), *model.belief_shape), dtype=np.int32)
    kidnap_from = np.zeros(max(n - 1, 0), dtype=np.int64)  # flat index of the best state (kidnap)
    for k in range(1, n):
        new = np.full(model.belief_shape, -np.inf)
        bp = pointers[k - 1]
        bp.fill(-2)
        for i, (t, src, dst, lw) in enumerate(log_terms(acts[k - 1])):
            cand = delta[t.src][src] + lw[src]
            region = new[t.dst][dst]
            better = cand > region
            region[better] = cand[better]
            bp[t.dst][dst][better] = i
        if p_kid > 0.0:
            j = int(np.argmax(delta))
            kidnap_from[k - 1] = j
            cand = delta.flat[j] + np.log(engine.kidnapped(model, 0.0))
            better = mask & (cand > new)
            new[better] = cand
            bp[better] = -1
        delta = observe(new, k)
    best = int(np.argmax(delta))
    states = [tuple(int(v) for v in np.unravel_index(best, model.belief_shape))]
    for k in range(n - 1, 0, -1):
        layer, r, c = states[-1]
        i = int(pointers[k - 1][layer, r, c])
        if i == -1:
            prev = np.unravel_index(int(kidnap_from[k - 1]), model.belief_shape)
        else:
            t = engine.terms(model, acts[k - 1])[i]
            prev = (t.src, r - t.dr, c - t.dc)
        states.append(tuple(int(v) for v in prev))
    states.reverse()
    path = states if full_state else [(r, c) for _, r, c in states]
    return path, float(delta.flat[best])
