"""Monte Carlo localisation: a particle filter on the same :class:`GridModel` as the exact filter."""

from __future__ import annotations

from typing import Any

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice, check_int, check_probability

__all__ = ["ParticleFilter", "systematic_resample"]


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of a systematic resample of normalised ``weights``: one uniform draw ``u``, then the
    particles at the points ``(u + i) / N``.  Each particle is copied ``floor(N w)`` or
    ``ceil(N w)`` times."""
    n = len(weights)
    points = (rng.random() + np.arange(n)) / n
    cum = np.cumsum(weights)
    cum[-1] = 1.0  # guard against round-off
    return np.minimum(np.searchsorted(cum, points, side="right"), n - 1)


class ParticleFilter:
    """A particle filter (Monte Carlo localisation) over a :class:`GridModel`.

    Each of ``n_particles`` particles is a hidden state ``(layer, row, col)`` with a weight.
    ``predict`` moves every particle by sampling the model's own transition (kidnapping
    included); ``update`` multiplies the weights by the reading's likelihood and resamples when
    the effective sample size ``1 / sum(w^2)`` falls below ``resample_threshold * n_particles``.
    The belief is the weighted histogram of the particles.

    Parameters
    ----------
    model:
        The model to sample and weigh with.
    n_particles:
        Number of particles N (at least 1).
    resample_threshold:
        Resample when ESS < ``resample_threshold * N``; 0 never resamples, 1 resamples at every
        update whose weights are not all equal.  Default 0.5.
    resampling:
        ``"systematic"`` (default, low variance) or ``"multinomial"``.
    rng:
        A ``numpy.random.Generator``, a seed, or None (fresh entropy).
    kidnap_prob:
        If given, a teleport to a uniform free state with this probability is mixed into the
        transition (as :class:`gym_gridloc.ForwardFilter`'s option); default: the model's own.
    on_depletion:
        What to do when every particle has weight zero (particle deprivation: no particle sits
        where the reading is possible) although the reading is possible somewhere:
        ``"reinitialise"`` (default) redraws all particles from the prior conditioned on that one
        reading and counts it in ``n_reinitialisations``; ``"raise"`` raises
        :class:`ImpossibleObservationError`.  A reading impossible in every state always raises.
    """

    def __init__(
        self,
        model: GridModel,
        n_particles: int = 1000,
        *,
        resample_threshold: float = 0.5,
        resampling: str = "systematic",
        rng: np.random.Generator | int | None = None,
        kidnap_prob: float | None = None,
        on_depletion: str = "reinitialise",
    ) -> None:
        model = engine.checked_model(model, "ParticleFilter needs a GridModel")
        if kidnap_prob is not None:
            model = model.with_kidnapping(kidnap_prob)
        self.model = model
        self.n_particles = check_int("n_particles", n_particles, minimum=1)
        self.resample_threshold = check_probability("resample_threshold", resample_threshold)
        self.resampling = check_choice("resampling", resampling, ("systematic", "multinomial"))
        self.on_depletion = check_choice("on_depletion", on_depletion, ("reinitialise", "raise"))
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._states: np.ndarray | None = None  # (N, 3): layer, row, col
        self._w: np.ndarray | None = None
        self.log_likelihood, self.n_resamples, self.n_reinitialisations = 0.0, 0, 0

    # -- sampling helpers -------------------------------------------------------------------------
    def seed(self, seed: int | np.random.SeedSequence | None) -> "ParticleFilter":
        """Restart the random generator from ``seed`` (anything ``numpy.random.default_rng`` takes)."""
        self.rng = np.random.default_rng(seed)
        return self

    def _draw_prior(self, reading: int | None = None) -> None:
        n = self.n_particles
        if reading is None:
            self._states = engine.sample_initial(self.model, n, self.rng)
        else:
            p = self.model.likelihood_vector(reading)
            flat = self.rng.choice(self.model.n_states, size=n, p=p / p.sum())
            self._states = engine.states_of(self.model, flat)
        self._w = np.full(n, 1.0 / n)

    # -- the API ---------------------------------------------------------------------------------
    def reset(self, observation: Any = None) -> "ParticleFilter":
        """Draw the particles from the prior (uniform over free states), then update with
        ``observation`` if given."""
        self._draw_prior()
        self.log_likelihood, self.n_resamples, self.n_reinitialisations = 0.0, 0, 0
        if observation is not None:
            self.update(observation)
        return self

    def predict(self, action: int | None = None) -> "ParticleFilter":
        """Move every particle by a draw from the transition of ``action`` (None: unknown)."""
        self._check_ready()
        self._states = engine.sample_next(self.model, self._states, action, self.rng)
        return self

    def update(self, observation: Any) -> "ParticleFilter":
        """Weigh the particles by the reading's likelihood; resample if the ESS is low."""
        self._check_ready()
        reading = self.model.sensor.to_reading(observation)
        w = self._w * self._likelihood(reading)
        z = float(w.sum())
        if not z > 0.0 or not np.isfinite(z):
            possible = float(engine.likelihood(self.model, reading).sum()) > 0.0
            if not possible or self.on_depletion == "raise":
                what = "in every state" if not possible else "at every particle (particle deprivation)"
                raise ImpossibleObservationError(
                    f"observation {observation!r} has probability zero {what} under the particle "
                    f"filter's model ({self.model!r})"
                )
            self._draw_prior(reading)
            self.n_reinitialisations += 1
            return self
        self._w = w / z
        self.log_likelihood += float(np.log(z))
        if self.effective_sample_size < self.resample_threshold * self.n_particles:
            self.resample()
        return self

    def step(self, action: int | None, observation: Any) -> "ParticleFilter":
        """Predict with ``action``, then update with ``observation``.  On an impossible
        observation the particles are left as they were before the step."""
        before = (self._states, self._w)
        self.predict(action)
        try:
            self.update(observation)
        except ImpossibleObservationError:
            self._states, self._w = before
            raise
        return self

    def resample(self) -> "ParticleFilter":
        """Resample the particles by their weights (the weights become equal)."""
        self._check_ready()
        n = self.n_particles
        if self.resampling == "systematic":
            idx = systematic_resample(self._w, self.rng)
        else:
            idx = self.rng.choice(n, size=n, p=self._w)
        self._states = self._states[idx]
        self._w = np.full(n, 1.0 / n)
        self.n_resamples += 1
        return self

    # -- reading the belief -----------------------------------------------------------------------
    @property
    def effective_sample_size(self) -> float:
        """``1 / sum(w^2)`` of the normalised weights (N when they are equal)."""
        self._check_ready()
        return float(1.0 / np.square(self._w).sum())

    @property
    def particles(self) -> np.ndarray:
        """The particles' states as an (N, 3) int array of ``(layer, row, col)`` (a copy)."""
        self._check_ready()
        return self._states.copy()

    @property
    def weights(self) -> np.ndarray:
        """The normalised weights, (N,) (a copy)."""
        self._check_ready()
        return self._w.copy()

    @property
    def full_belief(self) -> np.ndarray:
        """The weighted histogram of the particles over hidden states, (L, H, W) float64."""
        self._check_ready()
        L, H, W = self.model.belief_shape
        st = self._states
        flat = (st[:, 0] * H + st[:, 1]) * W + st[:, 2]
        return np.bincount(flat, weights=self._w, minlength=L * H * W).reshape(L, H, W)

    @property
    def position_belief(self) -> np.ndarray:
        """The weighted histogram of the particles' positions, (H, W) float64, summing to 1."""
        self._check_ready()
        H, W = self.model.shape
        st = self._states
        return np.bincount(st[:, 1] * W + st[:, 2], weights=self._w, minlength=H * W).reshape(H, W)

    @property
    def belief_vector(self) -> np.ndarray:
        """The histogram over free states as a vector (layer-major), like ForwardFilter's."""
        return self.model.to_vector(self.full_belief)

    def _likelihood(self, reading: int) -> np.ndarray:
        """P(reading | particle) for every particle."""
        lik = engine.likelihood(self.model, reading)
        st = self._states
        return lik[st[:, 0], st[:, 1], st[:, 2]] if lik.ndim == 3 else lik[st[:, 1], st[:, 2]]

    def _check_ready(self) -> None:
        if self._w is None:
            raise RuntimeError("call ParticleFilter.reset() before using the filter")
