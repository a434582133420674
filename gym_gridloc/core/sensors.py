"""Sensors: P(reading | position), how a reading looks as an observation, and how to sample one.

A reading is an integer index in ``0..n_readings-1``; an observation is what the environment
emits (an int for ``Discrete`` spaces, an int8 array for ``MultiBinary``).  Every sensor here
depends on the position only, not on a heading.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.validation import check_probability


class Sensor(ABC):
    """A sensor on a :class:`GridMap`."""

    n_readings: int
    observation_space: spaces.Space

    def __init__(self, grid: GridMap) -> None:
        self.grid = grid

    @abstractmethod
    def likelihood(self, reading: int) -> np.ndarray:
        """P(reading | position) as an (H, W) float64 array, zero on obstacles."""

    @abstractmethod
    def distribution(self, row: int, col: int) -> tuple[np.ndarray, np.ndarray]:
        """The readings possible at (row, col) and their probabilities (summing to 1)."""

    def likelihood_window(self, reading: int) -> tuple[slice, slice, np.ndarray] | None:
        """``(rows, cols, values)`` when P(reading | position) is zero outside a small window
        (the filter then touches only that window), else None."""
        return None

    def sample(self, row: int, col: int, rng: np.random.Generator) -> int:
        readings, probs = self.distribution(row, col)
        k = int(np.searchsorted(np.cumsum(probs), rng.random() * probs.sum(), side="right"))
        return int(readings[min(k, len(readings) - 1)])

    def to_observation(self, reading: int) -> Any:
        return int(reading)

    def to_reading(self, observation: Any) -> int:
        """The reading index of an observation as the environment emits it."""
        space = self.observation_space
        if type(observation) is int and type(space) is spaces.Discrete and space.start == 0:  # fast path
            if 0 <= observation < space.n:
                return observation
        try:
            ok = self.observation_space.contains(observation)
        except Exception:  # noqa: BLE001 - a malformed observation is reported below
            ok = False
        if not ok:
            try:
                ok = self.observation_space.contains(np.asarray(observation).astype(self.observation_space.dtype))
                ok = ok and np.array_equal(np.asarray(observation), np.asarray(observation).astype(self.observation_space.dtype))
            except Exception:  # noqa: BLE001
                ok = False
        if not ok:
            raise ValueError(f"observation {observation!r} is not in the sensor's space {self.observation_space}")
        return self._reading(observation)

    def _reading(self, observation: Any) -> int:
        return int(observation)

    def describe(self, reading: int) -> str:
        return str(reading)


class ColourSensor(Sensor):
    """Reads the colour of the cell: right with ``accuracy``, each wrong colour equally often."""

    def __init__(self, grid: GridMap, accuracy: float = 0.88) -> None:
        super().__init__(grid)
        self.accuracy = check_probability("accuracy", accuracy)
        self.colours = grid.symbols
        k = len(self.colours)
        self.n_readings = k
        self.observation_space = spaces.Discrete(k)
        wrong = (1.0 - self.accuracy) / (k - 1) if k > 1 else 0.0
        if k == 1:
            self.accuracy = 1.0
        self._table = np.empty((k, *grid.shape))
        for colour in range(k):
            self._table[colour] = np.where(grid.labels == colour, self.accuracy, wrong)
        self._table[:, ~grid.free] = 0.0
        self._table.setflags(write=False)
        self._wrong = wrong

    def likelihood(self, reading: int) -> np.ndarray:
        return self._table[reading]

    def distribution(self, row: int, col: int) -> tuple[np.ndarray, np.ndarray]:
        probs = self._table[:, row, col].copy()
        return np.arange(self.n_readings), probs

    def describe(self, reading: int) -> str:
        return self.colours[reading]


class WallSensor(Sensor):
    """Four independent bits in the order (W, N, E, S), 1 = "obstacle sensed".

    An obstacle (or the edge) is sensed with ``p_detect``; a free neighbour is sensed as an
    obstacle with ``p_false_alarm``.  Reading index = 8 W + 4 N + 2 E + S.
    """

    #: Bit order of the observation, as direction indices (N=0, E=1, S=2, W=3).
    ORDER = (3, 0, 1, 2)

    def __init__(self, grid: GridMap, p_detect: float = 0.85, p_false_alarm: float = 0.10) -> None:
        super().__init__(grid)
        self.p_detect = check_probability("p_detect", p_detect)
        self.p_false_alarm = check_probability("p_false_alarm", p_false_alarm)
        self.n_readings = 16
        self.observation_space = spaces.MultiBinary(4)
        blocked = grid.blocked()[list(self.ORDER)]  # (4, H, W) in (W, N, E, S) order
        p_one = np.where(blocked, self.p_detect, self.p_false_alarm)  # P(bit = 1 | cell)
        self._p_bits = p_one
        table = np.ones((16, *grid.shape))
        for reading in range(16):
            for i in range(4):
                bit = (reading >> (3 - i)) & 1
                table[reading] *= p_one[i] if bit else 1.0 - p_one[i]
        table[:, ~grid.free] = 0.0
        table.setflags(write=False)
        self._table = table

    def likelihood(self, reading: int) -> np.ndarray:
        return self._table[reading]

    def distribution(self, row: int, col: int) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(16), self._table[:, row, col].copy()

    def sample(self, row: int, col: int, rng: np.random.Generator) -> int:
        bits = rng.random(4) < self._p_bits[:, row, col]
        return int(bits[0]) * 8 + int(bits[1]) * 4 + int(bits[2]) * 2 + int(bits[3])

    def to_observation(self, reading: int) -> np.ndarray:
        return np.array([(reading >> 3) & 1, (reading >> 2) & 1, (reading >> 1) & 1, reading & 1], dtype=np.int8)

    def _reading(self, observation: Any) -> int:
        b = np.asarray(observation).astype(np.int64).reshape(4)
        return int(b[0] * 8 + b[1] * 4 + b[2] * 2 + b[3])

    def describe(self, reading: int) -> str:
        bits = self.to_observation(reading)
        return "[" + ", ".join("o" if b else "-" for b in bits) + "]  (W, N, E, S)"


class RingSensor(Sensor):
    """Reports a cell near the robot, or nothing.

    The true cell with ``p_true``; each of the 8 cells at Chebyshev distance 1 with ``p_ring1``;
    each of the 16 at distance 2 with ``p_ring2``; a reading that would fall outside the grid, and
    the rest, is "nothing".  Reading ``r * W + c`` is a cell, ``H * W`` is nothing.  The
    likelihood of a cell reading is computed from its 5x5 neighbourhood, never stored densely.
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
        self._kernel = np.choose(dist, [self.p_true, self.p_ring1, self.p_ring2])  # (5, 5), symmetric
        # P(nothing | cell) = 1 - sum of the kernel over the in-grid part of the window.
        inside = np.zeros((h + 4, w + 4))
        inside[2:-2, 2:-2] = 1.0
        in_grid_mass = np.zeros((h, w))
        for i in range(5):
            for j in range(5):
                in_grid_mass += self._kernel[i, j] * inside[i : i + h, j : j + w]
        self._nothing = np.where(grid.free, np.clip(1.0 - in_grid_mass, 0.0, 1.0), 0.0)
        self._nothing.setflags(write=False)

    @property
    def nothing_probability(self) -> np.ndarray:
        """P(nothing | cell) as an (H, W) array."""
        return self._nothing

    def likelihood_window(self, reading: int) -> tuple[slice, slice, np.ndarray] | None:
        if reading == self.nothing:
            return None
        h, w = self.grid.shape
        r0, c0 = divmod(int(reading), w)
        r1, r2, c1, c2 = max(0, r0 - 2), min(h, r0 + 3), max(0, c0 - 2), min(w, c0 + 3)
        values = self._kernel[r1 - r0 + 2 : r2 - r0 + 2, c1 - c0 + 2 : c2 - c0 + 2] * self.grid.free[r1:r2, c1:c2]
        return slice(r1, r2), slice(c1, c2), values

    def likelihood(self, reading: int) -> np.ndarray:
        if reading == self.nothing:
            return self._nothing
        h, w = self.grid.shape
        r0, c0 = divmod(int(reading), w)
        out = np.zeros((h, w))
        r1, r2, c1, c2 = max(0, r0 - 2), min(h, r0 + 3), max(0, c0 - 2), min(w, c0 + 3)
        out[r1:r2, c1:c2] = self._kernel[r1 - r0 + 2 : r2 - r0 + 2, c1 - c0 + 2 : c2 - c0 + 2]
        out[r1:r2, c1:c2] *= self.grid.free[r1:r2, c1:c2]
        return out

    def distribution(self, row: int, col: int) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.grid.shape
        r1, r2, c1, c2 = max(0, row - 2), min(h, row + 3), max(0, col - 2), min(w, col + 3)
        rr, cc = np.mgrid[r1:r2, c1:c2]
        probs = self._kernel[rr - row + 2, cc - col + 2].ravel()
        readings = (rr * w + cc).ravel()
        return np.append(readings, self.nothing), np.append(probs, self._nothing[row, col])

    def describe(self, reading: int) -> str:
        if reading == self.nothing:
            return "nothing"
        return str(divmod(int(reading), self.grid.width))
