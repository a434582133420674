"""Aggregates across seeds: mean, interquartile mean, bootstrap interval of the mean.

A handful of training seeds is a small sample; following Agarwal et al. (2021), "Deep
Reinforcement Learning at the Edge of the Statistical Precipice", a result across seeds is given
as the mean, the interquartile mean (IQM: robust to one outlying seed, less noisy than the median)
and a percentile-bootstrap 95% interval of the mean (resampling the seeds with replacement; the
resampling generator has a fixed seed, so the same values always give the same interval).

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
#: Bootstrap resamples.
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
