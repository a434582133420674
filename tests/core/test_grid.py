"""Maps (gym_gridloc/core/grid.py): parsing rows and files, layouts given to every environment, and
map errors that name the file, line and column."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc import (
    DIRECTIONS,
    GridMap,
    MapError,
    WindyMazeEnv,
    parse_colour_map,
    parse_maze,
)
from tests.helpers import COLOUR_MAP_WITH_WALLS, MAZE_WITH_WALLS

# -- parsing -------------------------------------------------------------------------------------------


def test_parsed_maps_have_their_obstacles():
    assert parse_colour_map(COLOUR_MAP_WITH_WALLS).n_free == 8
    assert parse_maze(MAZE_WITH_WALLS).n_free == 14


def test_to_text_round_trips_through_the_parsers():
    colour = parse_colour_map(COLOUR_MAP_WITH_WALLS)
    assert colour.to_text(",") == COLOUR_MAP_WITH_WALLS
    assert np.array_equal(parse_colour_map(colour.to_text(",")).labels, colour.labels)
    maze = parse_maze(MAZE_WITH_WALLS)
    assert maze.to_text() == MAZE_WITH_WALLS


def test_free_cells_index_and_blocked_directions():
    grid = parse_maze(MAZE_WITH_WALLS)
    assert grid.shape == (4, 5) and grid.height == 4 and grid.width == 5
    for i, (r, c) in enumerate(grid.free_cells):
        assert grid.cell_index[r, c] == i and grid.is_free(int(r), int(c))
    assert np.all(grid.cell_index[~grid.free] == -1)
    assert not grid.is_free(-1, 0) and not grid.is_free(0, 5) and not grid.is_free(0, 1)
    blocked = grid.blocked()
    for d, (dr, dc) in enumerate(DIRECTIONS):
        for r in range(4):
            for c in range(5):
                assert blocked[d, r, c] == (not grid.is_free(r + int(dr), c + int(dc)))
    # The map's arrays are read-only: a GridMap is shared data.
    for arr in (grid.labels, grid.free, grid.free_cells, grid.cell_index):
        assert not arr.flags.writeable


def test_a_map_needs_a_row_and_a_column():
    with pytest.raises(MapError, match=r"at least one row and one column"):
        GridMap(np.zeros((0, 3), dtype=np.int64))


# -- layouts -------------------------------------------------------------------------------------------
LAYOUT_CASES = [
    ("ColourGrid-v0", ["R,G,.", "B,Y,R"], (2, 3)),
    ("WindyMaze-v0", ["OO#", "OOO"], (2, 3)),
    ("RingSensor8x8-v0", ["OO#", "OOO"], (2, 3)),
]


@pytest.mark.parametrize("env_id,rows,shape", LAYOUT_CASES)
def test_layout_from_rows_and_from_file_give_the_same_env(tmp_path, env_id, rows, shape):
    """Every environment takes its map as ``layout=``: a path to a map file or a list of row
    strings."""
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


def test_map_from_a_good_file(tmp_path):
    maze = tmp_path / "maze.txt"
    maze.write_text("OO#\nOOO\n")
    env = gym.make("WindyMaze-v0", layout=str(maze))
    assert env.unwrapped.model.grid.n_free == 5
    assert maze.read_text() == "OO#\nOOO\n"  # nothing is written over


# -- map errors ----------------------------------------------------------------------------------------
def test_ragged_rows_in_a_list():
    with pytest.raises(MapError, match=r"<layout>, line 2: ragged row: 1 cells where line 1 has 2"):
        gym.make("ColourGrid-v0", layout=["R,G", "R"])
    with pytest.raises(MapError, match=r"<layout>, line 3: ragged row"):
        WindyMazeEnv(layout=["OOO", "OOO", "OOOO"])


def test_ragged_rows_in_a_file_name_file_and_line(tmp_path):
    path = tmp_path / "ragged.txt"
    path.write_text("OOOO\nO#OO\nOOO\n")
    with pytest.raises(MapError, match=rf"{re.escape(str(path))}, line 3: ragged row: 3 cells where line 1 has 4"):
        gym.make("WindyMaze-v0", layout=str(path))


def test_unknown_symbol_names_line_and_column():
    with pytest.raises(MapError, match=r"line 2, column 3: unknown symbol 'X' \(allowed: 'R', 'G', 'B', 'Y', '\.'\)"):
        gym.make("ColourGrid-v0", layout=["R,G", "R,X"])
    with pytest.raises(MapError, match=r"line 1, column 4: unknown symbol 'x' \(allowed: 'O', '#'\)"):
        WindyMazeEnv(layout=["OO#x", "OOOO"])


def test_unknown_symbol_in_a_file_names_path_line_and_column(tmp_path):
    colour = tmp_path / "colours.csv"
    colour.write_text("R,G,B\nY, R,.\nB,Q,G\n")
    with pytest.raises(MapError, match=rf"^{re.escape(str(colour))}, line 3, column 3: unknown symbol 'Q'"):
        parse_colour_map(colour)
    with pytest.raises(MapError, match=rf"^{re.escape(str(colour))}, line 3, column 3: unknown symbol 'Q'"):
        gym.make("ColourGrid-v0", layout=str(colour))
    maze = tmp_path / "maze.txt"
    maze.write_text("OOOO\nO#O*\n")
    with pytest.raises(MapError, match=rf"^{re.escape(str(maze))}, line 2, column 4: unknown symbol '\*'"):
        gym.make("WindyMaze-v0", layout=maze)


@pytest.mark.parametrize(
    "make",
    [
        lambda: gym.make("ColourGrid-v0", layout=[".,.", ".,."]),
        lambda: gym.make("WindyMaze-v0", layout=["##", "##"]),
        lambda: parse_maze(["#"]),
    ],
)
def test_no_free_cell(make):
    with pytest.raises(MapError, match=r"no free cell"):
        make()


def test_map_file_missing(tmp_path):
    missing = tmp_path / "nowhere" / "map.txt"
    with pytest.raises(MapError, match=rf"layout: no map file at '{re.escape(str(missing))}'"):
        gym.make("WindyMaze-v0", layout=str(missing))
    with pytest.raises(MapError, match=r"no map file at"):
        gym.make("ColourGrid-v0", layout=missing)


@pytest.mark.parametrize(
    "layout,message",
    [
        ([], r"the map is empty"),
        ("", r"layout: got an empty string"),
        ("OOO\nOOO", r"layout: got a multi-line string"),
        (["OOO", ""], r"<layout>, line 2: empty row"),
        (42, r"layout must be a path to a map file, a list of row strings, or a 2-D array of cell symbols, got int"),
        (["OOO", 5], r"layout: row 2 must be a string, got int"),
    ],
)
def test_malformed_layouts(layout, message):
    with pytest.raises((MapError, TypeError), match=message):
        WindyMazeEnv(layout=layout)


def test_layout_forms_and_limits(tmp_path):
    rows = ["OO#", "OOO"]
    ref = parse_maze(rows)
    assert np.array_equal(parse_maze(tuple(rows)).labels, ref.labels)
    assert np.array_equal(parse_maze(np.array([list(r) for r in rows])).labels, ref.labels)  # 2-D symbols
    assert np.array_equal(parse_colour_map(np.array([["R", "G"], [".", "Y"]])).labels,
                          parse_colour_map(["R,G", ".,Y"]).labels)
    bom = tmp_path / "bom.txt"
    bom.write_bytes("\ufeffOO#\nOOO\n".encode("utf-8"))  # a byte-order mark is not a cell
    assert np.array_equal(parse_maze(bom).labels, ref.labels)
    with pytest.raises(TypeError, match=r"got bytes \(decode them"):
        parse_maze(b"OO#")
    with pytest.raises(TypeError, match=r"got set \(a set or other unordered collection has no row order\)"):
        parse_maze({"OO#", "OOO"})
    with pytest.raises(TypeError, match=r"got a 2-D array of int64"):
        parse_maze(np.zeros((2, 2), dtype=np.int64))
    with pytest.raises(MapError, match=r"^<layout>: 4097 rows, more than the 4096 a map may have"):
        parse_maze(["O"] * 4097)
    with pytest.raises(MapError, match=r"<layout>, line 1: 4097 cells, more than the 4096 a map may have"):
        parse_maze(["O" * 4097])


def test_map_errors_are_value_errors():
    assert issubclass(MapError, ValueError)
