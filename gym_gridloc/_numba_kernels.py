"""The compiled (numba) kernels, one module each by concept, gathered here: the filter steps
(:mod:`gym_gridloc._numba_filter`; for beliefs with mass on few states, :mod:`gym_gridloc._numba_sparse`),
the readout (:mod:`gym_gridloc._numba_readout`), a bit
generator's draws (:mod:`gym_gridloc._numba_draws`), the step of N robots (:mod:`gym_gridloc._numba_vector`) and
the named structures it takes (:mod:`gym_gridloc._numba_structs`).
Imported only by :mod:`gym_gridloc.kernels`, and only when a model small enough for them is first
filtered (or a large one asks for the fused step): importing numba costs about 100 MiB of resident
memory, so a process that only works on large grids never pays it.  Every name here is one of
theirs (a compiled function calls another compiled function, not a Python one, so they import
each other's public names)."""

from __future__ import annotations

from gym_gridloc._numba_draws import perfect_maze_codes
from gym_gridloc._numba_filter import batch_update, fused_step, pairwise_program, pairwise_sum, stencil_update
from gym_gridloc._numba_readout import batch_entropy, batch_outcomes, batch_readout, entropy_sum, observed32, readout
from gym_gridloc._numba_structs import referee_blocks, step_maze, step_rows, step_tables
from gym_gridloc._numba_vector import all_below, draw_maps, draw_reading, sample_moves, vector_advance

__all__ = [
    "all_below", "batch_entropy", "batch_outcomes", "batch_readout", "batch_update", "draw_maps", "draw_reading",
    "entropy_sum", "fused_step", "observed32", "pairwise_program", "pairwise_sum", "perfect_maze_codes", "readout",
    "referee_blocks", "sample_moves", "stencil_update", "step_maze", "step_rows", "step_tables", "vector_advance",
]
