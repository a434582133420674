"""Sensors: P(reading | state), how a reading looks as an observation, and how to sample one.

A reading is an integer index in ``0..n_readings-1``; an observation is what the environment
emits (an int for ``Discrete`` spaces, an int8 array for ``MultiBinary``).  Every method that
the simulator, the filters and the vector environment call is batched over N readings or
states (``states`` are ``(N, 3)`` int arrays of ``(layer, row, col)``), so no caller needs a
sensor's inner tables.  The sensors here see the position only (``layered = False``): their
likelihoods are ``(H, W)`` and the same for every layer of a hidden state.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.validation import check_probability


class Sensor(ABC):
    """A sensor on a :class:`GridMap`.

    Subclasses set ``n_readings`` and ``observation_space`` and implement :meth:`likelihood` and
    :meth:`sample`; table sensors also :meth:`likelihoods` faster than one reading at a time.
    """

    n_readings: int
    observation_space: spaces.Space
    #: True when a reading's probability depends on the layer (e.g. the heading) as well as the cell.
    layered: bool = False

    def __init__(self, grid: GridMap) -> None:
        self.grid = grid

    # -- probabilities ----------------------------------------------------------------------------
    @abstractmethod
    def likelihood(self, reading: int) -> np.ndarray:
        """P(reading | position) as an (H, W) float64 array ((L, H, W) for a layered sensor),
        zero on obstacles."""

    def likelihoods(self, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """P(reading_i | state) for N readings, as an ``(N, H*W)`` array (``(N, L*H*W)`` for a
        layered sensor)."""
        readings = np.asarray(readings, dtype=np.int64).reshape(-1)
        rows = [np.asarray(self.likelihood(int(r)), dtype=np.float64).reshape(-1) for r in readings]
        if out is None:
            return np.stack(rows) if rows else np.zeros((0, self.grid.labels.size))
        for i, row in enumerate(rows):
            out[i] = row
        return out

    def reading_probabilities(self, masses: np.ndarray) -> np.ndarray:
        """``q[m, z] = sum_s P(z | s) masses[m, s]`` for M (unnormalised) masses over positions
        ``(M, H, W)`` (over states ``(M, L, H, W)`` for a layered sensor): ``(M, n_readings)``."""
        flat = np.asarray(masses).reshape(masses.shape[0], -1)
        table = self.likelihoods(np.arange(self.n_readings))  # (Z, cells)
        return flat @ table.T

    def reading_entropy(self) -> np.ndarray:
        """The entropy (bits) of the reading in each position, ``(H, W)`` (``(L, H, W)`` for a
        layered sensor); zero on obstacles."""
        table = self.likelihoods(np.arange(self.n_readings))
        return -_xlogx(table).sum(axis=0).reshape(np.shape(self.likelihood(0)))

    def distribution(self, row: int, col: int, layer: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The readings possible in state ``(layer, row, col)`` and their probabilities (summing to 1)."""
        table = np.stack([np.asarray(self.likelihood(z)) for z in range(self.n_readings)])
        probs = table[:, layer, row, col] if self.layered else table[:, row, col]
        keep = np.flatnonzero(probs > 0)
        return keep, probs[keep].copy()

    # -- sampling ---------------------------------------------------------------------------------
    @abstractmethod
    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One reading per state ``(N, 3)``, (N,) int64, drawn with ``rng``."""

    @staticmethod
    def _categorical(probs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One index per row of ``probs`` (N, K): the first whose cumulative probability exceeds
        a uniform draw times the row's total (one uniform per row)."""
        if probs.shape[0] == 1:  # the same numbers, with fewer array operations
            row = probs[0]
            x = rng.random(1)[0] * row.sum()
            return np.array([min(int(np.searchsorted(np.cumsum(row), x, side="right")), row.size - 1)])
        cum = np.cumsum(probs, axis=1)
        x = rng.random(probs.shape[0]) * probs.sum(axis=1)
        return np.minimum((cum <= x[:, None]).sum(axis=1), probs.shape[1] - 1)

    # -- observations -----------------------------------------------------------------------------
    def to_observation(self, reading: int) -> Any:
        """The observation the environment emits for ``reading``."""
        return int(reading)

    def observations(self, readings: np.ndarray) -> np.ndarray:
        """N readings as a batch of observations: ``(N,)`` int64 for ``Discrete``."""
        return np.asarray(readings, dtype=np.int64).copy()

    def to_reading(self, observation: Any) -> int:
        """The reading index of one observation as the environment emits it (checked)."""
        space = self.observation_space
        if type(observation) is int and type(space) is spaces.Discrete and space.start == 0:  # fast path
            if 0 <= observation < space.n:
                return observation
        return int(self.readings(np.asarray(observation)[None], 1, single=observation)[0])

    def readings(self, observations: Any, n: int, *, single: Any = None) -> np.ndarray:
        """The reading indices (N,) int64 of N observations batched as a vector env emits them
        (``(N,)`` ints for ``Discrete``); a clear error for anything else."""
        obs = np.asarray(observations)
        space = self.observation_space
        if obs.shape != (n,) or not (np.issubdtype(obs.dtype, np.integer) or self._whole(obs)):
            what = f"observation {single!r}" if single is not None else "observations"
            raise ValueError(f"{what} must be {'an integer' if single is not None else f'{n} integers (one per belief)'} in the sensor's space {space}, got {observations!r}")
        readings = obs.astype(np.int64) - int(space.start)
        bad = (readings < 0) | (readings >= space.n)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"observation {obs[i]!r}{'' if single is not None else f' of belief {i}'} is not in the sensor's space {space}")
        return readings

    @staticmethod
    def _whole(obs: np.ndarray) -> bool:
        return obs.dtype != object and np.issubdtype(obs.dtype, np.floating) and bool(np.all(np.isfinite(obs))) and bool(np.all(obs == np.round(obs)))

    @property
    def encoded_size(self) -> int:
        """The length of :meth:`encode`'s vectors."""
        return self.n_readings

    def encode(self, readings: np.ndarray) -> np.ndarray:
        """N readings as float32 vectors in [0, 1] for MLP policies, ``(N, encoded_size)``:
        one-hot for ``Discrete``."""
        r = np.asarray(readings, dtype=np.int64).reshape(-1)
        out = np.zeros((r.size, self.n_readings), dtype=np.float32)
        out[np.arange(r.size), r] = 1.0
        return out

    def describe(self, reading: int) -> str:
        """What a reading says, for people."""
        return str(reading)

    def observation_text(self, reading: int) -> str:
        """An observation and what it says, for messages: ``3 (Y)``."""
        obs = self.to_observation(reading)
        shown = obs.tolist() if isinstance(obs, np.ndarray) else obs
        text = self.describe(reading)
        return f"{shown!r}" if text == str(shown) else f"{shown!r} ({text})"


def _xlogx(x: np.ndarray) -> np.ndarray:
    """``x * log2(x)`` elementwise with ``0 log 0 = 0`` (x >= 0)."""
    return x * np.log2(np.where(x > 0.0, x, 1.0))


class TableSensor(Sensor):
    """A sensor whose likelihoods are one stored (H, W) table per reading (colour, wall)."""

    table: np.ndarray  # (n_readings, H, W), zero on obstacles, read-only

    def likelihood(self, reading: int) -> np.ndarray:
        return self.table[reading]

    def likelihoods(self, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        flat = self.table.reshape(self.table.shape[0], -1)
        readings = np.asarray(readings, dtype=np.int64).reshape(-1)
        if out is None:
            return flat[readings]
        return np.take(flat, readings, axis=0, out=out)

    def distribution(self, row: int, col: int, layer: int = 0) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(self.n_readings), self.table[:, row, col].copy()

    def reading_probabilities(self, masses: np.ndarray) -> np.ndarray:
        flat = np.asarray(masses).reshape(masses.shape[0], -1)
        return flat @ self.table.reshape(self.table.shape[0], -1).T

    def reading_entropy(self) -> np.ndarray:
        return -_xlogx(self.table).sum(axis=0)


class ColourSensor(TableSensor):
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
        table = np.empty((k, *grid.shape))
        for colour in range(k):
            table[colour] = np.where(grid.labels == colour, self.accuracy, wrong)
        table[:, ~grid.free] = 0.0
        table.setflags(write=False)
        self.table = table

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if states.shape[0] == 1:
            return self._categorical(self.table[:, int(states[0, 1]), int(states[0, 2])][None], rng)
        probs = np.ascontiguousarray(self.table[:, states[:, 1], states[:, 2]].T)  # (N, k)
        return self._categorical(probs, rng)

    def describe(self, reading: int) -> str:
        return self.colours[reading]


class WallSensor(TableSensor):
    """Four independent bits in the order (W, N, E, S), 1 = "obstacle sensed".

    An obstacle (or the edge) is sensed with ``p_detect``; a free neighbour is sensed as an
    obstacle with ``p_false_alarm``.  Reading index = 8 W + 4 N + 2 E + S.
    """

    #: Bit order of the observation, as direction indices (N=0, E=1, S=2, W=3).
    ORDER = (3, 0, 1, 2)
    _BITS = np.array([8, 4, 2, 1], dtype=np.int64)
    _SHIFTS = np.array([3, 2, 1, 0], dtype=np.int64)

    def __init__(self, grid: GridMap, p_detect: float = 0.85, p_false_alarm: float = 0.10) -> None:
        super().__init__(grid)
        self.p_detect = check_probability("p_detect", p_detect)
        self.p_false_alarm = check_probability("p_false_alarm", p_false_alarm)
        self.n_readings = 16
        self.observation_space = spaces.MultiBinary(4)
        blocked = grid.blocked()[list(self.ORDER)]  # (4, H, W) in (W, N, E, S) order
        self.p_bits = np.where(blocked, self.p_detect, self.p_false_alarm)  # P(bit = 1 | cell)
        self.p_bits.setflags(write=False)
        table = np.ones((16, *grid.shape))
        for reading in range(16):
            for i in range(4):
                bit = (reading >> (3 - i)) & 1
                table[reading] *= self.p_bits[i] if bit else 1.0 - self.p_bits[i]
        table[:, ~grid.free] = 0.0
        table.setflags(write=False)
        self.table = table

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if states.shape[0] == 1:
            p = self.p_bits[:, int(states[0, 1]), int(states[0, 2])]
            return np.array([int((rng.random(4) < p) @ self._BITS)])
        bits = rng.random((states.shape[0], 4)) < self.p_bits[:, states[:, 1], states[:, 2]].T
        return bits.astype(np.int64) @ self._BITS

    def to_observation(self, reading: int) -> np.ndarray:
        return self.observations(np.array([reading]))[0]

    def observations(self, readings: np.ndarray) -> np.ndarray:
        r = np.asarray(readings, dtype=np.int64).reshape(-1)
        return ((r[:, None] >> self._SHIFTS) & 1).astype(np.int8)

    def readings(self, observations: Any, n: int, *, single: Any = None) -> np.ndarray:
        obs = np.asarray(observations)
        if obs.shape != (n, 4) or not (np.issubdtype(obs.dtype, np.integer) or obs.dtype == bool or self._whole(obs)):
            what = f"observation {single!r}" if single is not None else "observations"
            raise ValueError(f"{what} must be {'4 bits' if single is not None else f'({n}, 4) bits (four per belief)'} (W, N, E, S) in {self.observation_space}, got {observations!r}")
        bits = obs.astype(np.int64)
        bad = np.any((bits != 0) & (bits != 1), axis=1)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"observation {obs[i]!r}{'' if single is not None else f' of belief {i}'} is not in the sensor's space {self.observation_space}")
        return bits @ self._BITS

    @property
    def encoded_size(self) -> int:
        return 4

    def encode(self, readings: np.ndarray) -> np.ndarray:
        return self.observations(readings).astype(np.float32)

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
        #: P(reading the cell at offset (i-2, j-2)), (5, 5), symmetric.
        self.kernel = np.choose(dist, [self.p_true, self.p_ring1, self.p_ring2])
        self.kernel.setflags(write=False)
        # P(nothing | cell) = 1 - sum of the kernel over the in-grid part of the window.
        inside = np.zeros((h + 4, w + 4))
        inside[2:-2, 2:-2] = 1.0
        in_grid_mass = np.zeros((h, w))
        for i in range(5):
            for j in range(5):
                in_grid_mass += self.kernel[i, j] * inside[i : i + h, j : j + w]
        self._nothing = np.where(grid.free, np.clip(1.0 - in_grid_mass, 0.0, 1.0), 0.0)
        self._nothing.setflags(write=False)

    @property
    def nothing_probability(self) -> np.ndarray:
        """P(nothing | cell) as an (H, W) array."""
        return self._nothing

    def likelihood(self, reading: int) -> np.ndarray:
        if reading == self.nothing:
            return self._nothing
        return self.likelihoods(np.array([reading]))[0].reshape(self.grid.shape)

    def likelihoods(self, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Cell readings write the 5x5 kernel round the cell (25 scatters over the batch),
        "nothing" its (H, W) row."""
        h, w = self.grid.shape
        readings = np.asarray(readings, dtype=np.int64).reshape(-1)
        if out is None:
            out = np.zeros((readings.size, h * w))
        else:
            out.fill(0.0)
        nothing = readings == self.nothing
        if nothing.any():
            out[nothing] = self._nothing.reshape(-1)
        cells = np.flatnonzero(~nothing)
        if cells.size:
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
        h, w = self.grid.shape
        inside = np.zeros((h + 4, w + 4))
        inside[2:-2, 2:-2] = 1.0
        ent = -_xlogx(self._nothing)
        k = -_xlogx(self.kernel)
        for i in range(5):
            for j in range(5):
                ent = ent + k[i, j] * inside[i : i + h, j : j + w]
        return np.where(self.grid.free, ent, 0.0)

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
        r, c = states[:, 1], states[:, 2]
        di, dj = np.divmod(np.arange(25), 5)
        rr = r[:, None] + di[None, :] - 2
        cc = c[:, None] + dj[None, :] - 2
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        probs = np.empty((states.shape[0], 26))
        probs[:, :25] = np.where(inside, self.kernel.reshape(-1)[None, :], 0.0)
        probs[:, 25] = self._nothing[r, c]
        k = self._categorical(probs, rng)
        cell = np.take_along_axis(rr * w + cc, np.minimum(k, 24)[:, None], axis=1)[:, 0]
        return np.where(k == 25, self.nothing, cell)

    def describe(self, reading: int) -> str:
        if reading == self.nothing:
            return "nothing"
        return str(divmod(int(reading), self.grid.width))
