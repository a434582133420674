"""Normalised scores of benchmark rows: 0 is the random walk, 1 the optimum where it is known, else
the best planner, on the same task (environment, keywords and maps) and the same episodes.

The metric is the mean steps to localise (lower is better), or the accuracy at L under the
research protocol (``episode_length``; higher is better).  With ``zero`` the random walk's value
and ``one`` the reference's, ``normalised_score = (zero - x) / (zero - one)`` for steps and
``(x - zero) / (one - zero)`` for accuracy: 1 is the reference, 0 the random walk, below 0 worse
than the random walk.  The reference, named in every row (``normalised_reference``), is, in order:

1. the ``optimal`` policy's row on the same episodes (the exact optimum of a noiseless model);
2. a certified value of the task (:data:`CERTIFIED`: ColourGrid-v0's depth-7 lower bound; the
   optimum lies between it and the best planner's mean, so a score against it is a lower bound of
   the score against the optimum, and a planner's mean on finite episodes may score above 1);
3. accuracy 1 for the noiseless DepthMaze under the protocol (the ceiling, which the optimal
   policy reaches there from L = 20 on) when the ``optimal`` row is absent;
4. the best planner's row (``central``, ``expectimax``, ``mcts``, ``pomcp``: the lowest mean steps or
   the highest accuracy).

A row across seeds also gets each seed's score (``per_seed[i]["normalised_score"]``), the values
:mod:`gym_gridloc_agents.evaluation.aggregate` pools across tasks.  ``normalised_score_ci95`` is
the row's interval of its metric mapped through the same affine map (the references held fixed).
"""

from __future__ import annotations

from typing import Any

from gym_gridloc_agents.policies import PLANNER_POLICIES

#: Certified references, per environment with its default keywords on its fixed map:
#: ``gridloc bound ColourGrid-v0 --depth 7`` (``results/bounds/colourgrid_d7.json``).
CERTIFIED = {
    "ColourGrid-v0": {"name": "lower bound (depth 7)", "value": 2.9690135354075524,
                      "kind": "certified lower bound on the optimum (gridloc bound ColourGrid-v0 --depth 7); "
                              "the optimum lies between it and the best planner"},
}
#: DepthMaze keywords that make the model noisy (the ceiling of accuracy 1 is then no optimum).
NOISE_KWARGS = ("p_turn_fail", "p_move_fail", "p_depth_error", "kidnap_prob")


def metric(row: dict[str, Any]) -> tuple[str, bool]:
    """``(row key, lower is better)`` of the row's task: ``accuracy_at_L`` under the protocol, else ``mean_steps``."""
    return ("accuracy_at_L", False) if row.get("episode_length") else ("mean_steps", True)


def task_key(row: dict[str, Any]) -> tuple:
    """What makes two rows the same task on the same episodes: environment, keywords, maps, first seed."""
    return (row["env"], repr(sorted((row.get("env_kwargs") or {}).items())), bool(row.get("test_set")),
            row.get("seed_start", 0))


def references(rows: list[dict[str, Any]]) -> dict[tuple, dict[str, Any]]:
    """Per :func:`task_key`, the ``normalised_reference`` of its rows (``zero`` or ``one`` None when missing)."""
    out: dict[tuple, dict[str, Any]] = {}
    for key in dict.fromkeys(task_key(r) for r in rows):
        mine = [r for r in rows if task_key(r) == key]
        col, lower = metric(mine[0])
        have = [r for r in mine if r.get(col) is not None]
        rand = next((r for r in have if r["policy"] == "random" and "options" not in r), None)
        ref = {"metric": col, "lower_is_better": lower,
               "zero": None if rand is None else {"name": "random", "value": float(rand[col])}, "one": None}
        first = mine[0]
        optimal = next((r for r in have if r["policy"] == "optimal"), None)
        kwargs = first.get("env_kwargs") or {}
        if optimal is not None:
            ref["one"] = {"name": "optimal", "value": float(optimal[col]), "kind": "exact optimum (the optimal policy)"}
        elif first["env"] in CERTIFIED and not kwargs and not first.get("test_set") and col == "mean_steps":
            ref["one"] = dict(CERTIFIED[first["env"]])
        elif first["env"] == "DepthMaze-v0" and col == "accuracy_at_L" and not any(kwargs.get(k) for k in NOISE_KWARGS):
            ref["one"] = {"name": "accuracy 1", "value": 1.0, "kind": "ceiling of a noiseless maze (no optimal row)"}
        else:
            planners = [r for r in have if r["policy"] in PLANNER_POLICIES]
            if planners:
                best = (min if lower else max)(planners, key=lambda r: r[col])
                ref["one"] = {"name": best["policy"], "value": float(best[col]), "kind": "best planner"}
        out[key] = ref
    return out


def normalise(value: float | None, ref: dict[str, Any]) -> float | None:
    """``value`` on the scale of ``ref`` (None without both references or with equal ones)."""
    if value is None or ref.get("zero") is None or ref.get("one") is None:
        return None
    zero, one = ref["zero"]["value"], ref["one"]["value"]
    if zero == one:
        return None
    return float((value - zero) / (one - zero)) + 0.0  # (no -0.0)


def add_normalised_scores(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``normalised_score``, ``normalised_score_ci95`` and ``normalised_reference`` of every row
    (and ``normalised_score`` of each seed of a row across seeds), in place; returns ``rows``."""
    refs = references(rows)
    for r in rows:
        ref = refs[task_key(r)]
        col = ref["metric"]
        r["normalised_reference"] = ref
        r["normalised_score"] = normalise(r.get(col), ref)
        ci = r.get(f"{col}_ci95")
        ends = None if ci is None or r["normalised_score"] is None else sorted(normalise(v, ref) for v in ci)
        r["normalised_score_ci95"] = ends
        for s in r.get("per_seed") or []:
            s["normalised_score"] = normalise(s.get(col), ref)
    return rows


__all__ = ["CERTIFIED", "add_normalised_scores", "metric", "normalise", "references", "task_key"]
