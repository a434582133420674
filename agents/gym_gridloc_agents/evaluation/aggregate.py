"""Aggregates across tasks and seeds as rliable defines them (Agarwal et al. 2021, "Deep
Reinforcement Learning at the Edge of the Statistical Precipice"), on normalised scores
(:mod:`gym_gridloc_agents.evaluation.scores`: 0 the random walk, 1 the optimum or the best planner).

A policy's scores are given per task: ``{task: [score of run 1, run 2, ...]}`` (one run per training
seed; a planner has one run per task).  Tasks may hold different numbers of runs.

- :func:`iqm_interval`: the interquartile mean of all runs x tasks (rliable's ``aggregate_iqm``:
  ``scipy.stats.trim_mean(scores, 0.25)`` of the pooled scores) with a *stratified* percentile
  bootstrap 95% interval: each resample draws every task's runs with replacement within that task
  (rliable's ``StratifiedBootstrap``), 10,000 resamples.  The interval is over runs (seeds); with
  one run per task there is nothing to resample and none is given.
- :func:`performance_profile`: the fraction of all runs x tasks whose score exceeds tau (rliable's
  score distribution, ``np.mean(scores > tau)``), with stratified bootstrap intervals.
- :func:`probability_of_improvement`: P(X > Y) per task from the runs (the Mann-Whitney U
  statistic over ``runs_x * runs_y``, ties counted half), averaged over tasks (rliable's
  ``probability_of_improvement``); the tasks are those both have.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from gym_gridloc_agents.evaluation.stats import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, percentile_interval

#: The thresholds of the performance profiles of ``gridloc report``.
PROFILE_TAUS = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0)


def _tasks(scores: Mapping[str, Sequence[float]]) -> list[np.ndarray]:
    arrays = [np.asarray(v, dtype=float).ravel() for v in scores.values()]
    if not arrays or any(a.size == 0 for a in arrays):
        raise ValueError("scores need at least one task, each with at least one run")
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise ValueError("scores must be finite numbers")
    return arrays


def _iqm_rows(pooled: np.ndarray) -> np.ndarray:
    """The IQM of each row of ``pooled`` (``scipy.stats.trim_mean(row, 0.25)``)."""
    from scipy.stats import trim_mean

    return np.asarray(trim_mean(pooled, 0.25, axis=-1), dtype=float)


def stratified_replicates(scores: Mapping[str, Sequence[float]], statistic, *, resamples: int = BOOTSTRAP_RESAMPLES,
                          seed: int = BOOTSTRAP_SEED) -> np.ndarray:
    """``statistic(pooled)`` of stratified resamples: every task's runs drawn with replacement
    within the task, the tasks' draws pooled into one row per replicate (``pooled`` is
    ``(replicates, all runs)``); returns one value (or row of values) per replicate."""
    arrays = _tasks(scores)
    rng = np.random.default_rng(seed)
    pooled = np.concatenate([a[rng.integers(0, a.size, size=(int(resamples), a.size))] for a in arrays], axis=1)
    return np.asarray(statistic(pooled))


def iqm_interval(scores: Mapping[str, Sequence[float]], *, confidence: float = 0.95,
                 resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> dict[str, Any]:
    """``{"iqm", "ci95", "tasks", "runs", "interval_over"}``: the IQM of all runs x tasks and its
    stratified bootstrap interval over runs (None with one run per task: nothing to resample)."""
    arrays = _tasks(scores)
    pooled = np.concatenate(arrays)
    out: dict[str, Any] = {"iqm": float(_iqm_rows(pooled[None])[0]), "tasks": len(arrays),
                           "runs": [int(a.size) for a in arrays], "ci95": None,
                           "interval_over": "runs (training seeds) within each task, stratified bootstrap"}
    if any(a.size > 1 for a in arrays):
        reps = stratified_replicates(scores, _iqm_rows, resamples=resamples, seed=seed)
        out["ci95"] = percentile_interval(reps, confidence)
    else:
        out["interval_over"] = "none: one run per task"
    return out


def performance_profile(scores: Mapping[str, Sequence[float]], taus: Sequence[float] = PROFILE_TAUS, *,
                        confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES,
                        seed: int = BOOTSTRAP_SEED) -> dict[str, Any]:
    """``{"taus", "fraction", "ci95"}``: per tau, the fraction of all runs x tasks scoring above
    it, with stratified bootstrap intervals (None with one run per task)."""
    arrays = _tasks(scores)
    taus = np.asarray(taus, dtype=float)
    pooled = np.concatenate(arrays)
    fraction = [float(np.mean(pooled > t)) for t in taus]
    ci = None
    if any(a.size > 1 for a in arrays):
        reps = stratified_replicates(scores, lambda p: (p[:, :, None] > taus).mean(axis=1), resamples=resamples, seed=seed)
        ci = [percentile_interval(reps[:, j], confidence) for j in range(taus.size)]
    return {"taus": [float(t) for t in taus], "fraction": fraction, "ci95": ci}


def probability_of_improvement(x: Mapping[str, Sequence[float]], y: Mapping[str, Sequence[float]]) -> float:
    """P(X > Y), averaged over the tasks both have: per task the Mann-Whitney U of X's runs against
    Y's over ``runs_x * runs_y`` (ties half; identical runs: 0.5)."""
    common = [t for t in x if t in y]
    if not common:
        raise ValueError("the two score sets share no task")
    probs = []
    for task in common:
        a, b = _tasks({task: x[task]})[0], _tasks({task: y[task]})[0]
        greater = (a[:, None] > b[None, :]).sum() + 0.5 * (a[:, None] == b[None, :]).sum()
        probs.append(greater / (a.size * b.size))
    return float(np.mean(probs))


__all__ = ["PROFILE_TAUS", "iqm_interval", "performance_profile", "probability_of_improvement", "stratified_replicates"]
