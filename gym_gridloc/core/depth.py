"""The depth sensor of the research protocol (Active Neural Localization's Maze2D): the depth to
the wall ahead of a robot with a heading, the one sensor whose readings depend on the layer."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.grid import DIRECTIONS, GridMap, read_only
from gym_gridloc.core.sensors import TableSensor
from gym_gridloc.core.validation import check_probability


class DepthSensor(TableSensor):
    """The depth to the wall ahead, for a robot with a heading (the Maze2D sensor of Active Neural
    Localization): ``1 +`` the number of free cells between the robot and the first wall (or the
    edge) in the direction of its heading (layer ``0 = N, 1 = E, 2 = S, 3 = W``).

    Readings are depths ``1..max_depth`` (0 is never read); the observation space is
    ``Discrete(max_depth + 1)``, so the reading index is the depth itself.  With
    ``p_depth_error`` the depth is off by one with that total probability, split evenly between
    ``d - 1`` and ``d + 1`` where both are in ``1..max_depth`` (all of it to the one that is).
    """

    layered = True

    def __init__(self, grid: GridMap, max_depth: int, p_depth_error: float = 0.0) -> None:
        super().__init__(grid)
        self.p_depth_error = check_probability("p_depth_error", p_depth_error)
        h, w = grid.shape
        free = grid.free
        depth = np.zeros((4, h, w), dtype=np.int64)
        for d, (dr, dc) in enumerate(DIRECTIONS):
            # Free cells ahead, by a scan against the heading: one vector step per row (column:
            # the same scan over the transposed views).
            run = np.zeros((h, w), dtype=np.int64)
            ahead, lines, step = (free, run, dr) if dr else (free.T, run.T, dc)
            n = lines.shape[0]
            for i in range(n - 1, -1, -1) if step > 0 else range(n):
                if 0 <= i + step < n:
                    lines[i] = np.where(ahead[i + step], lines[i + step] + 1, 0)
            depth[d] = np.where(free, run + 1, 0)
        if int(depth.max()) > max_depth:
            raise ValueError(f"max_depth={max_depth} is below the map's largest depth {int(depth.max())}")
        self.depth = read_only(depth)
        self.max_depth = int(max_depth)
        self.n_readings = self.max_depth + 1
        self.observation_space = spaces.Discrete(self.n_readings)
        table = np.zeros((self.n_readings, 4, h, w))
        eps = self.p_depth_error
        for z in range(1, self.n_readings):
            table[z] += np.where(depth == z, 1.0 - eps, 0.0)
            for other in (z - 1, z + 1):
                # P(read z | true depth `other`): the error that lands on z from `other`
                if 1 <= other <= self.max_depth:
                    two_sided = (other - 1 >= 1) & (other + 1 <= self.max_depth)
                    table[z] += np.where(depth == other, eps / 2 if two_sided else eps, 0.0)
        if self.max_depth == 1:
            table[1] = np.where(free, 1.0, 0.0)
        self._set_table(table)

    def describe(self, reading: int) -> str:
        return f"depth {reading}"
