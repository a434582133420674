"""The benchmark: JSON keys, consistent numbers, same seeds for every policy, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gym_gridloc_agents.bench import markdown_table, run_benchmark, run_episodes
from gym_gridloc_agents.cli import main

KEYS = {"env", "policy", "episodes", "success_rate", "truncated_rate", "mean_steps", "median_steps",
        "mean_steps_ci95", "accuracy_at", "seconds", "localised_correct_rate"}


def check_row(row, episodes):
    assert KEYS <= set(row)
    assert row["episodes"] == episodes
    assert 0.0 <= row["success_rate"] <= 1.0 - row["truncated_rate"] + 1e-12
    assert row["success_rate"] <= row["localised_rate"] + 1e-12
    assert abs(row["localised_rate"] + row["truncated_rate"] - 1.0) < 1e-12
    lo, hi = row["mean_steps_ci95"]
    assert lo <= row["mean_steps"] <= hi
    assert 1 <= row["median_steps"] <= row["max_episode_steps"]
    assert 1 <= row["mean_steps"] <= row["max_episode_steps"]
    assert set(row["accuracy_at"]) == {"5", "10", "25", "50"}
    assert all(0.0 <= v <= 1.0 for v in row["accuracy_at"].values())
    for k, v in row["accuracy_at"].items():
        lo, hi = row["accuracy_at_ci95"][k]
        assert 0.0 <= lo <= v <= hi <= 1.0
    lo, hi = row["success_rate_ci95"]
    assert 0.0 <= lo <= row["success_rate"] <= hi <= 1.0
    assert row["seconds"] >= 0
    curve = row["localised_curve"]
    assert len(curve) == row["max_episode_steps"] + 1 and np.all(np.diff(curve) >= 0)
    assert abs(curve[-1] - row["localised_rate"]) < 1e-12
    if row["localised_correct_rate"] is not None:
        assert abs(row["localised_correct_rate"] * row["localised_rate"] - row["success_rate"]) < 1e-12


def test_rows_have_the_keys_and_consistent_numbers():
    rows = run_benchmark(["WindyMaze-v0"], ["random", "greedy", "greedy2", "ppo"], 6, progress=False)
    assert [r["policy"] for r in rows] == ["random", "greedy", "greedy2", "ppo"]
    for r in rows:
        check_row(r, 6)
    json.dumps(rows)  # serialisable


def test_truncated_episodes_count_at_the_limit():
    # A threshold the colour sensor can never reach: every episode is truncated at 100 steps.
    row = run_episodes("ColourGrid-v0", "random", 3, env_kwargs={"localise_threshold": 1.0}, progress=False)
    check_row(row, 3)
    assert row["truncated_rate"] == 1.0 and row["success_rate"] == 0.0
    assert row["mean_steps"] == row["median_steps"] == 100
    assert row["localised_correct_rate"] is None


def test_same_seeds_give_the_same_episodes():
    a = run_episodes("ColourGrid-v0", "greedy", 5, seed_start=7, progress=False)
    b = run_episodes("ColourGrid-v0", "greedy", 5, seed_start=7, progress=False)
    for k in ("mean_steps", "accuracy_at", "localised_curve", "success_rate"):
        assert a[k] == b[k]


def test_steps_count_from_reset():
    # Greedy on ColourGrid localises in a few steps; the first step counts as 1, never 0.
    row = run_episodes("ColourGrid-v0", "greedy", 5, progress=False)
    assert row["localised_curve"][0] == 0.0
    assert row["mean_steps"] >= 1


def test_markdown_table():
    rows = run_benchmark(["ColourGrid-v0"], ["random"], 3, progress=False)
    table = markdown_table(rows)
    lines = table.splitlines()
    assert lines[0].startswith("| env | policy |") and len(lines) == 3
    assert "ColourGrid-v0 | random | 3 |" in lines[2]


def test_cli_bench_writes_json_and_plot(tmp_path, capsys):
    js, png = tmp_path / "b.json", tmp_path / "b.png"
    code = main(["bench", "--env", "ColourGrid-v0", "--policies", "random,greedy", "--episodes", "4",
                 "--json", str(js), "--plot", str(png), "--no-progress"])
    assert code == 0
    out = capsys.readouterr().out
    assert "| ColourGrid-v0 | greedy |" in out
    rows = json.loads(js.read_text())
    assert isinstance(rows, list) and len(rows) == 2
    for r in rows:
        check_row(r, 4)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_bench_user_model(tmp_path, capsys):
    from gym_gridloc_agents.policies import default_model_path

    js = tmp_path / "b.json"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "ppo", "--episodes", "2", "--no-progress",
                 "--ppo-model", str(default_model_path("ColourGrid-v0")), "--json", str(js)]) == 0
    assert json.loads(js.read_text())[0]["model"].endswith("ColourGrid-v0.zip")
    # A model of another environment is refused before any episode runs.
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "ppo", "--episodes", "2", "--no-progress",
                 "--ppo-model", str(default_model_path("WindyMaze-v0"))]) == 2
    assert "trained for WindyMaze-v0" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv,message",
    [
        (["bench", "--env", "Nope-v0"], "not a registered environment"),
        (["bench", "--env", "ColourGrid-v0", "--policies", "random,smart"], "unknown policy 'smart'"),
        (["bench", "--env", "ColourGrid-v0", "--episodes", "0"], "--episodes must be >= 1"),
        (["bench"], "exactly one of --env ENV_ID or --all"),
        (["bench", "--all", "--plot", "x.png"], "--plot takes one environment"),
    ],
)
def test_cli_bench_bad_input(argv, message, capsys):
    assert main([*argv, "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_parallel_chunks_give_the_same_numbers():
    one = run_benchmark(["ColourGrid-v0"], ["random", "greedy"], 5, seed_start=3, progress=False)
    two = run_benchmark(["ColourGrid-v0"], ["random", "greedy"], 5, seed_start=3, progress=False, jobs=2)
    for a, b in zip(one, two):
        a.pop("seconds"), b.pop("seconds")
        assert a == b


def test_cli_update_merges_rows(tmp_path, capsys):
    js = tmp_path / "b.json"
    base = ["bench", "--env", "ColourGrid-v0", "--episodes", "3", "--no-progress", "--json", str(js)]
    assert main([*base, "--policies", "greedy"]) == 0
    assert main([*base, "--policies", "random", "--update"]) == 0
    rows = json.loads(js.read_text())
    assert [r["policy"] for r in rows] == ["random", "greedy"]
    assert main([*base, "--policies", "random"]) == 0  # without --update: replaced
    assert [r["policy"] for r in json.loads(js.read_text())] == ["random"]


def test_wilson_interval_matches_known_values():
    from gym_gridloc_agents.bench import wilson_ci95

    # 0 of 10 and 10 of 10: the interval still has width (the normal approximation's would not).
    assert wilson_ci95(0, 10)[0] == 0.0 and abs(wilson_ci95(0, 10)[1] - 0.27753) < 1e-4
    assert abs(wilson_ci95(10, 10)[0] - 0.72247) < 1e-4 and wilson_ci95(10, 10)[1] == 1.0
    lo, hi = wilson_ci95(930, 1000)
    assert abs(lo - 0.9125) < 1e-3 and abs(hi - 0.9442) < 1e-3


def test_cli_without_the_rl_extra_says_what_to_install(monkeypatch, capsys):
    import importlib.util

    import gym_gridloc_agents.cli as cli

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "tqdm" else real(name, *a))
    assert cli.main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "needs the 'rl' extra (missing: tqdm)" in err and "pip install torch==2.13.0" in err


# -- nothing lost, nothing unexplained -----------------------------------------------------------------
@pytest.mark.parametrize("argv, message", [
    (["--env", "CartPole-v1"], "--env CartPole-v1: CartPole-v1 is not a gym_gridloc environment"),
    (["--env", "Nope-v0"], "--env Nope-v0: 'Nope-v0' is not a registered environment"),
    (["--env", "WindyMaze-v0", "--seed", "-1"], "--seed must be in 0.."),
    (["--env", "WindyMaze-v0", "--policies", ","], "--policies names no policy"),
    (["--env", "WindyMaze-v0", "--jobs", "0"], "--jobs must be >= 1, got 0"),
    (["--env", "WindyMaze-v0", "--episodes", "0"], "--episodes must be >= 1, got 0"),
    (["--env", "WindyMaze-v0", "--policies", "random,smart"], "unknown policy 'smart'"),
])
def test_bad_bench_arguments_get_one_line_and_exit_status_2(argv, message, capsys):
    extra = [] if "--episodes" in argv else ["--episodes", "2"]
    assert main(["bench", *argv, *extra, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_unwritable_outputs_are_refused_before_the_first_episode(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.bench as b

    monkeypatch.setattr(b, "run_benchmark", lambda *a, **k: pytest.fail("ran although an output is unwritable"))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for flag in ("--json", "--plot"):
        assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", flag, str(blocker / "out"), "--no-progress"]) == 2
        assert "is a file, not a directory" in capsys.readouterr().err
    other = tmp_path / "other.json"
    other.write_text('{"not": "rows"}')
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--json", str(other), "--update", "--no-progress"]) == 2
    assert "is not a bench JSON" in capsys.readouterr().err
    assert other.read_text() == '{"not": "rows"}'


def test_computed_rows_survive_a_failing_write(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.files as f

    target = tmp_path / "out.json"
    real = f.atomic_write_json

    def failing(path, data):
        if Path(path) == target:
            raise OSError(28, "No space left on device")
        return real(path, data)

    monkeypatch.setattr(f, "atomic_write_json", failing)
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--episodes", "3", "--json", str(target), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device; written to" in err
    rescued = Path(err.split("written to ")[1].split(" instead")[0])
    rows = json.loads(rescued.read_text())
    assert rows[0]["policy"] == "random" and rows[0]["episodes"] == 3
