"""Rendering: an ANSI table of beliefs, RGB frames drawn with numpy, and a pygame window.

Everything here draws a :class:`Frame` (the model, a position belief, the true state, the last
reading and action), whoever holds them: an environment, a recorded episode, the viewer.

The key of an RGB frame (docs/environments.md, "Reading a frame", shows it): dark grey cells are
obstacles; the belief is the shading of the free cells (``Frame.shading``); the orange dot is
the true position, an orange triangle the true pose of a model with a heading (pointing along it);
small triangles at a cell's sides (white, navy on a light cell) are the belief's headings there
(``Frame.headings``); a grey square is an estimate, a magenta line a path; a cyan outline is the
cell a ring sensor reported.  The strip under the grid is the last reading: the colour read (ColourGrid), the four
wall bits W N E S (WindyMaze: dark = a wall sensed), cyan for a reported cell or white for
nothing (RingSensor), or the depth ahead (DepthMaze: the robot's cell with a grey triangle, the
free cells it sees, then the wall it reads, dark).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from gym_gridloc.core.model import GridModel
from gym_gridloc.core.depth import DepthSensor
from gym_gridloc.core.ring import RingSensor
from gym_gridloc.core.sensors import ColourSensor, WallSensor

COLOUR_RGB = {"R": (220, 50, 47), "G": (60, 170, 60), "B": (50, 100, 220), "Y": (230, 200, 30)}
FREE_RGB = (235, 235, 235)
OBSTACLE_RGB = (40, 40, 40)
BELIEF_RGB = np.array([20, 30, 120], dtype=np.float64)
TRUTH_RGB = (255, 140, 0)
READING_RGB = (0, 200, 220)
ESTIMATE_RGB = (150, 150, 150)
PATH_RGB = (200, 0, 200)
HEADING_RGB = (255, 255, 255)
HEADING_ON_LIGHT_RGB = (20, 30, 120)  # (the heading marks on a cell lighter than LIGHT: navy)
LIGHT = 170
VIEWPOINT_RGB = (120, 120, 120)


def belief_table(belief: np.ndarray, free: np.ndarray, mark: tuple[int, int] | None = None) -> str:
    """A table of position beliefs in percent, ``####`` on obstacles (like seed 004's tables);
    ``mark`` puts a ``*`` after the true position."""
    def cell(r: int, c: int) -> str:
        text = f"{100 * belief[r, c]:.2f}" if free[r, c] else "####"
        return f"{text + ('*' if mark == (r, c) else ''):>7}"

    return "\n".join(" ".join(cell(r, c) for c in range(belief.shape[1])) for r in range(belief.shape[0]))


class Frame(NamedTuple):
    """What one picture shows.

    The fields after ``action`` are optional overlays (the viewer's, ``gridloc view``); left at
    their defaults, the picture is what it always was.
    """

    model: GridModel
    belief: np.ndarray  # (H, W) position belief
    state: tuple[int, int, int] | None  # the true (layer, row, col), or None (not drawn)
    reading: int | None = None
    action: int | None = None
    #: A position (row, col) outlined in grey inside its cell: e.g. the most probable position.
    estimate: tuple[int, int] | None = None
    #: Positions (row, col) joined by a line through the cell centres, the last one ringed: e.g.
    #: the Viterbi path up to now.
    path: Sequence[tuple[int, int]] | None = None
    #: Draw the true state as an arrow pointing along its heading (its layer: 0 = N, 1 = E,
    #: 2 = S, 3 = W) rather than as a dot, for models whose hidden state has a heading.
    heading: bool = False
    #: Pixels per cell (None: the default, at most 32 and 512 pixels along the longer side).
    tile: int | None = None
    #: ``"relative"``: the map's pastel colours darkened towards navy by the belief relative to its
    #: peak (the default); ``"absolute"`` (the viewer, like seed 000's): each free cell in its own
    #: map colour (navy on maps without colours) over white, with opacity equal to its probability,
    #: so a sure cell is fully coloured and a cell of probability 0.5 half; a small corner of every
    #: coloured cell keeps its map colour, so the map stays readable.
    shading: str = "relative"
    #: The (L, H, W) belief over hidden states, for a model with a heading (``heading=True``, four
    #: layers): at each cell with belief, a small triangle at each side, pointing out along that
    #: heading (N up), whose opacity is the heading's probability given the cell (white, or navy on
    #: a light cell).  None: not drawn.
    headings: np.ndarray | None = None


def ansi(frame: Frame) -> str:
    model = frame.model
    header = f"{model.name} {model.shape[0]}x{model.shape[1]}"
    if frame.action is not None:
        header += f"  action: {model.action_names[frame.action]}"
    if frame.reading is not None:
        header += f"  reading: {model.sensor.describe(frame.reading)}"
    mark = None if frame.state is None else (frame.state[1], frame.state[2])
    table = belief_table(frame.belief, model.grid.free, mark=mark)
    return f"{header}\nposition belief (%), * = true position\n{table}\n"


def base_image(model) -> np.ndarray:
    """(H, W, 3) float colours of the cells before the belief is drawn."""
    grid = model.grid
    img = np.full((*grid.shape, 3), FREE_RGB, dtype=np.float64)
    if isinstance(model.sensor, ColourSensor):
        for i, sym in enumerate(grid.symbols):
            img[grid.labels == i] = COLOUR_RGB.get(sym, FREE_RGB)
        img = 0.55 * img + 0.45 * 255  # pastel, so the belief stands out
    img[~grid.free] = OBSTACLE_RGB
    return img


def cell_colours(model) -> np.ndarray:
    """(H, W, 3) float: each cell's own colour at full strength (what ``shading="absolute"``
    draws a sure cell in): its map colour on a colour map, navy (:data:`BELIEF_RGB`) on a map
    without colours, :data:`OBSTACLE_RGB` on obstacles."""
    grid = model.grid
    img = np.empty((*grid.shape, 3), dtype=np.float64)
    img[:] = BELIEF_RGB
    if isinstance(model.sensor, ColourSensor):
        for i, sym in enumerate(grid.symbols):
            if sym in COLOUR_RGB:
                img[grid.labels == i] = COLOUR_RGB[sym]
    img[~grid.free] = OBSTACLE_RGB
    return img


def absolute_shade(colour, p) -> np.ndarray:
    """``colour`` with opacity ``p`` over white: ``(1 - p) * 255 + p * colour``."""
    p = np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0)[..., None]
    return (1.0 - p) * 255.0 + p * np.asarray(colour, dtype=np.float64)


def rgb_frame(frame: Frame) -> np.ndarray:
    """An RGB image: cells, the belief as intensity, the true position, the last reading."""
    model, belief = frame.model, frame.belief
    t = int(max(1, min(32, 512 // max(model.shape)))) if frame.tile is None else max(1, int(frame.tile))
    if frame.shading == "absolute":
        own = cell_colours(model)
        img = np.where(model.grid.free[..., None], absolute_shade(own, belief), own)
        image = np.rint(np.kron(img, np.ones((t, t, 1)))).astype(np.uint8)
        if isinstance(model.sensor, ColourSensor) and t >= 8:  # the map colour in each cell's corner
            k = max(2, t // 5)
            corner = np.tri(k, dtype=bool)[::-1]  # the top-left triangle
            for r, c in zip(*np.nonzero(model.grid.free)):
                image[r * t : r * t + k, c * t : c * t + k][corner] = own[r, c].astype(np.uint8)
    elif frame.shading == "relative":
        img = base_image(model)
        peak = max(float(belief.max()), 1e-12)
        alpha = np.sqrt(np.clip(belief / peak, 0.0, 1.0))[..., None] * 0.85
        img = np.where(model.grid.free[..., None], (1 - alpha) * img + alpha * BELIEF_RGB, img)
        image = np.kron(img, np.ones((t, t, 1))).astype(np.uint8)
    else:
        raise ValueError(f"shading must be 'relative' or 'absolute', got {frame.shading!r}")
    if t >= 4:  # grid lines
        image[::t, :, :] = 90
        image[:, ::t, :] = 90
    if frame.headings is not None and frame.heading and t >= 8:
        _heading_marks(image, np.asarray(frame.headings, dtype=np.float64), t)
    reading = frame.reading
    sensor = model.sensor
    if isinstance(sensor, RingSensor) and reading is not None and reading != sensor.nothing:
        _outline(image, *divmod(reading, model.shape[1]), t, READING_RGB, max(1, t // 6))
    if frame.path is not None and len(frame.path) > 0:
        _path(image, frame.path, t, PATH_RGB)
    if frame.estimate is not None:
        _outline(image, *map(int, frame.estimate), t, ESTIMATE_RGB, max(1, t // 10), inset=max(1, t // 6) + 1)
    if frame.state is not None:
        if frame.heading:
            _arrow(image, frame.state[1], frame.state[2], frame.state[0], t, TRUTH_RGB)
        else:
            _dot(image, frame.state[1], frame.state[2], t, TRUTH_RGB)
    # A strip along the bottom shows the last reading.
    strip = np.full((max(6, t), image.shape[1], 3), 255, dtype=np.uint8)
    if isinstance(sensor, ColourSensor) and reading is not None:
        strip[:] = COLOUR_RGB.get(sensor.colours[reading], (128, 128, 128))
    elif isinstance(sensor, WallSensor) and reading is not None:
        q = strip.shape[1] // 4
        for i, b in enumerate(sensor.to_observation(reading)):
            strip[:, i * q : (i + 1) * q - 1] = OBSTACLE_RGB if b else FREE_RGB
    elif isinstance(sensor, RingSensor):
        strip[:] = FREE_RGB if reading == sensor.nothing else READING_RGB
    elif isinstance(sensor, DepthSensor) and reading is not None:
        _depth_strip(strip, int(reading), sensor.max_depth, t)
    return np.ascontiguousarray(np.concatenate([image, strip], axis=0))


def _centred(t: int) -> np.ndarray:
    """``(y, x)`` of a cell's pixel centres relative to the cell's centre, each ``(t, t)``."""
    return np.mgrid[0:t, 0:t] + 0.5 - t / 2


def _dot(frame: np.ndarray, r: int, c: int, t: int, rgb) -> None:
    yy, xx = _centred(t)
    mask = yy**2 + xx**2 <= (max(t, 2) * 0.3) ** 2
    if t < 3:
        mask[:] = True
    frame[r * t : (r + 1) * t, c * t : (c + 1) * t][mask] = rgb


def _outline(frame: np.ndarray, r: int, c: int, t: int, rgb, width: int, inset: int = 0) -> None:
    tile = frame[r * t : (r + 1) * t, c * t : (c + 1) * t]
    if inset and t - 2 * inset > 2 * width:
        tile = tile[inset:-inset, inset:-inset]
    for edge in (np.s_[:width], np.s_[-width:], np.s_[:, :width], np.s_[:, -width:]):
        tile[edge] = rgb


def _arrow(frame: np.ndarray, r: int, c: int, heading: int, t: int, rgb) -> None:
    """A triangle in cell (r, c) pointing along ``heading`` (0 = N, 1 = E, 2 = S, 3 = W); it
    covers the cell's centre, like the dot it replaces."""
    if t < 5:
        _dot(frame, r, c, t, rgb)
        return
    v, u = _centred(t) / (t * 0.4)  # -1..1 across the cell, 0.8 of it
    # along: +1 at the tip; across: the distance from the axis
    along, across = {0: (-v, u), 1: (u, v), 2: (v, u), 3: (-u, v)}[int(heading) % 4]
    mask = (along <= 1.0) & (along >= -0.7) & (np.abs(across) <= (1.0 - along) * 0.45)
    frame[r * t : (r + 1) * t, c * t : (c + 1) * t][mask] = rgb


def _triangle(t: int, heading: int, tip: float, base: float, half: float) -> np.ndarray:
    """A (t, t) mask: a triangle pointing along ``heading`` (0 = N, 1 = E, 2 = S, 3 = W), its tip
    and base at these distances from the cell's centre (fractions of half a cell), ``half`` its
    half-width at the base (same unit)."""
    v, u = _centred(t) / (t / 2)
    along, across = {0: (-v, u), 1: (u, v), 2: (v, u), 3: (-u, v)}[int(heading) % 4]
    return (along <= tip) & (along >= base) & (np.abs(across) <= half * (tip - along) / (tip - base))


def _heading_marks(frame: np.ndarray, headings: np.ndarray, t: int) -> None:
    """Each cell's heading belief: a triangle at each side, opacity P(heading | cell), white on a
    dark cell and :data:`HEADING_ON_LIGHT_RGB` on a light one (e.g. a thin belief under
    ``shading="absolute"``)."""
    mass = headings.sum(axis=0)
    masks = [_triangle(t, h, 0.94, 0.5, 0.34) for h in range(4)]
    for r, c in zip(*np.nonzero(mass > 0)):
        tile = frame[r * t : (r + 1) * t, c * t : (c + 1) * t]
        ink = np.asarray(HEADING_RGB if tile[t // 4, t // 4].mean() < LIGHT else HEADING_ON_LIGHT_RGB, dtype=np.float64)
        for h in range(min(4, headings.shape[0])):
            p = float(headings[h, r, c] / mass[r, c])
            if p > 0:
                tile[masks[h]] = np.rint((1 - p) * tile[masks[h]] + p * ink).astype(np.uint8)


def _depth_strip(strip: np.ndarray, depth: int, max_depth: int, t: int) -> None:
    """The depth read, as a row of cells: the robot's cell (a grey triangle pointing along the
    row), the ``depth - 1`` free cells it sees, then the wall (dark); white beyond."""
    w = max(2, min(t, strip.shape[1] // (max_depth + 1)))
    h = strip.shape[0]
    cells = [None] + [FREE_RGB] * (depth - 1) + [OBSTACLE_RGB]
    for i, rgb in enumerate(cells[: strip.shape[1] // w]):
        seg = strip[:, i * w : (i + 1) * w]
        seg[:] = FREE_RGB if rgb is None else rgb
        seg[:, 0] = 90  # the cells' borders, like the grid lines
        seg[[0, -1]] = 90
        if rgb is None:
            v, u = np.mgrid[0:h, 0:w] + 0.5
            v, u = (v - h / 2) / (h / 2), (u - w / 2) / (w / 2)
            seg[(u >= -0.6) & (u <= 0.7) & (np.abs(v) <= 0.6 * (0.7 - u) / 1.3)] = VIEWPOINT_RGB
    strip[:, len(cells) * w : len(cells) * w + 1] = 90


def _path(frame: np.ndarray, cells: Sequence[tuple[int, int]], t: int, rgb) -> None:
    """Line segments through the centres of ``cells`` and a ring round the last one."""
    width = max(1.0, t / 12)
    pts = [((int(r) + 0.5) * t, (int(c) + 0.5) * t) for r, c in cells]
    for (y0, x0), (y1, x1) in itertools.pairwise(pts):
        n = int(max(abs(y1 - y0), abs(x1 - x0))) + 1
        for s in np.linspace(0.0, 1.0, n):
            y, x = y0 + s * (y1 - y0), x0 + s * (x1 - x0)
            frame[max(0, int(y - width / 2)) : int(y + width / 2) + 1,  # (slices stop at the frame's edge)
                  max(0, int(x - width / 2)) : int(x + width / 2) + 1] = rgb
    d = np.hypot(*_centred(t))
    ring = (d <= t * 0.42) & (d >= t * 0.42 - width)
    if t < 6:
        ring[:] = True
    r, c = int(cells[-1][0]), int(cells[-1][1])
    frame[r * t : (r + 1) * t, c * t : (c + 1) * t][ring] = rgb


class Window:
    """A pygame window showing RGB frames (``render_mode="human"``)."""

    def __init__(self, title: str, fps: int) -> None:
        try:
            import pygame
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise ImportError(
                "render_mode='human' needs pygame: pip install 'gym_gridloc[render]' (pygame-ce)"
            ) from exc
        self._pg = pygame
        pygame.display.init()  # not pygame.init(): no audio device is needed
        self.title = title
        self.fps = fps
        self.screen = None
        self.clock = pygame.time.Clock()

    def show(self, frame: np.ndarray) -> None:
        pg = self._pg
        h, w = frame.shape[:2]
        if self.screen is None:
            self.screen = pg.display.set_mode((w, h))
            pg.display.set_caption(self.title)
        self.screen.blit(pg.surfarray.make_surface(np.transpose(frame, (1, 0, 2))), (0, 0))
        pg.event.pump()
        pg.display.flip()
        self.clock.tick(self.fps)

    def close(self) -> None:
        self._pg.display.quit()
