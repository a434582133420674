"""The candidate_views extractor: each pose's view shows what the depth sensor reads from it, a
right turn turns the view, the most probable poses come first with their probabilities, the
layout of the flat observation is read where the wrapper writes it, and bad options are refused."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

import gym_gridloc
from gym_gridloc_agents.candidate_views import CandidateViews, view_cells
from gym_gridloc_agents.features import EXTRACTORS
from gym_gridloc_agents.training.config import ConfigError, validate_config


def _views(size: int, seed: int, radius: int):
    env = gym.make("DepthMaze-v0", size=size, map_seed=seed)
    model = env.unwrapped.model
    free = model.grid.free.astype(np.float64)
    padded = np.pad(free, radius).reshape(-1)
    side = 2 * radius + 1
    return model, padded[view_cells(size, radius)].reshape(4, size, size, side, side)


@pytest.mark.parametrize("size,seed,radius", [(7, 0, 3), (9, 4, 8), (15, 2, 6)])
def test_a_views_column_ahead_reads_the_sensors_depth(size, seed, radius):
    model, views = _views(size, seed, radius)
    depth = np.zeros((4, size, size), dtype=int)  # the noiseless depth each pose reads
    for reading in range(model.sensor.observation_space.n):
        depth[model.likelihood(reading) > 0.5] = reading
    checked = 0
    for h, r, c in zip(*np.nonzero(model.grid.free[None].repeat(4, 0))):
        view = views[h, r, c]
        assert view[radius, radius] == 1.0  # the robot's own cell, free
        run = 1
        while run <= radius and view[radius - run, radius] == 1.0:
            run += 1
        assert run == min(depth[h, r, c], radius + 1), (h, r, c)
        checked += 1
    assert checked == 4 * model.grid.n_free


def test_a_right_turn_turns_the_view_and_walls_lie_outside():
    size, radius = 9, 5
    model, views = _views(size, 1, radius)
    for h in range(4):
        assert np.array_equal(views[(h + 1) % 4], np.rot90(views[h], 1, axes=(2, 3)))
    # the corner cell (1, 1) facing north: two rows ahead lie outside the maze, walls
    assert np.all(views[0, 1, 1, : radius - 1] == 0.0)


def _flat_env(size: int = 7):
    return gym_gridloc.HMMBeliefWrapper(gym.make("DepthMaze-v0", size=size), full_state=True, map=True, flatten=True)


def test_the_most_probable_poses_come_first_with_their_views():
    size, radius, k = 7, 3, 3
    env = _flat_env(size)
    obs, _ = env.reset(seed=0)
    for a in (2, 1, 2):
        obs, *_ = env.step(a)
    ex = CandidateViews(env.observation_space, size=size, candidates=k, radius=radius)
    out = ex(torch.as_tensor(obs[None]))[0].numpy()
    n = obs.shape[0]
    assert out.shape == (ex.features_dim,) and ex.features_dim == n + k * (1 + (2 * radius + 1) ** 2)
    assert np.array_equal(out[:n], obs)  # keep: the raw observation first
    readings = size - 1
    belief = obs[readings : readings + 4 * size * size]
    order = np.argsort(-belief, kind="stable")[:k]
    assert np.allclose(out[n : n + k], belief[order])
    free = obs[readings + 4 * size * size : readings + 5 * size * size]
    padded = np.pad(free.reshape(size, size), radius).reshape(-1)
    expected = padded[view_cells(size, radius)[order]].reshape(-1)
    if len(set(belief[order])) == k:  # ties may come in either order
        assert np.array_equal(out[n + k :], expected)
    dropped = CandidateViews(env.observation_space, size=size, candidates=k, radius=radius, keep=False)
    out2 = dropped(torch.as_tensor(obs[None]))[0].numpy()
    assert np.array_equal(out2[:readings], obs[:readings])  # the reading; the belief and the maze left out
    assert out2.shape[0] == dropped.features_dim == n - 5 * size * size + k * (1 + (2 * radius + 1) ** 2)


def test_bad_options_and_spaces_are_refused():
    space = _flat_env(7).observation_space
    with pytest.raises(ValueError, match="flat Box"):
        CandidateViews(spaces.Dict({"belief": spaces.Box(0, 1, (4, 7, 7))}), size=7)
    with pytest.raises(ValueError, match="holds the reading"):
        CandidateViews(space, size=9)
    with pytest.raises(ValueError, match="keep must be true or false"):
        CandidateViews(space, size=7, keep=1)
    with pytest.raises(ValueError, match="radius"):
        CandidateViews(space, size=7, radius=0)


def test_a_config_names_it_with_integers_and_true_or_false(tmp_path):
    raw = {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": {"size": 7},
           "wrapper": {"belief": True, "flatten": True, "full_state": True, "map": True},
           "policy": "MlpPolicy", "total_timesteps": 64, "output": str(tmp_path / "m.zip"),
           "policy_kwargs": {"features_extractor": "candidate_views",
                             "features_extractor_kwargs": {"size": 7, "candidates": 2, "radius": 3, "keep": False}}}
    assert EXTRACTORS["candidate_views"] is CandidateViews and not CandidateViews.dict_observations
    validate_config(raw)
    for bad in ({"keep": "no"}, {"radius": 0}, {"candidates": 1.5}):
        cfg = {**raw, "policy_kwargs": {**raw["policy_kwargs"], "features_extractor_kwargs": bad}}
        with pytest.raises(ConfigError, match="positive integers or true/false"):
            validate_config(cfg)
    wrong = ({"env_kwargs": {"size": 9}}, {"wrapper": {**raw["wrapper"], "map": False}}, {"env_id": "WindyMaze-v0", "env_kwargs": {}})
    for change in wrong:  # another maze size, a layout without the maze, another environment
        with pytest.raises(ConfigError, match="candidate_views .* reads the flat pose belief and maze"):
            validate_config({**raw, **change})
