"""Generated maps, reproducible from a seed: random colour grids, mazes of any size, and perfect
mazes (Kruskal's algorithm, or Eller's row-by-row construction), with or without the mazes that
equal their own rotation.

Every generator takes a ``numpy.random.Generator`` (or an int seed) and returns a
:class:`~gym_gridloc.core.grid.GridMap` whose free cells are connected (4-neighbourhood).  The same
seed gives the same map.  Large maps (512 x 512 and more) are built with array operations, except
the maze, whose depth-first carving is a loop over the maze's cells (about 0.3 s at 512 x 512).
"""

from __future__ import annotations

import functools
import numbers
import string
from typing import Any

import numpy as np

from gym_gridloc import kernels
from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.validation import check_int, check_size, is_int

#: Colour symbols: seed 000's four first, then more letters (``n_colours`` up to 26).
COLOUR_SYMBOLS = ("R", "G", "B", "Y") + tuple(c for c in string.ascii_uppercase if c not in "RGBY")

#: The largest side a generated map may have.
MAX_SIDE = 4096


def as_rng(seed: Any, name: str = "map_seed") -> np.random.Generator:
    """A Generator from an int seed (>= 0), a Generator (used as is) or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        return np.random.default_rng()
    if not is_int(seed):
        raise TypeError(f"{name} must be a non-negative integer, a numpy Generator or None, got {seed!r}")
    return np.random.default_rng(check_int(name, seed, 0, what="a non-negative integer"))


def check_density(name: str, value: Any) -> float:
    """A fraction in [0, 1)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0.0 <= float(value) < 1.0:
        raise ValueError(f"{name} must be a number in [0, 1) (the fraction of obstacle cells), got {value!r}")
    return float(value)


def largest_component(free: np.ndarray) -> np.ndarray:
    """The largest 4-connected region of ``free`` as a bool mask (ties: the one met first)."""
    from scipy import ndimage

    labels, n = ndimage.label(free)
    if n <= 1:
        return free.copy()
    return labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))  # label 0: the obstacles


def is_connected(free: np.ndarray) -> bool:
    """True when the free cells form one 4-connected region."""
    from scipy import ndimage

    return int(ndimage.label(free)[1]) == 1


def colour_map(
    size: int | tuple[int, int],
    *,
    obstacle_density: float = 0.2,
    n_colours: int = 4,
    seed: Any = None,
) -> GridMap:
    """A random colour grid: each cell an obstacle with ``obstacle_density``, else a colour drawn
    uniformly from ``n_colours``.

    Free cells cut off from the largest free region become obstacles too, so the robot can reach
    every free cell (the map's obstacle fraction can then exceed ``obstacle_density`` a little;
    far more above about 0.4, where random obstacles start to wall regions off).
    """
    h, w = check_size("size", size, MAX_SIDE)
    density = check_density("obstacle_density", obstacle_density)
    k = check_int("n_colours", n_colours, 1, len(COLOUR_SYMBOLS))
    rng = as_rng(seed)
    colours = rng.integers(0, k, size=(h, w))
    free = rng.random((h, w)) >= density
    if not free.any():
        free[rng.integers(h), rng.integers(w)] = True
    return GridMap(np.where(largest_component(free), colours, -1), COLOUR_SYMBOLS[:k])


def maze_map(size: int | tuple[int, int], *, seed: Any = None) -> GridMap:
    """A maze: corridors one cell wide with walls between, every free cell reachable.

    A recursive backtracker (depth-first search with random neighbour order) on the lattice of
    cells at even (row, col); the walls between lattice cells it passes through are opened.  An
    even side leaves a last row (column) outside the lattice: its cells next to a lattice cell are
    opened with probability 1/2 (dead ends of length one), so every size is filled.
    """
    h, w = check_size("size", size, MAX_SIDE)
    rng = as_rng(seed)
    ch, cw = (h + 1) // 2, (w + 1) // 2  # lattice cells
    free = np.zeros((h, w), dtype=bool)  # lattice cell (r, c) is visited when free[2r, 2c]
    n = ch * cw
    start = int(rng.integers(n))
    free[2 * (start // cw), 2 * (start % cw)] = True
    stack = [start]
    # Random draws in blocks: one uniform per visit to a cell on the stack.
    block = rng.random(4 * n + 16)
    k = 0
    steps = ((-1, 0), (0, 1), (1, 0), (0, -1))
    while stack:
        r, c = divmod(stack[-1], cw)
        near = [(r + dr, c + dc) for dr, dc in steps]
        options = [(rr, cc) for rr, cc in near if 0 <= rr < ch and 0 <= cc < cw and not free[2 * rr, 2 * cc]]
        if not options:
            stack.pop()
            continue
        if k >= block.shape[0]:
            block, k = rng.random(4 * n + 16), 0
        rr, cc = options[int(block[k] * len(options))]
        k += 1
        free[r + rr, c + cc] = True  # the wall between (2r, 2c) and (2rr, 2cc)
        free[2 * rr, 2 * cc] = True
        stack.append(rr * cw + cc)
    # Dead ends into the extra row (column) only next to lattice cells: corridors stay one wide.
    for rows, n_rows, n_cols in ((free, h, w), (free.T, w, h)):  # free.T: the columns, as a view
        if n_rows % 2 == 0 and n_rows > 1:
            rows[n_rows - 1] = rows[n_rows - 2] & (rng.random(n_cols) < 0.5) & (np.arange(n_cols) % 2 == 0)
    return GridMap(np.where(free, 0, -1), ("O",))


@functools.lru_cache(maxsize=16)
def _maze_walls(k: int) -> tuple[tuple[tuple[int, int], ...], tuple[int, ...]]:
    """The walls between the rooms of a ``k x k`` perfect maze, in the order Kruskal shuffles
    them (each room and the room to its east, row by row, then each room and the room to its
    south), and each wall's flat cell index in the maze of side ``2k + 1``: the cell between rooms
    ``(2r1+1, 2c1+1)`` and ``(2r2+1, 2c2+1)``."""
    n = 2 * k + 1
    east = [(r * k + c, r * k + c + 1) for r in range(k) for c in range(k - 1)]
    south = [(r * k + c, (r + 1) * k + c) for r in range(k - 1) for c in range(k)]
    walls = tuple(east + south)
    cells = tuple((a // k + b // k + 1) * n + (a % k + b % k + 1) for a, b in walls)
    return walls, cells


def perfect_maze(size: int, *, seed: Any = None) -> GridMap:
    """A perfect maze of odd side ``size`` (>= 5): walls all round, exactly one path between any
    two free cells (connected, no cycle).

    The rooms are the cells at odd (row, col); Kruskal's algorithm joins them: every wall between
    two neighbouring rooms is listed once, the list is shuffled, and a wall is opened when the
    rooms on its two sides are not yet joined (a union-find forest over the rooms tells).  Each
    opened wall joins two trees, so the result is one spanning tree of the rooms.
    """
    n = _maze_side(size)
    rng = as_rng(seed)
    k = (n - 1) // 2  # rooms per side
    walls, cells = _maze_walls(k)
    parent = list(range(k * k))
    opened = []
    last = k * k - 1  # the walls a spanning tree of the k * k rooms opens
    # (Python ints and lists: about 5x faster than numpy scalars on a maze of a few rooms; the
    # same draw, the same mazes)
    for w in rng.permutation(len(walls)).tolist():
        a, b = walls[w]
        while parent[a] != a:  # the roots, halving the paths on the way
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a != b:
            parent[a] = b
            opened.append(cells[w])
            if len(opened) == last:  # a spanning tree: no later wall joins two trees
                break
    opened.sort()
    return _maze_map(n, tuple(opened))


def eller_maze(size: int, *, seed: Any = None) -> GridMap:
    """A perfect maze of odd side ``size`` (>= 5) built row by row (Eller's algorithm), the
    construction of the mazes Active Neural Localization (Chaplot et al., 2018) trained on.

    The rooms are the cells at odd (row, col); each room of the current row belongs to a set (the
    rooms it is already joined with).  Row by row, top to bottom:

    1. each wall between two neighbouring rooms of the row that lie in different sets is opened
       with probability 1/2 (the two sets merge); in the last row every such wall is opened;
    2. (not in the last row) each room opens the wall to the room below with probability 1/2; a
       set none of whose rooms did opens one of its rooms' walls, chosen uniformly; the rooms
       below take the set of the room above them, the others a new set of their own.

    Walls are opened only between different sets, and the last row joins every set left, so the
    result is one spanning tree of the rooms (connected, no cycle), like :func:`perfect_maze`'s;
    the distribution differs (Eller's mazes have more short horizontal corridors).  The draws,
    per row: ``k - 1`` uniforms for step 1 (one per wall, used where the sets differ), ``k``
    uniforms for step 2, then one integer per set without a passage down, in the order of the
    sets' leftmost rooms.
    """
    n = _maze_side(size)
    rng = as_rng(seed)
    k = (n - 1) // 2
    labels = np.full((n, n), -1, dtype=np.int64)
    labels[1::2, 1::2] = 0
    sets = list(range(k))
    fresh = k
    for r in range(k):
        y = 2 * r + 1
        last = r == k - 1
        joins = [True] * (k - 1) if last else (rng.random(k - 1) < 0.5).tolist()
        for c in range(k - 1):
            if joins[c] and sets[c] != sets[c + 1]:
                labels[y, 2 * c + 2] = 0
                old, keep = sets[c + 1], sets[c]
                sets = [keep if s == old else s for s in sets]
        if last:
            break
        down = (rng.random(k) < 0.5).tolist()
        members: dict[int, list[int]] = {}
        for c, s in enumerate(sets):
            members.setdefault(s, []).append(c)
        for cols in members.values():  # in the order of the sets' leftmost rooms
            if not any(down[c] for c in cols):
                down[cols[int(rng.integers(len(cols)))]] = True
        below = []
        for c in range(k):
            if down[c]:
                labels[y + 1, 2 * c + 1] = 0
                below.append(sets[c])
            else:
                below.append(fresh)
                fresh += 1
        sets = below
    return GridMap(labels, ("O",))


def mixed_maze(size: int, *, seed: Any = None) -> GridMap:
    """A perfect maze from Kruskal's algorithm (:func:`perfect_maze`) or Eller's
    (:func:`eller_maze`), each with probability 1/2: one uniform draw from ``seed`` chooses, the
    chosen generator draws the maze from the same generator.  A policy trained on these mazes has
    seen both constructions, whose distributions differ (see :func:`eller_maze`)."""
    rng = as_rng(seed)
    draw = eller_maze if rng.random() < 0.5 else perfect_maze
    return draw(size, seed=rng)


#: The generators of perfect mazes, by the name DepthMaze's ``generator=`` keyword takes.
MAZE_GENERATORS = ("kruskal", "eller", "mixed")


def is_rotation_symmetric(grid: GridMap) -> bool:
    """True when the map equals itself turned by 90 or 180 degrees.  In such a maze every pose has
    a twin (the pose turned with the maze) that reads the same depths after every sequence of
    actions, so no policy can tell the two apart: localisation fails there half the time or more."""
    labels = grid.labels
    if labels.shape[0] != labels.shape[1]:
        return bool(np.array_equal(labels, labels[::-1, ::-1]))
    return bool(np.array_equal(labels, np.rot90(labels, 2)) or np.array_equal(labels, np.rot90(labels, 1)))


def random_maze(size: int, rng: Any = None, *, generator: str = "kruskal", reject_symmetric: bool = False) -> GridMap:
    """A perfect maze from ``generator`` (``"kruskal"``: :func:`perfect_maze`, ``"eller"``:
    :func:`eller_maze`, ``"mixed"``: :func:`mixed_maze`); with ``reject_symmetric``, mazes equal to their own 90- or 180-degree
    rotation (:func:`is_rotation_symmetric`) are drawn again from the same generator until one is
    not.  ``random_maze(size, rng)`` draws what ``perfect_maze(size, seed=rng)`` draws."""
    draw = _maze_generator(generator)
    rng = as_rng(rng)
    maze = draw(size, seed=rng)
    while reject_symmetric and is_rotation_symmetric(maze):
        maze = draw(size, seed=rng)
    return maze


def _maze_generator(generator: Any):
    if generator == "kruskal":
        return perfect_maze
    if generator == "eller":
        return eller_maze
    if generator == "mixed":
        return mixed_maze
    raise ValueError(f"generator must be one of {', '.join(map(repr, MAZE_GENERATORS))} (how perfect mazes are drawn), got {generator!r}")


#: The most walls a perfect maze may have for :func:`perfect_maze_codes` (a code is an int64).
CODED_WALLS = 63


def perfect_maze_codes(size: int, rng: np.random.Generator, count: int) -> np.ndarray | None:
    """``count`` perfect mazes drawn from ``rng`` exactly as ``count`` calls of
    :func:`perfect_maze` (``seed=rng``) draw them (the same mazes; the generator left in the same
    state), each as its code: bit ``w`` set for each opened wall ``w``
    (:func:`perfect_maze_of_code` gives the map).  One compiled call: it shuffles the walls as
    numpy's ``Generator.permutation`` does, from the generator's own bit generator (its C
    interface, under its lock); ``tests/test_generators.py`` holds it to :func:`perfect_maze`.
    None when there is no compiled path (numba missing) or a code cannot hold the walls (more
    than :data:`CODED_WALLS`: a side above 13)."""
    # (a vector env calls this at most steps: plain ints pass without check_int's work)
    n = size if type(size) is int and 5 <= size <= MAX_SIDE and size % 2 else _maze_side(size)
    count = count if type(count) is int and count >= 0 else check_int("count", count, 0)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator, got {rng!r}")
    k = (n - 1) // 2
    fast = kernels.compiled(1)
    if fast is None or 2 * k * (k - 1) > CODED_WALLS:
        return None
    wall_a, wall_b = _maze_wall_rooms(k)
    codes = np.empty(count, dtype=np.int64)
    bits = rng.bit_generator
    functions = kernels.bit_functions(bits)
    with bits.lock:
        fast.perfect_maze_codes(functions[0], functions[2], wall_a, wall_b, k * k, codes)
    return codes


def perfect_maze_graph(size: int) -> tuple[np.ndarray, int] | None:
    """The graph whose random spanning trees :func:`perfect_maze_codes` draws for a side of
    ``size``: ``(walls, rooms)``, ``walls`` (2, W) int64 read-only the two rooms of each wall (wall
    ``w`` is bit ``w`` of a code), ``rooms`` how many; None when a code cannot hold the walls
    (more than :data:`CODED_WALLS`).  (A compiled step can draw the codes itself:
    ``engine.VectorBank.draw_maps``.)"""
    k = (_maze_side(size) - 1) // 2
    if 2 * k * (k - 1) > CODED_WALLS:
        return None
    walls = np.stack(_maze_wall_rooms(k))
    walls.flags.writeable = False
    return walls, k * k


def _maze_side(size: Any) -> int:
    """A perfect maze's side, checked: an odd integer in 5..MAX_SIDE."""
    n = check_int("size", size, 5, MAX_SIDE)
    if n % 2 == 0:
        raise ValueError(f"size must be odd (rooms at odd coordinates, walls all round), got {size!r}")
    return n


def perfect_maze_of_code(size: int, code: int) -> GridMap:
    """The perfect maze of side ``size`` whose opened walls are the bits of ``code`` (see
    :func:`perfect_maze_codes`): the same map object :func:`perfect_maze` returns for it while
    the last 256 mazes are kept."""
    _, cells = _maze_walls((size - 1) // 2)
    return _maze_map(size, tuple(sorted(c for w, c in enumerate(cells) if code >> w & 1)))


@functools.lru_cache(maxsize=16)
def _maze_wall_rooms(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Each wall's two rooms (:func:`_maze_walls`), as two read-only int64 arrays."""
    walls, _ = _maze_walls(k)
    out = (np.array([a for a, _ in walls], dtype=np.int64), np.array([b for _, b in walls], dtype=np.int64))
    for a in out:
        a.flags.writeable = False
    return out


@functools.lru_cache(maxsize=256)
def _maze_map(n: int, opened: tuple[int, ...]) -> GridMap:
    """The perfect maze of side ``n`` whose opened walls are the flat cells ``opened``.  (Kept
    for the last 256 mazes: a map is frozen data, and small mazes come again: a 7x7 one is one
    of 192.)"""
    labels = np.full((n, n), -1, dtype=np.int64)
    labels[1::2, 1::2] = 0
    labels.reshape(-1)[list(opened)] = 0
    return GridMap(labels, ("O",))
