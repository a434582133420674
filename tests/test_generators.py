"""Generated maps: reproducible from their seed, connected, and wired into the registered ids."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gym_gridloc
from gym_gridloc import kernels
from gym_gridloc.generators import (
    COLOUR_SYMBOLS,
    colour_map,
    is_connected,
    maze_map,
    perfect_maze,
    perfect_maze_codes,
    perfect_maze_of_code,
)


@pytest.mark.parametrize("size", [(1, 1), (1, 7), (5, 5), (17, 9), (64, 48)])
@pytest.mark.parametrize("density", [0.0, 0.2, 0.45])
def test_colour_maps_are_reproducible_and_connected(size, density):
    a = colour_map(size, obstacle_density=density, n_colours=5, seed=11)
    b = colour_map(size, obstacle_density=density, n_colours=5, seed=11)
    assert np.array_equal(a.labels, b.labels)
    assert a.shape == size
    assert is_connected(a.free)
    assert a.symbols == COLOUR_SYMBOLS[:5]
    assert a.labels.max() < 5
    if density == 0.0:
        assert a.free.all()


def test_colour_map_seeds_differ_and_density_is_roughly_kept():
    a = colour_map((64, 64), obstacle_density=0.2, seed=1)
    b = colour_map((64, 64), obstacle_density=0.2, seed=2)
    assert not np.array_equal(a.labels, b.labels)
    assert 0.15 < 1.0 - a.free.mean() < 0.3  # isolated pockets become obstacles too
    assert set(np.unique(a.labels[a.free])) == {0, 1, 2, 3}


@pytest.mark.parametrize("size", [(1, 1), (2, 2), (3, 3), (6, 7), (7, 6), (10, 10), (31, 31), (50, 41)])
def test_mazes_are_reproducible_and_connected_with_walls(size):
    a = maze_map(size, seed=5)
    assert np.array_equal(a.labels, maze_map(size, seed=5).labels)
    assert a.shape == size
    assert is_connected(a.free)
    if min(size) >= 3:
        assert not a.free.all()  # walls between the corridors
        # Corridors are one cell wide: no 2x2 block of free cells.
        f = a.free
        assert not np.any(f[:-1, :-1] & f[1:, :-1] & f[:-1, 1:] & f[1:, 1:])


@pytest.mark.parametrize("size", [5, 7, 15, 21])
def test_perfect_mazes_are_reproducible_spanning_trees(size):
    a = perfect_maze(size, seed=3)
    assert np.array_equal(a.labels, perfect_maze(size, seed=3).labels)
    assert a.shape == (size, size) and is_connected(a.free)
    f = a.free
    assert not f[0].any() and not f[-1].any() and not f[:, 0].any() and not f[:, -1].any()  # walls all round
    assert f[1::2, 1::2].all()  # every room is free
    k = (size - 1) // 2
    assert a.n_free == k * k + (k * k - 1)  # the rooms and the walls opened between them
    # One path between any two cells: the free cells and their adjacencies form a tree.
    edges = int((f[:-1, :] & f[1:, :]).sum() + (f[:, :-1] & f[:, 1:]).sum())
    assert edges == a.n_free - 1
    assert not np.array_equal(a.labels, perfect_maze(size, seed=4).labels)


def test_maze_seeds_differ():
    assert not np.array_equal(maze_map((21, 21), seed=1).labels, maze_map((21, 21), seed=2).labels)


def test_generator_arguments_are_checked():
    with pytest.raises(ValueError, match="obstacle_density"):
        colour_map((5, 5), obstacle_density=1.0)
    with pytest.raises(ValueError, match="n_colours"):
        colour_map((5, 5), n_colours=0)
    with pytest.raises(ValueError, match="n_colours"):
        colour_map((5, 5), n_colours=27)
    with pytest.raises(ValueError, match="size"):
        maze_map((0, 5))
    with pytest.raises(ValueError, match=r"^map_seed must be a non-negative integer, got -1"):
        maze_map((5, 5), seed=-1)
    with pytest.raises(TypeError, match=r"^map_seed must be a non-negative integer, a numpy Generator or None, got 1\.5"):
        maze_map((5, 5), seed=1.5)
    with pytest.raises(ValueError, match=r"size must be odd"):
        perfect_maze(6)
    with pytest.raises(ValueError, match=r"size must be at least 5"):
        perfect_maze(3)


def test_registered_ids_take_generated_maps():
    env = gym.make("ColourGrid-v0", size=(12, 10), obstacle_density=0.25, n_colours=6, map_seed=3)
    grid = env.unwrapped.model.grid
    assert grid.shape == (12, 10) and is_connected(grid.free)
    assert env.observation_space == gym.spaces.Discrete(6)
    same = gym.make("ColourGrid-v0", size=(12, 10), obstacle_density=0.25, n_colours=6, map_seed=3)
    assert np.array_equal(grid.labels, same.unwrapped.model.grid.labels)
    other = gym.make("ColourGrid-v0", size=(12, 10), obstacle_density=0.25, n_colours=6, map_seed=4)
    assert not np.array_equal(grid.labels, other.unwrapped.model.grid.labels)
    maze = gym.make("WindyMaze-v0", size=(9, 12), map_seed=1).unwrapped.model.grid
    assert maze.shape == (9, 12) and is_connected(maze.free)
    ring = gym.make("RingSensor8x8-v0", size=(12, 9))
    assert ring.unwrapped.model.shape == (12, 9)
    assert ring.observation_space == gym.spaces.Discrete(12 * 9 + 1)
    # The default maps are still the seeds'.
    assert gym.make("ColourGrid-v0").unwrapped.model.grid.n_free == 19
    assert gym.make("WindyMaze-v0").unwrapped.model.grid.n_free == 31


def test_layout_and_generated_map_together_is_an_error():
    with pytest.raises(ValueError, match="layout"):
        gym.make("ColourGrid-v0", layout=["R,G", "B,Y"], size=(5, 5))
    with pytest.raises(ValueError, match="layout"):
        gym.make("WindyMaze-v0", layout=["OO", "OO"], map_seed=2)
    with pytest.raises(TypeError, match="new_map_each_reset"):
        gym.make("WindyMaze-v0", new_map_each_reset="yes")


@pytest.mark.parametrize("env_id,kwargs", [
    ("ColourGrid-v0", {"size": (8, 9), "obstacle_density": 0.2}),
    ("WindyMaze-v0", {"size": (9, 9)}),
])
def test_new_map_each_reset_follows_the_reset_seed(env_id, kwargs):
    env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id, new_map_each_reset=True, **kwargs))
    maps = []
    for seed in (1, 1, 2):
        obs, _ = env.reset(seed=seed)
        maps.append(env.unwrapped.model.grid.labels.copy())
        # The wrapper follows the redrawn map: its belief is the environment's referee posterior.
        assert env.model is env.unwrapped.model
        for a in (0, 1, 2, 3, 0):
            obs, *_ = env.step(a)
        np.testing.assert_allclose(obs["belief"], env.unwrapped.posterior, atol=1e-6)
        assert np.all(obs["belief"][~env.unwrapped.model.grid.free] == 0)
    assert np.array_equal(maps[0], maps[1])
    assert not np.array_equal(maps[0], maps[2])


def test_generated_envs_pass_check_env():
    check_env(gym.make("ColourGrid-v0", size=(6, 7), n_colours=3, new_map_each_reset=True).unwrapped, skip_render_check=True)
    check_env(gym.make("WindyMaze-v0", size=(8, 8), map_seed=4).unwrapped, skip_render_check=True)


def _kruskal_reference(size, rng):
    """Kruskal's algorithm as perfect_maze's docstring says it, written plainly: the walls between
    rooms (east walls row by row, then south walls), shuffled by one permutation, each opened
    when its two rooms are not yet joined."""
    k = (size - 1) // 2
    walls = [((r, c), (r, c + 1)) for r in range(k) for c in range(k - 1)] + \
            [((r, c), (r + 1, c)) for r in range(k - 1) for c in range(k)]
    tree = {(r, c): (r, c) for r in range(k) for c in range(k)}

    def root(x):
        while tree[x] != x:
            x = tree[x]
        return x

    free = np.zeros((size, size), dtype=bool)
    free[1::2, 1::2] = True
    for w in rng.permutation(len(walls)):
        a, b = walls[w]
        if root(a) != root(b):
            tree[root(a)] = root(b)
            free[a[0] + b[0] + 1, a[1] + b[1] + 1] = True
    return free


@pytest.mark.parametrize("size", [5, 7, 9, 15, 31])
def test_perfect_mazes_are_kruskal_on_the_shuffled_walls(size):
    for seed in range(40):
        rng, ref = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(3):  # the same draws from a shared generator, maze after maze
            assert np.array_equal(perfect_maze(size, seed=rng).free, _kruskal_reference(size, ref))
        assert rng.random() == ref.random()


def test_a_small_perfect_maze_drawn_again_is_the_same_map():
    """A 7x7 perfect maze is one of 192 (the spanning trees of 3x3 rooms): a maze drawn again is
    the same (frozen) GridMap, so that what is derived from it can be kept."""
    rng = np.random.default_rng(0)
    mazes = {}
    for _ in range(2000):
        m = perfect_maze(7, seed=rng)
        assert mazes.setdefault(m.labels.tobytes(), m) is m
        assert not m.labels.flags.writeable
    assert 150 <= len(mazes) <= 192


@pytest.mark.parametrize("size", [5, 7, 9, 11, 13])
@pytest.mark.parametrize("bits", [np.random.PCG64, np.random.MT19937, np.random.Philox])
def test_perfect_maze_codes_draw_what_perfect_maze_draws(size, bits):
    """perfect_maze_codes (a native vector env's resets: N mazes in one compiled call, from the
    generator's bit stream): the same maps as N calls of perfect_maze (the very map objects), and
    the generator left where those calls leave it; on any numpy bit generator."""
    if kernels.compiled(1) is None:
        assert perfect_maze_codes(size, np.random.default_rng(0), 3) is None
        return
    for seed in range(12):
        a, b = np.random.Generator(bits(seed)), np.random.Generator(bits(seed))
        b.random(seed % 3)  # (a generator part-way through its stream, a 32-bit half buffered too)
        b.integers(2**32, size=seed % 2, dtype=np.uint32)
        a.random(seed % 3)
        a.integers(2**32, size=seed % 2, dtype=np.uint32)
        codes = perfect_maze_codes(size, a, seed % 5)
        assert codes.dtype == np.int64 and codes.shape == (seed % 5,)
        assert [perfect_maze_of_code(size, c) for c in codes.tolist()] == [perfect_maze(size, seed=b) for _ in range(seed % 5)]
        assert a.random() == b.random() and a.integers(2**32, dtype=np.uint32) == b.integers(2**32, dtype=np.uint32)


def test_perfect_maze_codes_are_checked_and_say_none_where_a_code_cannot_hold_the_walls():
    rng = np.random.default_rng(0)
    assert perfect_maze_codes(15, rng, 2) is None  # 84 walls: more than an int64's 63 bits
    for bad, match in (((6, rng, 1), "odd"), ((7, rng, -1), "count"), ((7, 3, 1), "Generator"), ((3, rng, 1), "size")):
        with pytest.raises((ValueError, TypeError), match=match):
            perfect_maze_codes(*bad)


@pytest.mark.skipif(kernels.compiled(1) is None, reason="numba is not installed (or switched off)")
def test_the_compiled_bounded_integers_are_numpys():
    """The vector step's start states: numpy's Generator.integers(high, size=k) (Lemire's
    multiply and reject on 32-bit draws), for highs from 2 to nearly 2**32."""
    from gym_gridloc import _numba_draws as fast

    for high in (2, 3, 7, 68, 196, 1000, 2**20 + 3, 2**31 + 11, 2**32 - 5):
        a, b = np.random.default_rng(high), np.random.default_rng(high)
        functions = kernels.bit_functions(a.bit_generator)
        drawn = [fast.bounded(functions[0], functions[2], high - 1) for _ in range(50)]
        assert drawn == b.integers(high, size=50).tolist()
        assert a.random() == b.random()


# -- Eller's mazes and the rotation-symmetric ones -------------------------------------------------
def _room_edges(grid):
    """The opened walls of a perfect maze as edges between rooms (row, col of the room lattice)."""
    free = grid.free
    n = free.shape[0]
    edges = []
    for y in range(1, n - 1):
        for x in range(1, n - 1):
            if free[y, x] and (y % 2) != (x % 2):  # a wall cell between two rooms, opened
                a, b = ((y - 1) // 2, x // 2), ((y + 1) // 2, x // 2)
                if y % 2:  # between rooms left and right
                    a, b = (y // 2, (x - 1) // 2), (y // 2, (x + 1) // 2)
                edges.append((a, b))
    return edges


@pytest.mark.parametrize("size", [5, 7, 9, 15, 21])
def test_eller_mazes_are_reproducible_spanning_trees(size):
    from gym_gridloc.generators import eller_maze

    k = (size - 1) // 2
    for seed in range(60):
        m = eller_maze(size, seed=seed)
        assert np.array_equal(m.labels, eller_maze(size, seed=seed).labels)
        assert m.shape == (size, size) and m.symbols == ("O",)
        assert not m.free[0].any() and not m.free[-1].any() and not m.free[:, 0].any() and not m.free[:, -1].any()
        assert m.free[1::2, 1::2].all() and not m.free[::2, ::2].any()  # rooms free, pillars walls
        edges = _room_edges(m)
        assert len(edges) == k * k - 1 and m.n_free == k * k + k * k - 1  # a tree's edge count...
        assert is_connected(m.free)  # ...and connected: no cycle, every room reachable


def test_eller_mazes_have_the_documented_distribution():
    """On 5x5 mazes (2 x 2 rooms: four spanning trees, each leaving one of the four walls shut),
    Eller's steps as documented give: the top wall shut 1/2 (the top rooms not joined, each then
    goes down), the bottom one 1/2 * 1/4 (joined, both went down), each side 1/2 * 3/8 (joined, only
    the other side went down, by its own draw or as the set's one forced passage).  Kruskal's
    order is uniform: 1/4 each."""
    from gym_gridloc.generators import eller_maze

    shut = {"top": (1, 2), "bottom": (3, 2), "left": (2, 1), "right": (2, 3)}
    expected = {"eller": {"top": 0.5, "bottom": 0.125, "left": 0.1875, "right": 0.1875},
                "kruskal": {"top": 0.25, "bottom": 0.25, "left": 0.25, "right": 0.25}}
    rng = np.random.default_rng(7)
    n = 8000
    for name, draw in (("eller", eller_maze), ("kruskal", perfect_maze)):
        counts = dict.fromkeys(shut, 0)
        for _ in range(n):
            free = draw(5, seed=rng).free
            closed = [w for w, (y, x) in shut.items() if not free[y, x]]
            assert len(closed) == 1
            counts[closed[0]] += 1
        for w, p in expected[name].items():  # within 4.5 standard errors
            assert abs(counts[w] / n - p) < 4.5 * np.sqrt(p * (1 - p) / n), (name, w, counts)


def test_eller_first_row_walls_open_with_probability_one_half():
    from gym_gridloc.generators import eller_maze

    rng = np.random.default_rng(3)
    n = 4000
    opened = np.zeros(4)
    for _ in range(n):
        opened += eller_maze(11, seed=rng).free[1, 2:10:2]  # the four walls between the first row's five rooms
    assert np.all(np.abs(opened / n - 0.5) < 4.5 * np.sqrt(0.25 / n)), opened / n


def test_rotation_symmetric_mazes_are_found_and_rejected():
    from gym_gridloc.generators import eller_maze, is_rotation_symmetric, random_maze

    pinwheel = np.full((7, 7), -1)
    pinwheel[1::2, 1::2] = 0
    for y, x in ((2, 3), (3, 4), (4, 3), (3, 2), (1, 4), (4, 5), (5, 2), (2, 1)):  # centre to every side, then turning
        pinwheel[y, x] = 0
    grid = gym_gridloc.GridMap(pinwheel, ("O",))
    assert is_rotation_symmetric(grid)  # equal to its 90-degree turn
    half = perfect_maze(7, seed=next(s for s in range(10_000) if is_rotation_symmetric(perfect_maze(7, seed=s))))
    assert np.array_equal(half.labels, np.rot90(half.labels, 2))
    assert not is_rotation_symmetric(perfect_maze(7, seed=0)) or not is_rotation_symmetric(perfect_maze(7, seed=1))
    for generator, draw in (("kruskal", perfect_maze), ("eller", eller_maze)):
        seed = next(s for s in range(10_000) if is_rotation_symmetric(draw(7, seed=s)))
        rng, again = np.random.default_rng(seed), np.random.default_rng(seed)
        kept = random_maze(7, np.random.default_rng(seed), generator=generator)
        assert np.array_equal(kept.labels, draw(7, seed=seed).labels)  # without rejection: the plain draw
        m = random_maze(7, rng, generator=generator, reject_symmetric=True)
        assert not is_rotation_symmetric(m)
        first = draw(7, seed=again)  # the symmetric one, drawn and dropped...
        while is_rotation_symmetric(first):
            first = draw(7, seed=again)
        assert np.array_equal(m.labels, first.labels)  # ...then the next draws of the same generator
        assert rng.random() == again.random()
        drawn = [random_maze(7, rng, generator=generator, reject_symmetric=True) for _ in range(600)]
        assert not any(is_rotation_symmetric(x) for x in drawn)
    with pytest.raises(ValueError, match="generator must be one of 'kruskal', 'eller'"):
        random_maze(7, 0, generator="prim")


def test_mixed_mazes_come_from_either_generator_half_the_time():
    """``generator="mixed"``: one uniform draw chooses Eller's (below 1/2) or Kruskal's
    construction, which then draws from the same generator; both halves are perfect mazes."""
    from gym_gridloc import maps
    from gym_gridloc.generators import eller_maze, mixed_maze, random_maze

    chosen = {"eller": 0, "kruskal": 0}
    for seed in range(400):
        rng = np.random.default_rng(seed)
        eller = rng.random() < 0.5
        expected = (eller_maze if eller else perfect_maze)(7, seed=rng)
        m = mixed_maze(7, seed=seed)
        assert np.array_equal(m.labels, expected.labels)
        assert np.array_equal(m.labels, random_maze(7, seed, generator="mixed").labels)
        assert is_connected(m.free) and m.n_free == 9 + 8  # 3 x 3 rooms joined by a spanning tree
        chosen["eller" if eller else "kruskal"] += 1
    assert abs(chosen["eller"] / 400 - 0.5) < 4.5 * np.sqrt(0.25 / 400)
    env = gym.make("DepthMaze-v0", generator="mixed", episode_length=15).unwrapped
    assert env.map_options == {"generator": "mixed", "reject_symmetric": True}
    with pytest.raises(ValueError, match="generator must be 'kruskal' or 'eller'"):  # held-out sets are per generator
        maps.test_set("DepthMaze-v0", 7, generator="mixed", reject_symmetric=True)
