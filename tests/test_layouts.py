"""Every environment takes its map as ``layout=``: a path to a map file or a list of row strings."""

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401

CASES = [
    ("ColourGrid-v0", ["R,G,.", "B,Y,R"], (2, 3)),
    ("WindyMaze-v0", ["OO#", "OOO"], (2, 3)),
    ("RingSensor8x8-v0", ["OO#", "OOO"], (2, 3)),
]


@pytest.mark.parametrize("env_id,rows,shape", CASES)
def test_layout_from_rows_and_from_file_give_the_same_env(tmp_path, env_id, rows, shape):
    path = tmp_path / "map.txt"
    path.write_text("\n".join(rows) + "\n")
    envs = [gym.make(env_id, layout=rows), gym.make(env_id, layout=str(path)), gym.make(env_id, layout=path)]
    free = [e.unwrapped.model.grid.free for e in envs]
    assert all(f.shape == shape for f in free)
    assert all(np.array_equal(free[0], f) for f in free)
    assert not free[0][0, 2]  # the obstacle
    trajectories = []
    for env in envs:
        obs, info = env.reset(seed=3)
        steps = [(np.asarray(obs).tolist(), info["position"])]
        for a in [0, 1, 2, 3, 1, 1]:
            obs, _, _, _, info = env.step(a)
            assert info["position"] != (0, 2)
            steps.append((np.asarray(obs).tolist(), info["position"]))
        trajectories.append(steps)
    assert trajectories[0] == trajectories[1] == trajectories[2]


def test_ring_sensor_layout_keeps_the_cell_readings_of_its_grid():
    env = gym.make("RingSensor8x8-v0", layout=["OO#", "OOO"])
    assert env.observation_space == gym.spaces.Discrete(2 * 3 + 1)
    model = env.unwrapped.model
    # A cell reading can name the obstacle cell (the sensor reports cells, not free cells) ...
    readings, probs = model.sensor.distribution(0, 1)
    assert 2 in readings.tolist()
    # ... but the robot is never there.
    assert model.prior()[0, 0, 2] == 0


def test_ring_sensor_size_that_disagrees_with_layout_is_an_error():
    with pytest.raises(ValueError, match="size=.*disagrees with the layout"):
        gym.make("RingSensor8x8-v0", size=(3, 3), layout=["OO#", "OOO"])
