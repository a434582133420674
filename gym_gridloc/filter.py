"""The exact forward filter (HMM): ``f' = alpha * O * T^T * f``, one sparse step at a time."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel


class ForwardFilter:
    """Exact forward filter over a :class:`GridModel`.

    The belief is kept as an (L, H, W) array (``L`` hidden states per cell, e.g. headings).  A
    prediction costs one multiply-add per non-zero transition (a stencil over shifted arrays);
    an update one multiply per state.  Observations are given exactly as the environment emits
    them.  ``kidnap_prob`` (default: the model's own) mixes a teleport to a uniformly chosen free
    state with that probability into every prediction, so the belief recovers from kidnapping.

    >>> import gym_gridloc
    >>> f = gym_gridloc.ForwardFilter(gym_gridloc.windy_maze_model())
    >>> _ = f.reset([0, 0, 0, 1])          # the seed's first reading (W, N, E, S)
    >>> _ = f.step(0, [0, 1, 0, 0])         # move N, then read
    >>> round(float(f.position_belief.max()), 4)
    0.425
    """

    def __init__(self, model: GridModel, *, kidnap_prob: float | None = None) -> None:
        if not isinstance(model, GridModel):
            raise TypeError(f"ForwardFilter needs a GridModel, got {type(model).__name__}")
        if kidnap_prob is not None:
            # The kidnapped robot: mix a teleport to a uniform free state with this probability
            # into every prediction (0.0 switches off any kidnapping the model has).
            model = model.with_kidnapping(kidnap_prob)
        self.model = model
        self._f: np.ndarray | None = None
        self._spare: np.ndarray | None = None  # the other buffer of predict's double buffering
        self._scale = 1.0  # the belief is self._f * self._scale (see step)
        self._fast: dict = {}  # action -> kernel step (or False)
        self._liks: dict = {}  # reading -> flat likelihood, for the kernel step
        self.log_likelihood = 0.0

    # -- the API ---------------------------------------------------------------------------------
    def reset(self, observation: Any = None) -> "ForwardFilter":
        """Start from the prior (uniform over free states), updated with ``observation`` if given."""
        self._f = self.model.prior()
        self._scale = 1.0
        self.log_likelihood = 0.0
        if observation is not None:
            self.update(observation)
        return self

    def predict(self, action: int | None = None) -> "ForwardFilter":
        """One transition step; ``None`` means the action is unknown (the actions' average)."""
        f = self._belief()
        spare = self._spare
        if spare is None or spare is f or spare.shape != f.shape:
            spare = None
        self._f = self.model.predict(f, action, out=spare)
        self._spare = f
        return self

    def update(self, observation: Any) -> "ForwardFilter":
        """Condition on a reading.  Raises :class:`ImpossibleObservationError` (and keeps the
        belief as it was) when the observation has probability zero under the model."""
        reading = self.model.sensor.to_reading(observation)
        f = self._belief()
        window = self.model.sensor.likelihood_window(reading)
        if window is not None:  # the likelihood is zero outside a small window (ring sensor)
            rows, cols, lik = window
            post = f[:, rows, cols] * lik
            z = float(post.sum())
        else:
            lik = self.model.likelihood(reading)
            # einsum, not np.dot: a BLAS dot can be 100x slower on a busy machine (thread pools).
            z = float(np.einsum("lk,k->", f.reshape(f.shape[0], -1), lik.reshape(-1)))
        if not z > 0.0 or not np.isfinite(z):
            self._raise_impossible(observation)
        if f is self._spare:  # never write into the other buffer
            f = f.copy()
        if window is not None:
            post /= z
            f.fill(0.0)
            f[:, rows, cols] = post
        else:
            np.multiply(f, lik, out=f)
            f /= z
        self._f = f
        self.log_likelihood += float(np.log(z))
        return self

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_fast"], state["_liks"] = {}, {}  # kernel closures and views: rebuilt on use
        state.pop("_lik_form", None)
        return state

    def _fast_path(self, action: int | None):
        """A call ``(belief, out, likelihood) -> sum`` of the model's kernel plan for ``action``
        (predict and update in one call, unnormalised output), or False with kidnapping."""
        model = self.model
        plan = model.stencil_plan(action) if model.kidnap_prob == 0.0 else None
        run = plan.run_flat if plan is not None else False
        if plan is not None:
            self._lik_form = plan.likelihood_form
        self._fast[None if action is None else model.check_action(action)] = run
        return run

    def _raise_impossible(self, observation: Any) -> None:
        raise ImpossibleObservationError(
            f"observation {observation!r} is impossible under the filter's model "
            f"({self.model!r}) given the belief so far: every state that could be reached "
            "gives it probability 0 (model mismatch?)"
        )

    def step(self, action: int | None, observation: Any) -> "ForwardFilter":
        """Predict with ``action``, then update with ``observation``.  On an impossible
        observation the belief is left as it was before the step."""
        run = self._fast.get(action) if action is None or type(action) is int else None
        if run is None and self._f is not None:
            run = self._fast_path(action)
        if run:  # predict + update in one kernel call
            reading = self.model.sensor.to_reading(observation)
            lik = self._liks.get(reading)
            if lik is None and self.model.sensor.likelihood_window(reading) is None:
                lik = self._liks[reading] = self._lik_form(self.model.likelihood(reading))
            if lik is not None:
                before = self._f  # the belief is before * self._scale
                out = self._spare
                if out is None or out is before:
                    out = np.empty_like(before)
                z = run(before.ravel(), out.ravel(), lik)
                if not z > 0.0 or z == math.inf:
                    self._spare = out
                    self._raise_impossible(observation)
                self.log_likelihood += math.log(z * self._scale)
                # Normalised lazily: the next read (or predict) multiplies by 1/z, a pass the
                # filter-only loop never pays; at most one pass per step in any case.
                self._f, self._spare, self._scale = out, before, 1.0 / z
                if z < 1e-150:  # keep the raw numbers far from underflow
                    self._belief()
                return self
        before = self._belief()
        self.predict(action)
        try:
            self.update(observation)
        except ImpossibleObservationError:
            self._f = before
            raise
        return self

    # -- reading the belief -----------------------------------------------------------------------
    @property
    def belief(self) -> np.ndarray:
        """The hidden-state belief as a vector over free states (layer-major), float64."""
        return self.model.to_vector(self._belief())

    @property
    def full_belief(self) -> np.ndarray:
        """The hidden-state belief as an (L, H, W) array (a copy)."""
        return self._belief().copy()

    @property
    def position_belief(self) -> np.ndarray:
        """P(position) as an (H, W) float64 array: zero on obstacles, summing to 1."""
        f = self._belief()
        return f[0].copy() if f.shape[0] == 1 else f.sum(axis=0)

    def set_belief(self, belief: np.ndarray) -> "ForwardFilter":
        """Replace the belief with an (L, H, W) array or an (S,) vector (checked, normalised)."""
        b = np.asarray(belief, dtype=np.float64)
        if b.shape == (self.model.n_states,):
            b = self.model.from_vector(b)
        elif b.shape != self.model.belief_shape:
            raise ValueError(
                f"belief must have shape {self.model.belief_shape} or ({self.model.n_states},), got {b.shape}"
            )
        if not np.all(np.isfinite(b)) or np.any(b < 0) or np.any(b[~self.model.state_mask] != 0):
            raise ValueError("belief must be finite, non-negative and zero on obstacles")
        z = b.sum()
        if not z > 0:
            raise ValueError("belief must have positive total mass")
        self._f = b / z
        self._scale = 1.0
        return self

    def _belief(self) -> np.ndarray:
        if self._f is None:
            raise RuntimeError("call ForwardFilter.reset() before using the filter")
        if self._scale != 1.0:  # see step(): the belief is normalised on first read
            self._f *= self._scale
            self._scale = 1.0
        return self._f
