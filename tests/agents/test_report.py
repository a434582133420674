"""``gridloc report``: every marked table of the repository's markdown files is what the results
files give (a number edited by hand fails here), and the command's check, rewrite and errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from gym_gridloc_agents.cli import main
from gym_gridloc_agents.evaluation.report_command import OPEN, markers, report

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results"


def marked_files() -> list[Path]:
    """The repository's markdown files that hold gridloc-report markers (README.md once it has them)."""
    found = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [p for p in found if p.is_file() and OPEN.search(p.read_text(encoding="utf-8"))]


def test_results_page_has_generated_tables():
    assert ROOT / "docs" / "results.md" in marked_files()
    names = [name for name, _, _ in markers((ROOT / "docs" / "results.md").read_text(encoding="utf-8"))]
    assert {"rows:bench", "rows:bench_10k"} <= set(names) and any(n.startswith("aggregate:") for n in names)


@pytest.mark.parametrize("path", marked_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_marked_tables_are_what_gridloc_report_writes(path):
    stale = report([path], RESULTS, check=True)
    assert not stale, f"{path.relative_to(ROOT)}: a table differs from the results files; run `gridloc report`"


def _edited(tmp_path) -> tuple[Path, str]:
    """A copy of docs/results.md with one number inside a generated table changed."""
    text = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    name, start, end = next(m for m in markers(text) if m[0] == "rows:bench")
    block = text[start:end]
    changed = re.sub(r"\| 5\.79 \(", "| 5.71 (", block, count=1)
    assert changed != block
    copy = tmp_path / "results.md"
    copy.write_text(text[:start] + changed + text[end:], encoding="utf-8")
    return copy, text


def test_check_fails_on_a_hand_edited_number_and_the_report_mends_it(tmp_path, capsys):
    copy, original = _edited(tmp_path)
    assert main(["report", str(copy), "--results", str(RESULTS), "--check"]) == 1
    assert "stale" in capsys.readouterr().err
    assert copy.read_text(encoding="utf-8") != original  # --check writes nothing
    assert main(["report", str(copy), "--results", str(RESULTS)]) == 0
    assert copy.read_text(encoding="utf-8") == original
    assert main(["report", str(copy), "--results", str(RESULTS), "--check"]) == 0


def test_text_outside_the_markers_is_kept_and_a_new_table_is_filled(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("before 1.23\n<!-- gridloc-report:rows:bench_depthmaze7 -->\nold\n<!-- /gridloc-report:rows:bench_depthmaze7 -->\nafter\n")
    assert report([doc], RESULTS) == [doc]
    text = doc.read_text()
    assert text.startswith("before 1.23\n<!-- gridloc-report:rows:bench_depthmaze7 -->\n| task |") and text.endswith(
        "|\n<!-- /gridloc-report:rows:bench_depthmaze7 -->\nafter\n")
    rows = json.loads((RESULTS / "bench_depthmaze7.json").read_text())
    assert f"{rows[0]['accuracy_at_L']:.3f}" in text and "old" not in text
    assert report([doc], RESULTS, check=True) == []


@pytest.mark.parametrize("body, message", [
    ("<!-- gridloc-report:rows:bench -->\nno end\n", "has no closing"),
    ("<!-- gridloc-report:nosuch:bench -->\n<!-- /gridloc-report:nosuch:bench -->\n", "unknown table"),
    ("<!-- gridloc-report:rows:missing_file -->\n<!-- /gridloc-report:rows:missing_file -->\n", "no such results file"),
])
def test_bad_markers_get_one_line_and_exit_status_2(tmp_path, capsys, body, message):
    doc = tmp_path / "doc.md"
    doc.write_text(body)
    assert main(["report", str(doc), "--results", str(RESULTS)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gridloc report: error: ") and message in err and str(doc) in err
    assert doc.read_text() == body


def test_bench_compare_prints_pairs_and_keeps_them_in_the_rows(tmp_path, capsys):
    out = tmp_path / "rows.json"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "random,greedy2", "--episodes", "40", "--no-progress",
                 "--compare", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| ColourGrid-v0 | random | greedy2 | steps | 40 |" in printed
    rows = json.loads(out.read_text())
    pair = rows[0]["pairs"][0]
    steps = [[int(v) for v in r["per_episode"]["steps"][0].split()] for r in rows]
    assert pair["difference"] == pytest.approx(sum(a - b for a, b in zip(*steps)) / 40)
    lo, hi = pair["ci95"]
    assert pair["verdict"] == ("worse" if lo > 0 else "better" if hi < 0 else "tie")
    assert rows[0]["normalised_score"] == 0.0 and "pairs" not in rows[1]
    # the pairs table of the report reads the same rows
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- gridloc-report:pairs:rows -->\n<!-- /gridloc-report:pairs:rows -->\n")
    assert report([doc], tmp_path) == [doc] and "| ColourGrid-v0 | random | greedy2 | steps | 40 |" in doc.read_text()


def test_bench_plot_legend_names_the_episodes_of_curves_on_different_counts(tmp_path, monkeypatch):
    from gym_gridloc_agents.evaluation import report as rep

    seen = {}
    monkeypatch.setattr(rep, "save_figure", lambda fig, path, title=None, **kw: seen.update(fig=fig, title=title))
    rows = json.loads((RESULTS / "bench.json").read_text())
    ring = [r for r in rows if r["env"] == "RingSensor8x8-v0" and r["policy"] in ("random", "pomcp")]
    assert [r["episodes"] for r in ring] == [1000, 20]
    rep.plot(ring, tmp_path / "x.png")
    labels = [t.get_text() for t in seen["fig"].axes[0].get_legend().get_texts()]
    assert "episodes 0-999" in labels[0] and "episodes 0-19" in labels[1] and "legend" in seen["title"]
    rep.plot(ring[:1], tmp_path / "x.png")
    assert "the same 1000 episodes" in seen["title"]


def test_learning_curves_legend_says_which_episodes_curves_and_lines_use(tmp_path, monkeypatch):
    import matplotlib.figure

    from gym_gridloc_agents.evaluation import curves

    seen = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig",
                        lambda fig, *a, **k: seen.extend(t.get_text() for t in fig.axes[0].get_legend().get_texts()))
    c = {"label": "ppo", "seeds": [0, 1], "steps": [0, 10], "wall_time_seconds": [1.0, 2.0], "iqm": [5.0, 4.0],
         "ci95": [[4.5, 5.5], [3.5, 4.5]], "metric": "mean_steps", "env_id": "WindyMaze-v0"}
    curves.plot_curves([c], {"greedy2": 4.6}, tmp_path / "c.png")
    assert any("validation episodes" in t for t in seen) and any("greedy2" in t and "benchmark episodes" in t for t in seen)


def test_a_marker_quoted_inside_a_line_is_no_marker(tmp_path):
    doc = tmp_path / "doc.md"
    body = "Tables sit between `<!-- gridloc-report:rows:bench -->` and its closing marker.\n"
    doc.write_text(body)
    assert markers(body) == [] and report([doc], RESULTS, check=True) == []


def test_rows_across_seeds_of_older_files_show_the_seeds_range_not_an_interval():
    from gym_gridloc_agents.evaluation import tables

    text = tables.table("rows:bench_10k", RESULTS)
    rows = json.loads((RESULTS / "bench_10k.json").read_text())
    ppo = next(r for r in rows if r["policy"] == "ppo" and r["env"] == "WindyMaze-v0")
    assert "iqm_trimmed" not in ppo  # written before intervals resampled seeds and episodes
    values = [s["mean_steps"] for s in ppo["per_seed"]]
    lo, hi = ppo["mean_steps_ci95"]
    assert f"{ppo['mean_steps']:.2f} (seeds {min(values):.2f}-{max(values):.2f})" in text
    assert f"({lo:.2f}-{hi:.2f})" not in text


def test_bench_tables_show_the_normalised_score_where_rows_have_one():
    from gym_gridloc_agents.evaluation.report import markdown_table, terminal_table
    from gym_gridloc_agents.evaluation.rows import add_gaps

    rows = add_gaps([r for r in json.loads((RESULTS / "bench.json").read_text())
                     if r["env"] == "WindyMaze-v0" and r["policy"] in ("random", "greedy2", "expectimax")])
    assert [r["normalised_score"] for r in rows][0] == 0.0 and rows[2]["normalised_score"] is not None
    short, full = terminal_table(rows, width=200), markdown_table(rows)
    assert "norm." in short.splitlines()[0] and f"{rows[2]['normalised_score']:.2f}" in short
    assert "normalised score" in full.splitlines()[0] and f"{rows[2]['normalised_score']:.3f}" in full
    for r in rows:
        r.pop("normalised_score")
    assert "norm." not in terminal_table(rows, width=200) and "normalised" not in markdown_table(rows)
