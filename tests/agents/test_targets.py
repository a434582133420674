"""Targets judged by intervals (gym_gridloc_agents/evaluation/targets.py): met only when the
interval excludes the target, a tie between equal policies, a missing row named, bad specs refused."""

from __future__ import annotations

import json

import pytest

from gym_gridloc_agents.evaluation.bench import run_benchmark
from gym_gridloc_agents.evaluation.tables import table
from gym_gridloc_agents.evaluation.targets import judge, read_targets

ACC = {"env": "DepthMaze-v0", "env_kwargs": {"size": 7, "episode_length": 15, "generator": "kruskal"}, "policy": "ppo",
       "episodes": 1000, "episode_length": 15, "accuracy_at_L": 0.993}


def _target(**goal):
    return {"task": "t", "source": "s", "env": "DepthMaze-v0", "env_kwargs": dict(ACC["env_kwargs"]), "policy": "ppo", **goal}


@pytest.mark.parametrize("ci,goal,verdict", [((0.991, 0.996), {"at_least": 0.99}, "met"),
                                             ((0.985, 0.996), {"at_least": 0.99}, "undecided"),
                                             ((0.980, 0.989), {"at_least": 0.99}, "not met"),
                                             ((0.980, 0.989), {"at_most": 0.99}, "met"),
                                             ((0.985, 0.996), {"at_most": 0.99}, "undecided")])
def test_a_number_is_met_only_when_the_interval_excludes_it(ci, goal, verdict):
    row = {**ACC, "accuracy_at_L_ci95": list(ci)}
    assert judge(_target(**goal), [row])["verdict"] == verdict


def test_a_missing_row_is_not_measured_and_the_kwargs_must_match():
    row = {**ACC, "accuracy_at_L_ci95": [0.991, 0.996]}
    other = {**row, "env_kwargs": {**row["env_kwargs"], "generator": "eller"}}
    target = {**_target(at_least=0.99), "env_kwargs": dict(row["env_kwargs"])}
    assert judge(target, [other])["verdict"] == "not measured"
    assert judge(target, [other, row])["verdict"] == "met"
    fixed = {**row, "env_kwargs": {}}  # a fixed map's target is not met by a random-map row of the same env
    assert judge({**target, "env_kwargs": {}}, [row])["verdict"] == "not measured"
    assert judge({**target, "env_kwargs": {}}, [row, fixed])["verdict"] == "met"


def test_a_policy_against_itself_is_a_tie_and_against_the_random_walk_better(tmp_path):
    rows = run_benchmark(["ColourGrid-v0"], ["random", "greedy"], 60, progress=False)
    rows += [{**rows[1], "policy": "greedy_again"}]
    base = {"task": "t", "source": "r", "env": "ColourGrid-v0", "env_kwargs": {}}
    assert judge({**base, "policy": "greedy", "better_than": "random"}, rows)["verdict"] == "met"
    assert judge({**base, "policy": "random", "better_than": "greedy"}, rows)["verdict"] == "not met"
    assert judge({**base, "policy": "greedy", "better_than": "greedy_again"}, rows)["verdict"] == "tie"
    (tmp_path / "r.json").write_text(json.dumps(rows))
    (tmp_path / "targets.json").write_text(json.dumps([{**base, "task": "ColourGrid", "policy": "greedy", "better_than": "random"},
                                                       {**base, "task": "other file", "source": "x", "policy": "greedy",
                                                        "at_most": 3}]))
    text = table("targets:r", tmp_path)
    assert "| ColourGrid | better than random (paired) | greedy | 60 on one map, one model |" in text and text.rstrip().endswith("| met |")
    assert "other file" not in text  # its source is not among the table's files


def test_within_a_fraction_of_another_policy_is_judged_on_the_paired_interval():
    rows = run_benchmark(["ColourGrid-v0"], ["random", "greedy"], 200, progress=False)
    base = {"task": "t", "source": "r", "env": "ColourGrid-v0", "env_kwargs": {}}
    greedy, rand = rows[1]["mean_steps"], rows[0]["mean_steps"]
    assert greedy < rand
    found = judge({**base, "policy": "greedy", "within": {"of": "random", "fraction": 0.0}}, rows)
    assert found["verdict"] == "met" and "vs 1 x" in found["measured"]
    assert judge({**base, "policy": "random", "within": {"of": "greedy", "fraction": 0.1}}, rows)["verdict"] == "not met"
    # the random walk within a fraction generous enough: the scaled greedy mean is far above it
    big = 2 * rand / greedy
    assert judge({**base, "policy": "random", "within": {"of": "greedy", "fraction": big}}, rows)["verdict"] == "met"
    # the difference is A's mean minus (1 + fraction) times B's
    assert f"{rand - 1.1 * greedy:+.2f}" in judge({**base, "policy": "random", "within": {"of": "greedy", "fraction": 0.1}}, rows)["measured"]
    with pytest.raises(ValueError, match="within compares mean steps"):
        judge({**_target(within={"of": "random", "fraction": 0.1})}, [{**ACC, "per_episode": {}}, {**ACC, "policy": "random", "per_episode": {}}])


def test_bad_target_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="cannot read the targets"):
        read_targets(tmp_path)
    (tmp_path / "targets.json").write_text(json.dumps([_target(at_least=0.9, at_most=1.0)]))
    with pytest.raises(ValueError, match="needs exactly one of at_least, at_most, better_than"):
        read_targets(tmp_path)
    (tmp_path / "targets.json").write_text(json.dumps([{**_target(at_least=0.9), "colour": "red"}]))
    with pytest.raises(ValueError, match="target 0 must have task, source, env and policy, and only"):
        read_targets(tmp_path)
    for bad in ({"of": "ppo"}, {"of": "ppo", "fraction": -0.1}, {"of": 3, "fraction": 0.1}, 0.1):
        (tmp_path / "targets.json").write_text(json.dumps([_target(within=bad)]))
        with pytest.raises(ValueError, match="within must be"):
            read_targets(tmp_path)
