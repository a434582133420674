"""Targets judged by intervals: the ``targets`` table of ``gridloc report``.

A target is a line of ``targets.json`` in the results directory: which row (``source``, the stem
of a results file; ``env``; the row's ``env_kwargs``, all of them; ``policy``) and what it must
reach: ``at_least`` or ``at_most`` a number (of the row's metric: accuracy at L under the
protocol, mean steps otherwise), ``better_than`` another policy of the same task, or ``within``
a fraction of another policy's mean steps (``{"of": "ppo", "fraction": 0.1}``: at most 10% more
steps).  The verdict comes from an interval, never from a point estimate:

- a number: ``met`` when the row's 95% interval (over the episodes, or over the seeds and then the
  episodes for a row across training seeds) lies wholly on the target's side of it, ``not met``
  when it lies wholly on the other side, else ``undecided`` (the interval holds the target);
- another policy: the paired comparison on the common episodes
  (:func:`gym_gridloc_agents.evaluation.paired.compare`): ``met`` when it says ``better``, ``not
  met`` when it says ``worse``, ``tie`` otherwise;
- a fraction of another policy: the paired interval of A's mean minus ``1 + fraction`` times B's
  on the common episodes: ``met`` when it lies below 0, ``not met`` above, else ``undecided``.

A target whose row is not in the results files is listed as ``not measured``: a table never
leaves a target out.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from gym_gridloc_agents.evaluation.report import env_label
from gym_gridloc_agents.evaluation.scores import metric

SPEC = "targets.json"
KEYS = {"task", "source", "env", "env_kwargs", "policy", "at_least", "at_most", "better_than", "within"}
GOALS = ("at_least", "at_most", "better_than", "within")


def read_targets(results: str | Path) -> list[dict[str, Any]]:
    """The targets of ``results/targets.json``, checked (``ValueError`` naming what is wrong)."""
    path = Path(results) / SPEC
    try:
        targets = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read the targets ({exc})") from None
    if not isinstance(targets, list):
        raise ValueError(f"{path}: expected a list of targets, got {type(targets).__name__}")
    for i, t in enumerate(targets):
        if not isinstance(t, dict) or not {"task", "source", "env", "policy"} <= set(t) or set(t) - KEYS:
            raise ValueError(f"{path}: target {i} must have task, source, env and policy, and only {', '.join(sorted(KEYS))}")
        if sum(k in t for k in GOALS) != 1:
            raise ValueError(f"{path}: target {i} ({t['task']}) needs exactly one of {', '.join(GOALS)}")
        w = t.get("within")
        if w is not None and not (isinstance(w, dict) and set(w) == {"of", "fraction"} and isinstance(w["of"], str)
                                  and isinstance(w["fraction"], (int, float)) and 0 <= w["fraction"] < 10):
            raise ValueError(f"{path}: target {i} ({t['task']}): within must be {{\"of\": POLICY, \"fraction\": F}} "
                             f"with F from 0 (e.g. 0.1: at most 10% more steps), got {w!r}")
    return targets


def _row(rows: Sequence[dict[str, Any]], target: dict[str, Any], policy: str) -> dict[str, Any] | None:
    want = target.get("env_kwargs", {})
    for r in rows:
        if r.get("env") == target["env"] and r.get("policy") == policy and r.get("env_kwargs", {}) == want:
            return r
    return None


def _episodes(r: dict[str, Any]) -> str:
    maps = r.get("maps")
    on = "" if maps is None else " on one map" if maps == 1 else f" on {maps} maps"
    return f"{r['episodes']}{on} x {r['seeds']} seeds" if "seeds" in r else f"{r['episodes']}{on}, one model"


def judge(target: dict[str, Any], rows: Sequence[dict[str, Any]]) -> dict[str, str]:
    """The measured value, its interval and the verdict of one target on these rows."""
    row = _row(rows, target, target["policy"])
    if row is None:
        return {"measured": "-", "episodes": "-", "verdict": "not measured"}
    col, lower_is_better = metric(row)
    digits = 4 if col == "accuracy_at_L" else 2  # (an interval's end can round onto the target at 3)
    if "better_than" in target or "within" in target:
        from gym_gridloc_agents.evaluation import paired

        within = target.get("within")
        if within and not lower_is_better:
            raise ValueError(f"target {target['task']!r}: within compares mean steps, not {col}")
        scale = 1.0 + within["fraction"] if within else 1.0
        other = _row(rows, target, within["of"] if within else target["better_than"])
        if other is None or "per_episode" not in row or "per_episode" not in other:
            return {"measured": f"{row[col]:.{digits}f}", "episodes": _episodes(row), "verdict": "not measured"}
        p = paired.compare(row, other, scale=scale)
        lo, hi = p["ci95"]
        versus = f"{scale:g} x " if within else ""
        return {"measured": f"{row[col]:.{digits}f} vs {versus}{other[col]:.{digits}f}: difference {p['difference']:+.{digits}f} "
                            f"({lo:+.{digits}f} to {hi:+.{digits}f}, paired)",
                "episodes": _episodes(row),
                "verdict": {"better": "met", "worse": "not met"}.get(p["verdict"], "undecided" if within else "tie")}
    lo, hi = row.get(f"{col}_ci95") or (row[col], row[col])
    goal, above = (target["at_least"], True) if "at_least" in target else (target["at_most"], False)
    if (lo > goal if above else hi < goal):
        verdict = "met"
    elif (hi < goal if above else lo > goal):
        verdict = "not met"
    else:
        verdict = "undecided"
    return {"measured": f"{row[col]:.{digits}f} ({lo:.{digits}f}-{hi:.{digits}f})", "episodes": _episodes(row),
            "verdict": verdict}


def targets_table(files, targets: Sequence[dict[str, Any]]) -> str:
    """One line per target whose ``source`` is among ``files`` (``(stem, rows)``)."""
    by_stem = dict(files)
    lines = ["| task | target | policy | episodes | measured (95% CI) | verdict |", "| --- | --- | --- | --- | --- | --- |"]
    for t in targets:
        if t["source"] not in by_stem:
            continue
        goal = (f">= {t['at_least']}" if "at_least" in t else f"<= {t['at_most']}" if "at_most" in t
                else f"within {100 * t['within']['fraction']:g}% of {t['within']['of']} (paired)" if "within" in t
                else f"better than {t['better_than']} (paired)")
        found = judge(t, by_stem[t["source"]])
        lines.append(f"| {t['task']} | {goal} | {t['policy']} | {found['episodes']} | {found['measured']} | {found['verdict']} |")
    return "\n".join(lines)


__all__ = ["SPEC", "judge", "read_targets", "targets_table"]
