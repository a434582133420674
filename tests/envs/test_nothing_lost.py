"""Nothing lost in the core: values checked where they enter (no silently wrong belief, no truncation)."""

from __future__ import annotations

import importlib.util

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc.generators import perfect_maze


def test_np_bool_is_a_bool_everywhere():
    for env_id, kw in (("DepthMaze-v0", {}), ("WindyMaze-v0", {"size": 7}), ("ColourGrid-v0", {"size": 5})):
        env = gym.make(env_id, new_map_each_reset=np.bool_(True), **kw)
        assert env.unwrapped._map_factory is not None
    venv = gym.make_vec("WindyMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", map=np.bool_(True))
    assert venv.map is True


def test_a_reset_map_of_another_shape_is_refused():
    env = gym_gridloc.HMMBeliefWrapper(gym.make("DepthMaze-v0", size=7))
    with pytest.raises(ValueError, match="'map'.*7x7"):
        env.reset(seed=0, options={"map": perfect_maze(5, seed=1)})
    obs, _ = env.reset(seed=0, options={"map": perfect_maze(7, seed=1)})
    assert env.observation_space.contains(obs)
    windy = gym_gridloc.HMMBeliefWrapper(gym.make("WindyMaze-v0", size=7, map_seed=0))
    for rows in (["OOOO", "O#OO", "OOOO"], ["O" * 9] * 2):
        with pytest.raises(ValueError, match="'map'"):
            windy.reset(seed=0, options={"map": rows})


@pytest.mark.parametrize("kw", [{"key": "map", "map": True}, {"key": "lookahead", "lookahead": 1}])
def test_the_belief_key_never_collides(kw):
    with pytest.raises(ValueError, match="choose another key"):
        gym_gridloc.HMMBeliefWrapper(gym.make("ColourGrid-v0"), **kw)


def test_a_layout_with_another_size_is_refused():
    layout = perfect_maze(9, seed=0)
    with pytest.raises(ValueError, match="size=7 but the layout is a 9x9"):
        gym.make("DepthMaze-v0", layout=layout, size=7)
    assert gym.make("DepthMaze-v0", layout=layout, size=9).unwrapped.model.shape == (9, 9)
    assert gym.make("DepthMaze-v0", layout=layout).unwrapped.model.shape == (9, 9)


def test_a_stored_episode_keeps_its_map():
    env = gym_gridloc.RecordTrajectory(gym.make("DepthMaze-v0"))
    env.reset(seed=0)
    for a in (0, 2, 1):
        env.step(a)
    ep = env.trajectory
    before = ep.smooth()
    env.reset(seed=1)  # a new maze
    assert env.unwrapped.model is not ep.model
    np.testing.assert_array_equal(env.episodes[-1].smooth(), before)


@pytest.mark.skipif(importlib.util.find_spec("pomdp_py") is None, reason="needs the planning extra")
def test_pomdp_py_adapter_checks_its_values():
    from gym_gridloc.interop import to_pomdp_py

    model = gym_gridloc.colour_grid_model()
    for kw, err in (({"pose": "no"}, TypeError), ({"discount": None}, TypeError), ({"discount": 0}, ValueError)):
        with pytest.raises(err, match=next(iter(kw))):
            to_pomdp_py(model, **kw)
    adapter = to_pomdp_py(model)
    free = tuple(int(v) for v in np.argwhere(model.grid.free)[0])
    for bad in ((0, free[0] + 0.7, free[1]), (0, 1.7, 1.2), (0, 1, 1.5)):
        with pytest.raises(ValueError, match="whole numbers"):
            adapter.to_state(bad)
    for n in (0, -1, 2.5):
        with pytest.raises(ValueError, match="n_particles"):
            adapter.agent(model.prior(), n_particles=n)


def test_an_episode_length_above_the_step_limit_is_refused_not_cut_short():
    with pytest.raises(ValueError, match="episode_length.*1..100"):
        gym.make("DepthMaze-v0", episode_length=150)
    with pytest.raises(ValueError, match="episode_length.*1..100"):
        gym.make_vec("DepthMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", episode_length=101)
    with pytest.raises(ValueError, match="episode_length=60 is above max_episode_steps=50"):
        gym.make_vec("DepthMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", episode_length=60, max_episode_steps=50)
    assert gym_gridloc.envs.depth_maze.MAX_EPISODE_LENGTH == gym.spec("DepthMaze-v0").max_episode_steps
    for env in (gym.make("DepthMaze-v0", episode_length=100),
                gym.make_vec("DepthMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", episode_length=100)):
        env.reset(seed=0)
        steps = 0
        while True:
            steps += 1
            *_, terminated, truncated, _ = env.step(np.full(2, 2) if hasattr(env, "num_envs") else 2)
            if np.any(truncated) or np.any(terminated):
                break
        assert steps == 100 and np.all(truncated) and not np.any(terminated)


def test_a_depth_maze_layout_has_the_size_cap_of_size(tmp_path):
    rows = ["#" * 603] + ["#" + "O" * 601 + "#"] * 601 + ["#" * 603]
    (tmp_path / "big.txt").write_text("\n".join(rows) + "\n")
    for layout in (str(tmp_path / "big.txt"), rows, ["#" * 203] + ["#" + "O" * 201 + "#"] * 3 + ["#" * 203]):
        with pytest.raises(ValueError, match=r"layout is a \d+x\d+ maze; a DepthMaze side is at most 201"):
            gym.make("DepthMaze-v0", layout=layout)
    gym.make("DepthMaze-v0", layout=["#####", "#OOO#", "#O#O#", "#OOO#", "#####"]).reset(seed=0)
