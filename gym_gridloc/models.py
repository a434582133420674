"""The models of the source documents, as thin builders over :class:`GridModel`."""

from __future__ import annotations

import os
import warnings
from typing import Sequence

import numpy as np

from gym_gridloc.core.grid import DIRECTIONS, GridMap, parse_rows, read_layout
from gym_gridloc.core.model import GridModel, Term, move_terms
from gym_gridloc.core.ring import RingSensor
from gym_gridloc.core.depth import DepthSensor
from gym_gridloc.core.sensors import ColourSensor, WallSensor
from gym_gridloc.core.validation import check_choice, check_probability, check_size
from gym_gridloc.seeds import COLOUR_GRID_LAYOUT, WINDY_MAZE_LAYOUT

COLOURS = ("R", "G", "B", "Y")


def parse_colour_map(layout: str | os.PathLike | Sequence[str]) -> GridMap:
    """A colour map in seed 000's format: comma-separated ``R, G, B, Y`` cells, ``.`` obstacles."""
    rows, source = read_layout(layout, sep=",")
    return parse_rows(rows, COLOURS, (".",), sep=",", source=source)


def parse_maze(layout: str | os.PathLike | Sequence[str]) -> GridMap:
    """A maze in seed 004's format: rows of ``O`` (free) and ``#`` (obstacle)."""
    rows, source = read_layout(layout)
    return parse_rows(rows, ("O",), ("#",), sep=None, source=source)


def colour_grid_model(
    layout: str | os.PathLike | Sequence[str] | GridMap | None = None,
    *,
    slip: float = 0.1,
    accuracy: float = 0.88,
) -> GridModel:
    """Seed 000's colour-sensing robot.

    Under action a the robot moves one cell in direction a with probability ``1 - slip`` and in a
    uniformly random direction of the four with probability ``slip``; blocked moves stay.  The
    sensor reads the true colour with ``accuracy``; the wrong colours share the rest equally.
    ``slip = 1`` is the seed's robot (a uniformly random move whatever the action).
    """
    grid = layout if isinstance(layout, GridMap) else parse_colour_map(COLOUR_GRID_LAYOUT if layout is None else layout)
    slip = check_probability("slip", slip)
    transitions = [move_terms(grid, np.full(4, slip / 4) + (1.0 - slip) * np.eye(4)[a]) for a in range(4)]
    return GridModel(grid, transitions, ColourSensor(grid, accuracy), name="ColourGrid",
                     params={"slip": slip, "accuracy": accuracy})


def windy_maze_model(
    layout: str | os.PathLike | Sequence[str] | GridMap | None = None,
    *,
    drift: float = 0.1,
    p_detect: float = 0.85,
    p_false_alarm: float = 0.10,
) -> GridModel:
    """Seed 004's windy maze.

    Under action a: ``1 - 2 drift`` to the neighbour in direction a, ``drift`` to the neighbour on
    a's left and ``drift`` on its right; a blocked target means staying.  Sensor: four independent
    bits (W, N, E, S), an obstacle sensed with ``p_detect``, a free neighbour with ``p_false_alarm``.
    """
    grid = layout if isinstance(layout, GridMap) else parse_maze(WINDY_MAZE_LAYOUT if layout is None else layout)
    drift = check_probability("drift", drift)
    if drift > 0.5:
        raise ValueError(f"drift must be in [0, 0.5] (the robot drifts left and right with drift each), got {drift!r}")
    # Direction a with 1 - 2 drift, its left (a - 1) and right (a + 1) neighbours with drift each.
    transitions = [move_terms(grid, np.roll([drift, 1.0 - 2.0 * drift, drift, 0.0], a - 1)) for a in range(4)]
    return GridModel(
        grid,
        transitions,
        WallSensor(grid, p_detect, p_false_alarm),
        name="WindyMaze",
        params={"drift": drift, "p_detect": p_detect, "p_false_alarm": p_false_alarm},
    )


def heading_probs(grid: GridMap, keep: float) -> np.ndarray:
    """``P[h, h', r, c]``: the next heading given heading h at (r, c), by the seeds' rule.

    If h does not face a wall, keep it with ``keep``, else a uniformly chosen other heading that
    does not face a wall (``1 - keep`` shared among them; if there is none, h is kept).  If h faces a
    wall, a uniformly chosen heading that does not.  Where every heading faces a wall, the heading
    is kept and the robot cannot move (it stays).
    """
    open_ = ~grid.blocked()  # (4, H, W)
    n_open = open_.sum(axis=0)
    h, w = grid.shape
    out = np.zeros((4, 4, h, w))
    for hd in range(4):
        others_open = open_.copy()
        others_open[hd] = False
        n_others = others_open.sum(axis=0)
        facing_free = open_[hd]
        # The turns to every heading at once; keeping heading hd is set below.
        out[hd] = np.where(
            facing_free,
            np.where(others_open, (1.0 - keep) / np.maximum(n_others, 1), 0.0),
            np.where(open_, 1.0 / np.maximum(n_open, 1), 0.0),
        )
        # Nowhere to go: keep the heading (and stay; see ring_sensor_model).
        out[hd, hd] = np.where(n_open == 0, 1.0, np.where(facing_free, np.where(n_others > 0, keep, 1.0), 0.0))
    out[:, :, ~grid.free] = 0.0
    return out


def ring_sensor_model(
    size: int | tuple[int, int] = (8, 8),
    *,
    dynamics: str = "commanded",
    keep_heading: float = 0.7,
    p_true: float = 0.1,
    p_ring1: float = 0.05,
    p_ring2: float = 0.025,
    layout: str | os.PathLike | Sequence[str] | GridMap | None = None,
) -> GridModel:
    """Seeds 001/003's robot on an empty grid with a vague location sensor.

    ``layout`` (optional) gives a map of ``O`` (free) and ``#`` (obstacle) rows, as a maze file or
    a list of rows, in place of the empty ``size`` grid; its shape must then agree with ``size``
    unless ``size`` is left at its default.

    ``dynamics="passive"`` (the seeds' robot): the hidden state is (heading, position); the heading
    follows the seeds' rule (keep it with ``keep_heading`` unless it faces a wall, else a uniformly
    chosen heading that does not), then the robot moves one cell; the action plays no part.
    ``"seed"`` is a deprecated alias.  ``dynamics="commanded"`` (the default): the hidden state is
    the position and the action takes the role of the heading.
    """
    if dynamics == "seed":
        warnings.warn('dynamics="seed" is deprecated: use dynamics="passive" (the same robot)', DeprecationWarning, stacklevel=2)
        dynamics = "passive"
    dynamics = check_choice("dynamics", dynamics, ("commanded", "passive"))
    keep = check_probability("keep_heading", keep_heading)
    h, w = check_size("size", size)
    if layout is None:
        grid = GridMap(np.zeros((h, w), dtype=np.int64), ("O",))
    else:
        grid = layout if isinstance(layout, GridMap) else parse_maze(layout)
        if grid.shape != (h, w) and (h, w) != (8, 8):
            raise ValueError(f"size={size!r} disagrees with the layout's shape {grid.shape}; give one or the other")
    sensor = RingSensor(grid, p_true, p_ring1, p_ring2)
    hp = heading_probs(grid, keep)  # (4, 4, H, W)
    stuck = grid.blocked().all(axis=0) & grid.free
    params = {"dynamics": dynamics, "keep_heading": keep, "p_true": p_true, "p_ring1": p_ring1, "p_ring2": p_ring2}
    if dynamics == "passive":
        terms = []
        for hd in range(4):
            terms += [Term(hd, nh, int(dr), int(dc), np.where(stuck, 0.0, hp[hd, nh]))
                      for nh, (dr, dc) in enumerate(DIRECTIONS)]
            terms.append(Term(hd, hd, 0, 0, np.where(stuck, 1.0, 0.0)))
        return GridModel(grid, [terms] * 4, sensor, n_layers=4, name="RingSensor", params=params)
    # The action plays the current heading: the next heading is drawn by the rule, then one
    # move.  No move is blocked (the rule only picks open headings), except where none is open.
    transitions = [move_terms(grid, hp[a]) for a in range(4)]
    return GridModel(grid, transitions, sensor, name="RingSensor", params=params)


def depth_maze_model(
    layout: str | os.PathLike | Sequence[str] | GridMap,
    *,
    p_turn_fail: float = 0.0,
    p_move_fail: float = 0.0,
    p_depth_error: float = 0.0,
    max_depth: int | None = None,
) -> GridModel:
    """The Maze2D robot of Active Neural Localization: a heading (layers ``0 = N, 1 = E, 2 = S,
    3 = W``) and a depth sensor.

    Actions: ``0`` turns left (heading - 1 mod 4), ``1`` turns right (heading + 1 mod 4), ``2``
    moves one cell forward (into a wall: stays); each fails (does nothing) with ``p_turn_fail`` or
    ``p_move_fail``.  The reading is the depth to the wall ahead (see :class:`DepthSensor`), off
    by one with ``p_depth_error``.  ``max_depth`` (the observation space's largest depth) defaults
    to the largest a map of this shape can have: ``max(H, W) - 2`` with walls all round, else
    ``max(H, W)``.
    """
    grid = layout if isinstance(layout, GridMap) else parse_maze(layout)
    turn_fail = check_probability("p_turn_fail", p_turn_fail)
    move_fail = check_probability("p_move_fail", p_move_fail)
    if max_depth is None:
        walled = not (grid.free[0].any() or grid.free[-1].any() or grid.free[:, 0].any() or grid.free[:, -1].any())
        max_depth = max(grid.shape) - 2 if walled and min(grid.shape) > 2 else max(grid.shape)
    free = grid.free.astype(np.float64)
    blocked = grid.blocked()
    # Left (step -1) and right (+1): from heading h, the turned heading or (failing) h itself.
    turns = [[Term(h, nh, 0, 0, p * free)
              for h in range(4) for nh, p in (((h + step) % 4, 1.0 - turn_fail), (h, turn_fail))]
             for step in (-1, 1)]
    forward = []
    for h, (dr, dc) in enumerate(DIRECTIONS):
        go = (1.0 - move_fail) * np.where(blocked[h], 0.0, free)
        forward += [Term(h, h, int(dr), int(dc), go), Term(h, h, 0, 0, free - go)]
    sensor = DepthSensor(grid, max_depth, p_depth_error)
    return GridModel(grid, [*turns, forward], sensor, n_layers=4, name="DepthMaze",
                     action_names=("left", "right", "forward"),
                     params={"p_turn_fail": turn_fail, "p_move_fail": move_fail, "p_depth_error": p_depth_error,
                             "max_depth": sensor.max_depth})
