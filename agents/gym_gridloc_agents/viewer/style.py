"""The viewer's look: colours, sizes, fonts, and what one picture shows (:class:`Shown`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

PAD = 12
PANEL_W = 470
MIN_H = 640
GRID_PX = 480  # the grid's longer side, in pixels (cells of 4..96 pixels)
BG = (250, 250, 250)
INK = (25, 25, 25)
DIM = (110, 110, 110)
GOOD = (0, 130, 0)
BAD = (170, 30, 30)
OFF = (70, 70, 70)
HEADINGS = ("N", "E", "S", "W")
BUTTON = (232, 232, 232)
BUTTON_ON = (190, 215, 245)



@dataclass
class Shown:
    """One time step as the screen shows it."""

    model: Any
    belief: np.ndarray  # (H, W) position belief drawn as shading
    state: tuple[int, int, int]  # the true (layer, row, col)
    reading: int | None
    action: int | None
    info: dict[str, Any]  # the referee's info
    estimate: tuple[int, int] | None = None
    path: list[tuple[int, int]] | None = None
    full: np.ndarray | None = None  # (L, H, W) hidden-state belief, for the headings


def load_font(pg, size: int, bold: bool = False):
    """DejaVu Sans (matplotlib's copy, so every install draws the same text), else a system
    DejaVu, else pygame's default font."""
    import importlib.util

    name = "DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"
    spec = importlib.util.find_spec("matplotlib")
    for root in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(root) / "mpl-data" / "fonts" / "ttf" / name
        if path.is_file():
            return pg.font.Font(str(path), size)
    found = pg.font.match_font("dejavusans", bold=bold)
    font = pg.font.Font(found, size) if found else pg.font.Font(None, int(size * 1.4))
    if bold and not found:
        font.set_bold(True)
    return font


def fmt_prob(p: float) -> str:
    """A probability in a few characters: ``1``, ``.925``, ``0``."""
    if p == 0.0:
        return "0"
    if p >= 0.9995:
        return "1" if p == 1.0 else "1.000"
    if p < 0.0005:
        return "<.001"
    return f"{p:.3f}"[1:]


def percent(p: float) -> str:
    """A probability in percent for a cell: ``100``, ``57``, ``3.2``, ``<0.1``."""
    q = 100.0 * p
    if q >= 9.95:
        return f"{q:.0f}"
    return f"{q:.1f}" if q >= 0.05 else "<0.1"


def shade(p: float) -> tuple[int, int, int]:
    """The belief colour of probability ``p`` on white (square-root scale)."""
    from gym_gridloc.rendering import BELIEF_RGB

    a = float(np.sqrt(np.clip(p, 0.0, 1.0))) * 0.85
    return tuple(int(v) for v in (1 - a) * 255 + a * BELIEF_RGB)
