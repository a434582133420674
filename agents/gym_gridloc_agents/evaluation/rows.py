"""Benchmark rows: one row from the per-episode arrays of a policy's episodes (:func:`summarise`),
one row across training seeds (:func:`seed_aggregate`), and the gap of every row to the best
planner of its environment and its normalised score (:func:`add_gaps`).
:mod:`gym_gridloc_agents.evaluation.bench` runs the episodes; this module only counts.

Every row keeps its episodes' results compactly in ``per_episode`` (what paired comparisons on the
same episodes need, :mod:`gym_gridloc_agents.evaluation.paired`): ``{"seeds": S, "steps": [S
strings of space-separated steps], "accuracy_at_L": [S strings of 0/1]}`` (the latter under the
protocol), one string per model seed, episode ``i`` in place ``i``; :func:`episode_arrays` reads
them back as ``(S, episodes)`` arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc_agents.evaluation import stats
from gym_gridloc_agents.evaluation.scores import add_normalised_scores
from gym_gridloc_agents.evaluation.stats import wilson_ci95
from gym_gridloc_agents.policies import PLANNER_POLICIES

#: Steps after which the accuracy (most probable cell = the truth) is reported.
BUDGETS = (5, 10, 25, 50)


@dataclass(frozen=True)
class Task:
    """One row's policy on one environment: ``env_kwargs`` for ``gym.make``, ``model_path`` for a
    learned policy (None: the shipped one), ``options`` for the policy (e.g. a planner's depth)."""

    env_id: str
    policy: str
    env_kwargs: dict = field(default_factory=dict)
    model_path: str | Path | None = None
    options: dict = field(default_factory=dict)


def summarise(task: Task | str, policy_name: str | None = None, parts: Sequence[dict[str, Any]] = (), *,
              seed_start: int, budgets: Sequence[int] = BUDGETS, test_set: bool = False) -> dict[str, Any]:
    """One benchmark row from the per-episode arrays of one or more :func:`simulate` runs
    (``summarise(task, parts=...)``, or ``summarise(env_id, policy_name, parts)``)."""
    if not isinstance(task, Task):
        task = Task(task, policy_name)
    cat = {k: np.concatenate([p[k] for p in parts]) for k in ("steps", "localised", "success", "truncated", "correct_at", "collapsed_end")}
    steps, localised, success, correct_at = cat["steps"], cat["localised"], cat["success"], cat["correct_at"]
    max_steps, length = parts[0]["max_steps"], parts[0].get("episode_length")
    n = len(steps)
    mean = float(steps.mean())
    sd = float(steps.std(ddof=1)) if n > 1 else 0.0
    half = 1.96 * sd / math.sqrt(n)
    decisions = sum(p["decisions"] for p in parts)
    row = {
        "env": task.env_id,
        "policy": task.policy,
        "episodes": int(n),
        "success_rate": float(success.mean()),
        "truncated_rate": float(cat["truncated"].mean()),
        "localised_rate": float(localised.mean()),
        "localised_correct_rate": float(success.sum() / localised.sum()) if localised.any() else None,
        "mean_steps": mean,
        "median_steps": float(np.median(steps)),
        "mean_steps_ci95": [mean - half, mean + half],
        "std_steps": sd,
        "accuracy_at": {str(k): float(correct_at[:, k].mean()) for k in budgets},
        "accuracy_at_ci95": {str(k): wilson_ci95(int(correct_at[:, k].sum()), n) for k in budgets},
        "success_rate_ci95": wilson_ci95(int(success.sum()), n),
        "ms_per_decision": 1000.0 * sum(p["decision_seconds"] for p in parts) / max(decisions, 1),
        "max_episode_steps": int(max_steps),
        "seed_start": int(seed_start),
        "seconds": round(sum(p["seconds"] for p in parts), 3),
        **({"maps": len(set().union(*(p["maps"] for p in parts)))} if all("maps" in p for p in parts) else {}),
        "model": parts[0]["model"],
        "localised_curve": [float(np.mean(localised & (steps <= s))) for s in range(max_steps + 1)],
        "accuracy_curve": [float(x) for x in correct_at[:, : max_steps + 1].mean(axis=0)],
    }
    row.update({k: dict(v) for k, v in (("env_kwargs", task.env_kwargs), ("options", task.options)) if v})
    row["per_episode"] = _per_episode([steps], [cat["collapsed_end"]] if length else None)
    if test_set:
        row["test_set"] = True
    if length:
        hits, argmax_hits = int(cat["collapsed_end"].sum()), int(correct_at[:, length].sum())
        row.update({"episode_length": int(length), "accuracy_at_L": hits / n, "accuracy_at_L_ci95": wilson_ci95(hits, n),
                    "argmax_accuracy_at_L": argmax_hits / n, "argmax_accuracy_at_L_ci95": wilson_ci95(argmax_hits, n)})
    return row


def seed_aggregate(task: Task, runs: Sequence[Sequence[dict[str, Any]]], *, seed_start: int,
                   budgets: Sequence[int] = BUDGETS, test_set: bool = False) -> dict[str, Any]:
    """One row across seeds from the :func:`simulate` parts of several models (``runs[i]``: model
    ``i``'s parts, every model on the same episodes); see the module docstring."""
    per = [summarise(task, parts=parts, seed_start=seed_start, budgets=budgets, test_set=test_set) for parts in runs]
    row = summarise(task, parts=[p for parts in runs for p in parts], seed_start=seed_start, budgets=budgets, test_set=test_set)
    if len({r["episodes"] for r in per}) != 1:
        raise ValueError(f"the seeds of {task.policy} on {task.env_id} played different numbers of episodes")

    def seeds_episodes(key: str) -> np.ndarray:  # (seeds, episodes): every seed's results on the same episodes
        return np.stack([np.concatenate([np.asarray(p[key]) for p in parts]) for parts in runs]).astype(float)

    steps, success, correct_at = seeds_episodes("steps"), seeds_episodes("success"), seeds_episodes("correct_at")
    agg = stats.aggregate([r["mean_steps"] for r in per])
    row.update({
        "episodes": per[0]["episodes"], "episodes_total": row["episodes"], "seeds": len(per),
        "mean_steps": agg["mean"], "mean_steps_iqm": agg["iqm"], "mean_steps_ci95": stats.hierarchical_ci(steps),
        "mean_steps_seed_range": [min(agg["values"]), max(agg["values"])], "iqm_trimmed": len(per) >= 4,
        "ci95": "95% interval of the mean across seeds: a bootstrap resampling the seeds, then the episodes every seed "
                "played (mean_steps, success_rate, accuracy_at, accuracy_at_L)",
        "success_rate_ci95": stats.hierarchical_ci(success),
        "accuracy_at_ci95": {k: stats.hierarchical_ci(correct_at[:, :, int(k)]) for k in row["accuracy_at"]},
        "model": [r["model"] for r in per],
        "per_seed": [{k: r[k] for k in ("model", "mean_steps", "median_steps", "mean_steps_ci95", "success_rate", "truncated_rate",
                                        "localised_correct_rate", "accuracy_at", "seconds", "accuracy_at_L") if k in r} for r in per],
    })
    collapsed = seeds_episodes("collapsed_end") if "accuracy_at_L" in row else None
    if collapsed is not None:
        acc = stats.aggregate([r["accuracy_at_L"] for r in per])
        row.update({"accuracy_at_L": acc["mean"], "accuracy_at_L_iqm": acc["iqm"], "accuracy_at_L_ci95": stats.hierarchical_ci(collapsed),
                    "accuracy_at_L_seed_range": [min(acc["values"]), max(acc["values"])]})
    row["per_episode"] = _per_episode(steps, collapsed)
    return row


def _per_episode(steps, collapsed) -> dict[str, Any]:
    """The compact ``per_episode`` entry of a row (module docstring) from ``(seeds, episodes)`` arrays."""
    out: dict[str, Any] = {"seeds": len(steps), "steps": [" ".join(str(int(v)) for v in s) for s in steps]}
    if collapsed is not None:
        out["accuracy_at_L"] = ["".join("1" if v else "0" for v in c) for c in collapsed]
    return out


def episode_arrays(row: dict[str, Any]) -> dict[str, np.ndarray] | None:
    """A row's ``per_episode`` entry as ``(seeds, episodes)`` arrays (``steps``, and
    ``accuracy_at_L`` under the protocol); None for a row without one (an older results file)."""
    entry = row.get("per_episode")
    if not entry:
        return None
    out = {"steps": np.array([[int(v) for v in s.split()] for s in entry["steps"]], dtype=float)}
    if "accuracy_at_L" in entry:
        out["accuracy_at_L"] = np.array([[c == "1" for c in s] for s in entry["accuracy_at_L"]], dtype=float)
    return out


def add_gaps(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``gap_to_best_planner`` of every row: its mean steps over the lowest mean steps of a
    planner's row on the same environment (and keyword arguments), where there is one; and its
    normalised score (:func:`gym_gridloc_agents.evaluation.scores.add_normalised_scores`)."""
    best: dict[str, float] = {}
    for r in rows:
        if r["policy"] in PLANNER_POLICIES:
            key = _env_key(r)
            best[key] = min(best.get(key, math.inf), r["mean_steps"])
    for r in rows:
        b = best.get(_env_key(r))
        r["gap_to_best_planner"] = None if b is None or b <= 0 else r["mean_steps"] / b
    return add_normalised_scores(rows)


def _env_key(row: dict[str, Any]) -> str:
    return f"{row['env']} {sorted(row.get('env_kwargs', {}).items())} {row.get('test_set', False)}"
