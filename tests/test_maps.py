"""Held-out maps (gym_gridloc/maps.py): fixed test and validation sets per family and size, the same
on every machine (stored checksums), apart from each other and usable as an episode's map."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc import maps
from gym_gridloc.generators import is_connected

CASES = [("DepthMaze-v0", 7), ("WindyMaze-v0", 9), ("ColourGrid-v0", 9)]


def test_families():
    assert maps.families() == ("DepthMaze-v0", "WindyMaze-v0", "ColourGrid-v0")
    assert set(maps.CHECKSUMS) >= {(env_id, purpose, size) for env_id, size in CASES for purpose in ("test", "validation")}


@pytest.mark.parametrize("env_id,size", CASES)
def test_sets_are_fixed_valid_and_apart(env_id, size):
    test = maps.test_set(env_id, size, n=20)
    again = maps.test_set(env_id, size, n=5)
    val = maps.validation_set(env_id, size, n=20)
    assert len(test) == 20 and [m.index for m in test] == list(range(20))
    for a, b in zip(test, again):
        assert np.array_equal(a.grid.labels, b.grid.labels) and a.state == b.state
    layers = 4 if env_id == "DepthMaze-v0" else 1
    for m in test + val:
        assert m.grid.shape == (size, size) and is_connected(m.grid.free)
        layer, r, c = m.state
        assert 0 <= layer < layers and m.grid.free[r, c]
    keys = {(m.grid.labels.tobytes(), m.state) for m in test}
    assert len(keys) == 20  # different maps
    assert not keys & {(m.grid.labels.tobytes(), m.state) for m in val}  # never a validation episode
    # The stored checksum covers the first 1000 maps and their start states.
    assert maps.checksum(maps.test_set(env_id, size, n=1000)) == maps.CHECKSUMS[(env_id, "test", size)]


def test_a_changed_generator_is_caught(monkeypatch):
    monkeypatch.setitem(maps.CHECKSUMS, ("WindyMaze-v0", "test", 9), "0" * 64)
    with pytest.raises(RuntimeError, match="differ from the stored checksum: the map generator changed"):
        maps.test_set("WindyMaze-v0", 9, n=3)
    with pytest.raises(ValueError, match=r"no held-out maps for 'RingSensor8x8-v0'; families with random maps: DepthMaze-v0"):
        maps.test_set("RingSensor8x8-v0", 8)
    for n in (0, -5):  # a stored set too (it is drawn 1000 long and cut)
        with pytest.raises(ValueError, match=rf"^n must be at least 1 and at most 100000, got {n}"):
            maps.validation_set("WindyMaze-v0", 9, n=n)
        with pytest.raises(ValueError, match=rf"^n must be at least 1 and at most 100000, got {n}"):
            maps.test_set("WindyMaze-v0", 11, n=n)


@pytest.mark.parametrize("env_id,size", CASES)
def test_a_held_out_map_is_an_episodes_map(env_id, size):
    kwargs = {"size": size} if env_id == "DepthMaze-v0" else {"size": (size, size)}
    env = gym.make(env_id, **kwargs).unwrapped
    first = env.model
    held = maps.test_set(env_id, size, n=2)
    for m in held:
        env.reset(seed=0, options={"map": m.grid, "state": m.state})
        assert np.array_equal(env.model.grid.labels, m.grid.labels) and env.state == m.state
        assert env._referee.model is env.model
    env.reset(seed=0)  # without the option: the environment's own map again (or a redrawn one)
    assert env.model is first or env._map_factory is not None


@pytest.mark.parametrize("generator", ["kruskal", "eller"])
@pytest.mark.parametrize("size", [7, 15, 21])
def test_depth_maze_variant_sets_are_stored_asymmetric_and_their_own(generator, size):
    from gym_gridloc.generators import is_rotation_symmetric

    name = maps.set_name("DepthMaze-v0", generator, True)
    for purpose, draw in (("test", maps.test_set), ("validation", maps.validation_set)):
        held = draw("DepthMaze-v0", size, 1000, generator=generator, reject_symmetric=True)
        assert maps.checksum(held) == maps.CHECKSUMS[(name, purpose, size)]
        assert not any(is_rotation_symmetric(m.grid) for m in held)
    plain = maps.test_set("DepthMaze-v0", size, 50)
    variant = maps.test_set("DepthMaze-v0", size, 50, generator=generator, reject_symmetric=True)
    assert sum(np.array_equal(a.grid.labels, b.grid.labels) and a.state == b.state for a, b in zip(plain, variant)) < 10


def test_the_default_depth_maze_set_keeps_its_symmetric_mazes_and_variants_are_checked():
    from gym_gridloc.generators import is_rotation_symmetric

    held = maps.test_set("DepthMaze-v0", 7)  # today's set, as it always was (its checksum above)
    assert 0.02 < np.mean([is_rotation_symmetric(m.grid) for m in held]) < 0.1
    assert maps.set_name("DepthMaze-v0") == "DepthMaze-v0"
    with pytest.raises(ValueError, match="generator= and reject_symmetric= choose DepthMaze's maze variants"):
        maps.test_set("WindyMaze-v0", 9, 3, generator="eller")
    with pytest.raises(ValueError, match="generator must be 'kruskal' or 'eller'"):
        maps.test_set("DepthMaze-v0", 7, 3, generator="prim", reject_symmetric=True)
