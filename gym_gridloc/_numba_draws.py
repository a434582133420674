"""A numpy bit generator's draws in compiled code, as numpy's ``Generator`` makes them: from the
generator's own C functions, whose addresses come as integers (:func:`gym_gridloc.kernels.bit_functions`),
the compiled vector step draws what the Python calls it replaces drew, in the same order (tests
hold them equal): doubles, bounded integers, permutations, and the perfect mazes drawn from them."""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.extending import intrinsic


@intrinsic
def draw_u32(typingctx, function, state):  # pragma: no cover - compiled
    """A numpy bit generator's ``next_uint32(state)``: ``function`` and ``state`` are the
    addresses of its C function and its state (``bit_generator.ctypes``), passed as integers (a
    ctypes function argument costs about 1.5 us a call to unbox; an integer, nothing)."""
    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.IntType(32), [pointer]).as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], pointer)])

    return numba.types.uint32(numba.types.uintp, numba.types.uintp), codegen


@intrinsic
def draw_double(typingctx, function, state):  # pragma: no cover - compiled
    """A numpy bit generator's ``next_double(state)`` (addresses as for :func:`draw_u32`):
    ``Generator.random`` fills its arrays with these."""
    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.DoubleType(), [pointer]).as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], pointer)])

    return numba.types.float64(numba.types.uintp, numba.types.uintp), codegen



@numba.njit(cache=True, nogil=True)
def bounded(next_u32, state, top):  # pragma: no cover - compiled
    """numpy's ``buffered_bounded_lemire_uint32`` for ``0 < top < 2**32 - 1``: a uniform
    integer in ``0..top`` by Lemire's multiply and reject (``Generator.integers(top + 1)``
    draws each of its int64 values so)."""
    excl = np.uint64(top) + np.uint64(1)
    m = np.uint64(draw_u32(next_u32, state)) * excl
    leftover = m & np.uint64(0xFFFFFFFF)
    if leftover < excl:
        threshold = (np.uint64(0xFFFFFFFF) - np.uint64(top)) % excl
        while leftover < threshold:
            m = np.uint64(draw_u32(next_u32, state)) * excl
            leftover = m & np.uint64(0xFFFFFFFF)
    return np.int64(m >> np.uint64(32))


@numba.njit(cache=True, nogil=True)
def interval(next_u32, state, top):  # pragma: no cover - compiled
    """numpy's ``random_interval(bitgen, top)`` for ``0 <= top < 2**32``: a uniform integer in
    ``0..top``, by rejection on the smallest all-ones mask covering ``top``."""
    if top == 0:
        return 0
    mask = np.uint64(top)
    mask |= mask >> np.uint64(1)
    mask |= mask >> np.uint64(2)
    mask |= mask >> np.uint64(4)
    mask |= mask >> np.uint64(8)
    mask |= mask >> np.uint64(16)
    while True:
        value = np.uint64(draw_u32(next_u32, state)) & mask
        if value <= np.uint64(top):
            return np.int64(value)



@numba.njit(cache=True, nogil=True)
def perfect_maze_codes(next_u32, state, wall_a, wall_b, n_rooms, codes):  # pragma: no cover - compiled
    """``codes.size`` perfect mazes in a row, each as :func:`maze_code` draws it (at most 63
    walls)."""
    order = np.empty(wall_a.shape[0], dtype=np.int64)
    parent = np.empty(n_rooms, dtype=np.int64)
    for m in range(codes.shape[0]):
        codes[m] = maze_code(next_u32, state, wall_a, wall_b, n_rooms, order, parent)


@numba.njit(cache=True, nogil=True)
def maze_code(next_u32, state, wall_a, wall_b, n_rooms, order, parent):  # pragma: no cover - compiled
    """One perfect maze drawn as ``generators.perfect_maze`` draws it: the walls shuffled as
    numpy's ``Generator.permutation`` shuffles ``arange(n_walls)`` (from the last position down,
    each swap partner by ``random_interval`` from the bit generator's ``next_uint32`` at
    ``state``: both addresses), then Kruskal's union-find with path halving until the rooms are
    one tree.  Returns its code: bit ``w`` set for each opened wall ``w``.  ``order`` (walls) and
    ``parent`` (rooms) are scratch."""
    n_walls = wall_a.shape[0]
    for i in range(n_walls):
        order[i] = i
    for i in range(n_walls - 1, 0, -1):
        j = interval(next_u32, state, i)
        order[i], order[j] = order[j], order[i]
    for r in range(n_rooms):
        parent[r] = r
    opened = 0
    code = 0
    for t in range(n_walls):
        w = order[t]
        a, b = wall_a[w], wall_b[w]
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a != b:
            parent[a] = b
            code |= np.int64(1) << w
            opened += 1
            if opened == n_rooms - 1:
                break
    return code
