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
    code = _blocks(README, "python")[0]
    assert "terminated or truncated" in code and "env.reset()" in code and "for " in code
    exec(compile(code, "README.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed, "no episode ended in the example's loop"


def test_the_first_training_runs_and_its_model_is_benchmarked(tmp_path, monkeypatch, capsys):
    """The README's SB3 snippet, as written but for a shorter run, then the bench command it gives."""
    pytest.importorskip("stable_baselines3")
    code = next(b for b in _blocks(README, "python") if "PPO(" in b)
    assert "model.learn(20_000)" in code and "torch.set_num_threads(1)" in code
    monkeypatch.chdir(tmp_path)
    exec(compile(code.replace("model.learn(20_000)", "model.learn(2_048)"), "README.md", "exec"), {})
    assert (tmp_path / "my_ppo.zip").is_file()
    command = re.search(r"(?m)^(gridloc bench --env WindyMaze-v0 --policies greedy2,ppo --ppo-model my_ppo.zip.*)$", README)
    assert command, "the README names the bench command for the trained model"
    from gym_gridloc_agents.cli import main

    assert main([*shlex.split(command.group(1))[1:], "--episodes", "20", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "| ppo" in out and any(word in out for word in ("tie", "better", "worse"))


def _first_command_block() -> str:
    block = re.search(r"<!-- readme-first-command -->\n```text\n(.*?)```\n<!-- /readme-first-command -->", README, re.S)
    assert block, "the README shows what its first command prints"
    return block.group(1)


def _cells(table: str) -> list[list[str]]:
    """The table's rows, without the time per decision (it depends on the machine)."""
    lines = [line for line in table.splitlines() if line.startswith("|") and not line.startswith("|-")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    keep = [i for i, h in enumerate(head) if h != "ms/dec"]
    return [[[c.strip() for c in line.strip("|").split("|")][i] for i in keep] for line in lines]


def test_the_first_command_prints_what_the_readme_shows(capsys):
    pytest.importorskip("stable_baselines3")
    from gym_gridloc_agents.cli import main

    bench = README.splitlines()[3].split("#")[0].split("&&")[1].strip()
    assert main([*shlex.split(bench)[1:], "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert _cells(printed) == _cells(_first_command_block())


def test_the_benchmark_columns_are_explained_beside_the_first_command():
    head = _cells(_first_command_block())[0] + ["ms/dec"]
    section = README[README.index("## What the first command prints"):README.index("## Install")]
    explained = set(re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", section, flags=re.S)))
    words = {"mean steps (95% CI)": "mean steps"}
    assert {words.get(h, h) for h in head} - {"env", "policy"} <= explained
    assert "--markdown PATH" in section and "--json PATH" in section


def test_no_result_number_is_typed_by_hand_in_the_results_section():
    """The results section's tables come from gridloc report (its markers); its prose has no numbers
    but those it attributes to others."""
    section = README[README.index("## Results"):README.index("## Watch it")]
    assert section.count("<!-- gridloc-report:targets:") == 1
    prose = re.sub(r"<!-- gridloc-report:(.*?)-->.*?<!-- /gridloc-report:\1-->", "", section, flags=re.S)
    numbers = re.findall(r"(?<![\w.])\d+\.\d+", prose)
    assert set(numbers) <= {"0.995", "0.999", "0.905", "0.980"}, numbers  # the published agent's, as reported (7x7, 15x15)


def test_the_product_speaks_of_no_development_history():
    pattern = re.compile(r"\bissues? ?#?\d+|\b(this|last|next|later|earlier|previous|a) session\b|\bsessions\b", re.I)
    files = [ROOT / "README.md", ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").glob("*.md")),
             *sorted((ROOT / "gym_gridloc").rglob("*.py")), *sorted((ROOT / "agents").rglob("*.py")),
             *sorted((ROOT / "configs").glob("*.yml")), *sorted((ROOT / "scripts").glob("*"))]
    hits = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in files if p.is_file()
            for m in pattern.finditer(p.read_text(encoding="utf-8", errors="replace"))]
    assert hits == []
