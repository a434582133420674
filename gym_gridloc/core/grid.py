"""Grid maps: which cells are free, what is written on them, and how they are parsed.

A map is H rows by W columns; row 0 is the top row, column 0 the left one.  Positions are
``(row, col)``.  Outside the grid counts as an obstacle.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from gym_gridloc.core.errors import MapError

#: Directions and actions: 0 = N (row-1), 1 = E (col+1), 2 = S (row+1), 3 = W (col-1).
DIRECTIONS = np.array([(-1, 0), (0, 1), (1, 0), (0, -1)], dtype=np.int64)


def read_only(arr: np.ndarray) -> np.ndarray:
    """``arr``, made read-only (the arrays that maps, models and sensors keep)."""
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class GridMap:
    """A rectangular grid of free cells and obstacles, with an optional label per cell.

    ``labels`` holds, for every cell, a small integer (e.g. a colour index) or -1 for an obstacle.
    """

    labels: np.ndarray
    symbols: tuple[str, ...] = ()
    free: np.ndarray = field(init=False, repr=False)
    free_cells: np.ndarray = field(init=False, repr=False)
    cell_index: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        labels = np.asarray(self.labels, dtype=np.int64)
        if labels.ndim != 2 or labels.shape[0] < 1 or labels.shape[1] < 1:
            raise MapError(f"a map needs at least one row and one column, got shape {labels.shape}")
        free = labels >= 0
        if not free.any():
            raise MapError("the map has no free cell: a robot needs somewhere to be")
        cells = np.argwhere(free)
        index = np.full(labels.shape, -1, dtype=np.int64)
        index[free] = np.arange(len(cells))
        for name, arr in (("labels", labels), ("free", free), ("free_cells", cells), ("cell_index", index)):
            object.__setattr__(self, name, read_only(arr))

    @property
    def shape(self) -> tuple[int, int]:
        return self.labels.shape  # type: ignore[return-value]

    @property
    def height(self) -> int:
        return self.labels.shape[0]

    @property
    def width(self) -> int:
        return self.labels.shape[1]

    @property
    def n_free(self) -> int:
        return len(self.free_cells)

    def is_free(self, row: int, col: int) -> bool:
        return 0 <= row < self.height and 0 <= col < self.width and bool(self.free[row, col])

    def blocked(self) -> np.ndarray:
        """A (4, H, W) bool array: ``blocked[d, r, c]`` is True when moving from (r, c) in
        direction d would leave the grid or enter an obstacle."""
        padded = np.zeros((self.height + 2, self.width + 2), dtype=bool)
        padded[1:-1, 1:-1] = self.free
        out = np.empty((4, self.height, self.width), dtype=bool)
        for d, (dr, dc) in enumerate(DIRECTIONS):
            out[d] = ~padded[1 + dr : 1 + dr + self.height, 1 + dc : 1 + dc + self.width]
        return out

    def to_text(self, sep: str = "") -> list[str]:
        """The map as rows of symbols ('.' or '#' for obstacles)."""
        obstacle = "." if sep else "#"
        return [sep.join(self.symbols[v] if v >= 0 else obstacle for v in row) for row in self.labels]


#: The largest side a map may have (rows or columns), from a file or from rows.
MAX_SIDE = 4096


def read_layout(layout: str | os.PathLike | Sequence[str], what: str = "layout", *, sep: str | None = None) -> tuple[list[str], str]:
    """Return ``(rows, source)`` for a layout given as a path to a text file (UTF-8, a leading
    byte-order mark is accepted), a list or tuple of row strings, or a 2-D array of cell
    symbols (joined with ``sep``).  ``source`` names the file (or ``<layout>``) for error
    messages.  Anything else, or a map larger than :data:`MAX_SIDE` either way, is refused with
    a message that says what is accepted."""
    accepted = "a path to a map file, a list of row strings, or a 2-D array of cell symbols"
    if isinstance(layout, bytes):
        raise TypeError(f"{what} must be {accepted}, got bytes (decode them: layout.decode('utf-8').splitlines())")
    if isinstance(layout, (str, os.PathLike)):
        path = Path(layout)
        if isinstance(layout, str) and not layout.strip():
            raise MapError(f"{what}: got an empty string; pass {accepted}")
        if isinstance(layout, str) and "\n" in layout:
            raise MapError(f"{what}: got a multi-line string; pass {accepted} (e.g. text.splitlines())")
        if not path.is_file():
            raise MapError(f"{what}: no map file at {str(path)!r} (pass {accepted})")
        limit = (MAX_SIDE * 2 + 2) * MAX_SIDE  # rows of up to MAX_SIDE cells with separators
        try:
            size = path.stat().st_size
            if size > limit:
                raise MapError(f"{what}: {path} has {size} bytes, more than a {MAX_SIDE} x {MAX_SIDE} map can have")
            text = path.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise MapError(f"{what}: cannot read map file {str(path)!r}: {exc}") from None
        rows = text.splitlines()
        while rows and not rows[-1].strip():
            rows.pop()
        return rows, str(path)
    if isinstance(layout, np.ndarray):
        if layout.ndim not in (1, 2) or layout.dtype.kind not in "US":
            raise TypeError(f"{what} must be {accepted}; got a {layout.ndim}-D array of {layout.dtype}")
        layout = [(sep or "").join(map(str, row)) if layout.ndim == 2 else str(row) for row in layout.tolist()]
    if not isinstance(layout, (list, tuple)):
        raise TypeError(f"{what} must be {accepted}, got {type(layout).__name__} (a set or other unordered collection has no row order)")
    rows = list(layout)
    for i, row in enumerate(rows):
        if not isinstance(row, str):
            raise TypeError(f"{what}: row {i + 1} must be a string, got {type(row).__name__} ({row!r}); pass {accepted}")
    return rows, "<layout>"


def parse_rows(
    rows: Sequence[str],
    symbols: Sequence[str],
    obstacles: Sequence[str],
    *,
    sep: str | None,
    source: str = "<layout>",
) -> GridMap:
    """Parse map rows into a :class:`GridMap`.

    ``symbols`` are the free-cell labels in index order, ``obstacles`` the obstacle symbols.
    With ``sep`` (e.g. ``","``) cells are separated (and stripped of white space); without,
    every character is a cell.  Errors name the source, line and column.
    """
    if len(rows) == 0:
        raise MapError(f"{source}: the map is empty (it needs at least one row)")
    if len(rows) > MAX_SIDE:
        raise MapError(f"{source}: {len(rows)} rows, more than the {MAX_SIDE} a map may have")
    lookup = {**{s: i for i, s in enumerate(symbols)}, **dict.fromkeys(obstacles, -1)}
    allowed = ", ".join(repr(s) for s in [*symbols, *obstacles])
    grid: list[np.ndarray] = []  # one small int array per row: a large map never becomes Python lists
    width = None
    for line_no, row in enumerate(rows, start=1):
        row = row.rstrip("\r")
        cells = list(row) if sep is None else [p.strip() for p in row.split(sep)]
        if len(cells) == 0 or (len(cells) == 1 and cells[0] == ""):
            raise MapError(f"{source}, line {line_no}: empty row")
        if len(cells) > MAX_SIDE:
            raise MapError(f"{source}, line {line_no}: {len(cells)} cells, more than the {MAX_SIDE} a map may have")
        width = width or len(cells)  # line 1's (a row has at least one cell here)
        if len(cells) != width:
            raise MapError(
                f"{source}, line {line_no}: ragged row: {len(cells)} cells where line 1 has {width}"
            )
        try:
            grid.append(np.array([lookup[c] for c in cells], dtype=np.int8 if len(symbols) < 127 else np.int64))
        except KeyError:
            k = next(i for i, c in enumerate(cells) if c not in lookup)
            raise MapError(
                f"{source}, line {line_no}, column {_column(row, sep, k)}: unknown symbol {cells[k]!r} "
                f"(allowed: {allowed})"
            ) from None
    labels = np.stack(grid).astype(np.int64)
    if not (labels >= 0).any():
        raise MapError(f"{source}: the map has no free cell: a robot needs somewhere to be")
    return GridMap(labels, tuple(symbols))


def _column(row: str, sep: str | None, k: int) -> int:
    """The 1-based column where cell ``k`` of ``row`` starts (its first non-blank character)."""
    if sep is None:
        return k + 1
    parts = row.split(sep)
    col = 1 + sum(len(p) + len(sep) for p in parts[:k])
    return col + len(parts[k]) - len(parts[k].lstrip())
