"""The native vector environment's whole step of N robots in one compiled call
(:func:`gym_gridloc._numba_vector.vector_advance`): moves, new episodes and their random draws,
readings, beliefs, and with the referee's blocks its readout and outcomes.  :class:`VectorBank`
holds each robot's model (the tables of models of one size stacked, one slot each;
:meth:`VectorBank.draw_maps`: the new episodes' small mazes drawn in the same call, a table from
code to slot); :func:`vector_advancer` is a bank of one.  The same draws and numbers as the
engine's functions called in turn (:mod:`gym_gridloc.engine` re-exports these names).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from gym_gridloc import derived, kernels
from gym_gridloc.core.model import GridModel

__all__ = ["vector_advancer", "vector_bank", "VectorBank"]


def vector_advancer(model: GridModel) -> Callable[..., None] | None:
    """A vector step of N robots on ``model`` as one compiled call, for the native vector
    environment: ``(states, readings, actions, beliefs, out, modes, rng)``.  Row ``i``
    with ``modes[i]`` 0 moves under ``actions[i]``, reads, and ``out[i]`` receives its normalised
    posterior (:func:`~gym_gridloc.engine.sample_next`, :func:`~gym_gridloc.engine.sample_readings`, :func:`~gym_gridloc.engine.step`); 1 starts an episode
    (:func:`~gym_gridloc.engine.sample_initial`, :func:`~gym_gridloc.engine.sample_readings`, :func:`~gym_gridloc.engine.first_posterior`); 2 keeps its state,
    reading and belief.  ``states`` ``(N, 3)`` and ``readings`` (N,) int64 are updated in place
    (``out`` gets the kept beliefs too); ``actions`` N int64 in
    ``0..A-1`` (not checked: the caller has); ``modes`` N int8; ``beliefs`` and ``out``
    C-contiguous float64 ``(N, L*H*W)``, apart.  The same random draws and numbers as those
    functions called in that order (the moving rows, then the starting rows): a test holds them
    equal.  None when the model has no compiled path (a large grid, kidnapping, a sensor without
    :meth:`~gym_gridloc.core.sensors.Sensor.draw_table`, or too many readings for the tables).
    N robots each on its own model: :class:`VectorBank`."""
    bank = vector_bank(model, 1)
    if bank is None:
        return None

    def advance_one_model(states, readings, actions, beliefs, out, modes, rng):
        bank.advance(states, readings, actions, beliefs, out, modes, rng, np.zeros(modes.size, dtype=np.int64))

    return advance_one_model


def vector_bank(model: GridModel, n_rows: int) -> "VectorBank | None":
    """A :class:`VectorBank` for ``n_rows`` robots whose first model is ``model``, or None when
    ``model`` has no compiled vector step (see :func:`vector_advancer`)."""
    tables = _vector_tables(model)
    return None if tables is None else VectorBank(model, n_rows, tables)


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


def _vector_function(scalars: tuple[int, ...], stacked: tuple[np.ndarray, ...], model_at: Callable[[int], GridModel],
                     maze: tuple | None = None, place: Callable[[np.ndarray, np.ndarray, np.ndarray], Callable] | None = None):
    """The vector step over ``stacked`` tables (a leading slot axis):
    ``(states, readings, actions, beliefs, out, modes, rng, slots, readout=None, ending=None,
    maps=False)``; ``model_at(slot)`` names the model in an impossible reading's error.
    ``readout``: the referee's blocks (:func:`gym_gridloc.referee.readout_blocks`), which the same call fills
    for every row; ``ending`` (with ``readout``): the referee's :func:`gym_gridloc.referee.ending_blocks`,
    the same for how each row's step ends; ``maps`` (with ``maze``, a bank's ``(walls, rooms,
    code slots)``): the starting rows' maps are drawn first, in the same call, and
    ``place(codes, modes, slots)`` places the models of codes without a slot and returns the
    bank's step (its tables may have grown), which goes on (:meth:`VectorBank.draw_maps`)."""
    width, n_layers, layered, kind, per_draw, n_states = scalars
    keys, w, meta, liks, cum, total, values, free_cells, posts, possible = stacked
    kernel = kernels.compiled(1).vector_advance

    def advance(states, readings, actions, beliefs, out, modes, rng, slots, readout=None, ending=None, maps=False):
        bits = rng.bit_generator
        functions = kernels.bit_functions(bits)
        pose, threshold, scratch, kept, ints, confidence, estimate, flags, observed = _NO_READOUT if readout is None else readout
        restarted, elapsed, limit, fixed, belief, rewards, ends = _NO_ENDING if ending is None else ending
        walls, rooms, code_slots, codes = _NO_MAZE if not maps else (*maze, np.empty(modes.shape[0], dtype=np.int64))
        with bits.lock:  # (the draws are the generator's: as its own methods, under its lock)
            bad = kernel(keys, w, meta, width, n_layers, layered, liks, kind, cum, total, values, per_draw,
                         free_cells, posts, possible, slots, modes, states, actions, beliefs, out, readings, functions, n_states,
                         walls, rooms, code_slots, codes, readout is not None, pose, threshold, scratch, kept, ints,
                         confidence, estimate, flags, observed, ending is not None, restarted, elapsed, limit, fixed, belief,
                         rewards, ends)
        if bad == -2:  # new maps: their models placed, the rows' slots set; then the rest of the step
            return place(codes, modes, slots)(states, readings, actions, beliefs, out, modes, rng, slots, readout, ending)
        if bad >= 0:
            model = model_at(int(slots[bad]))
            text = model.sensor.observation_text(int(readings[bad]))
            raise derived.impossible(model, int(readings[bad]), label=f"observation {text} of belief {bad}")

    return advance


#: The ending arguments of a vector step that computes none (the types of the real blocks).
_NO_ENDING = (np.empty(0, dtype=bool), np.empty(0, dtype=np.int64), 0, False, False, np.empty(0), np.empty((3, 0), dtype=bool))
#: The map arguments of a vector step that draws no maps (the types of the real ones).
_NO_MAZE = (np.empty((2, 0), dtype=np.int64), 1, np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))
#: The readout arguments of a vector step that reads nothing (the types of the real blocks).
_NO_READOUT = (False, 0.0, np.empty((2, 0, 1)), np.empty(0, dtype=np.int64), np.empty((5, 0), dtype=np.int64), np.empty(0), np.empty((2, 0, 2), dtype=np.int64),
               np.empty((2, 0), dtype=bool), np.empty((0, 1), dtype=np.float32))


class VectorBank:
    """The vector step of N robots each on its own model, in one compiled call: the tables of
    models of the same sizes (the first model's) stacked, one slot per model (the native vector
    environment with maps redrawn at reset); :func:`vector_bank` makes one.  :meth:`slot` places a model (its tables are copied
    once; a model already placed keeps its slot); ``advance`` is :func:`vector_advancer`'s
    step with the row's slots last: ``(states, readings, actions, beliefs, out, modes, rng,
    slots, readout=None, ending=None, maps=False)``, the same draws and numbers as
    :func:`vector_advancer` of each row's model (``readout``, ``ending``, ``maps``: see
    :meth:`draw_maps` and ``_vector_function``).

    The bank holds at most ``max(N + 1, BYTES / one model's tables)`` models; when it is full, a
    new model takes the least recently placed slot that no row uses (N rows use at most N).  It
    holds its models (strongly: the bank belongs to one vector environment).

    A bank can also draw the maps of the rows that start an episode, in the step's own call
    (:meth:`draw_maps`: mazes, by their codes, a table from each code to its slot)."""

    #: The bank's tables grow to this many bytes before slots are reused (and beyond, to N + 1 slots).
    BYTES = 32 * 2**20
    #: The most walls of the mazes whose codes :meth:`draw_maps` keeps a table of slots for (2**16 codes: 512 KiB).
    CODE_WALLS = 16

    def __init__(self, model: GridModel, n_rows: int, tables: tuple[tuple[int, ...], tuple[np.ndarray, ...]]) -> None:
        self.scalars, arrays = tables
        self.signature = self._signature(tables)
        per_model = sum(a.nbytes for a in arrays)
        self.limit = max(n_rows + 1, min(self.BYTES // max(per_model, 1), 4096))
        self.models: list[GridModel | None] = []
        self._slot_of: dict[int, int] = {}
        self._placed = np.zeros(0, dtype=np.int64)  # when each slot was last placed (its model asked for)
        self._clock = 0
        self._stacked = tuple(np.empty((0, *a.shape), dtype=a.dtype) for a in arrays)
        self._maze: tuple | None = None  # (walls, rooms, code -> slot) of draw_maps
        self._model_of_code: Callable[[int], GridModel] | None = None
        self._slot_codes: dict[int, int] = {}  # slot -> the code its model was placed for
        self._place(model, tables, np.zeros(0, dtype=np.int64))

    def draw_maps(self, walls: np.ndarray, rooms: int, model_of_code: Callable[[int], GridModel]) -> bool:
        """Let ``advance(..., maps=True)`` draw the starting rows' maps in the step's own call:
        perfect mazes on the graph of ``rooms`` rooms and ``walls`` ((2, W) int64: each wall's two
        rooms), drawn as :func:`gym_gridloc.generators.perfect_maze_codes` draws their codes (from
        the step's generator, before the step's other draws), each code's model
        ``model_of_code(code)``, placed when its code first comes (its slot then kept in a table
        of every code).  False, and nothing changes, when the table would be too large (more than
        :data:`CODE_WALLS` walls)."""
        walls = np.ascontiguousarray(walls, dtype=np.int64)
        if walls.ndim != 2 or walls.shape[0] != 2 or walls.shape[1] > self.CODE_WALLS:
            return False
        self._maze = (walls, int(rooms), np.full(1 << walls.shape[1], -1, dtype=np.int64))
        self._model_of_code = model_of_code
        self._bind()
        return True

    def _place_codes(self, codes: np.ndarray, modes: np.ndarray, slots: np.ndarray) -> Callable:
        """The slots of the starting rows (``modes`` 1, in order) for their maps' ``codes``:
        each code's model placed if its code has no slot yet (the other rows' slots kept).
        Returns the bank's step (bound again if the tables grew)."""
        table = self._maze[2]
        for i, code in zip(np.flatnonzero(modes == 1).tolist(), codes.tolist()):
            s = int(table[code])
            if s < 0:
                s = self.slot(self._model_of_code(code), slots)
                if s is None:
                    raise ValueError(f"the map of code {code} has a model of other sizes than the bank's")
                table[code] = s
                self._slot_codes[s] = code
            slots[i] = s
        return self.advance

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
        self.advance = _vector_function(self.scalars, self._stacked, lambda s: self.models[s], self._maze, self._place_codes)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("advance", "_slot_of")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._slot_of = {id(m): s for s, m in enumerate(self.models) if m is not None}
        self._bind()
