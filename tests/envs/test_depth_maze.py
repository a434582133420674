"""DepthMaze-v0 (gym_gridloc/envs/depth_maze.py): any size and keyword arguments either build a
working environment or raise an error naming what is wrong (hypothesis); the documented robot and
depth sensor; a new perfect maze at every reset, following the reset seed; the pose referee and
the research protocol's fixed episode length and belief reward."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gym_gridloc import DepthMazeEnv, depth_maze_model, kernels
from gym_gridloc.core.grid import DIRECTIONS
from gym_gridloc.generators import perfect_maze
from tests.helpers import PROPERTY_SETTINGS, bad_keywords, exercise, kwargs_for


@PROPERTY_SETTINGS
@given(size=st.one_of(st.sampled_from([5, 7, 9]), st.sampled_from([4, 6, 3, 0, -5])), kwargs=kwargs_for(DepthMazeEnv))
def test_depth_maze_any_input(size, kwargs):
    bad = bad_keywords(kwargs)
    if size < 5 or size % 2 == 0:
        bad.add("size")
    exercise(lambda: gym.make("DepthMaze-v0", size=size, **kwargs), bad, True)


def brute_depth(grid, layer: int, r: int, c: int) -> int:
    """1 + the free cells ahead of (r, c) facing ``layer``, walking cell by cell."""
    dr, dc = (int(v) for v in DIRECTIONS[layer])
    n = 0
    while grid.is_free(r + dr * (n + 1), c + dc * (n + 1)):
        n += 1
    return n + 1


@pytest.mark.parametrize("seed", [0, 1])
def test_the_robot_and_its_sensor_are_as_documented(seed):
    grid = perfect_maze(9, seed=seed)
    model = depth_maze_model(grid, p_turn_fail=0.2, p_move_fail=0.3, p_depth_error=0.4)
    assert model.n_layers == 4 and model.action_names == ("left", "right", "forward")
    assert model.sensor.max_depth == 7 and model.sensor.n_readings == 8
    for s in range(model.n_states):
        layer, r, c = model.state_of_index(s)
        assert dict(model.outcomes((layer, r, c), 0)) == pytest.approx({((layer - 1) % 4, r, c): 0.8, (layer, r, c): 0.2})
        assert dict(model.outcomes((layer, r, c), 1)) == pytest.approx({((layer + 1) % 4, r, c): 0.8, (layer, r, c): 0.2})
        dr, dc = (int(v) for v in DIRECTIONS[layer])
        ahead = dict(model.outcomes((layer, r, c), 2))
        if grid.is_free(r + dr, c + dc):
            assert ahead == pytest.approx({(layer, r + dr, c + dc): 0.7, (layer, r, c): 0.3})
        else:
            assert ahead == pytest.approx({(layer, r, c): 1.0})
        d = brute_depth(grid, layer, r, c)
        assert model.sensor.depth[layer, r, c] == d
        readings, probs = model.sensor.distribution(r, c, layer)
        dist = dict(zip(readings.tolist(), probs.tolist()))
        expected = {d: 0.6}
        near = [z for z in (d - 1, d + 1) if 1 <= z <= 7]
        for z in near:
            expected[z] = expected.get(z, 0.0) + 0.4 / len(near)
        assert {z: p for z, p in dist.items() if p > 0} == pytest.approx(expected)
        assert dist.get(0, 0.0) == 0.0  # depth 0 is never read


def test_a_new_maze_at_every_reset_follows_the_seed():
    env = gym.make("DepthMaze-v0").unwrapped
    assert env.observation_space == gym.spaces.Discrete(6) and env.action_space == gym.spaces.Discrete(3)
    mazes = []
    for seed in (1, 1, 2):
        env.reset(seed=seed)
        mazes.append(env.model.grid.labels.copy())
        assert env._referee.model is env.model
    assert np.array_equal(mazes[0], mazes[1]) and not np.array_equal(mazes[0], mazes[2])
    fixed = gym.make("DepthMaze-v0", map_seed=3).unwrapped
    labels = fixed.model.grid.labels.copy()
    assert np.array_equal(labels, perfect_maze(7, seed=3).labels)
    for seed in range(3):
        fixed.reset(seed=seed)
        assert np.array_equal(fixed.model.grid.labels, labels)
    rows = ["#######", "#OOOOO#", "#O###O#", "#OOOOO#", "#######"]
    given_ = gym.make("DepthMaze-v0", layout=rows).unwrapped
    given_.reset(seed=0)
    assert given_.model.grid.to_text() == rows


def test_arguments_are_checked():
    with pytest.raises(ValueError, match=r"^size must be odd \(rooms at odd coordinates, walls all round\), got 8"):
        gym.make("DepthMaze-v0", size=8)
    with pytest.raises(ValueError, match=r"^size must be at least 5 and at most 201, got 3"):
        gym.make("DepthMaze-v0", size=3)
    with pytest.raises(ValueError, match=r"give either layout=\.\.\. \(a fixed maze\) or a generated one"):
        gym.make("DepthMaze-v0", layout=["#####", "#OOO#", "#####"], map_seed=1)
    with pytest.raises(TypeError, match=r"new_map_each_reset must be True or False, got 'yes'"):
        gym.make("DepthMaze-v0", new_map_each_reset="yes")
    env = gym.make("DepthMaze-v0")
    with pytest.raises(ValueError, match=r"max_depth=5 is below the map's largest depth 7"):
        env.reset(options={"map": perfect_maze(9, seed=1)})  # a 9 x 9 maze in a 7 x 7 environment


def test_the_pose_referee_and_the_research_protocol():
    env = gym.make("DepthMaze-v0", episode_length=12, reward="belief").unwrapped
    assert env.referee_pose
    for seed in range(3):
        _, info = env.reset(seed=seed)
        for t in range(1, 13):
            _, reward, terminated, truncated, info = env.step(t % 3)
            full = env._referee.full_belief
            assert info["confidence"] == full.max() and reward == info["confidence"]
            assert info["success"] == (info["localised"] and (info["estimate_heading"], *info["estimate"]) == env.state)
            assert terminated is False and truncated is (t == 12)


def test_a_maze_drawn_again_reuses_its_model():
    """A small map redrawn at reset is not built again: the same maze gives the same (frozen)
    model, shared by every environment with the same arguments, and only by those."""
    from gym_gridloc.envs import base

    a, b = gym.make("DepthMaze-v0").unwrapped, gym.make("DepthMaze-v0").unwrapped
    by_maze: dict[bytes, object] = {}
    for seed in range(400):  # (192 mazes: fewer than the models kept)
        for env in (a, b):
            env.reset(seed=seed)
            assert by_maze.setdefault(env.model.grid.labels.tobytes(), env.model) is env.model
    assert len(by_maze) < 400  # mazes came again
    other = gym.make("DepthMaze-v0", p_depth_error=0.1).unwrapped
    ours = {id(m) for m in by_maze.values()}
    for seed in range(50):
        other.reset(seed=seed)
        assert id(other.model) not in ours and other.model.sensor.p_depth_error == 0.1
    assert len(base._REDRAWN) <= base.REDRAWN_MODELS
    big = gym.make("DepthMaze-v0", size=17).unwrapped  # 289 cells: not kept
    assert base._redraw_key(big.map_factory.build, big.model.grid) is None


def test_a_maze_drawn_once_keeps_nothing():
    """Mazes that do not come again (15x15) keep no model: a map's model is kept from its second
    draw on; the first is held weakly, so it is freed with the last environment on it."""
    import gc
    import weakref

    from gym_gridloc.envs import base

    env = gym.make("DepthMaze-v0", size=15).unwrapped
    kept = set(map(id, base._REDRAWN.values()))
    refs = []
    for seed in range(30):
        env.reset(seed=1000 + seed)
        refs.append(weakref.ref(env.model))
    del env
    gc.collect()
    assert all(r() is None for r in refs)
    assert not any(m.shape == (15, 15) and id(m) not in kept for m in base._REDRAWN.values())
    # drawn twice (two environments, one seed): kept, and the same model
    a, b = gym.make("DepthMaze-v0", size=15).unwrapped, gym.make("DepthMaze-v0", size=15).unwrapped
    a.reset(seed=5)
    b.reset(seed=5)
    assert a.model is b.model and any(m is a.model for m in base._REDRAWN.values())


def test_the_map_factory_draws_mazes_as_codes_as_it_draws_them_one_by_one():
    """MapFactory.codes (the native vector env's resets: all of a step's mazes in one call) and
    model_of_code give the models that as many calls of the factory give, from the same draws;
    a family without codes says None, and codes come with the map they stand for or not at all."""
    from gym_gridloc.envs.base import MapFactory

    factory = gym.make("DepthMaze-v0").unwrapped.map_factory
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    codes = factory.codes(a, 6)
    if codes is None:  # (no numba: the vector env calls the factory once per maze)
        assert kernels.compiled(1) is None
        return
    one_by_one = [factory(b) for _ in range(6)]
    assert [factory.model_of_code(c) for c in codes.tolist()] == one_by_one  # the same (kept) models
    assert a.random() == b.random()
    assert gym.make("WindyMaze-v0", new_map_each_reset=True).unwrapped.map_factory.codes(a, 2) is None
    with pytest.raises(ValueError, match="both codes= and of_code="):
        MapFactory(factory.build, factory.draw, codes=lambda rng, count: None)
    with pytest.raises(ValueError, match="give codes= and of_code= too"):
        MapFactory(factory.build, factory.draw, graph=factory.graph)


def test_the_map_factorys_graph_is_the_one_its_codes_are_trees_of():
    """MapFactory.graph (generators.perfect_maze_graph): each wall's two rooms, in the codes' bit
    order; a code's opened walls join all the rooms into one tree; too many walls: None."""
    from gym_gridloc.generators import perfect_maze_graph

    factory = gym.make("DepthMaze-v0").unwrapped.map_factory
    walls, rooms = factory.graph
    assert walls.shape == (2, 12) and rooms == 9 and not walls.flags.writeable
    assert perfect_maze_graph(13)[0].shape == (2, 60) and perfect_maze_graph(15) is None
    assert gym.make("DepthMaze-v0", size=15).unwrapped.map_factory.graph is None
    with pytest.raises(ValueError, match="size must be odd"):
        perfect_maze_graph(8)
    codes = factory.codes(np.random.default_rng(4), 20)
    if codes is None:
        return
    for code in codes.tolist():
        opened = [w for w in range(walls.shape[1]) if code >> w & 1]
        assert len(opened) == rooms - 1
        parent = list(range(rooms))

        def root(a):
            while parent[a] != a:
                a = parent[a]
            return a

        for w in opened:
            a, b = root(walls[0, w]), root(walls[1, w])
            assert a != b  # no cycle: a tree
            parent[a] = b


@pytest.mark.skipif(kernels.compiled(1) is None, reason="numba is not installed (or switched off)")
@pytest.mark.parametrize("autoreset", ["NextStep", "SameStep"])
@pytest.mark.parametrize("full", [False, True])
def test_the_vector_steps_own_map_draws_are_those_of_the_map_factory(autoreset, full, monkeypatch):
    """The native vector env's compiled step draws its new episodes' mazes itself (a code per maze,
    a table from code to the bank's slot): the same mazes, episodes and numbers, and the
    generator left where they leave it, as the map factory's draws before the call; with a full
    bank too (``full``: N + 1 slots), whose reused slots' codes are dropped from the table."""
    from gym_gridloc import engine

    if full:
        monkeypatch.setattr(engine.VectorBank, "BYTES", 1)
    n, steps = 6, 250

    def run(in_call):
        if not in_call:
            monkeypatch.setattr(engine.VectorBank, "CODE_WALLS", 0)  # (no table: the factory's draws)
        env = gym.make_vec("DepthMaze-v0", num_envs=n, vectorization_mode="vector_entry_point", autoreset_mode=autoreset,
                           max_episode_steps=12).unwrapped
        monkeypatch.setattr(engine.VectorBank, "CODE_WALLS", 16)
        assert env.batch._maps_in_call == in_call
        out = [env.reset(seed=9)]
        rng = np.random.default_rng(0)
        for _ in range(steps):
            out.append(env.step(rng.integers(0, 3, size=n)))
            out.append([m.grid.labels.tobytes() for m in env.models])
        out.append(env.reset(seed=10, options={"reset_mask": np.arange(n) % 2 == 0}))
        out.append([m.grid.labels.tobytes() for m in env.models])
        out.append(env.np_random.random())
        if full:
            assert len(env.batch.bank.models) == n + 1
        return out

    def same(a, b):
        if isinstance(a, dict):
            return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
        if isinstance(a, (list, tuple)):
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
        if isinstance(a, np.ndarray) and a.dtype != object:
            return a.dtype == b.dtype and a.tobytes() == b.tobytes()
        if isinstance(a, np.ndarray):
            return same(a.tolist(), b.tolist())
        return a == b

    assert same(run(True), run(False))


# -- maze variants: the generator and the rotation-symmetric mazes --------------------------------
def test_the_protocol_rejects_rotation_symmetric_mazes_by_default():
    from gym_gridloc.generators import is_rotation_symmetric

    def symmetric_share(**kwargs):
        env = gym.make("DepthMaze-v0", size=7, **kwargs).unwrapped
        env.reset(seed=5)
        count = 0
        for _ in range(600):
            env.reset()
            count += is_rotation_symmetric(env.model.grid)
        return count / 600

    assert symmetric_share() > 0.02  # about 5% of 7x7 mazes equal their own rotation
    assert symmetric_share(episode_length=15) == 0.0  # the research protocol: drawn again
    assert symmetric_share(episode_length=15, reject_symmetric=False) > 0.02
    assert symmetric_share(reject_symmetric=True, generator="eller") == 0.0
    env = gym.make("DepthMaze-v0", episode_length=15).unwrapped
    assert env.map_options == {"generator": "kruskal", "reject_symmetric": True}
    assert env.map_factory.graph is None  # the vector env draws these mazes through the factory
    assert gym.make("DepthMaze-v0").unwrapped.map_factory.graph is not None


@pytest.mark.parametrize("generator", ["kruskal", "eller"])
def test_the_generator_keyword_draws_its_mazes_from_the_reset_seed(generator):
    from gym_gridloc.generators import random_maze

    env = gym.make("DepthMaze-v0", size=9, generator=generator, reject_symmetric=False).unwrapped
    for seed in (0, 3, 11):
        env.reset(seed=seed)
        a = env.model.grid.labels.copy()
        env.reset(seed=seed)
        assert np.array_equal(a, env.model.grid.labels)
    fixed = gym.make("DepthMaze-v0", size=9, generator=generator, map_seed=4).unwrapped
    assert np.array_equal(fixed.model.grid.labels, random_maze(9, 4, generator=generator).labels)
    assert fixed.map_factory is None


def test_maze_variant_keywords_are_checked():
    with pytest.raises(ValueError, match=r"generator must be one of 'kruskal', 'eller', 'mixed' \(how perfect mazes are drawn\), got 'prim'"):
        gym.make("DepthMaze-v0", generator="prim")
    with pytest.raises(TypeError, match=r"reject_symmetric must be True, False or None, got 'yes'"):
        gym.make("DepthMaze-v0", reject_symmetric="yes")
