"""The named structures the compiled step takes (numba structrefs), each made by one compiled
constructor from the arrays the Python side keeps under the same names:

* :data:`TABLES` (:func:`step_tables`): a bank's models' tables, stacked on a leading slot axis
  (``gym_gridloc.bank``), and the sizes they share;
* :data:`ROWS` (:func:`step_rows`): N robots: their states, readings, beliefs (two buffers, the
  current one named by ``current[0]``), models' slots and step counts (``gym_gridloc.batch.Rows``);
* :data:`BLOCKS` (:func:`referee_blocks`): the referee's rules and what it fills for the N rows,
  the readout and how each step ends (``gym_gridloc.referee.Blocks``);
* :data:`MAZE` (:func:`step_maze`): the graph whose random spanning trees are the new episodes'
  maps, the slot of each map's code, and the codes drawn (``gym_gridloc.bank.VectorBank.draw_maps``).

A structure is passed as one argument (the kernels read its fields by name): a call takes four
of them, not their forty arrays.  The Python side never reads a structure's fields: it keeps the
arrays.
"""

from __future__ import annotations

import numba
from numba.core import types
from numba.experimental import structref


@structref.register
class StepStructType(types.StructRef):
    """The numba type of the compiled step's structures (one per list of fields)."""


class StepStruct(structref.StructRefProxy):
    """A compiled structure as Python holds it: opaque, passed to the kernels whole."""


structref.define_boxing(StepStructType, StepStruct)

_i8, _f8, _b1, _f4 = types.int64, types.float64, types.boolean, types.float32

TABLES = StepStructType([
    ("keys", _i8[:, :, :, ::1]), ("w", _f8[:, :, :, ::1]), ("meta", _i8[:, :, :, ::1]), ("liks", _f8[:, :, ::1]),
    ("cum", _f8[:, :, ::1]), ("total", _f8[:, ::1]), ("values", _i8[:, :, ::1]), ("free_cells", _i8[:, :, ::1]),
    ("posts", _f8[:, :, ::1]), ("possible", _b1[:, ::1]),
    ("width", _i8), ("n_layers", _i8), ("layered", _i8), ("kind", _i8), ("per_draw", _i8), ("n_states", _i8),
])
ROWS = StepStructType([
    ("states", _i8[:, ::1]), ("readings", _i8[::1]), ("beliefs", _f8[:, :, ::1]), ("current", _i8[::1]),
    ("slots", _i8[::1]), ("elapsed", _i8[::1]),
])
BLOCKS = StepStructType([
    ("pose", _b1), ("threshold", _f8), ("limit", _i8), ("fixed_length", _b1), ("belief_reward", _b1),
    ("scratch", _f8[:, :, ::1]), ("kept", _i8[::1]), ("ints", _i8[:, ::1]), ("confidence", _f8[::1]),
    ("estimate", _i8[:, :, ::1]), ("flags", _b1[:, ::1]), ("observed", _f4[:, ::1]), ("rewards", _f8[::1]),
    ("ends", _b1[:, ::1]), ("support", _i8[::1]), ("spans", _i8[::1]),
])
MAZE = StepStructType([("walls", _i8[:, ::1]), ("n_rooms", _i8), ("code_slots", _i8[::1]), ("codes", _i8[::1])])


@numba.njit(cache=True)
def step_tables(keys, w, meta, liks, cum, total, values, free_cells, posts, possible,
                width, n_layers, layered, kind, per_draw, n_states):  # pragma: no cover - compiled
    """:data:`TABLES` of these arrays (C-contiguous, a leading slot axis) and sizes."""
    s = structref.new(TABLES)
    s.keys, s.w, s.meta, s.liks, s.cum, s.total, s.values = keys, w, meta, liks, cum, total, values
    s.free_cells, s.posts, s.possible = free_cells, posts, possible
    s.width, s.n_layers, s.layered, s.kind, s.per_draw, s.n_states = width, n_layers, layered, kind, per_draw, n_states
    return s


@numba.njit(cache=True)
def step_rows(states, readings, beliefs, current, slots, elapsed):  # pragma: no cover - compiled
    """:data:`ROWS` of these arrays."""
    s = structref.new(ROWS)
    s.states, s.readings, s.beliefs, s.current, s.slots, s.elapsed = states, readings, beliefs, current, slots, elapsed
    return s


@numba.njit(cache=True)
def referee_blocks(pose, threshold, limit, fixed_length, belief_reward, scratch, kept, ints, confidence, estimate,
                   flags, observed, rewards, ends, support, spans):  # pragma: no cover - compiled
    """:data:`BLOCKS` of these rules and arrays."""
    s = structref.new(BLOCKS)
    s.pose, s.threshold, s.limit, s.fixed_length, s.belief_reward = pose, threshold, limit, fixed_length, belief_reward
    s.scratch, s.kept, s.ints, s.confidence, s.estimate, s.flags = scratch, kept, ints, confidence, estimate, flags
    s.observed, s.rewards, s.ends, s.support, s.spans = observed, rewards, ends, support, spans
    return s


@numba.njit(cache=True)
def step_maze(walls, n_rooms, code_slots, codes):  # pragma: no cover - compiled
    """:data:`MAZE` of these arrays."""
    s = structref.new(MAZE)
    s.walls, s.n_rooms, s.code_slots, s.codes = walls, n_rooms, code_slots, codes
    return s
