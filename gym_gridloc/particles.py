"""Monte Carlo localisation: a particle filter on the same :class:`GridModel` as the exact filter."""

from __future__ import annotations

from typing import Any

import numpy as np

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


class _Sampler:
    """Vectorised sampling of the next states of many particles under one action.

    For every state, the cumulative probabilities of the stencil's terms (zero for terms whose
    source layer is another one) are laid out as ``cum[layer, row, col, term]``; a particle's next
    term is the first whose cumulative probability exceeds one uniform draw.
    """

    def __init__(self, model: GridModel, action: int | None) -> None:
        terms = model.terms(action)
        table = np.zeros((*model.belief_shape, len(terms)))
        for i, t in enumerate(terms):
            table[t.src, :, :, i] = t.weight
        self.cum = np.cumsum(table, axis=-1)
        self.dst = np.array([t.dst for t in terms], dtype=np.int64)
        self.dr = np.array([t.dr for t in terms], dtype=np.int64)
        self.dc = np.array([t.dc for t in terms], dtype=np.int64)

    def __call__(self, layer: np.ndarray, row: np.ndarray, col: np.ndarray, rng: np.random.Generator):
        cum = self.cum[layer, row, col]  # (N, n_terms)
        u = rng.random(len(layer)) * cum[:, -1]
        idx = np.minimum((cum <= u[:, None]).sum(axis=1), cum.shape[1] - 1)
        return self.dst[idx], row + self.dr[idx], col + self.dc[idx]


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
        if not isinstance(model, GridModel):
            raise TypeError(f"ParticleFilter needs a GridModel, got {type(model).__name__}")
        if kidnap_prob is not None:
            model = model.with_kidnapping(kidnap_prob)
        self.model = model
        self.n_particles = check_int("n_particles", n_particles, minimum=1)
        self.resample_threshold = check_probability("resample_threshold", resample_threshold)
        self.resampling = check_choice("resampling", resampling, ("systematic", "multinomial"))
        self.on_depletion = check_choice("on_depletion", on_depletion, ("reinitialise", "raise"))
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._samplers: dict[int | None, _Sampler] = {}
        free_cells = np.asarray(model.grid.free_cells, dtype=np.int64).reshape(-1, 2)
        self._free_rows, self._free_cols = free_cells[:, 0], free_cells[:, 1]
        self._layer: np.ndarray | None = None
        self._row: np.ndarray | None = None
        self._col: np.ndarray | None = None
        self._w: np.ndarray | None = None
        self.log_likelihood = 0.0
        self.n_resamples = 0
        self.n_reinitialisations = 0

    # -- sampling helpers -------------------------------------------------------------------------
    def seed(self, seed: int | np.random.SeedSequence | None) -> "ParticleFilter":
        """Restart the random generator from ``seed`` (anything ``numpy.random.default_rng`` takes)."""
        self.rng = np.random.default_rng(seed)
        return self

    def _states(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """State indices (layer-major over free cells) -> (layer, row, col) arrays."""
        layer, cell = np.divmod(flat, self.model.grid.n_free)
        return layer.astype(np.int64), self._free_rows[cell], self._free_cols[cell]

    def _draw_prior(self, reading: int | None = None) -> None:
        n, s = self.n_particles, self.model.n_states
        if reading is None:
            flat = self.rng.integers(s, size=n)
        else:
            p = self.model.likelihood_vector(reading)
            flat = self.rng.choice(s, size=n, p=p / p.sum())
        self._layer, self._row, self._col = self._states(flat)
        self._w = np.full(n, 1.0 / n)

    def _sampler(self, action: int | None) -> _Sampler:
        if action not in self._samplers:
            self._samplers[action] = _Sampler(self.model, action)
        return self._samplers[action]

    # -- the API ---------------------------------------------------------------------------------
    def reset(self, observation: Any = None) -> "ParticleFilter":
        """Draw the particles from the prior (uniform over free states), then update with
        ``observation`` if given."""
        self._draw_prior()
        self.log_likelihood = 0.0
        self.n_resamples = 0
        self.n_reinitialisations = 0
        if observation is not None:
            self.update(observation)
        return self

    def predict(self, action: int | None = None) -> "ParticleFilter":
        """Move every particle by a draw from the transition of ``action`` (None: unknown)."""
        self._check_ready()
        a = None if action is None else self.model.check_action(action)
        layer, row, col = self._sampler(a)(self._layer, self._row, self._col, self.rng)
        p = self.model.kidnap_prob
        if p > 0.0:
            kidnapped = self.rng.random(self.n_particles) < p
            k = int(kidnapped.sum())
            if k:
                kl, kr, kc = self._states(self.rng.integers(self.model.n_states, size=k))
                layer[kidnapped], row[kidnapped], col[kidnapped] = kl, kr, kc
        self._layer, self._row, self._col = layer, row, col
        return self

    def update(self, observation: Any) -> "ParticleFilter":
        """Weigh the particles by the reading's likelihood; resample if the ESS is low."""
        self._check_ready()
        reading = self.model.sensor.to_reading(observation)
        lik = self.model.likelihood(reading)[self._row, self._col]
        w = self._w * lik
        z = float(w.sum())
        if not z > 0.0 or not np.isfinite(z):
            possible = float(self.model.likelihood(reading).sum()) > 0.0
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
        before = (self._layer, self._row, self._col, self._w)
        self.predict(action)
        try:
            self.update(observation)
        except ImpossibleObservationError:
            self._layer, self._row, self._col, self._w = before
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
        self._layer, self._row, self._col = self._layer[idx], self._row[idx], self._col[idx]
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
        return np.stack([self._layer, self._row, self._col], axis=1)

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
        flat = (self._layer * H + self._row) * W + self._col
        return np.bincount(flat, weights=self._w, minlength=L * H * W).reshape(L, H, W)

    @property
    def position_belief(self) -> np.ndarray:
        """The weighted histogram of the particles' positions, (H, W) float64, summing to 1."""
        self._check_ready()
        H, W = self.model.shape
        return np.bincount(self._row * W + self._col, weights=self._w, minlength=H * W).reshape(H, W)

    @property
    def belief(self) -> np.ndarray:
        """The histogram over free states as a vector (layer-major), like ForwardFilter.belief."""
        return self.model.to_vector(self.full_belief)

    def _check_ready(self) -> None:
        if self._w is None:
            raise RuntimeError("call ParticleFilter.reset() before using the filter")
