"""The exact forward filter (HMM): ``f' = alpha * O * T^T * f``, for one belief or N at once.

:class:`ForwardFilter` keeps one belief, :class:`BatchFilter` N beliefs (one array, one engine call
per step).  Both hold what they hold under the same names: ``full_belief(s)`` over the hidden
state ``(L, H, W)``, ``position_belief(s)`` over positions ``(H, W)``.  The numbers are
:mod:`gym_gridloc.engine`'s.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_int


def checked_belief(model: GridModel, belief: Any) -> np.ndarray:
    """An (L, H, W) array, an (S,) vector or (one layer) an (H, W) array as a normalised (L, H, W)
    belief, or a clear error."""
    try:
        b = np.asarray(belief, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"belief must be an array of numbers, got {type(belief).__name__}") from None
    if b.shape == (model.n_states,):
        b = model.from_vector(b)
    elif model.n_layers == 1 and b.shape == model.shape:
        b = b[None]
    elif b.shape != model.belief_shape:
        one = f", {model.shape}" if model.n_layers == 1 else ""
        raise ValueError(f"belief must have shape {model.belief_shape}{one} or ({model.n_states},), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b < 0) or np.any(b[~model.state_mask] != 0):
        raise ValueError("belief must be finite, non-negative and zero on obstacles")
    peak = float(b.max())
    if not peak > 0.0:
        raise ValueError("belief must have positive total mass")
    b = b / peak  # scaled first, so that values near the float64 limit cannot overflow the sum
    return b / b.sum()


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

    ``read_every_step=True`` (the environment's referee, whose belief is read after every step)
    normalises in the step's own pass instead of on the next read: the same numbers when the
    belief is read between steps (each value times ``1 / z`` either way), one array pass fewer.
    """

    def __init__(self, model: GridModel, *, kidnap_prob: float | None = None, read_every_step: bool = False) -> None:
        model = engine.checked_model(model, "ForwardFilter needs a GridModel")
        if kidnap_prob is not None:
            # The kidnapped robot: mix a teleport to a uniform free state with this probability
            # into every prediction (0.0 switches off any kidnapping the model has).
            model = model.with_kidnapping(kidnap_prob)
        self.model = model
        self.read_every_step = bool(read_every_step)
        self._bind()
        self._f: np.ndarray | None = None
        self._spare: np.ndarray | None = None  # the other buffer: steps alternate between the two
        self._scale = 1.0  # the belief is self._f * self._scale (see step)
        self._lent: np.ndarray | None = None  # a belief shown, not owned: never written (see _show)
        self._log_likelihood: float | None = 0.0  # None: unknown since a belief was shown (see _show)

    # -- the API ---------------------------------------------------------------------------------
    def reset(self, observation: Any = None, *, reading: int | None = None) -> "ForwardFilter":
        """Start from the prior (uniform over free states), updated with ``observation`` if given
        (or with its reading index ``reading``, unchecked: for the environment, which drew it)."""
        self._f, self._spare, self._scale = self.model.prior(), None, 1.0
        self._log_likelihood = 0.0
        if observation is not None or reading is not None:
            self.update(observation, reading=reading)
        return self

    def predict(self, action: int | None = None) -> "ForwardFilter":
        """One transition step; ``None`` means the action is unknown (the actions' average)."""
        f = self._belief()
        out = self._spare
        if out is None or out is f or out.shape != f.shape:
            out = np.empty_like(f)
        self._f, self._spare = engine.predict(self.model, f, action, out=out), None if f is self._lent else f
        return self

    def update(self, observation: Any = None, *, reading: int | None = None) -> "ForwardFilter":
        """Condition on a reading.  Raises :class:`ImpossibleObservationError` (and keeps the
        belief as it was) when the observation has probability zero under the model."""
        if reading is None:
            reading = self.model.sensor.to_reading(observation)
        post = self._belief().copy()
        if self._log_likelihood is not None:  # (unknown after _show)
            self._log_likelihood += math.log(float(engine.update(self.model, post, reading)[0]))
        self._f = post
        return self

    def step(self, action: int | None, observation: Any = None, *, reading: int | None = None) -> "ForwardFilter":
        """Predict with ``action``, then update with ``observation`` (or with its reading index
        ``reading``, an int not checked: for the environment, which drew it).  On an impossible
        observation the belief is left as it was before the step."""
        if reading is None:
            reading = self._to_reading(observation)
        before = self._f
        if before is None:
            raise RuntimeError("call ForwardFilter.reset() before using the filter")
        out = self._spare  # the other buffer, as in predict() (same shapes here)
        if out is None or out is before:
            out = np.empty_like(before)
        if self._step_now is not None:  # normalised in the pass (times 1 / z, as on a read)
            zz = self._step_now(before, action, reading, out)
            if self._log_likelihood is not None:  # (unknown after _show)
                self._log_likelihood += math.log(zz * self._scale)
            self._f, self._spare, self._scale = out, None if before is self._lent else before, 1.0
            return self
        zz = self._step(before, action, reading, out)
        # Normalised lazily: the next read (or step) multiplies by 1/z, a pass that a loop of
        # steps without reads never pays; the log likelihood carries the deferred scale.
        if self._log_likelihood is not None:  # (unknown after _show)
            self._log_likelihood += math.log(zz * self._scale)
        self._f, self._spare, self._scale = out, None if before is self._lent else before, 1.0 / zz
        if zz < 1e-150:  # keep the raw numbers far from underflow
            self._belief()
        return self

    def _show(self, belief: np.ndarray) -> None:
        """Hold ``belief`` (an (L, H, W) float64 array that its owner writes: an environment's
        posterior) as this filter's normalised belief, without a copy; the filter's own steps
        never write into it.  Its owner does not say how likely the readings were:
        :attr:`log_likelihood` is unknown until the next :meth:`reset`."""
        self._f, self._spare, self._scale, self._lent = belief, None, 1.0, belief
        self._log_likelihood = None

    @property
    def log_likelihood(self) -> float:
        """``log P(readings so far | actions)`` since :meth:`reset`.  An environment's
        :attr:`~gym_gridloc.GridLocEnv.exact_filter` shows the step's posterior without it and
        raises ``ValueError``: run a ``ForwardFilter`` of your own beside the environment."""
        if self._log_likelihood is None:
            raise ValueError("this filter shows an environment's posterior (GridLocEnv.exact_filter), whose step does not "
                             "compute log P(readings); for it, run a ForwardFilter(env.unwrapped.model) of your own: "
                             "reset(reading=...) with the first reading, then step(action, reading=...) after every step")
        return self._log_likelihood

    @log_likelihood.setter
    def log_likelihood(self, value: float) -> None:
        self._log_likelihood = value

    def _bind(self) -> None:
        """The engine's bound functions (rebuilt on load).  ``_step_now`` normalises in the pass
        (the engine's normalised step multiplies by ``1 / z``, exactly as a read does), without
        kidnapping (whose step normalises in a pass of its own either way)."""
        self._step = engine.stepper(self.model, normalise=False)
        eager = self.read_every_step and self.model.kidnap_prob == 0.0
        self._step_now = engine.stepper(self.model, normalise=True) if eager else None
        self._to_reading = self.model.sensor.to_reading

    def __getstate__(self) -> dict:
        # all but the bound functions, which are rebuilt on load
        return {k: v for k, v in self.__dict__.items() if k not in ("_step", "_step_now", "_to_reading")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.__dict__.setdefault("read_every_step", False)
        self.__dict__.setdefault("_lent", None)
        if "log_likelihood" in self.__dict__:  # pickled before it was a property
            self._log_likelihood = self.__dict__.pop("log_likelihood")
        self._bind()

    # -- reading the belief -----------------------------------------------------------------------
    @property
    def full_belief(self) -> np.ndarray:
        """The hidden-state belief as an (L, H, W) array (a copy)."""
        return self._belief().copy()

    @property
    def belief_view(self) -> np.ndarray:
        """The hidden-state belief as an (L, H, W) array, not copied: read it, never write it; it
        changes at the filter's next step (for hot loops: the environment's referee and the
        wrapper's observation read it once per step)."""
        return self._belief()

    @property
    def position_belief(self) -> np.ndarray:
        """P(position) as an (H, W) float64 array: zero on obstacles, summing to 1."""
        f = self._belief()
        return f[0].copy() if f.shape[0] == 1 else f.sum(axis=0)

    @property
    def belief_vector(self) -> np.ndarray:
        """The hidden-state belief as a vector over free states (layer-major), float64."""
        return self.model.to_vector(self._belief())

    @property
    def belief(self) -> np.ndarray:
        """Deprecated name of :attr:`belief_vector`."""
        warnings.warn("ForwardFilter.belief is deprecated: use belief_vector (the (S,) vector), full_belief "
                      "or position_belief", DeprecationWarning, stacklevel=2)
        return self.belief_vector

    def set_belief(self, belief: np.ndarray) -> "ForwardFilter":
        """Replace the belief with an (L, H, W) array, an (S,) vector or, for a model of one layer,
        an (H, W) array like :attr:`position_belief` (checked, normalised)."""
        self._f, self._spare, self._scale = checked_belief(self.model, belief), None, 1.0
        return self

    def _belief(self) -> np.ndarray:
        if self._f is None:
            raise RuntimeError("call ForwardFilter.reset() before using the filter")
        if self._scale != 1.0:  # see step(): the belief is normalised on first read
            self._f *= self._scale
            self._scale = 1.0
        return self._f


class BatchFilter:
    """N exact forward filters over one :class:`GridModel`, updated together.

    >>> import numpy as np, gym_gridloc
    >>> bf = gym_gridloc.BatchFilter(gym_gridloc.windy_maze_model(), 2)
    >>> _ = bf.reset([[0, 0, 0, 1], [1, 0, 0, 1]])
    >>> _ = bf.step([0, 1], [[0, 1, 0, 0], [0, 1, 0, 0]])
    >>> bf.full_beliefs.shape
    (2, 1, 6, 7)

    Each belief equals the one a :class:`ForwardFilter` computes from the same actions and
    observations, within 1e-12.

    Parameters
    ----------
    model:
        The model of every belief.
    n:
        The number of beliefs.
    """

    def __init__(self, model: GridModel, n: int) -> None:
        self.model = engine.checked_model(model, "BatchFilter needs a GridModel")
        self.n = check_int("n (the number of beliefs)", n, what="a positive integer", error=ValueError)
        self._b = np.empty((self.n, *model.belief_shape))
        self._spare = np.empty_like(self._b)
        self._ready = np.zeros(self.n, dtype=bool)
        self.log_likelihood = np.zeros(self.n)

    def reset(self, observations: Any = None, mask: Any = None, *, readings: Any = None) -> "BatchFilter":
        """Start the beliefs (those where ``mask`` is True; default all) from the prior, updated
        with their observations when given (a batch of N, as for :meth:`step`).  ``readings``
        (N reading indices) may replace ``observations``."""
        sel = self._mask(mask)
        idx = np.flatnonzero(sel)
        post = np.broadcast_to(self.model.prior(), (idx.size, *self.model.belief_shape)).copy()
        z = np.ones(idx.size)
        if observations is not None or readings is not None:
            z = engine.update(self.model, post, self._readings(observations, readings)[idx])
        self._b[idx] = post
        self.log_likelihood[idx] = np.log(z)
        self._ready[idx] = True
        return self

    def step(self, actions: Any, observations: Any = None, mask: Any = None, *, readings: Any = None) -> "BatchFilter":
        """Predict each belief with its action, then update it with its observation (only the
        beliefs where ``mask`` is True; default all).  On an impossible observation nothing
        changes and :class:`ImpossibleObservationError` names the belief.  ``readings`` (N
        reading indices) may replace ``observations``."""
        sel = self._mask(mask)
        if not np.all(self._ready[sel]):
            raise RuntimeError("call BatchFilter.reset() before step() (some beliefs were never reset)")
        acts = np.asarray(actions)
        if acts.shape != (self.n,):
            raise ValueError(f"actions must be {self.n} actions (one per belief), got shape {acts.shape}")
        acts = np.where(sel, acts, 0)  # checked (None: unknown) by the engine, masked-out ones skipped
        rs = self._readings(observations, readings)
        partial = not sel.all()
        if partial:
            self._spare[...] = self._b
        _, z = engine.step(self.model, self._b, acts, np.where(sel, rs, 0), out=self._spare,
                           mask=sel if partial else None)
        self._b, self._spare = self._spare, self._b
        self.log_likelihood[sel] += np.log(z[sel])
        return self

    def _readings(self, observations: Any, readings: Any) -> np.ndarray:
        if readings is not None:
            rs = np.asarray(readings, dtype=np.int64)
            if rs.shape != (self.n,) or np.any((rs < 0) | (rs >= self.model.sensor.n_readings)):
                raise ValueError(f"readings must be {self.n} reading indices in 0..{self.model.sensor.n_readings - 1}")
            return rs
        return self.model.sensor.readings(observations, self.n)

    def _mask(self, mask: Any) -> np.ndarray:
        if mask is None:
            return np.ones(self.n, dtype=bool)
        m = np.asarray(mask)
        if m.shape != (self.n,) or m.dtype != bool:
            raise ValueError(f"mask must be {self.n} booleans, got shape {m.shape} dtype {m.dtype}")
        return m

    # -- reading the beliefs ---------------------------------------------------------------------
    @property
    def full_beliefs(self) -> np.ndarray:
        """The hidden-state beliefs, (N, L, H, W) float64 (a view: copy it to keep it)."""
        return self._b

    @property
    def position_beliefs(self) -> np.ndarray:
        """P(position) per belief, (N, H, W) float64."""
        b = self._b
        return b[:, 0] if b.shape[1] == 1 else b.sum(axis=1)

    @property
    def beliefs(self) -> np.ndarray:
        """Deprecated name of :attr:`full_beliefs`."""
        warnings.warn("BatchFilter.beliefs is deprecated: use full_beliefs", DeprecationWarning, stacklevel=2)
        return self._b
