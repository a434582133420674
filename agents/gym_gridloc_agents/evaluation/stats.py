"""Aggregates across seeds: mean, interquartile mean, bootstrap intervals of the mean.

A handful of training seeds is a small sample; following Agarwal et al. (2021), "Deep
Reinforcement Learning at the Edge of the Statistical Precipice", a result across seeds is given
as the mean, the interquartile mean (IQM: robust to one outlying seed, less noisy than the median)
and a percentile-bootstrap 95% interval of the mean (resampling the seeds with replacement; the
resampling generator has a fixed seed, so the same values always give the same interval).

A bootstrap over a handful of seeds alone says little: with 3 seeds the percentile interval of
their mean is their range, and their IQM is their mean (nothing is trimmed below 4 values).  Where
every seed played the same episodes, :func:`hierarchical_ci` resamples the seeds, then the common
episodes, so the interval holds both sources of spread.

Used by ``gridloc sweep`` (per configuration) and ``gridloc bench`` with several ``--ppo-model``
files (one row across seeds); :func:`wilson_ci95` gives the benchmark's intervals of rates.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: Seed of the bootstrap's generator: the interval is a function of the values alone.
BOOTSTRAP_SEED = 0
#: Bootstrap resamples (every interval of this package; rliable's examples use 2000 to 50,000).
BOOTSTRAP_RESAMPLES = 10_000


def _values(values: Sequence[float]) -> np.ndarray:
    x = np.asarray(values, dtype=float).ravel()
    if x.size == 0:
        raise ValueError("no values to aggregate")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"values must be finite numbers, got {list(values)!r}")
    return x


def mean(values: Sequence[float]) -> float:
    return float(_values(values).mean())


def iqm(values: Sequence[float]) -> float:
    """Interquartile mean: ``scipy.stats.trim_mean(x, 0.25)``, the mean after dropping
    ``floor(n / 4)`` values at each end of the sorted values (rliable's ``aggregate_iqm``).  With
    fewer than 4 values nothing is dropped: it is the mean."""
    from scipy.stats import trim_mean

    return float(trim_mean(_values(values), 0.25))


def bootstrap_ci(values: Sequence[float], *, confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES,
                 seed: int = BOOTSTRAP_SEED, statistic: Callable[..., Any] = np.mean) -> list[float]:
    """Percentile-bootstrap interval of ``statistic`` (the mean; :func:`iqm` for learning
    curves): ``scipy.stats.bootstrap`` with ``resamples`` resamples of the values with
    replacement, generator ``numpy.random.default_rng(seed)``.  Values that are all equal (one
    value, say) give ``[value, value]``."""
    from scipy.stats import bootstrap

    x = _values(values)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if np.ptp(x) == 0:
        return [float(x[0]), float(x[0])]
    if statistic is iqm:
        from scipy.stats import trim_mean

        statistic = functools.partial(trim_mean, proportiontocut=0.25)
    res = bootstrap((x,), statistic, n_resamples=int(resamples), confidence_level=confidence, method="percentile",
                    rng=np.random.default_rng(seed), vectorized=True, axis=-1)
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def aggregate(values: Sequence[float]) -> dict[str, Any]:
    """``{"n", "mean", "iqm", "ci95", "values"}`` of the values (one per seed)."""
    x = _values(values)
    return {"n": int(x.size), "mean": mean(x), "iqm": iqm(x), "ci95": bootstrap_ci(x),
            "values": [float(v) for v in x]}


def hierarchical_replicates(groups: Sequence[np.ndarray], signs: Sequence[float] | None = None, *,
                            resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> np.ndarray:
    """Bootstrap replicates of ``sum_g signs[g] * mean(groups[g])`` where ``groups[g]`` is a
    ``(seeds, episodes)`` array, every group and seed on the same episodes (common random numbers).
    Each replicate draws every group's seeds with replacement (independently per group), then the
    episodes with replacement, the same draw of episodes for every group and seed (so that a
    difference of two groups stays paired).  With one seed per group it is the paired bootstrap
    over episodes."""
    arrays = [np.atleast_2d(np.asarray(g, dtype=float)) for g in groups]
    signs = [1.0] * len(arrays) if signs is None else [float(s) for s in signs]
    if not arrays or len(signs) != len(arrays):
        raise ValueError("hierarchical_replicates needs one sign per group and at least one group")
    n = arrays[0].shape[1]
    if n == 0 or any(a.shape[1] != n or a.shape[0] == 0 for a in arrays):
        raise ValueError(f"every group needs seeds on the same, non-empty episodes, got shapes {[a.shape for a in arrays]}")
    for a in arrays:
        _values(a)
    rng = np.random.default_rng(seed)
    out = np.empty(int(resamples))
    chunk = max(1, min(int(resamples), 4_000_000 // n))  # a chunk of replicates x episodes stays small
    for lo in range(0, int(resamples), chunk):
        r = min(chunk, int(resamples) - lo)
        per_episode = np.zeros((r, n))
        for a, sign in zip(arrays, signs):
            s = a.shape[0]
            drawn = rng.multinomial(s, np.full(s, 1.0 / s), size=r)  # how often each seed is drawn
            per_episode += sign * (drawn @ a) / s
        episodes = rng.integers(0, n, size=(r, n))
        out[lo: lo + r] = np.take_along_axis(per_episode, episodes, axis=1).mean(axis=1)
    return out


def percentile_interval(replicates: np.ndarray, confidence: float = 0.95) -> list[float]:
    """The percentile interval of bootstrap replicates (``numpy.percentile``'s linear rule, as
    ``scipy.stats.bootstrap(method="percentile")``)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    alpha = (1 - confidence) / 2
    lo, hi = np.percentile(replicates, [100 * alpha, 100 * (1 - alpha)])
    return [float(lo), float(hi)]


def hierarchical_ci(values: Sequence[Sequence[float]] | np.ndarray, *, confidence: float = 0.95,
                    resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> list[float]:
    """Percentile-bootstrap interval of the mean of ``values`` (``(seeds, episodes)``: each seed's
    results on the same episodes), resampling the seeds, then the episodes
    (:func:`hierarchical_replicates`).  Values that are all equal give ``[value, value]``."""
    x = np.atleast_2d(np.asarray(values, dtype=float))
    if x.size and np.ptp(_values(x)) == 0:
        return [float(x.flat[0])] * 2
    return percentile_interval(hierarchical_replicates([x], resamples=resamples, seed=seed), confidence)


def median_index(scores: Sequence[float]) -> int:
    """The position of the median of ``scores`` (lower median for an even count: the
    ``(n - 1) // 2``-th smallest; ties keep the earlier position)."""
    x = _values(scores)
    return sorted(range(x.size), key=lambda i: (x[i], i))[(x.size - 1) // 2]


def wilson_ci95(successes: int, n: int) -> list[float]:
    """The Wilson score 95% interval of a proportion ``successes / n``
    (``scipy.stats.binomtest(successes, n).proportion_ci(0.95, method="wilson")``)."""
    from scipy.stats import binomtest

    if n <= 0:
        return [0.0, 1.0]
    ci = binomtest(int(successes), int(n)).proportion_ci(0.95, method="wilson")
    return [0.0 if successes == 0 else max(0.0, float(ci.low)),  # exact ends, no rounding residue
            1.0 if successes == n else min(1.0, float(ci.high))]
