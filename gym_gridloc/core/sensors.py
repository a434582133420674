"""Sensors: P(reading | state), how a reading looks as an observation, and how to sample one.

A reading is an integer index in ``0..n_readings-1``; an observation is what the environment
emits (an int for ``Discrete`` spaces, an int8 array for ``MultiBinary``).  Every method that
the simulator, the filters and the vector environment call is batched over N readings or
states (``states`` are ``(N, 3)`` int arrays of ``(layer, row, col)``), so no caller needs a
sensor's inner tables.  The sensors here (and :class:`~gym_gridloc.core.ring.RingSensor`) see the position only
(``layered = False``): their likelihoods are ``(H, W)`` and the same for every layer of a hidden
state; :class:`~gym_gridloc.core.depth.DepthSensor` sees the heading too.
"""

from __future__ import annotations

import bisect

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.grid import GridMap, read_only
from gym_gridloc.core.validation import check_probability, whole_numbers


class Sensor(ABC):
    """A sensor on a :class:`GridMap`.

    Subclasses set ``n_readings`` and ``observation_space`` and implement :meth:`likelihood` and
    :meth:`sample`; table sensors also :meth:`likelihoods` faster than one reading at a time.
    """

    n_readings: int
    observation_space: spaces.Space
    #: True when a reading's probability depends on the layer (e.g. the heading) as well as the cell.
    layered: bool = False

    #: At most this many states' reading distributions are kept for single draws.
    ROWS_CACHED = 1 << 16

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
        return -xlogx(table).sum(axis=0).reshape(np.shape(self.likelihood(0)))

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

    def sample_one(self, state: tuple[int, int, int], rng: np.random.Generator) -> int:
        """:meth:`sample` for one state ``(layer, row, col)`` (a tuple of ints): the same draws,
        as an ``int`` (the single environment's hot loop)."""
        return int(self.sample(np.array([state], dtype=np.int64), rng)[0])

    def _draw_one(self, key: Any, row_of, rng: np.random.Generator) -> int:
        """:meth:`_categorical` for one state (the same uniform and arithmetic), its row of
        probabilities ``row_of()`` summed once per state ``key`` and kept while few are kept."""
        rows = self.__dict__.get("_rows")
        if rows is None:
            rows = self.__dict__["_rows"] = {}
        found = rows.get(key)
        if found is None:
            row = row_of()
            # (the total as a Python float: the same product with the uniform, without numpy scalars)
            found = (np.cumsum(row).tolist(), float(row.sum()), row.size - 1)
            if len(rows) < self.ROWS_CACHED:
                rows[key] = found
        cum, total, last = found
        return min(bisect.bisect_right(cum, rng.random() * total), last)

    def draw_table(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray] | None:
        """:meth:`sample` as one row per state (cell ``r * W + c``; ``layer * H * W + r * W + c``
        if layered) for compiled loops, or None: ``(kind, probs, totals, values)``.  Kind 0, one
        uniform ``u``: ``probs`` the running sums of the reading probabilities, ``totals`` their
        sums (:meth:`sample`'s numbers); the reading is ``values[s, k]`` for the first ``k`` whose
        running sum exceeds ``u * totals[s]`` (at most the last).  Kind 1, independent bits of one
        uniform each: the sum of ``values[s, b]`` over the bits with ``u_b < probs[s, b]``."""
        return None

    @staticmethod
    def _categorical_table(probs: np.ndarray, values: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """The kind-0 :meth:`draw_table` of reading probabilities ``probs`` and readings ``values`` (S, K)."""
        probs = np.ascontiguousarray(probs, dtype=np.float64)
        return 0, np.cumsum(probs, axis=1), probs.sum(axis=1), np.ascontiguousarray(values, dtype=np.int64)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_rows"}  # (a cache: rebuilt on use)

    @staticmethod
    def _categorical(probs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One index per row of ``probs`` (N, K): the first whose cumulative probability exceeds
        a uniform draw times the row's total (one uniform per row)."""
        if probs.shape[0] == 1:  # the same numbers, with fewer array operations
            row = probs[0]
            x = rng.random() * row.sum()
            return np.array([min(bisect.bisect_right(np.cumsum(row).tolist(), x), row.size - 1)])
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
        if obs.shape != (n,) or not whole_numbers(obs):
            what = f"observation {single!r}" if single is not None else "observations"
            raise ValueError(f"{what} must be {'an integer' if single is not None else f'{n} integers (one per belief)'} in the sensor's space {space}, got {observations!r}")
        readings = obs.astype(np.int64) - int(space.start)
        self._check_in_space(obs, (readings < 0) | (readings >= space.n), single)
        return readings

    def _check_in_space(self, obs: np.ndarray, bad: np.ndarray, single: Any) -> None:
        """The error for the first of N observations ``obs`` that ``bad`` marks, if any."""
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            shown = single if single is not None else obs[i].tolist()
            where = "" if single is not None else f" of belief {i}"
            raise ValueError(f"observation {shown!r}{where} is not in the sensor's space {self.observation_space}")

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


def xlogx(x: np.ndarray) -> np.ndarray:
    """``x * log2(x)`` elementwise with ``0 log 0 = 0`` (x >= 0)."""
    return x * np.log2(np.where(x > 0.0, x, 1.0))


class TableSensor(Sensor):
    """A sensor whose likelihoods are one stored table per reading: ``(H, W)`` (colour, wall), or
    ``(L, H, W)`` for a layered sensor (depth)."""

    table: np.ndarray  # (n_readings, H, W) or (n_readings, L, H, W), zero on obstacles, read-only

    def likelihood(self, reading: int) -> np.ndarray:
        return self.table[reading]

    def _set_table(self, table: np.ndarray) -> None:
        """Keep ``table`` as :attr:`table`: zeroed on obstacles, read-only."""
        table[..., ~self.grid.free] = 0.0
        self.table = read_only(table)

    def _columns(self, states: np.ndarray) -> np.ndarray:
        """P(reading | state) for each of N states, ``(N, n_readings)``."""
        if states.shape[0] == 1:
            s = tuple(int(v) for v in states[0, 0 if self.layered else 1:])
            return self.table[(slice(None), *s)][None]
        idx = (states[:, 0], states[:, 1], states[:, 2]) if self.layered else (states[:, 1], states[:, 2])
        return np.ascontiguousarray(self.table[(slice(None), *idx)].T)

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if states.shape[0] == 1:
            return np.array([self.sample_one(tuple(states[0].tolist()), rng)])
        return self._categorical(self._columns(states), rng)

    def sample_one(self, state: tuple[int, int, int], rng: np.random.Generator) -> int:
        key = state if self.layered else state[1:]
        return self._draw_one(key, lambda: self.table[(slice(None), *key)], rng)

    def draw_table(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        k = self.table.shape[0]
        probs = self.table.reshape(k, -1).T  # (states, readings), as _columns gives them
        return self._categorical_table(probs, np.broadcast_to(np.arange(k), probs.shape))

    def likelihoods(self, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        flat = self.table.reshape(self.table.shape[0], -1)
        return np.take(flat, np.asarray(readings, dtype=np.int64).reshape(-1), axis=0, out=out)

    def distribution(self, row: int, col: int, layer: int = 0) -> tuple[np.ndarray, np.ndarray]:
        column = self.table[:, layer, row, col] if self.layered else self.table[:, row, col]
        return np.arange(self.n_readings), column.copy()

    def reading_probabilities(self, masses: np.ndarray) -> np.ndarray:
        flat = np.asarray(masses).reshape(masses.shape[0], -1)
        return flat @ self.table.reshape(self.table.shape[0], -1).T


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
        self._set_table(np.where(grid.labels == np.arange(k)[:, None, None], self.accuracy, wrong))  # (k, H, W)

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
    #: The observation of each of the 16 readings, and each reading keyed by its observation's bytes.
    _OBSERVATIONS = ((np.arange(16)[:, None] >> _SHIFTS) & 1).astype(np.int8)
    _CODES = dict(zip(map(np.ndarray.tobytes, _OBSERVATIONS), range(16)))

    def __init__(self, grid: GridMap, p_detect: float = 0.85, p_false_alarm: float = 0.10) -> None:
        super().__init__(grid)
        self.p_detect = check_probability("p_detect", p_detect)
        self.p_false_alarm = check_probability("p_false_alarm", p_false_alarm)
        self.n_readings = 16
        self.observation_space = spaces.MultiBinary(4)
        blocked = grid.blocked()[list(self.ORDER)]  # (4, H, W) in (W, N, E, S) order
        self.p_bits = read_only(np.where(blocked, self.p_detect, self.p_false_alarm))  # P(bit = 1 | cell)
        # reading r: the product over its bits, in (W, N, E, S) order, of P(bit | cell), one bit at
        # a time (a (16, 4, H, W) temporary would cost 134 MB on a 512 x 512 map)
        table = np.ones((16, *grid.shape))
        for reading in range(16):
            for i in range(4):
                table[reading] *= self.p_bits[i] if (reading >> (3 - i)) & 1 else 1.0 - self.p_bits[i]
        self._set_table(table)

    def draw_table(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        p = np.ascontiguousarray(self.p_bits.reshape(4, -1).T)  # (cells, 4): P(bit = 1), (W, N, E, S)
        return 1, p, np.zeros(p.shape[0]), np.ascontiguousarray(np.broadcast_to(self._BITS, p.shape))

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if states.shape[0] == 1:
            return np.array([self.sample_one(tuple(states[0].tolist()), rng)])
        bits = rng.random((states.shape[0], 4)) < self.p_bits[:, states[:, 1], states[:, 2]].T
        return bits.astype(np.int64) @ self._BITS

    def sample_one(self, state: tuple[int, int, int], rng: np.random.Generator) -> int:
        """The same draws and comparisons as :meth:`Sensor.sample`, on scalars."""
        key = state[1:]
        rows = self.__dict__.get("_rows")
        if rows is None:
            rows = self.__dict__["_rows"] = {}
        p = rows.get(key)
        if p is None:
            p = self.p_bits[(slice(None), *key)].tolist()
            if len(rows) < self.ROWS_CACHED:
                rows[key] = p
        u = rng.random(4).tolist()
        return (u[0] < p[0]) * 8 + (u[1] < p[1]) * 4 + (u[2] < p[2]) * 2 + (u[3] < p[3])

    def to_observation(self, reading: int) -> np.ndarray:
        if type(reading) is int and 0 <= reading < 16:
            return self._OBSERVATIONS[reading].copy()
        return self.observations(np.array([reading]))[0]

    def to_reading(self, observation: Any) -> int:
        if type(observation) is np.ndarray and observation.dtype == np.int8 and observation.shape == (4,):  # fast path
            reading = self._CODES.get(observation.tobytes())
            if reading is not None:
                return reading
        return super().to_reading(observation)

    def observations(self, readings: np.ndarray) -> np.ndarray:
        r = readings if type(readings) is np.ndarray and readings.ndim == 1 and readings.dtype.kind == "i" else np.asarray(readings, dtype=np.int64).reshape(-1)
        return self._OBSERVATIONS.take(r, axis=0)  # (a new array; a reading outside 0..15 raises)

    def readings(self, observations: Any, n: int, *, single: Any = None) -> np.ndarray:
        obs = np.asarray(observations)
        if obs.shape != (n, 4) or not (obs.dtype == bool or whole_numbers(obs)):
            what = f"observation {single!r}" if single is not None else "observations"
            raise ValueError(f"{what} must be {'4 bits' if single is not None else f'({n}, 4) bits (four per belief)'} (W, N, E, S) in {self.observation_space}, got {observations!r}")
        bits = obs.astype(np.int64)
        self._check_in_space(obs, np.any((bits != 0) & (bits != 1), axis=1), single)
        return bits @ self._BITS

    @property
    def encoded_size(self) -> int:
        return 4

    def encode(self, readings: np.ndarray) -> np.ndarray:
        return self.observations(readings).astype(np.float32)

    def describe(self, reading: int) -> str:
        bits = self.to_observation(reading)
        return "[" + ", ".join("o" if b else "-" for b in bits) + "]  (W, N, E, S)"
