"""The result tables ``gridloc report`` writes into markdown files, each made from results files
alone (no number typed by hand).

A table is named ``KIND:SOURCES``: ``SOURCES`` is one or more results files joined by ``+``, each
the stem of a bench JSON in the results directory (``bench`` is ``results/bench.json``).  Kinds:

- ``rows``: one line per row: mean steps (or accuracy at L under the protocol) with its 95%
  interval (a row across seeds from an older file: the seeds' range instead), median, success, ms per decision, the ratio to the best planner, the normalised score;
- ``seeds``: the rows across training seeds: each seed's value, their mean, their IQM (only from 4
  seeds on: below, nothing is trimmed), and the 95% interval with what it is over;
- ``references``: per task, the metric and the two points of the normalised score;
- ``normalised``: the normalised score of every policy (columns) on every task (lines);
- ``aggregate``: per policy, across tasks and seeds, rliable's IQM of the normalised score with its
  stratified bootstrap interval, and the performance profile (the fraction of runs x tasks above tau);
- ``improvement``: rliable's probability of improvement of each policy over each other, on the
  tasks both ran;
- ``pairs``: the paired comparisons on common episodes (:mod:`gym_gridloc_agents.evaluation.paired`;
  rows that keep their episodes' results only);
- ``targets``: the targets of ``targets.json`` in the results directory whose rows are in these
  files, each judged by an interval (:mod:`gym_gridloc_agents.evaluation.targets`).

Normalised scores are computed per results file, from its rows (:func:`load`), so files written
before rows carried them get them too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

from gym_gridloc_agents.evaluation import aggregate
from gym_gridloc_agents.evaluation.report import env_label, read_rows
from gym_gridloc_agents.evaluation.scores import add_normalised_scores, metric

KINDS = ("rows", "seeds", "references", "normalised", "aggregate", "improvement", "pairs", "targets")


def load(results: str | Path, stems: Sequence[str]) -> list[tuple[str, list[dict[str, Any]]]]:
    """``(stem, rows)`` of each results file, with normalised scores; ``ValueError`` naming a missing file."""
    out = []
    for stem in stems:
        path = Path(results) / f"{stem}.json"
        if not path.is_file():
            raise ValueError(f"{path}: no such results file")
        out.append((stem, add_normalised_scores(read_rows(path))))
    return out


def _name(row: dict[str, Any]) -> str:
    """The policy with its options (no seed count): how tables across tasks name a policy."""
    opts = row.get("options")
    return row["policy"] + (" (" + ", ".join(f"{k}={v}" for k, v in sorted(opts.items())) + ")" if opts else "")


def _f(value: Any, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _ci(ci: Sequence[float] | None, digits: int) -> str:
    return "-" if ci is None else f"{ci[0]:.{digits}f}-{ci[1]:.{digits}f}"


def _label(r: dict[str, Any]) -> str:
    return env_label(r)


def rows_table(files) -> str:
    lines = ["| task | policy | episodes | mean steps or acc@L (95% CI) | median steps | success | ms / decision | "
             "/ best planner | normalised score |", "| --- | --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |"]
    for _, rows in files:
        for r in rows:
            col, _lower = metric(r)
            digits = 3 if col == "accuracy_at_L" else 2
            interval = _ci(r.get(f"{col}_ci95"), digits)
            if "seeds" in r and "iqm_trimmed" not in r:  # an older file's interval over the seeds' means alone: their range
                values = [s[col] for s in r.get("per_seed", []) if s.get(col) is not None]
                interval = f"seeds {min(values):.{digits}f}-{max(values):.{digits}f}" if values else "-"
            value = f"{r[col]:.{digits}f} ({interval})" + (" acc@L" if col == "accuracy_at_L" else "")
            episodes = f"{r['episodes']} x {r['seeds']}" if "seeds" in r else str(r["episodes"])
            lines.append(f"| {_label(r)} | {_name(r)} | {episodes} | {value} | {r['median_steps']:g} | {r['success_rate']:.3f} | "
                         f"{_f(r.get('ms_per_decision'), '.3g')} | {_f(r.get('gap_to_best_planner'), '.3f')} | "
                         f"{_f(r.get('normalised_score'), '.3f')} |")
    return "\n".join(lines)


def seeds_table(files) -> str:
    lines = ["| task | policy | seeds x episodes | metric | per seed | mean | IQM | 95% CI | interval over |",
             "| --- | --- | --- | --- | --- | ---: | ---: | --- | --- |"]
    for _, rows in files:
        for r in rows:
            if "per_seed" not in r:
                continue
            col, _lower = metric(r)
            digits = 3
            per = ", ".join(f"{s[col]:.{digits}f}" for s in r["per_seed"] if s.get(col) is not None)
            iqm = r.get(f"{col}_iqm") if col != "mean_steps" else r.get("mean_steps_iqm")
            if "iqm_trimmed" in r:  # an interval over seeds and the episodes they played
                ci, over = _ci(r.get(f"{col}_ci95"), digits), "seeds, then episodes"
            else:  # an older file: its interval was a bootstrap of the seeds' means alone (their range, with 3)
                ci, over = "-", "not stored (older file: its interval was over the seeds' means alone)"
            lines.append(f"| {_label(r)} | {_name(r)} | {r['seeds']} x {r['episodes']} | "
                         f"{'accuracy at L' if col == 'accuracy_at_L' else 'mean steps'} | {per} | {r[col]:.{digits}f} | "
                         f"{_f(iqm, f'.{digits}f') if r['seeds'] >= 4 else '- (< 4 seeds)'} | {ci} | {over} |")
    return "\n".join(lines)


def _tasks(files) -> list[tuple[str, list[dict[str, Any]]]]:
    """``(task label, rows)`` in order; the label names the file when several files are given."""
    out: dict[str, list] = {}
    for stem, rows in files:
        for r in rows:
            label = _label(r) + (f" [{stem}]" if len(files) > 1 else "")
            out.setdefault(label, []).append(r)
    return list(out.items())


def _point(p: dict[str, Any] | None) -> str:
    return "-" if p is None else f"{p['name']} {p['value']:.3f}"


def references_table(files) -> str:
    lines = ["| task | metric | 0 = | 1 = | what 1 is |", "| --- | --- | --- | --- | --- |"]
    for label, rows in _tasks(files):
        ref = rows[0]["normalised_reference"]
        lines.append(f"| {label} | {'accuracy at L' if ref['metric'] == 'accuracy_at_L' else 'mean steps'} | "
                     f"{_point(ref['zero'])} | {_point(ref['one'])} | {'-' if ref['one'] is None else ref['one']['kind']} |")
    return "\n".join(lines)


def _policies(files) -> list[str]:
    return list(dict.fromkeys(_name(r) for _, rows in files for r in rows))


def normalised_table(files) -> str:
    names = _policies(files)
    lines = ["| task | " + " | ".join(names) + " |", "| --- |" + " ---: |" * len(names)]
    for label, rows in _tasks(files):
        by = {_name(r): r.get("normalised_score") for r in rows}
        lines.append(f"| {label} | " + " | ".join(_f(by.get(n), ".3f") if n in by else "" for n in names) + " |")
    return "\n".join(lines)


def policy_scores(files) -> dict[str, dict[str, list[float]]]:
    """Per policy, per task, the normalised scores of its runs (each seed's, or the row's own)."""
    out: dict[str, dict[str, list[float]]] = {}
    for label, rows in _tasks(files):
        for r in rows:
            runs = [s.get("normalised_score") for s in r["per_seed"]] if r.get("per_seed") else [r.get("normalised_score")]
            if runs and all(v is not None for v in runs):
                out.setdefault(_name(r), {})[label] = [float(v) for v in runs]
    return out


def aggregate_table(files) -> str:
    taus = aggregate.PROFILE_TAUS
    lines = ["| policy | tasks | runs | IQM of the normalised score (95% CI) | interval over | "
             + " | ".join(f"> {t:g}" for t in taus) + " |", "| --- | ---: | ---: | --- | --- |" + " ---: |" * len(taus)]
    for name, scores in policy_scores(files).items():
        agg = aggregate.iqm_interval(scores)
        prof = aggregate.performance_profile(scores, taus)
        ci = "" if agg["ci95"] is None else f" ({_ci(agg['ci95'], 3)})"
        lines.append(f"| {name} | {agg['tasks']} | {sum(agg['runs'])} | {agg['iqm']:.3f}{ci} | {agg['interval_over']} | "
                     + " | ".join(f"{v:.2f}" for v in prof["fraction"]) + " |")
    return "\n".join(lines)


def improvement_table(files) -> str:
    scores = policy_scores(files)
    names = list(scores)
    lines = ["| P(row > column) | " + " | ".join(names) + " |", "| --- |" + " ---: |" * len(names)]
    for a in names:
        cells = []
        for b in names:
            common = [t for t in scores[a] if t in scores[b]]
            cells.append("" if a == b or not common else f"{aggregate.probability_of_improvement(scores[a], scores[b]):.2f}")
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pairs_table(files) -> str:
    from gym_gridloc_agents.evaluation import paired

    found = [p for _, rows in files for p in paired.pairs(rows)]
    if not found:
        raise ValueError("no two rows of one task keep their episodes' results (per_episode): no pairs to compare")
    return paired.pairs_table(found)


GENERATORS: dict[str, Callable[[list], str]] = {
    "rows": rows_table, "seeds": seeds_table, "references": references_table, "normalised": normalised_table,
    "aggregate": aggregate_table, "improvement": improvement_table, "pairs": pairs_table,
}


def table(name: str, results: str | Path) -> str:
    """The markdown table ``name`` (``KIND:STEM[+STEM...]``, module docstring) from the results files in ``results``."""
    kind, colon, sources = name.partition(":")
    if kind not in KINDS or not colon or not sources:
        raise ValueError(f"unknown table {name!r}: expected KIND:RESULTS (e.g. rows:bench), KIND one of {', '.join(KINDS)}")
    if kind == "targets":
        from gym_gridloc_agents.evaluation.targets import read_targets, targets_table

        return targets_table(load(results, sources.split("+")), read_targets(results))
    return GENERATORS[kind](load(results, sources.split("+")))


__all__ = ["GENERATORS", "KINDS", "load", "policy_scores", "table"]
