"""The README as a newcomer reads it: the two commands at the top work as written, `gridloc` is
reachable after set-up, the first example runs, the facts it states agree with the project."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
TOP = README[: README.index("\n## ")]  # everything before the first section


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, re.S)


def test_the_first_two_lines_are_the_two_commands_and_they_are_reachable():
    lines = README.splitlines()
    assert lines[0] == "# gym_gridloc" and lines[2] == "```bash"
    bench, tests = (line.split("#")[0].strip() for line in lines[3:5])
    assert bench.startswith("bash scripts/setup.sh && .venv/bin/gridloc bench ")
    assert tests == "bash scripts/setup.sh && .venv/bin/python -m pytest -n 2 -q"
    assert (ROOT / "scripts" / "setup.sh").is_file()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["scripts"]["gridloc"] == "gym_gridloc_agents.cli:main"  # what makes .venv/bin/gridloc
    setup = (ROOT / "scripts" / "setup.sh").read_text(encoding="utf-8")
    assert "-m venv .venv" in setup and '-e ".[' in setup and "dev" in setup  # pytest, xdist come with [dev]
    # the benchmark's arguments parse and name real policies
    pytest.importorskip("gym_gridloc_agents.cli")
    from gym_gridloc_agents.cli import build_parser
    from gym_gridloc_agents.policies import POLICY_NAMES

    args = build_parser().parse_args(shlex.split(bench.split("&&")[1])[1:])
    assert args.command == "bench" and set(args.policies.split(",")) <= set(POLICY_NAMES)


def test_the_activate_hint_comes_before_any_bare_gridloc_command():
    hint = README.index("source .venv/bin/activate")
    assert README[:hint].count("\n") < 12
    bare = [m.start() for m in re.finditer(r"(?m)^(?:\$ )?gridloc ", README)]
    assert bare and min(bare) > hint


def test_every_gridloc_command_in_the_readme_is_a_real_subcommand():
    pytest.importorskip("gym_gridloc_agents.cli")
    from gym_gridloc_agents.cli import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if a.dest == "command").choices
    used = set(re.findall(r"(?:^|[\s`/])gridloc (\w+)", README, re.M))
    assert used and used <= set(subs), used - set(subs)


def test_the_python_versions_match_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    low = re.fullmatch(r">=\s*3\.(\d+)", project["requires-python"]).group(1)
    assert f"Python 3.{low} or newer" in TOP


def test_the_first_example_runs_its_loop_and_resets_after_termination(capsys):
    code = _blocks(TOP, "python")[0]
    assert "terminated or truncated" in code and "env.reset()" in code and "for " in code
    exec(compile(code, "README.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed, "no episode ended in the example's loop"


def test_the_benchmark_columns_are_explained_beside_the_first_command():
    pytest.importorskip("gym_gridloc_agents.evaluation.report")
    from gym_gridloc_agents.evaluation.report import terminal_table

    row = {"env": "WindyMaze-v0", "policy": "greedy", "mean_steps": 5.0, "mean_steps_ci95": [4.0, 6.0],
           "success_rate": 0.9, "accuracy_at": {"10": 0.9}, "ms_per_decision": 0.1, "gap_to_best_planner": 1.1,
           "accuracy_at_L": 0.9}
    head = [c.strip() for c in terminal_table([row], width=1000).splitlines()[0].strip("|").split("|")]
    explained = re.findall(r"(?m)^\| `([^`]+)`(?:, `([^`]+)`)? \|", TOP)
    names = {n for pair in explained for n in pair if n}
    assert set(head) - {"env", "policy"} <= names, set(head) - names
    assert "--markdown PATH" in TOP and "--json PATH" in TOP
