"""The benchmark: JSON keys, consistent numbers, same seeds for every policy, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gym_gridloc_agents.evaluation.bench import run_benchmark, run_episodes
from gym_gridloc_agents.evaluation.report import markdown_table
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
    rows = run_benchmark(["WindyMaze-v0"], ["random", "greedy", "greedy2", "distilled"], 6, progress=False)
    assert [r["policy"] for r in rows] == ["random", "greedy", "greedy2", "distilled"]
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
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "distilled", "--episodes", "2", "--no-progress",
                 "--distilled-model", str(default_model_path("ColourGrid-v0", "distilled")), "--json", str(js)]) == 0
    assert json.loads(js.read_text())[0]["model"].endswith("ColourGrid-v0-distilled.zip")
    # A model of another environment is refused before any episode runs.
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "distilled", "--episodes", "2", "--no-progress",
                 "--distilled-model", str(default_model_path("WindyMaze-v0", "distilled"))]) == 2
    assert "trained for WindyMaze-v0" in capsys.readouterr().err
    # The old name: a distilled model passed as --ppo-model is benchmarked as distilled, with a warning.
    js2 = tmp_path / "old.json"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "ppo", "--episodes", "2", "--no-progress",
                 "--ppo-model", str(default_model_path("ColourGrid-v0", "distilled")), "--json", str(js2)]) == 0
    assert "was distilled from a planner: its row is named 'distilled'" in capsys.readouterr().err
    assert [r["policy"] for r in json.loads(js2.read_text())] == ["distilled"]
    with pytest.warns(FutureWarning, match="distilled from a planner"):
        rows = run_benchmark(["ColourGrid-v0"], ["ppo"], 2, ppo_model=default_model_path("ColourGrid-v0", "distilled"),
                             progress=False)
    assert [r["policy"] for r in rows] == ["distilled"]


@pytest.mark.parametrize(
    "argv,message",
    [
        (["bench", "--env", "Nope-v0"], "not a registered environment"),
        (["bench", "--env", "ColourGrid-v0", "--policies", "random,smart"], "unknown policy 'smart'"),
        (["bench", "--env", "ColourGrid-v0", "--episodes", "0"], "--episodes must be at least 1"),
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
        for key in ("seconds", "ms_per_decision"):  # timings differ
            a.pop(key), b.pop(key)
        assert a == b


def test_cli_update_merges_rows(tmp_path, capsys):
    js = tmp_path / "b.json"
    base = ["bench", "--env", "ColourGrid-v0", "--episodes", "3", "--no-progress", "--json", str(js)]
    assert main([*base, "--policies", "greedy"]) == 0
    assert main([*base, "--policies", "random", "--update"]) == 0
    rows = json.loads(js.read_text())
    assert [r["policy"] for r in rows] == ["random", "greedy"]
    assert main([*base, "--policies", "random"]) == 2  # without --update or --force: refused, the rows kept
    assert [r["policy"] for r in json.loads(js.read_text())] == ["random", "greedy"]
    assert main([*base, "--policies", "random", "--force"]) == 0  # --force: replaced
    assert [r["policy"] for r in json.loads(js.read_text())] == ["random"]


def test_cli_update_recomputes_the_gap_to_a_planner_of_an_earlier_run(tmp_path):
    js = tmp_path / "b.json"
    base = ["bench", "--env", "ColourGrid-v0", "--episodes", "3", "--no-progress", "--json", str(js)]
    assert main([*base, "--policies", "expectimax"]) == 0
    assert main([*base, "--policies", "random", "--update"]) == 0
    rows = {r["policy"]: r for r in json.loads(js.read_text())}
    assert rows["expectimax"]["gap_to_best_planner"] == 1.0
    assert rows["random"]["gap_to_best_planner"] == rows["random"]["mean_steps"] / rows["expectimax"]["mean_steps"]


def test_wilson_interval_matches_known_values():
    from gym_gridloc_agents.evaluation.stats import wilson_ci95

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
    (["--env", "WindyMaze-v0", "--jobs", "0"], "--jobs must be at least 1, got 0"),
    (["--env", "WindyMaze-v0", "--episodes", "0"], "--episodes must be at least 1, got 0"),
    (["--env", "WindyMaze-v0", "--policies", "random,smart"], "unknown policy 'smart'"),
])
def test_bad_bench_arguments_get_one_line_and_exit_status_2(argv, message, capsys):
    extra = [] if "--episodes" in argv else ["--episodes", "2"]
    assert main(["bench", *argv, *extra, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_unwritable_outputs_are_refused_before_the_first_episode(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.evaluation.bench as b

    monkeypatch.setattr(b, "run_benchmark", lambda *a, **k: pytest.fail("ran although an output is unwritable"))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for flag in ("--json", "--plot"):
        assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", flag, str(blocker / "out"), "--no-progress"]) == 2
        assert "is a file, not a directory" in capsys.readouterr().err
    other = tmp_path / "other.json"
    other.write_text('{"not": "rows"}')
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--json", str(other), "--update", "--no-progress"]) == 2
    assert "holds a file of another kind, not bench results" in capsys.readouterr().err
    assert other.read_text() == '{"not": "rows"}'


def test_computed_rows_survive_a_failing_write(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.files as f

    target = tmp_path / "out.json"
    real = f.atomic_write_json

    def failing(path, data, *kind):
        if Path(path) == target:
            raise OSError(28, "No space left on device")
        return real(path, data, *kind)

    monkeypatch.setattr(f, "atomic_write_json", failing)
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--episodes", "3", "--json", str(target), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device; written to" in err
    rescued = Path(err.split("written to ")[1].split(" instead")[0])
    rows = json.loads(rescued.read_text())
    assert rows[0]["policy"] == "random" and rows[0]["episodes"] == 3


def test_test_set_protocol_rows_report_accuracy_at_L(tmp_path, capsys):
    """DepthMaze on held-out maps with fixed-length episodes: every episode runs L steps on map i of
    the test set, from its start pose; accuracy at L counts beliefs collapsed on the truth."""
    from gym_gridloc import maps

    js, front = tmp_path / "d.json", tmp_path / "front.png"
    md = tmp_path / "d.md"
    code = main(["bench", "--env", "DepthMaze-v0", "--size", "7", "--test-set", "--episode-length", "6",
                 "--policies", "random,greedy", "--episodes", "5", "--json", str(js), "--frontier", str(front), "--no-progress",
                 "--markdown", str(md)])
    assert code == 0
    short = capsys.readouterr().out
    assert "| acc@L " in short and max(len(line) for line in short.splitlines() if line.startswith("|")) <= 100
    table = md.read_text()
    assert "acc@L (95% CI)" in table
    assert "DepthMaze-v0 episode_length=6, generator=kruskal, reject_symmetric=True, size=7, test maps | greedy |" in table
    rows = json.loads(js.read_text())
    for r in rows:  # the rows name the maze variant of their test set (the protocol rejects symmetric mazes)
        assert r["test_set"] and r["episode_length"] == 6
        assert r["env_kwargs"] == {"size": 7, "episode_length": 6, "generator": "kruskal", "reject_symmetric": True}
        assert 0 <= r["accuracy_at_L"] <= r["argmax_accuracy_at_L"] <= 1
        lo, hi = r["accuracy_at_L_ci95"]
        assert lo <= r["accuracy_at_L"] <= hi
        assert r["max_episode_steps"] == 6 and 1 <= r["mean_steps"] <= 6
        assert r["ms_per_decision"] > 0
    assert front.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # episode i is map i of the test set from its start pose: replay one by hand
    import gymnasium as gym

    from gym_gridloc import HMMBeliefWrapper
    from gym_gridloc_agents.policies import make_policy
    from gym_gridloc_agents.evaluation.rollout import rollout

    m = maps.test_set("DepthMaze-v0", 7, 5, reject_symmetric=True)[2]
    env = HMMBeliefWrapper(gym.make("DepthMaze-v0", size=7, episode_length=6), full_state=True)
    ep = rollout(env, make_policy("greedy", env.unwrapped.model, pose=True), m.index, keep=True,
                 reset_options={"map": m.grid, "state": m.state})
    assert np.array_equal(ep.states[0], m.state) and ep.steps == 6
    assert np.array_equal(env.unwrapped.model.grid.free, m.grid.free)


def test_markdown_table_columns_follow_the_rows():
    rows = run_benchmark(["ColourGrid-v0"], ["greedy", "expectimax"], 3, progress=False, policy_options={"expectimax": {"depth": 1}})
    table = markdown_table(rows)
    assert "/ best planner" in table and "ms/decision" in table and "acc@L" not in table
    assert "| expectimax (depth=1) |" in table
    exp = next(r for r in rows if r["policy"] == "expectimax")
    assert exp["gap_to_best_planner"] == 1.0 and exp["options"] == {"depth": 1}


def test_merge_keeps_rows_with_other_options_or_maps():
    from gym_gridloc_agents.evaluation.report import merge_rows

    base = {"env": "WindyMaze-v0", "policy": "expectimax", "episodes": 1, "mean_steps": 4.0, "success_rate": 1.0}
    rows = merge_rows([base, {**base, "options": {"depth": 3}}], [{**base, "mean_steps": 3.9}, {**base, "env_kwargs": {"size": 9}}])
    assert len(rows) == 3 and [r["mean_steps"] for r in rows if not r.get("options") and not r.get("env_kwargs")] == [3.9]


@pytest.mark.parametrize("argv, message", [
    (["--option", "expectimax.depth=2"], "not among the benchmarked policies"),
    (["--option", "depth=2"], "expected POLICY.KEY=VALUE"),
    (["--test-set"], "--test-set needs --size"),
    (["--size", "0"], "--size must be at least 1"),
    (["--env-kwarg", "size"], "expected KEY=VALUE"),
])
def test_bench_protocol_arguments_are_checked(argv, message, capsys):
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "random", "--episodes", "1", *argv]) == 2
    assert message in capsys.readouterr().err


def test_gridloc_bound(tmp_path, capsys):
    from gym_gridloc_agents.planners import lower_bound

    js = tmp_path / "lb.json"
    assert main(["bound", "ColourGrid-v0", "--depth", "1", "--json", str(js)]) == 0
    assert "no policy localises ColourGrid-v0 in fewer than" in capsys.readouterr().out
    got = json.loads(js.read_text())
    import gymnasium as gym

    assert got["bound"] == pytest.approx(lower_bound(gym.make("ColourGrid-v0").unwrapped.model, 1)["bound"])
    assert main(["bound", "ColourGrid-v0", "--depth", "0"]) == 2
    assert main(["bound", "DepthMaze-v0", "--env-kwarg", "episode_length=5"]) == 2


def test_central_runs_where_it_applies_and_is_left_out_elsewhere(capsys):
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "random,central", "--episodes", "3", "--no-progress"]) == 0
    out, err = capsys.readouterr()
    assert "'central' does not apply to ColourGrid-v0" in err and "| central |" not in out and "| random |" in out
    rows = run_benchmark(["RingSensor8x8-v0"], ["central"], 2, progress=False)
    assert [r["policy"] for r in rows] == ["central"]


def test_default_policies_leave_out_learned_rows_without_a_model(capsys):
    argv = ["bench", "--env", "DepthMaze-v0", "--size", "9", "--episode-length", "6", "--episodes", "2", "--no-progress"]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert "no shipped ppo model for DepthMaze-v0" in err and "| greedy2 |" in out and "| ppo |" not in out
    assert "no shipped distilled model for DepthMaze-v0" in err and "| distilled |" not in out


def test_training_curves_plot(tmp_path, capsys):
    for name, kwargs, evals in [("proto", {"size": 7, "episode_length": 15}, [(0, 0.9, 15.0), (500, 0.4, 15.0)]),
                                ("steps", {}, [(0, 0.9, 3.1), (500, 0.92, 3.0)])]:
        (tmp_path / f"{name}.zip").write_bytes(b"")
        meta = {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": kwargs, "selected_timesteps": 0,
                "evaluations": [{"num_timesteps": t, "accuracy": a, "mean_steps": m} for t, a, m in evals]}
        (tmp_path / f"{name}.json").write_text(json.dumps(meta))
    out = tmp_path / "curves.png"
    assert main(["plot", "--training", str(tmp_path / "proto.zip"), str(tmp_path / "steps.zip"), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "bare.zip").write_bytes(b"")
    (tmp_path / "bare.json").write_text(json.dumps({"algo": "ppo", "env_id": "DepthMaze-v0"}))
    assert main(["plot", "--training", str(tmp_path / "bare.zip"), "--out", str(out)]) == 2
    assert "has no evaluations" in capsys.readouterr().err


# -- the terminal table ------------------------------------------------------------------------------
def _row(policy="greedy", env="WindyMaze-v0", **extra):
    row = {"env": env, "policy": policy, "episodes": 200, "mean_steps": 5.71, "mean_steps_ci95": [5.03, 6.4],
           "median_steps": 5, "success_rate": 0.96, "truncated_rate": 0.0, "localised_correct_rate": 0.96,
           "accuracy_at": {"5": 0.85, "10": 0.935, "25": 0.96, "50": 0.96}, "ms_per_decision": 0.0598, "seconds": 0.2}
    row.update(extra)
    return row


def test_terminal_table_fits_100_columns_and_keeps_the_key_numbers():
    from gym_gridloc_agents.evaluation.report import terminal_table

    plain = terminal_table([_row(), _row("greedy2", mean_steps=4.83)])
    assert max(map(len, plain.splitlines())) <= 100
    head = [c.strip() for c in plain.splitlines()[0].strip("|").split("|")]
    assert head == ["env", "policy", "mean steps (95% CI)", "success", "acc@10", "ms/dec"]
    assert "5.71 (5.03-6.40)" in plain and "0.935" in plain and "0.0598" in plain
    # the longest rows there are: kwargs, test maps, options, seeds, the protocol's accuracy at L, a gap
    long = [_row("expectimax", env="DepthMaze-v0", env_kwargs={"size": 21, "episode_length": 15, "n_colours": 4},
                 test_set=True, options={"depth": 3, "leaves": "entropy", "threshold": 0.9}, gap_to_best_planner=1.0,
                 accuracy_at_L=0.91, accuracy_at_L_ci95=[0.88, 0.93], episode_length=15),
            _row("ppo", seeds=5, mean_steps_iqm=4.8, gap_to_best_planner=1.21, ms_per_decision=0.405)]
    table = terminal_table(long)
    assert max(map(len, table.splitlines())) <= 100, table
    assert len(table.splitlines()) == 4 and "0.910" in table and "~" in table  # labels cut, marked
    roomy = terminal_table(long, width=140)
    assert max(map(len, roomy.splitlines())) <= 140 and "0.0598" in roomy and "0.405" in roomy
    assert "acc@L" in table.splitlines()[0]  # the protocol's number stays longest
    assert terminal_table(long, width=200).count("/ best") == 1  # room: the optional columns stay


def test_cli_bench_prints_the_short_table_and_writes_the_full_one(tmp_path, capsys):
    md = tmp_path / "full.md"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "random,greedy", "--episodes", "3", "--no-progress",
                 "--markdown", str(md)]) == 0
    out = capsys.readouterr().out
    table = [line for line in out.splitlines() if line.startswith("|")]
    assert len(table) == 4 and max(map(len, table)) <= 100
    full = md.read_text()
    assert full.endswith("\n") and "acc@5" in full and "truncated" in full and "correct if localised" in full
    assert len(full.splitlines()) == 4 and "acc@5" not in out


# -- the warm-up ----------------------------------------------------------------------------------------
class _SlowFirstCall:
    """A policy whose first decision costs 0.3 s (a compilation), then nothing."""

    def __init__(self, policy):
        self.policy, self.calls = policy, 0

    def reset(self, seed=None, model=None):
        self.policy.reset(seed=seed, model=model)

    def act(self, observation, belief):
        self.calls += 1
        if self.calls == 1:
            import time

            time.sleep(0.3)
        return self.policy.act(observation, belief)


def test_warm_up_keeps_first_call_costs_out_of_the_timed_decisions(monkeypatch):
    from gym_gridloc_agents.evaluation import bench

    real = bench.make_task_policy
    monkeypatch.setattr(bench, "make_task_policy", lambda task, env: _SlowFirstCall(real(task, env)))
    task = bench.Task("ColourGrid-v0", "greedy", {}, None, {})
    specs = bench.episode_specs("ColourGrid-v0", {}, 3, 0, False)
    cold = bench.simulate(task, specs, progress=False, warmup=False)
    warm = bench.simulate(task, specs, progress=False)
    assert cold["decision_seconds"] >= 0.3 and cold["seconds"] >= 0.3
    assert warm["decision_seconds"] < 0.15 and warm["seconds"] < 0.3
    assert warm["decisions"] == cold["decisions"]


@pytest.mark.parametrize("env_id, policy", [("WindyMaze-v0", "random"), ("WindyMaze-v0", "greedy"),
                                            ("ColourGrid-v0", "greedy2"), ("ColourGrid-v0", "ppo"),
                                            ("WindyMaze-v0", "recurrent"), ("ColourGrid-v0", "mcts")])
def test_warm_up_changes_nothing_but_the_timings(env_id, policy):
    from gym_gridloc_agents.evaluation import bench

    options = {"simulations": 30} if policy == "mcts" else {}
    task = bench.Task(env_id, policy, {}, None, options)  # learned: the shipped model
    specs = bench.episode_specs(env_id, {}, 4, 3, False)
    cold = bench.simulate(task, specs, progress=False, warmup=False)
    warm = bench.simulate(task, specs, progress=False, warmup=True)
    for key in cold:
        if key not in ("seconds", "decision_seconds"):
            assert np.array_equal(np.asarray(cold[key]), np.asarray(warm[key])), key


def test_depth_maze_test_sets_follow_the_maze_variant():
    from gym_gridloc import maps
    from gym_gridloc_agents.evaluation.bench import episode_specs

    for kwargs, variant in (({"size": 7, "episode_length": 15, "generator": "eller"}, {"generator": "eller", "reject_symmetric": True}),
                            ({"size": 7, "episode_length": 15}, {"generator": "kruskal", "reject_symmetric": True}),
                            ({"size": 7, "episode_length": 15, "reject_symmetric": False}, {}),
                            ({"size": 7}, {})):
        specs = episode_specs("DepthMaze-v0", kwargs, 4, 10, True)
        held = maps.test_set("DepthMaze-v0", 7, 4, **variant)
        assert [s for s, _ in specs] == [10 + m.index for m in held]
        assert all(np.array_equal(o["map"].labels, m.grid.labels) and o["state"] == m.state for (_, o), m in zip(specs, held))


def test_a_row_counts_the_maps_its_episodes_ran_on():
    """A size keyword alone gives one generated map; new_map_each_reset a new one per episode: the
    row says which, so a table never calls one map 'fresh random maps'."""
    one = run_episodes("WindyMaze-v0", "random", 4, env_kwargs={"size": 5}, progress=False)
    fresh = run_episodes("WindyMaze-v0", "random", 4, env_kwargs={"size": 9, "new_map_each_reset": True}, progress=False)
    test = run_episodes("DepthMaze-v0", "random", 3, env_kwargs={"size": 7}, test_set=True, progress=False)
    assert (one["maps"], fresh["maps"], test["maps"]) == (1, 4, 3)


def test_several_recurrent_models_make_one_row_across_seeds(tmp_path, capsys):
    """``--recurrent-model`` takes one model per seed, as ``--ppo-model`` does: the row is then the
    aggregate across seeds, each seed's numbers those of its model alone."""
    import shutil

    from gym_gridloc_agents.learned import default_model_path

    shipped = default_model_path("ColourGrid-v0", "recurrent")
    seeds = tmp_path / "seeds"
    seeds.mkdir()
    for name, seed in (("a", 0), ("b", 1)):  # the same network twice, as two seeds
        shutil.copy(shipped, seeds / f"{name}.zip")
        meta = json.loads(shipped.with_suffix(".json").read_text())
        meta["seed"] = seed
        (seeds / f"{name}.json").write_text(json.dumps(meta))
    js = tmp_path / "bench.json"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "recurrent", "--episodes", "4", "--recurrent-model",
                 str(seeds), "--json", str(js), "--no-progress"]) == 0
    row, = json.loads(js.read_text())
    assert row["policy"] == "recurrent" and row["seeds"] == 2 and row["episodes_total"] == 8
    single = run_benchmark(["ColourGrid-v0"], ["recurrent"], 4, recurrent_model=shipped, progress=False)[0]
    assert "seeds" not in single
    assert [r["mean_steps"] for r in row["per_seed"]] == [single["mean_steps"]] * 2
    assert row["mean_steps"] == pytest.approx(single["mean_steps"])
    capsys.readouterr()
    # one seed twice is refused, naming the flag
    (seeds / "b.json").write_text((seeds / "a.json").read_text())
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "recurrent", "--recurrent-model", str(seeds)]) == 2
    assert "--recurrent-model:" in capsys.readouterr().err
