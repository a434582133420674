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
DIRECTION_NAMES = ("N", "E", "S", "W")


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
        labels.setflags(write=False)
        free.setflags(write=False)
        cells = np.argwhere(free)
        cells.setflags(write=False)
        index = np.full(labels.shape, -1, dtype=np.int64)
        index[free] = np.arange(len(cells))
        index.setflags(write=False)
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "free_cells", cells)
        object.__setattr__(self, "cell_index", index)

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
        rows = []
        for r in range(self.height):
            cells = [self.symbols[v] if v >= 0 else obstacle for v in self.labels[r]]
            rows.append(sep.join(cells))
        return rows


def read_layout(layout: str | os.PathLike | Sequence[str], what: str = "layout") -> tuple[list[str], str]:
    """Return ``(rows, source)`` for a layout given as a path to a text file or a list of row
    strings.  ``source`` names the file (or ``<layout>``) for error messages."""
    if isinstance(layout, (str, os.PathLike)):
        path = Path(layout)
        if isinstance(layout, str) and not layout.strip():
            raise MapError(f"{what}: got an empty string; pass a path to a map file or a list of row strings")
        if isinstance(layout, str) and "\n" in layout:
            raise MapError(
                f"{what}: got a multi-line string; pass a path to a map file or a list of row strings"
            )
        if not path.is_file():
            raise MapError(f"{what}: no map file at {str(path)!r} (pass a path or a list of row strings)")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise MapError(f"{what}: cannot read map file {str(path)!r}: {exc}") from exc
        rows = text.splitlines()
        while rows and not rows[-1].strip():
            rows.pop()
        return rows, str(path)
    if isinstance(layout, np.ndarray):
        layout = [str(r) for r in layout.tolist()]
    try:
        rows = list(layout)
    except TypeError:
        raise TypeError(
            f"{what} must be a path to a map file or a list of row strings, got {type(layout).__name__}"
        ) from None
    for i, row in enumerate(rows):
        if not isinstance(row, str):
            raise TypeError(
                f"{what}: row {i + 1} must be a string, got {type(row).__name__} ({row!r})"
            )
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
    lookup = {s: i for i, s in enumerate(symbols)}
    lookup.update({s: -1 for s in obstacles})
    allowed = ", ".join(repr(s) for s in [*symbols, *obstacles])
    grid: list[list[int]] = []
    width = None
    for line_no, row in enumerate(rows, start=1):
        if sep is None:
            cells = list(row.rstrip("\r"))
            columns = list(range(1, len(cells) + 1))
        else:
            parts = row.rstrip("\r").split(sep)
            cells = [p.strip() for p in parts]
            columns, col = [], 1
            for p in parts:
                columns.append(col + (len(p) - len(p.lstrip())))
                col += len(p) + len(sep)
        if len(cells) == 0 or (len(cells) == 1 and cells[0] == ""):
            raise MapError(f"{source}, line {line_no}: empty row")
        if width is None:
            width = len(cells)
        elif len(cells) != width:
            raise MapError(
                f"{source}, line {line_no}: ragged row: {len(cells)} cells where line 1 has {width}"
            )
        out = []
        for cell, column in zip(cells, columns):
            if cell not in lookup:
                raise MapError(
                    f"{source}, line {line_no}, column {column}: unknown symbol {cell!r} "
                    f"(allowed: {allowed})"
                )
            out.append(lookup[cell])
        grid.append(out)
    labels = np.array(grid, dtype=np.int64)
    if not (labels >= 0).any():
        raise MapError(f"{source}: the map has no free cell: a robot needs somewhere to be")
    return GridMap(labels, tuple(symbols))
