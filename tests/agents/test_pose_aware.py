"""One pose-aware test of localisation: where the environment's referee tests poses (DepthMaze,
``referee_pose=True``), the pomdp_py adapter, the rollouts on the belief MDP and the lower bound
(``gridloc bound``) stop on the pose too, through :func:`gym_gridloc.referee.localised`."""

from __future__ import annotations

import importlib.util
import json

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401 - registers the environments
from gym_gridloc import engine, referee
from gym_gridloc_agents.cli import main
from gym_gridloc_agents.planners import belief_rollouts, lower_bound
from gym_gridloc_agents.policies import GreedyPolicy

#: A 7x7 maze on which some first readings leave the position known and the heading not.
MAZE = {"size": 7, "map_seed": 3}


def depth_maze():
    env = gym.make("DepthMaze-v0", **MAZE)
    assert env.unwrapped.referee_pose  # the environment's referee tests poses
    return env.unwrapped.model


def one_cell_two_headings(model) -> np.ndarray:
    b = np.zeros(model.belief_shape)
    r, c = (int(v) for v in model.grid.free_cells[0])
    b[0, r, c] = b[2, r, c] = 0.5  # the position is sure, the heading is not
    return b


@pytest.mark.skipif(importlib.util.find_spec("pomdp_py") is None, reason="needs pomdp_py (the planning extra)")
def test_the_pomdp_py_adapter_tests_the_pose_where_the_referee_does():
    from gym_gridloc.interop import to_pomdp_py

    model = depth_maze()
    b = one_cell_two_headings(model)
    assert not to_pomdp_py(model, pose=True, seed=0).localised(b)
    assert to_pomdp_py(model, seed=0).localised(b)  # (the position test)
    assert to_pomdp_py(model, pose=True, seed=0).confidence(b) == 0.5
    assert not referee.localised(b[None], referee.LOCALISE_THRESHOLD, pose=True)[0]


def test_rollouts_on_the_belief_mdp_go_on_until_the_pose_is_known():
    model = depth_maze()
    by_position = belief_rollouts(model, GreedyPolicy(model), 30, max_steps=40)
    by_pose = belief_rollouts(model, GreedyPolicy(model), 30, max_steps=40, pose=True)
    # the same draws: an episode tested on the pose is the one tested on the position, continued
    assert (by_pose["steps"] >= by_position["steps"]).all() and (by_pose["steps"] > by_position["steps"]).any()
    beliefs = by_pose["beliefs"]
    assert not referee.localised(beliefs, referee.LOCALISE_THRESHOLD, pose=True).any()
    assert referee.localised(beliefs, referee.LOCALISE_THRESHOLD).any()  # where the position test would have stopped


def _brute_depth_one_bound(model, pose: bool) -> float:
    """``E_z0[1 + min_a sum_z p(z | b0, a) [b_az not localised]]`` from the engine and the referee alone."""
    free = np.broadcast_to(model.grid.free, model.belief_shape).astype(float)
    prior = free / free.sum()
    Z = model.sensor.n_readings
    total = 0.0
    for z0 in range(Z):
        b0 = prior * engine.likelihood(model, z0)
        p0 = b0.sum()
        if p0 == 0:
            continue
        b0 = b0 / p0
        costs = []
        for a in range(model.n_actions):
            pred = engine.predict(model, b0, a)
            cost = 0.0
            for z in range(Z):
                post = pred * engine.likelihood(model, z)
                pz = post.sum()
                if pz > 0 and not referee.localised((post / pz)[None], referee.LOCALISE_THRESHOLD - 1e-9, pose=pose)[0]:
                    cost += pz
            costs.append(cost)
        total += p0 * (1.0 + min(costs))
    return total


def test_the_lower_bound_is_of_the_pose_where_the_referee_tests_poses():
    model = depth_maze()
    by_pose, by_position = lower_bound(model, 1, pose=True), lower_bound(model, 1)
    assert by_pose["pose"] and not by_position["pose"]
    assert by_pose["bound"] == pytest.approx(_brute_depth_one_bound(model, True), abs=1e-12)
    assert by_position["bound"] == pytest.approx(_brute_depth_one_bound(model, False), abs=1e-12)
    assert by_pose["bound"] > by_position["bound"]  # this maze has first readings that leave only the heading open


def test_gridloc_bound_on_a_depth_maze_bounds_the_pose(tmp_path, capsys):
    js = tmp_path / "bound.json"
    argv = ["bound", "DepthMaze-v0", "--depth", "1", "--json", str(js)]
    assert main([*argv, *(f"--env-kwarg={k}={v}" for k, v in MAZE.items())]) == 0
    assert "pose" in capsys.readouterr().out
    got = json.loads(js.read_text())
    assert got["pose"] is True
    assert got["bound"] == lower_bound(depth_maze(), 1, pose=True)["bound"]
    assert got["bound"] == pytest.approx(_brute_depth_one_bound(depth_maze(), True), abs=1e-12)
