"""Held-out maps: fixed test and validation sets per environment family and size.

:func:`test_set` gives ``n`` (default 1000) maps with a start pose each, the same on every
machine (the first 1000 of each stored size are checked against a SHA-256 checksum kept here).
They are drawn from seed sequences that training never uses: map ``i`` of a set comes from
``numpy.random.SeedSequence([TAG, purpose, family, size]).spawn(n)[i]``, a spawned sequence,
while an environment reset with ``reset(seed=s)`` (``s`` an int) draws from
``SeedSequence(s)``, which is never spawned: the two can never be the same stream.
:func:`validation_set` is the same with another ``purpose`` (for training curves: never the
test set).

DepthMaze's sets are drawn as the environment draws its mazes: ``generator`` (``"kruskal"``, the
default, or ``"eller"``) and ``reject_symmetric`` (mazes equal to their own 90- or 180-degree
rotation drawn again; see :class:`gym_gridloc.DepthMazeEnv`).  Each such variant is a set of its
own, from seed sequences of its own; the default variant (Kruskal's, symmetric mazes kept) is the
set these functions have always given.

>>> from gym_gridloc.maps import test_set
>>> maps = test_set("DepthMaze-v0", 7, n=3)
>>> maps[0].grid.shape, len(maps[0].state)
((7, 7), 3)
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.validation import check_int
from gym_gridloc.generators import colour_map, maze_map, perfect_maze, random_maze

#: The sets' seed-sequence tag (the letters "gridloc" in ASCII, folded into 32 bits).
TAG = 0x67726C63
PURPOSES = {"test": 1, "validation": 2}
#: Per family: its number in the seed sequences and its map generator ``(size, rng) -> GridMap``.
_GENERATORS: dict[str, tuple[int, Callable[[int, np.random.Generator], GridMap]]] = {
    "DepthMaze-v0": (1, lambda size, rng: perfect_maze(size, seed=rng)),
    "WindyMaze-v0": (2, lambda size, rng: maze_map((size, size), seed=rng)),
    "ColourGrid-v0": (3, lambda size, rng: colour_map((size, size), obstacle_density=0.2, n_colours=4, seed=rng)),
}
#: DepthMaze's other variants ``(generator, reject_symmetric)``: the set's name and its family number.
_MAZE_VARIANTS: dict[tuple[str, bool], tuple[str, int]] = {
    ("kruskal", True): ("DepthMaze-v0:kruskal:asymmetric", 4),
    ("eller", True): ("DepthMaze-v0:eller:asymmetric", 5),
    ("eller", False): ("DepthMaze-v0:eller", 6),
}


#: SHA-256 of the first 1000 maps and start states of each stored set (see :func:`checksum`).
CHECKSUMS: dict[tuple[str, str, int], str] = {
    ("DepthMaze-v0", "test", 7): "8c1dbf08e476d7ee85ea6d2ed395b1e673bc2a7443a226528a04f345ed6510e5",
    ("DepthMaze-v0", "validation", 7): "95ff7a5f842e926998367f7c0a0518b335ade8d863c6581b473c89759c5b2ab0",
    ("DepthMaze-v0", "test", 15): "281fdfaf265fdef129fe9df8e8e45ba2b291b0fa00443c2499118e32e317d21a",
    ("DepthMaze-v0", "validation", 15): "2ed48b4b6ecf9110ab61445334fa8013168620a238e87ce260a20c3f9288ae89",
    ("DepthMaze-v0", "test", 21): "c2c46375db1fa4cd8fb0e5701f85ae7116f7d39e6b483134959ebdd60f379ebd",
    ("DepthMaze-v0", "validation", 21): "ac0b64b43fed905019e3b5a7d799a4f709fb85bf1d231d7308f85cd8dac763cd",
    ("WindyMaze-v0", "test", 9): "ab84b91ebfba7c71a49fb8594cb74dccf2172e170bcc0e1510669ffce2b2b2db",
    ("WindyMaze-v0", "validation", 9): "273649cc0c8ca5b34ca23c6498b1f8cfb7ffc4f5918b53c37fdcaff1d128b3da",
    ("WindyMaze-v0", "test", 15): "83b8ca37663b71b2073e26564f3da393ec346cde6418a3056c85538ba3bd97ed",
    ("WindyMaze-v0", "validation", 15): "40a51470505996481e9f3a555cc325257599984d38e53a52d241eb032848cdde",
    ("ColourGrid-v0", "test", 9): "8a735ea7514b7d28bd9f9e1ff1421902cc5e7b9fd2efbc0ca6c4880f7c36939b",
    ("ColourGrid-v0", "validation", 9): "4af5a4ac48f10d1f63bdb471259951dca15caa266eec302086bb12b91ecaf8ea",
    # DepthMaze's variants (see set_name)
    ("DepthMaze-v0:kruskal:asymmetric", "test", 7): "bd27d3131aed2f2e2562a4a2019ae815d831f4184b2ea9c61d8038e298609682",
    ("DepthMaze-v0:kruskal:asymmetric", "validation", 7): "38629fb66d221944f744da4a7848eb73c1fd43125e2f6ff27a43f91de83c567c",
    ("DepthMaze-v0:kruskal:asymmetric", "test", 15): "f4c15fbb148145076a851ca9ceac3a6e23c84b79dac96aa50acbd56667376253",
    ("DepthMaze-v0:kruskal:asymmetric", "validation", 15): "d5e2ef983d84f9fefbc8bbefee47615a6afb00fc86421c40f782df206e83a219",
    ("DepthMaze-v0:kruskal:asymmetric", "test", 21): "3d83b625f101aac8ac89b7016356a315bcfa33c0d127f67ded21eee2ca09b6cc",
    ("DepthMaze-v0:kruskal:asymmetric", "validation", 21): "4592324ce45a643cde4ab1214e5ea6e79ddd6354fe942885affb9a0fcd8e9cea",
    ("DepthMaze-v0:eller:asymmetric", "test", 7): "85d1fe8b411b7c42fda8306e1a2962157c8620e875c61370735b0578b5750a08",
    ("DepthMaze-v0:eller:asymmetric", "validation", 7): "240595d534513ebaf41675591f8d5b4596ee1f9c88930840c0c087b884ff59bd",
    ("DepthMaze-v0:eller:asymmetric", "test", 15): "b4909f84a89023d8ef420f36fd5deeaa1b91c84a58465412b2fe5ab42c5ea0ba",
    ("DepthMaze-v0:eller:asymmetric", "validation", 15): "897454b9d8e1e7d1443ca4608ba5e499717e2de8cb8f3576e1b326092329da9a",
    ("DepthMaze-v0:eller:asymmetric", "test", 21): "2af7f90bd73dc48c93eb831900819c45606e5e6c0bff44ac3ccf2b1cfe45abfb",
    ("DepthMaze-v0:eller:asymmetric", "validation", 21): "de2da0aeea2413d283e80b1ffec4b55c32b370570e7f1507d2c8d1d72a3b505b",
}


@dataclass(frozen=True, eq=False)
class HeldOutMap:
    """One held-out episode: the map and the start state ``(layer, row, col)``."""

    grid: GridMap
    state: tuple[int, int, int]
    index: int


def families() -> tuple[str, ...]:
    """The environment ids that have held-out sets."""
    return tuple(_GENERATORS)


def set_name(env_id: str, generator: str = "kruskal", reject_symmetric: bool = False) -> str:
    """The name a held-out set is stored under: ``env_id``, or for DepthMaze's other maze variants
    ``"DepthMaze-v0:<generator>[:asymmetric]"``."""
    if env_id not in _GENERATORS:
        raise ValueError(f"no held-out maps for {env_id!r}; families with random maps: {', '.join(_GENERATORS)}")
    if (generator, reject_symmetric) == ("kruskal", False):
        return env_id
    if env_id != "DepthMaze-v0":
        raise ValueError(f"generator= and reject_symmetric= choose DepthMaze's maze variants; {env_id} has one set per size")
    if (generator, bool(reject_symmetric)) not in _MAZE_VARIANTS:
        raise ValueError(f"generator must be 'kruskal' or 'eller' and reject_symmetric True or False, got {generator!r}, {reject_symmetric!r}")
    return _MAZE_VARIANTS[generator, bool(reject_symmetric)][0]


def _draw(env_id: str, size: int, n: int, purpose: str, generator: str = "kruskal", reject_symmetric: bool = False) -> list[HeldOutMap]:
    name = set_name(env_id, generator, reject_symmetric)
    size = check_int("size", size, 2, 4096)
    family, generate = _GENERATORS[env_id]
    if name != env_id:
        family = _MAZE_VARIANTS[generator, bool(reject_symmetric)][1]
        generate = lambda size, rng: random_maze(size, rng, generator=generator, reject_symmetric=reject_symmetric)  # noqa: E731
    layers = 4 if env_id == "DepthMaze-v0" else 1
    out = []
    for i, child in enumerate(np.random.SeedSequence([TAG, PURPOSES[purpose], family, size]).spawn(n)):
        rng = np.random.default_rng(child)
        grid = generate(size, rng)
        layer, cell = divmod(int(rng.integers(layers * grid.n_free)), grid.n_free)
        out.append(HeldOutMap(grid, (layer, *map(int, grid.free_cells[cell])), i))
    return out


def checksum(maps: list[HeldOutMap]) -> str:
    """SHA-256 over every map's labels and start state, in order."""
    h = hashlib.sha256()
    for m in maps:
        h.update(np.ascontiguousarray(m.grid.labels, dtype=np.int64).tobytes())
        h.update(np.array(m.state, dtype=np.int64).tobytes())
    return h.hexdigest()


def _checked(env_id: str, size: int, n: int, purpose: str, generator: str, reject_symmetric: bool) -> list[HeldOutMap]:
    n = check_int("n", n, 1, 100_000)  # before drawing: a stored set is drawn 1000 long
    name = set_name(env_id, generator, reject_symmetric)
    expected = CHECKSUMS.get((name, purpose, size))
    maps = _draw(env_id, size, n if expected is None else max(n, 1000), purpose, generator, reject_symmetric)
    if expected is not None and checksum(maps[:1000]) != expected:
        raise RuntimeError(
            f"the {purpose} maps of {name} size {size} differ from the stored checksum: the map generator "
            "changed, so results on them are not comparable with earlier ones"
        )
    return maps[:n]


def test_set(env_id: str, size: int, n: int = 1000, *, generator: str = "kruskal",
             reject_symmetric: bool = False) -> list[HeldOutMap]:
    """``n`` fixed held-out maps with start states for ``env_id`` (``DepthMaze-v0``,
    ``WindyMaze-v0``, ``ColourGrid-v0``) at side ``size``; identical on every machine.  DepthMaze
    takes its maze variant: ``generator`` and ``reject_symmetric`` (as the environment's keywords)."""
    return _checked(env_id, size, n, "test", generator, reject_symmetric)


def validation_set(env_id: str, size: int, n: int = 200, *, generator: str = "kruskal",
                   reject_symmetric: bool = False) -> list[HeldOutMap]:
    """Like :func:`test_set`, from other seeds: for training curves and model selection."""
    return _checked(env_id, size, n, "validation", generator, reject_symmetric)


test_set.__test__ = False  # not a pytest test
