"""The ring sensor of seeds 001 and 003: a vague report of a cell near the robot, or nothing.

Its likelihoods are computed from a 5x5 kernel: an H x W grid has H*W + 1 readings, so only a
small grid keeps them as one (readings x cells) table.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.grid import GridMap, read_only
from gym_gridloc.core.sensors import Sensor, xlogx
from gym_gridloc.core.validation import check_probability


class RingSensor(Sensor):
    """Reports a cell near the robot, or nothing.

    The true cell with ``p_true``; each of the 8 cells at Chebyshev distance 1 with ``p_ring1``;
    each of the 16 at distance 2 with ``p_ring2``; a reading that would fall outside the grid, and
    the rest, is "nothing".  Reading ``r * W + c`` is a cell, ``H * W`` is nothing.  The
    likelihood of a cell reading is computed from its 5x5 neighbourhood, stored densely on small
    grids only (:data:`DENSE_MAX`).
    """

    def __init__(self, grid: GridMap, p_true: float = 0.1, p_ring1: float = 0.05, p_ring2: float = 0.025) -> None:
        super().__init__(grid)
        self.p_true = check_probability("p_true", p_true)
        self.p_ring1 = check_probability("p_ring1", p_ring1)
        self.p_ring2 = check_probability("p_ring2", p_ring2)
        total = self.p_true + 8 * self.p_ring1 + 16 * self.p_ring2
        if total > 1.0 + 1e-12:
            raise ValueError(
                f"p_true + 8 p_ring1 + 16 p_ring2 must be at most 1, got {total:.6g} "
                f"(p_true={p_true!r}, p_ring1={p_ring1!r}, p_ring2={p_ring2!r})"
            )
        h, w = grid.shape
        self.n_readings = h * w + 1
        self.nothing = h * w
        self.observation_space = spaces.Discrete(h * w + 1)
        off = np.arange(-2, 3)
        dist = np.maximum(np.abs(off)[:, None], np.abs(off)[None, :])
        #: P(reading the cell at offset (i-2, j-2)), (5, 5), symmetric.
        self.kernel = read_only(np.choose(dist, [self.p_true, self.p_ring1, self.p_ring2]))
        # P(nothing | cell) = 1 - sum of the kernel over the in-grid part of the window.
        in_grid_mass = self._in_grid(np.zeros((h, w)), self.kernel)
        self._nothing = read_only(np.where(grid.free, np.clip(1.0 - in_grid_mass, 0.0, 1.0), 0.0))

    def _in_grid(self, total: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``total`` (H, W) plus, at each cell, ``values[i, j]`` (5, 5) for every offset
        ``(i-2, j-2)`` of its window that falls inside the grid."""
        h, w = self.grid.shape
        inside = np.zeros((h + 4, w + 4))
        inside[2:-2, 2:-2] = 1.0
        for i in range(5):
            for j in range(5):
                total = total + values[i, j] * inside[i : i + h, j : j + w]
        return total

    @property
    def nothing_probability(self) -> np.ndarray:
        """P(nothing | cell) as an (H, W) array."""
        return self._nothing

    def likelihood(self, reading: int) -> np.ndarray:
        if reading == self.nothing:
            return self._nothing
        h, w = self.grid.shape
        r0, c0 = divmod(int(reading), w)
        out = np.zeros((h, w))
        r1, r2, c1, c2 = max(0, r0 - 2), min(h, r0 + 3), max(0, c0 - 2), min(w, c0 + 3)
        out[r1:r2, c1:c2] = self.kernel[r1 - r0 + 2 : r2 - r0 + 2, c1 - c0 + 2 : c2 - c0 + 2] * self.grid.free[r1:r2, c1:c2]
        return out

    #: Grids with at most this many (readings x cells) likelihoods (8 MiB) keep them as one dense
    #: table, built on first use: a batch's likelihoods are then one gather.
    DENSE_MAX = 2**20

    def likelihoods(self, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Rows of the dense table on small grids (:data:`DENSE_MAX`); on larger ones, cell
        readings write the 5x5 kernel round the cell (25 scatters over the batch), "nothing" its
        (H, W) row.  The same numbers either way (the table is built by the scatters)."""
        readings = np.asarray(readings, dtype=np.int64).reshape(-1)
        table = self.__dict__.get("_dense")
        if table is None and self.n_readings * self.grid.free.size <= self.DENSE_MAX:
            table = self.__dict__["_dense"] = read_only(self._scattered(np.arange(self.n_readings), None))
        if table is not None:
            return np.take(table, readings, axis=0, out=out)
        return self._scattered(readings, out)

    def __getstate__(self) -> dict:
        return {k: v for k, v in super().__getstate__().items() if k != "_dense"}  # (a cache)

    def _scattered(self, readings: np.ndarray, out: np.ndarray | None) -> np.ndarray:
        h, w = self.grid.shape
        if out is None:
            out = np.zeros((readings.size, h * w))
        else:
            out.fill(0.0)
        nothing = readings == self.nothing
        if nothing.any():
            out[nothing] = self._nothing.reshape(-1)
        cells = np.flatnonzero(~nothing)
        if cells.size:  # (no 25 scatters of empty selections when every reading is "nothing")
            r0, c0 = np.divmod(readings[cells], w)
            free = self.grid.free
            for i in range(5):
                rr = r0 + i - 2
                for j in range(5):
                    cc = c0 + j - 2
                    ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                    if ok.any():
                        r, c, k = rr[ok], cc[ok], cells[ok]
                        out[k, r * w + c] = self.kernel[i, j] * free[r, c]
        return out

    def reading_probabilities(self, masses: np.ndarray) -> np.ndarray:
        """Cell readings: the masses correlated with the 5x5 kernel (25 shifted adds); then
        nothing.  Never a (readings x cells) table."""
        m = np.asarray(masses, dtype=np.float64)
        n, (h, w) = m.shape[0], self.grid.shape
        c = m * self.grid.free
        padded = np.zeros((n, h + 4, w + 4))
        padded[:, 2:-2, 2:-2] = c
        q = np.zeros((n, h * w + 1))
        cells = q[:, : h * w].reshape(n, h, w)
        for i in range(5):
            for j in range(5):
                # reading (r, c) from a robot at (r + 2 - i, c + 2 - j): kernel[i, j]
                cells += self.kernel[i, j] * padded[:, 4 - i : 4 - i + h, 4 - j : 4 - j + w]
        q[:, h * w] = (c * self._nothing).reshape(n, -1).sum(axis=1)
        return q

    def reading_entropy(self) -> np.ndarray:
        return np.where(self.grid.free, self._in_grid(-xlogx(self._nothing), -xlogx(self.kernel)), 0.0)

    def distribution(self, row: int, col: int, layer: int = 0) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.grid.shape
        r1, r2, c1, c2 = max(0, row - 2), min(h, row + 3), max(0, col - 2), min(w, col + 3)
        rr, cc = np.mgrid[r1:r2, c1:c2]
        probs = self.kernel[rr - row + 2, cc - col + 2].ravel()
        readings = (rr * w + cc).ravel()
        return np.append(readings, self.nothing), np.append(probs, self._nothing[row, col])

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The 25 window cells in row-major order (zero off the grid), then nothing."""
        h, w = self.grid.shape
        if states.shape[0] == 1:
            return np.array([self.sample_one(tuple(states[0].tolist()), rng)])
        probs, rr, cc = self._window(states)
        k = self._categorical(probs, rng)
        cell = np.take_along_axis(rr * w + cc, np.minimum(k, 24)[:, None], axis=1)[:, 0]
        return np.where(k == 25, self.nothing, cell)

    def draw_table(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        h, w = self.grid.shape
        rows, cols = np.divmod(np.arange(h * w), w)
        states = np.stack((np.zeros_like(rows), rows, cols), axis=1)
        probs, rr, cc = self._window(states)
        values = np.empty(probs.shape, dtype=np.int64)
        values[:, :25] = rr * w + cc  # (off the grid: probability 0, never drawn)
        values[:, 25] = self.nothing
        return self._categorical_table(probs, values)

    def sample_one(self, state: tuple[int, int, int], rng: np.random.Generator) -> int:
        """The same draw as :meth:`gym_gridloc.core.sensors.Sensor.sample`, its probabilities kept per cell."""
        key = state[1:]
        k = self._draw_one(key, lambda: self._window(np.array([state], dtype=np.int64))[0][0], rng)
        return self.nothing if k == 25 else (key[0] + k // 5 - 2) * self.grid.shape[1] + key[1] + k % 5 - 2

    def _window(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(probabilities (N, 26), rows (N, 25), columns (N, 25))`` of each state's readings."""
        h, w = self.grid.shape
        r, c = states[:, 1], states[:, 2]
        di, dj = np.divmod(np.arange(25), 5)
        rr = r[:, None] + di[None, :] - 2
        cc = c[:, None] + dj[None, :] - 2
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        probs = np.empty((states.shape[0], 26))
        probs[:, :25] = np.where(inside, self.kernel.reshape(-1)[None, :], 0.0)
        probs[:, 25] = self._nothing[r, c]
        return probs, rr, cc

    def describe(self, reading: int) -> str:
        if reading == self.nothing:
            return "nothing"
        return str(divmod(int(reading), self.grid.width))
