"""``gridloc suite``: every task of the benchmark into one results JSON, resumable, read by ``gridloc report``."""

from __future__ import annotations

import json

import pytest

from gym_gridloc_agents.cli import main
from gym_gridloc_agents.evaluation import suite
from gym_gridloc_agents.evaluation.report_command import report


def test_the_suite_holds_every_task_of_the_benchmark():
    names = {(t.env_id, tuple(sorted(t.env_kwargs.items())), t.test_set) for t in suite.SUITE}
    for env_id in ("WindyMaze-v0", "ColourGrid-v0", "RingSensor8x8-v0"):
        assert (env_id, (), False) in names
    assert ("WindyMaze-v0", (("size", 9),), True) in names
    for size, lengths in ((7, (15, 30)), (15, (20, 40)), (21, (30, 60))):
        for length in lengths:
            for generator in ("kruskal", "eller"):
                kwargs = {"size": size, "episode_length": length, "generator": generator, "reject_symmetric": True}
                assert ("DepthMaze-v0", tuple(sorted(kwargs.items())), True) in names
    assert len(suite.SUITE) == 4 + 12 and len(set(suite.TASK_NAMES)) == len(suite.SUITE)
    assert suite.default_policies(suite.select(["depthmaze7-L15-eller"])[0])[2] == "optimal"
    with pytest.raises(ValueError, match="unknown suite task"):
        suite.select(["depthmaze9"])


def test_suite_runs_resumes_and_feeds_the_report(tmp_path, capsys, monkeypatch):
    out = tmp_path / "suite.json"
    argv = ["suite", "--tasks", "colourgrid,depthmaze7-L15-eller", "--policies", "random,greedy2,optimal",
            "--episodes", "6", "--json", str(out), "--no-progress"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "colourgrid: optimal does not apply" in err
    rows = json.loads(out.read_text())
    assert [(r["suite_task"], r["policy"]) for r in rows] == [
        ("colourgrid", "random"), ("colourgrid", "greedy2"),
        ("depthmaze7-L15-eller", "random"), ("depthmaze7-L15-eller", "greedy2"), ("depthmaze7-L15-eller", "optimal")]
    maze = rows[2]
    assert maze["env_kwargs"] == {"size": 7, "episode_length": 15, "generator": "eller", "reject_symmetric": True}
    assert maze["test_set"] and maze["episodes"] == 6 and len(maze["per_episode"]["accuracy_at_L"][0]) == 6
    assert rows[4]["normalised_score"] == 1.0 and rows[4]["normalised_reference"]["one"]["name"] == "optimal"

    from gym_gridloc_agents.evaluation import bench

    def no_run(*args, **kwargs):
        raise AssertionError("a finished task ran again")

    monkeypatch.setattr(bench, "run_benchmark", no_run)
    assert main(argv) == 0  # resumed: every task is done
    assert capsys.readouterr().err.count("done already") == 2
    assert json.loads(out.read_text()) == rows

    doc = tmp_path / "doc.md"
    doc.write_text("<!-- gridloc-report:pairs:suite -->\n<!-- /gridloc-report:pairs:suite -->\n")
    assert report([doc], tmp_path) == [doc]
    assert doc.read_text().count("| DepthMaze-v0 ") == 3  # the three pairs of the maze task


def test_an_interrupted_task_keeps_the_finished_ones(tmp_path, monkeypatch, capsys):
    from gym_gridloc_agents.evaluation import bench

    out = tmp_path / "suite.json"
    real = bench.run_benchmark
    calls = []

    def interrupted(env_ids, policies, *args, **kwargs):
        calls.append(env_ids)
        if len(calls) == 2:
            raise bench.BenchmarkInterrupted([], 1)
        return real(env_ids, policies, *args, **kwargs)

    monkeypatch.setattr(bench, "run_benchmark", interrupted)
    assert main(["suite", "--tasks", "colourgrid,windymaze", "--policies", "random", "--episodes", "3", "--json", str(out),
                 "--no-progress"]) == 130
    assert "run the same command again" in capsys.readouterr().err
    assert [r["suite_task"] for r in json.loads(out.read_text())] == ["windymaze"]


@pytest.mark.parametrize("argv, message", [
    (["--tasks", "nosuch"], "unknown suite task"),
    (["--policies", "random,nosuch"], "unknown policy"),
    (["--episodes", "0"], "--episodes"),
    (["--jobs", "2", "--address", "auto"], "--jobs sets the processes"),
])
def test_bad_suite_arguments_get_one_line_and_exit_status_2(tmp_path, capsys, argv, message):
    assert main(["suite", *argv, "--json", str(tmp_path / "s.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gridloc suite: error: ") and message in err
    assert not (tmp_path / "s.json").exists()


def test_jobs_address_and_a_models_folder_reach_the_benchmark(tmp_path, monkeypatch):
    import shutil

    from gym_gridloc_agents.evaluation import bench
    from gym_gridloc_agents.policies import default_model_path

    seeds = tmp_path / "models" / "DepthMaze-v0-size7-ppo"  # one model per seed, in a directory of the shipped name
    seeds.mkdir(parents=True)
    shipped = default_model_path("DepthMaze-v0", "ppo", {"size": 7})
    for i in range(2):
        shutil.copy(shipped, seeds / f"seed{i}.zip")
        meta = json.loads(shipped.with_suffix(".json").read_text())
        (seeds / f"seed{i}.json").write_text(json.dumps({**meta, "seed": i}))
    seen = []
    monkeypatch.setattr(bench, "run_benchmark", lambda env_ids, policies, episodes, **kw: seen.append((policies, kw)) or [])
    suite.run_suite(["random", "ppo", "distilled"], 5, tmp_path / "s.json", tasks=["depthmaze7-L15-eller"], jobs=2,
                    address=None, models=tmp_path / "models", progress=False)
    suite.run_suite(["random"], 5, tmp_path / "s.json", tasks=["windymaze"], address="auto", progress=False)
    (policies, kw), (_, kw2) = seen
    assert policies == ["random", "ppo", "distilled"] and kw["jobs"] == 2 and kw2["address"] == "auto"
    assert kw["ppo_model"] == [seeds / "seed0.zip", seeds / "seed1.zip"]  # the row across the folder's seeds
    assert kw["distilled_model"] == [default_model_path("DepthMaze-v0", "distilled", {"size": 7})]  # none there: shipped
    assert kw["test_set"] and kw["env_kwargs"]["generator"] == "eller"
