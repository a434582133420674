"""The compiled step of N robots, each on its own model (:class:`VectorBank`: the tables of
models of one size stacked, one slot each; :meth:`VectorBank.draw_maps`: the new episodes' small
mazes drawn in the same call, a table from code to slot), and the robots it steps (:class:`Rows`).
One call (:func:`gym_gridloc._numba_vector.vector_advance`, on named structures) moves, reads and
filters the N, starts the episodes that start, with their random draws, and fills the referee's
blocks.  :mod:`gym_gridloc.batch` calls it, or its numpy reference, behind one function; the same
draws and numbers as the engine's functions called in turn (:mod:`gym_gridloc.engine`
re-exports these names).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from gym_gridloc import derived, kernels
from gym_gridloc.core.model import GridModel

_INT64, _INT8 = np.dtype(np.int64), np.dtype(np.int8)

__all__ = ["Rows", "vector_bank", "VectorBank"]

#: What a step does with each row (``modes``, int8): move, read and filter; start an episode at a
#: drawn state; keep the row as it is; start an episode at the state the row holds.
STEP, START, KEEP, START_AT = 0, 1, 2, 3


class Rows:
    """N robots as the step keeps them, by name: ``states`` (N, 3) int64 (layer, row, col),
    ``readings`` (N,) int64, ``beliefs`` (2, N, L*H*W) float64, two buffers: ``current[0]``
    names the one that holds the beliefs (:attr:`belief`; a step writes the other and makes it
    current), ``slots`` (N,) int64 each robot's model in its bank, ``elapsed`` (N,) int64 the
    steps of each episode.  :attr:`compiled` is the same arrays as the compiled step takes them."""

    __slots__ = ("states", "readings", "beliefs", "current", "slots", "elapsed", "_compiled")

    def __init__(self, n: int, size: int) -> None:
        self.states, self.readings = np.zeros((n, 3), dtype=np.int64), np.zeros(n, dtype=np.int64)
        self.beliefs, self.current = np.zeros((2, n, size)), np.zeros(1, dtype=np.int64)
        self.slots, self.elapsed = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
        self._compiled = None

    @property
    def belief(self) -> np.ndarray:
        """The current beliefs, (N, L*H*W) (a view)."""
        return self.beliefs[self.current[0]]

    @property
    def spare(self) -> np.ndarray:
        """The other buffer, which a step writes, (N, L*H*W) (a view)."""
        return self.beliefs[1 - self.current[0]]

    def flip(self) -> None:
        """Make the other buffer current (after a step wrote it)."""
        self.current[0] = 1 - self.current[0]

    @property
    def compiled(self):
        """The compiled structure of these arrays (``_numba_structs.ROWS``), made once."""
        if self._compiled is None:
            self._compiled = kernels.compiled(1).step_rows(self.states, self.readings, self.beliefs, self.current,
                                                           self.slots, self.elapsed)
        return self._compiled

    def __getstate__(self) -> dict:
        return {k: getattr(self, k) for k in self.__slots__ if k != "_compiled"}

    def __setstate__(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)
        self._compiled = None


def vector_bank(model: GridModel, n_rows: int, keep: int | None = None) -> "VectorBank | None":
    """A :class:`VectorBank` for ``n_rows`` robots whose first model is ``model``, or None when
    ``model`` has no compiled step: a large grid, kidnapping, a sensor without
    :meth:`~gym_gridloc.core.sensors.Sensor.draw_table`, or too many readings for the tables."""
    tables = _vector_tables(model)
    return None if tables is None else VectorBank(model, n_rows, tables, keep)


def _vector_tables(model: GridModel) -> tuple[tuple[int, ...], tuple[np.ndarray, ...]] | None:
    """``(scalars, arrays)`` of :func:`gym_gridloc._numba_vector.vector_advance` for one model, or None when
    it has no compiled path: ``scalars`` (width, layers, layered, the draw table's kind, uniforms
    per reading, states), ``arrays`` in the kernel's order (the moves' keys, the filter plan's
    weights, from which the moves are drawn too, and meta, every reading's likelihood, the
    sensor's draw table, the free cells, every reading's first posterior and whether it is
    possible), C-contiguous (a bank copies them; they are not kept: a bank of maps that never
    come again keeps one copy)."""
    d = derived.of(model)
    fast = kernels.compiled(model.n_layers * model.shape[0] * model.shape[1])
    if fast is None or model.kidnap_prob > 0.0 or not isinstance(d.plan, kernels.NumbaPlan):
        return None
    draw = model.sensor.draw_table()
    first = d.first_table(now=True)
    if draw is None or first is None:
        return None
    kind, cum, total, values = draw
    posts, possible = first
    liks = derived.likelihoods(model, np.arange(model.sensor.n_readings))
    arrays = (d.plan.keys, d.plan.w, d.plan.meta, liks, cum, total, values, model.grid.free_cells.astype(np.int64), posts, possible)
    scalars = (model.shape[1], model.n_layers, d.layered, kind, cum.shape[1] if kind == 1 else 1, model.n_states)
    return scalars, tuple(np.ascontiguousarray(a) for a in arrays)


class VectorBank:
    """The compiled step of N robots each on its own model: the tables of models of the same
    sizes (the first model's) stacked, one slot per model (one model: a bank of one slot);
    :func:`vector_bank` makes one.  :meth:`slot` places a model (its tables are copied once; a
    model already placed keeps its slot); :meth:`advance` is the step.

    The bank holds at most ``max(N + 1, BYTES / one model's tables)`` models (``keep``: at most
    that many, but N + 1); when it is full, a new model takes the least recently placed slot that
    no row uses (N rows use at most N).  It holds its models (strongly: the bank belongs to one
    environment).

    A bank can also draw the maps of the rows that start an episode, in the step's own call
    (:meth:`draw_maps`: mazes, by their codes, a table from each code to its slot)."""

    #: The bank's tables grow to this many bytes before slots are reused (and beyond, to N + 1 slots).
    BYTES = 32 * 2**20
    #: The most walls of the mazes whose codes :meth:`draw_maps` keeps a table of slots for (2**16 codes: 512 KiB).
    CODE_WALLS = 16

    def __init__(self, model: GridModel, n_rows: int, tables: tuple[tuple[int, ...], tuple[np.ndarray, ...]],
                 keep: int | None = None) -> None:
        self.scalars, arrays = tables
        self.signature = self._signature(tables)
        per_model = sum(a.nbytes for a in arrays)
        self.limit = max(n_rows + 1, min(self.BYTES // max(per_model, 1), 4096, keep or 4096))
        self.n_rows = n_rows
        self.models: list[GridModel | None] = []
        self._slot_of: dict[int, int] = {}
        self._placed = np.zeros(0, dtype=np.int64)  # when each slot was last placed (its model asked for)
        self._clock = 0
        self._stacked = tuple(np.empty((0, *a.shape), dtype=a.dtype) for a in arrays)
        self._maze: tuple | None = None  # (walls, rooms, code -> slot, codes drawn) of draw_maps
        self._model_of_code: Callable[[int], GridModel] | None = None
        self._slot_codes: dict[int, int] = {}  # slot -> the code its model was placed for
        self._place(model, tables, np.zeros(0, dtype=np.int64))

    def advance(self, rows: Rows, actions: np.ndarray, modes: np.ndarray, rng: np.random.Generator, blocks: Any,
                maps: bool = False) -> None:
        """One step of the N ``rows`` (:class:`Rows`, ``rows.slots`` each one's model), in one
        compiled call: row ``i`` with ``modes[i]`` (int8) ``STEP`` moves under ``actions[i]``
        (int64 in ``0..A-1``, not checked: the caller has; those of other rows are not read),
        reads and filters; ``START`` starts an episode (a state drawn uniformly); ``START_AT``
        starts one at its state ``rows.states[i]``; ``KEEP`` keeps its state, reading and
        belief (``rows.elapsed`` too).  Random numbers from ``rng``'s bit generator, as
        ``Generator.random`` and ``Generator.integers`` draw them: the moving rows' moves, then
        their readings, the drawn starts, the starting rows' readings.  ``blocks``
        (:class:`gym_gridloc.referee.Blocks`) receive the referee's readout and how each step ended.
        ``maps`` (after :meth:`draw_maps`): the starting rows' maps are drawn first, from the same
        generator, and each row's slot set (new codes' models placed by Python between two
        calls).  An impossible reading raises (it cannot happen to readings drawn from the model)."""
        bits = rng.bit_generator
        if bits is not self._bits:  # (the addresses of the last bit generator are kept)
            self._bits, self._functions = bits, kernels.bit_functions(bits)
        functions, fast = self._functions, self._fast
        if maps:
            with bits.lock:  # (the draws are the generator's: as its own methods, under its lock)
                missing = fast.draw_maps(self._maze_struct, rows.slots, modes, functions)
            if missing:
                self._place_codes(self._maze[3], modes, rows.slots)
        args = (self._tables, rows.compiled, actions, modes, blocks.compiled, functions)
        if (actions.dtype == _INT64 and modes.dtype == _INT8 and actions.flags.c_contiguous and modes.flags.c_contiguous
                and actions.flags.writeable and modes.flags.writeable):  # the usual types: the kept entry point
            entry = self._entry
            if entry is None or entry[1] is not rows or entry[2] is not blocks:
                entry = self._entry = self._entry_point(args, rows, blocks)
            step = entry[0]
        else:  # other types: numba's dispatcher chooses (and compiles) the step for them
            step = fast.vector_advance
        with bits.lock:
            bad = step(*args)
        if bad >= 0:
            model = self.models[int(rows.slots[bad])]
            reading = int(rows.readings[bad])
            raise derived.impossible(model, reading, label=f"observation {model.sensor.observation_text(reading)} of belief {bad}")

    def _entry_point(self, args: tuple, rows: Rows, blocks: Any) -> tuple[Callable[..., int], Rows, Any]:
        """The compiled step for arguments of the types of ``args`` (the usual ones: C-contiguous
        writable int64 actions and int8 modes), as numba's dispatcher would choose it, to be
        called without the dispatch (a microsecond of each step's cost, where a small map's whole
        step costs a few): compiled once if needed, its entry point kept with the rows and blocks
        it was made for (made again for others, and for new tables)."""
        step = self._fast.vector_advance
        types = tuple(step.typeof_pyval(a) for a in args)
        if types not in step.overloads:
            step.compile(types)
        return step.overloads[types].entry_point, rows, blocks

    def draw_maps(self, walls: np.ndarray, rooms: int, model_of_code: Callable[[int], GridModel]) -> bool:
        """Let ``advance(..., maps=True)`` draw the starting rows' maps in the step's own call:
        perfect mazes on the graph of ``rooms`` rooms and ``walls`` ((2, W) int64: each wall's two
        rooms), drawn as :func:`gym_gridloc.generators.perfect_maze_codes` draws their codes (from
        the step's generator, before the step's other draws), each code's model
        ``model_of_code(code)``, placed when its code first comes (its slot then kept in a table
        of every code).  False, and nothing changes, when the table would be too large (more than
        :data:`CODE_WALLS` walls)."""
        walls = np.array(walls, dtype=np.int64, order="C")  # (a writable copy: the compiled structure's type)
        if walls.ndim != 2 or walls.shape[0] != 2 or walls.shape[1] > self.CODE_WALLS:
            return False
        self._maze = (walls, int(rooms), np.full(1 << walls.shape[1], -1, dtype=np.int64), np.empty(self.n_rows, dtype=np.int64))
        self._model_of_code = model_of_code
        self._bind()
        return True

    def _place_codes(self, codes: np.ndarray, modes: np.ndarray, slots: np.ndarray) -> None:
        """The slots of the starting rows (``modes`` 1, in order) for their maps' ``codes``:
        each code's model placed if its code has no slot yet (the other rows' slots kept)."""
        table = self._maze[2]
        for i, code in zip(np.flatnonzero(modes == START).tolist(), codes.tolist()):
            s = int(table[code])
            if s < 0:
                s = self.slot(self._model_of_code(code), slots)
                if s is None:
                    raise ValueError(f"the map of code {code} has a model of other sizes than the bank's")
                table[code] = s
                self._slot_codes[s] = code
            slots[i] = s

    @staticmethod
    def _signature(tables) -> tuple:
        scalars, arrays = tables
        return scalars, tuple((a.shape, a.dtype.str) for a in arrays)

    def slot(self, model: GridModel, in_use: np.ndarray) -> int | None:
        """The slot of ``model`` (placed now if new), or None when the bank cannot hold it (no
        compiled path, or other sizes).  ``in_use``: the rows' slots, which are not reused."""
        self._clock += 1
        s = self._slot_of.get(id(model))
        if s is not None and self.models[s] is model:
            self._placed[s] = self._clock
            return s
        tables = _vector_tables(model)
        if tables is None or self._signature(tables) != self.signature:
            return None
        return self._place(model, tables, in_use)

    def _place(self, model: GridModel, tables, in_use: np.ndarray) -> int:
        s = self._free_slot(in_use)
        old = self.models[s]
        if old is not None:
            del self._slot_of[id(old)]
            code = self._slot_codes.pop(s, None)
            if code is not None:  # (its code has no slot any more)
                self._maze[2][code] = -1
        self.models[s] = model
        self._slot_of[id(model)] = s
        self._placed[s] = self._clock
        for bank, a in zip(self._stacked, tables[1]):
            bank[s] = a
        return s

    def _free_slot(self, in_use: np.ndarray) -> int:
        size = len(self.models)
        if size < self.limit:  # grow (doubling: copies amortised)
            if size == self._stacked[0].shape[0]:
                grown = min(self.limit, max(1, 2 * size))
                self._stacked = tuple(np.concatenate([a, np.empty((grown - size, *a.shape[1:]), dtype=a.dtype)]) for a in self._stacked)
                self._placed = np.concatenate([self._placed, np.zeros(grown - size, dtype=np.int64)])
                self._bind()
            self.models.append(None)
            return size
        placed = self._placed.copy()
        placed[in_use] = np.iinfo(np.int64).max  # (never a slot a row is on: N rows leave one free)
        return int(np.argmin(placed))

    def _bind(self) -> None:
        """The compiled structures of the tables (and the maze), made again when the tables grow."""
        self._fast = fast = kernels.compiled(1)
        self._bits = self._functions = None
        self._tables = fast.step_tables(*self._stacked, *(int(x) for x in self.scalars))
        self._entry = None  # (the step's entry point, for these tables: see _entry_point)
        self._maze_struct = None if self._maze is None else fast.step_maze(*self._maze)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("_tables", "_maze_struct", "_slot_of", "_fast", "_bits", "_functions", "_entry")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._slot_of = {id(m): s for s, m in enumerate(self.models) if m is not None}
        self._bind()
