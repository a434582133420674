"""``gridloc play ENV`` and ``gridloc view ENV``: a pygame window to drive the robot and to watch a
policy localise it, with the belief, the estimate and the model's own numbers on screen.

* ``play``: the arrow keys command the robot (``DepthMaze-v0``: left/right turn, up moves forward;
  the others: up/right/down/left = N/E/S/W; digit keys give any action by number).  Every step
  shows the reading, the exact belief (the referee's posterior), the estimate and its error,
  the entropy and whether the referee has declared the robot localised.  ``r`` starts a new
  episode, ``esc`` (or ``q``) quits.
* ``view``: runs one episode of a policy (:func:`gym_gridloc_agents.policies.make_policy`) and
  lets you step through the recorded trajectory (right/left arrows, ``home``/``end``, ``space``
  plays and pauses), overlay the smoothed belief (``s``, :func:`gym_gridloc.smooth`) and the
  Viterbi path (``v``, :func:`gym_gridloc.viterbi`); ``n`` runs a new episode (the next seed),
  ``r`` rewinds.

Both have the inspector of the seed documents' transition and sensor views: click a cell and the
side panel shows ``P(next position | cell, action)`` for every action (``model.outcomes``) and
``P(reading | cell)`` for every reading (``model.sensor.distribution``); until a cell is clicked
(and after a right click or ``c``) it follows the robot.  ``h`` cycles the inspected heading on models
whose hidden state has one.

``--record FILE.gif`` (or ``.mp4`` with imageio and its ffmpeg plugin) writes what was shown;
``--no-window`` draws off screen for scripts and tests (``--keys right,right,s`` feeds key
presses; without ``--keys``, ``view`` shows every step of the episode and ``play --steps N``
presses N random arrow keys).

The event loop is our own, not :func:`gymnasium.utils.play.play`: that loop resets only when an
episode ends (immediately, so the final "localised" frame is never seen) and has no key for a
reset, ignores mouse events (the inspector needs clicks), shows ``env.render()`` alone (no side
panel), calls ``pygame.quit()`` on exit, and steps a live environment, whereas ``view`` moves
back and forth through a recorded episode.  So both commands draw ``rgb_array`` frames of
:mod:`gym_gridloc.rendering` (``Frame``/``rgb_frame``) and a panel with ``pygame.font`` on an
off-screen surface, and a small loop shows it (or, with ``--no-window``, nothing is shown).

pygame (pygame-ce, the ``render`` extra) is imported only when a command runs.

This module is longer than 400 lines: the two commands share one panel, one inspector, one
loop and one recorder, and it is kept as one file (sections: arguments, the app and its panel,
play, view, the loop and the recording, the commands); split it along those lines if it grows.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

RENDER_HINT = "pip install 'gym_gridloc[render]'"
MP4_HINT = "pip install imageio imageio-ffmpeg"

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


class UsageError(Exception):
    """A bad argument or a missing dependency: one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one clear line instead of usage + error
        raise UsageError(message)


# -- arguments -------------------------------------------------------------------------------------
def parse_value(text: str) -> Any:
    """An environment keyword's value: ``true``/``false`` (bool), ``none``, an int, a float, a
    comma-separated tuple of those (``16,16``), or else the string itself."""
    if "," in text:
        return tuple(parse_value(part) for part in text.split(",") if part.strip())
    t = text.strip()
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    if low == "none":
        return None
    for kind in (int, float):
        try:
            return kind(t)
        except ValueError:
            pass
    return t


def parse_kw(items: Sequence[str] | None) -> dict[str, Any]:
    """``["slip=0.2", "size=16,16"]`` -> ``{"slip": 0.2, "size": (16, 16)}``."""
    out: dict[str, Any] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise UsageError(f"--kw takes KEY=VALUE (e.g. --kw slip=0.2 --kw size=16,16), got {item!r}")
        out[key] = parse_value(value)
    return out


def _cell(text: str, what: str) -> tuple[int, int]:
    value = parse_value(text)
    if not (isinstance(value, tuple) and len(value) == 2 and all(type(v) is int for v in value)):
        raise UsageError(f"{what} takes ROW,COL (two integers), got {text!r}")
    return value


def _common_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("env", help="environment id, e.g. WindyMaze-v0")
    p.add_argument("--kw", action="append", metavar="KEY=VALUE",
                   help="an environment keyword (repeatable): int, float, bool or comma-separated tuple, e.g. size=16,16")
    p.add_argument("--layout", metavar="PATH", help="a map file (the environment's layout keyword)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0; later episodes seed+1, ...)")
    p.add_argument("--steps", type=int, metavar="N", help="at most N steps per episode")
    p.add_argument("--record", metavar="FILE", help="write what was shown as an animated .gif (or .mp4: needs imageio-ffmpeg)")
    p.add_argument("--no-window", action="store_true", help="draw off screen (with --record: for scripts and tests)")
    p.add_argument("--keys", metavar="K1,K2,...", help="scripted key presses (pygame key names: up, left, space, s, ...)")
    p.add_argument("--inspect", metavar="ROW,COL", help="pin the inspector on this cell")
    p.add_argument("--delay", type=int, default=600, metavar="MS",
                   help="milliseconds per step when playing and per frame of a scripted recording (default 600)")
    p.add_argument("--tile", type=int, metavar="PX", help=f"pixels per cell (default: about {GRID_PX} pixels for the grid)")


def _checked(args: argparse.Namespace) -> None:
    if args.steps is not None and args.steps < 1:
        raise UsageError(f"--steps must be at least 1, got {args.steps}")
    if args.delay < 1:
        raise UsageError(f"--delay must be at least 1 ms, got {args.delay}")
    if args.tile is not None and not 2 <= args.tile <= 200:
        raise UsageError(f"--tile must be 2..200 pixels, got {args.tile}")
    if args.record is not None:
        suffix = Path(args.record).suffix.lower()
        if suffix not in (".gif", ".mp4"):
            raise UsageError(f"--record writes .gif or .mp4 files, got {args.record!r}")
        if suffix == ".mp4":
            import importlib.util

            missing = [m for m in ("imageio", "imageio_ffmpeg") if importlib.util.find_spec(m) is None]
            if missing:
                raise UsageError(f"--record .mp4 needs imageio with its ffmpeg plugin (missing: {', '.join(missing)}): "
                                 f"{MP4_HINT}, or record a .gif")
        from gym_gridloc_agents.files import OutputError, writable_file

        try:
            writable_file(args.record, "recording")
        except OutputError as exc:
            raise UsageError(str(exc)) from None
    args.keys = None if args.keys is None else [k.strip().lower() for k in args.keys.split(",") if k.strip()]
    args.inspect = None if args.inspect is None else _cell(args.inspect, "--inspect")


def _env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    kwargs = parse_kw(args.kw)
    if args.layout is not None:
        if "layout" in kwargs:
            raise UsageError("give the layout once: --layout PATH or --kw layout=PATH")
        if not Path(args.layout).is_file():
            raise UsageError(f"--layout: {args.layout} is not a file")
        kwargs["layout"] = args.layout
    return kwargs


def build_env(env_id: str, kwargs: dict[str, Any]):
    """``gym.make(env_id, **kwargs)`` for a gym_gridloc environment, or a one-line :class:`UsageError`."""
    import gymnasium as gym

    import gym_gridloc
    from gym_gridloc.core.errors import GridLocError
    from gym_gridloc.envs.base import GridLocEnv

    if env_id not in gym.registry:
        raise UsageError(f"{env_id!r} is not a registered environment (gym_gridloc's: {', '.join(gym_gridloc.ENV_IDS)})")
    try:
        env = gym.make(env_id, **kwargs)
    except (TypeError, ValueError, OSError, GridLocError, gym.error.Error) as exc:
        detail = " ".join(str(exc).split())
        raise UsageError(f"{env_id} does not build with {kwargs}: {detail}") from None
    if not isinstance(env.unwrapped, GridLocEnv):
        env.close()
        raise UsageError(f"{env_id} is not a gym_gridloc environment (allowed: {', '.join(gym_gridloc.ENV_IDS)})")
    return env


def import_pygame(command: str):
    """pygame (pygame-ce), or a :class:`UsageError` naming the ``render`` extra."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError:
        raise UsageError(f"{command} needs pygame-ce (the 'render' extra): {RENDER_HINT}") from None
    pygame.font.init()
    return pygame


# -- what one picture shows ------------------------------------------------------------------------
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


def _font(pg, size: int, bold: bool = False):
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


def _fmt(p: float) -> str:
    """A probability in a few characters: ``1``, ``.925``, ``0``."""
    if p == 0.0:
        return "0"
    if p >= 0.9995:
        return "1" if p == 1.0 else "1.000"
    if p < 0.0005:
        return "<.001"
    return f"{p:.3f}"[1:]


def _shade(p: float) -> tuple[int, int, int]:
    from gym_gridloc.rendering import BELIEF_RGB

    a = float(np.sqrt(np.clip(p, 0.0, 1.0))) * 0.85
    return tuple(int(v) for v in (1 - a) * 255 + a * BELIEF_RGB)


class App:
    """What both commands share: the grid picture, the side panel, the inspector, the events.

    ``draw()`` returns an off-screen surface of the whole window; ``key(name)`` and
    ``click(x, y, button)`` take the events (``handle_event`` turns pygame events into these);
    ``texts`` holds the strings the last ``draw()`` wrote (for tests).
    """

    command = "gridloc"

    def __init__(self, pg, env_id: str, *, tile: int | None = None, inspect: tuple[int, int] | None = None) -> None:
        self.pg = pg
        self.env_id = env_id
        self.tile_arg = tile
        self.pinned = inspect  # the inspected cell, or None: follow the robot
        self.pinned_layer = 0
        self.grow = 0  # extra window height, once a panel needed it (the window never shrinks back)
        self.running = True
        self.dirty = True
        self.message = ""
        self.texts: list[str] = []
        self.font = _font(pg, 14)
        self.small = _font(pg, 12)
        self.bold = _font(pg, 15, bold=True)

    # -- to be given by the commands ---------------------------------------------------------------
    def shown(self) -> Shown:
        raise NotImplementedError

    def status(self, s: Shown) -> list[tuple[str, tuple[int, int, int]]]:
        raise NotImplementedError

    def help_lines(self) -> list[str]:
        raise NotImplementedError

    def on_key(self, name: str) -> bool:
        """The command's own keys; True when the key was used."""
        return False

    def tick(self, now: float) -> None:
        """Called every loop iteration (e.g. playing)."""

    # -- geometry ----------------------------------------------------------------------------------
    def tile(self, model=None) -> int:
        model = model if model is not None else self.shown().model
        if self.tile_arg is not None:
            return int(self.tile_arg)
        return int(max(4, min(96, GRID_PX // max(model.shape))))

    def size(self, model=None) -> tuple[int, int]:
        model = model if model is not None else self.shown().model
        t = self.tile(model)
        h, w = model.shape
        gw, gh = w * t, h * t + min(max(6, t), 24)
        return 2 * PAD + gw + PANEL_W, max(MIN_H, gh + 2 * PAD + 70) + self.grow

    def cell_rect(self, r: int, c: int) -> tuple[int, int, int, int]:
        """The screen rectangle ``(x, y, w, h)`` of cell (r, c)."""
        t = self.tile()
        return PAD + c * t, PAD + r * t, t, t

    def cell_at(self, x: int, y: int) -> tuple[int, int] | None:
        model = self.shown().model
        t = self.tile(model)
        r, c = (y - PAD) // t, (x - PAD) // t
        if y < PAD or x < PAD or not (0 <= r < model.shape[0] and 0 <= c < model.shape[1]):
            return None
        return int(r), int(c)

    # -- events --------------------------------------------------------------------------------------
    def handle_event(self, event) -> None:
        pg = self.pg
        if event.type == pg.QUIT:
            self.running = False
        elif event.type == pg.KEYDOWN:
            self.key(pg.key.name(event.key))
        elif event.type == pg.MOUSEBUTTONDOWN:
            self.click(*event.pos, button=event.button)
        elif event.type in (getattr(pg, "WINDOWEXPOSED", -1), getattr(pg, "VIDEOEXPOSE", -1)):
            self.dirty = True

    def key(self, name: str) -> None:
        name = name.lower()
        self.message = ""
        if name in ("escape", "q"):
            self.running = False
        elif name == "h":
            model = self.shown().model
            if model.n_layers > 1:
                if self.pinned is None:
                    self.pinned = self.shown().state[1:]
                    self.pinned_layer = self.shown().state[0]
                self.pinned_layer = (self.pinned_layer + 1) % model.n_layers
        elif name == "c":
            self.pinned = None
        elif not self.on_key(name):
            return
        self.dirty = True

    def click(self, x: int, y: int, button: int = 1) -> None:
        if button == 3:
            self.pinned = None
            self.dirty = True
            return
        if button != 1:
            return
        cell = self.cell_at(x, y)
        if cell is None:
            return
        s = self.shown()
        self.pinned_layer = s.state[0]
        if s.full is not None and s.full.shape[0] > 1 and s.full[:, cell[0], cell[1]].max() > 0:
            self.pinned_layer = int(np.argmax(s.full[:, cell[0], cell[1]]))  # the most probable heading there
        self.pinned = cell
        self.dirty = True

    # -- the inspector's numbers ----------------------------------------------------------------------
    def inspected(self) -> tuple[int, int, int]:
        """The inspected hidden state ``(layer, row, col)``: the clicked cell, else the robot's."""
        s = self.shown()
        h, w = s.model.shape
        if self.pinned is not None and not (0 <= self.pinned[0] < h and 0 <= self.pinned[1] < w):
            self.pinned = None  # a new map of another size
        if self.pinned is None:
            return tuple(int(v) for v in s.state)
        return (int(self.pinned_layer), int(self.pinned[0]), int(self.pinned[1]))

    def inspector(self) -> dict[str, Any] | None:
        """What the inspector shows for the inspected state: ``transitions[action]`` maps next
        states ``(layer, row, col)`` to P(next | state, action) (``model.outcomes``: kidnapping
        left out), ``positions[action]`` the same summed over layers by position, and
        ``readings`` maps every reading to P(reading | state) (``sensor.distribution``).  None on
        an obstacle."""
        model = self.shown().model
        layer, r, c = self.inspected()
        if not model.grid.free[r, c]:
            return None
        transitions, positions = {}, {}
        for a in range(model.n_actions):
            nxt: dict[tuple[int, int, int], float] = {}
            pos: dict[tuple[int, int], float] = {}
            for (l2, r2, c2), p in model.outcomes((layer, r, c), a):
                key = (int(l2), int(r2), int(c2))
                nxt[key] = nxt.get(key, 0.0) + p
                pos[key[1:]] = pos.get(key[1:], 0.0) + p
            transitions[a], positions[a] = nxt, pos
        zs, ps = model.sensor.distribution(r, c, layer)
        readings = {int(z): float(p) for z, p in zip(zs, ps)}
        return {"state": (layer, r, c), "transitions": transitions, "positions": positions, "readings": readings}

    # -- drawing ---------------------------------------------------------------------------------------
    def frame_image(self, s: Shown) -> np.ndarray:
        from gym_gridloc import rendering

        t = self.tile(s.model)
        frame = rendering.Frame(s.model, s.belief, s.state, s.reading, s.action, estimate=s.estimate,
                                path=s.path, heading=s.model.n_layers == 4, tile=t)
        image = rendering.rgb_frame(frame)
        grid_h = s.model.shape[0] * t
        if np.all(image[grid_h:] == 255):  # a sensor the strip does not show (depth): no strip
            return image[:grid_h]
        return image[: grid_h + min(max(6, t), 24)]  # a thinner reading strip

    def draw(self):
        pg = self.pg
        s = self.shown()
        self.texts = []
        surf = pg.Surface(self.size(s.model))
        surf.fill(BG)
        img = self.frame_image(s)
        h, w = img.shape[:2]
        surf.blit(pg.image.frombuffer(np.ascontiguousarray(img).tobytes(), (w, h), "RGB"), (PAD, PAD))
        if self.pinned is not None:  # the pinned cell: a thin frame in the grid
            x, y, tw, th = self.cell_rect(*self.pinned)
            pg.draw.rect(surf, (255, 140, 0), (x, y, tw + 1, th + 1), width=2)
        y = PAD + h + 6
        y = self._text(surf, self.reading_label(s), PAD, y, self.small, DIM)
        for line in self.legend(s):
            y = self._text(surf, line, PAD, y, self.small, DIM)
        self.draw_panel(surf, s, PAD * 2 + w, PAD)
        if not self.fits:  # a taller panel than any before: a taller window
            self.grow += self.short
            return self.draw()
        self.dirty = False
        return surf

    def reading_label(self, s: Shown) -> str:
        from gym_gridloc.core.ring import RingSensor
        from gym_gridloc.core.sensors import ColourSensor, WallSensor

        sensor = s.model.sensor
        if isinstance(sensor, ColourSensor):
            return "strip under the grid: the colour read"
        if isinstance(sensor, WallSensor):
            return "strip under the grid: the bits read, W N E S (dark = obstacle sensed)"
        if isinstance(sensor, RingSensor):
            return "strip under the grid: cyan = a cell was reported, white = nothing"
        return "the reading is in the panel"

    def legend(self, s: Shown) -> list[str]:
        lines = ["shading: the belief (darker = more probable)",
                 "orange: the true position" + (" and heading" if s.model.n_layers == 4 else ""),
                 "grey square: the estimate (most probable position)"]
        if s.path is not None:
            lines.append("magenta: the Viterbi path up to now (ringed)")
        from gym_gridloc.core.ring import RingSensor

        if isinstance(s.model.sensor, RingSensor):
            lines.append("cyan outline: the cell the ring sensor reported")
        return lines

    def _text(self, surf, text: str, x: int, y: int, font=None, colour=INK) -> int:
        font = font or self.font
        self.texts.append(text)
        surf.blit(font.render(text, True, colour, BG), (x, y))
        return y + font.get_linesize()

    def draw_panel(self, surf, s: Shown, x0: int, y: int) -> None:
        pg = self.pg
        width = surf.get_width() - x0 - PAD
        for text, colour in self.status(s):
            y = self._text(surf, text, x0, y, self.bold if colour is None else self.font, colour or INK)
        if self.message:
            y = self._text(surf, self.message, x0, y, self.font, BAD)
        y += 6
        pg.draw.line(surf, (200, 200, 200), (x0, y), (x0 + width, y))
        y += 6
        y = self.draw_inspector(surf, s, x0, y, width)
        bottom = surf.get_height() - PAD - len(self.help_lines()) * self.small.get_linesize()
        self.short = max(0, y + 6 - bottom)  # pixels the window lacks for the help lines
        self.fits = self.short == 0
        y = max(y + 6, bottom)
        for line in self.help_lines():
            y = self._text(surf, line, x0, y, self.small, DIM)

    def draw_inspector(self, surf, s: Shown, x0: int, y: int, width: int) -> int:
        from gym_gridloc.core.ring import RingSensor

        model = s.model
        data = self.inspector()
        layer, r, c = self.inspected()
        where = f"cell ({r}, {c})" + (f" facing {HEADINGS[layer]}" if model.n_layers == 4 else
                                      f" layer {layer}" if model.n_layers > 1 else "")
        how = "clicked; right click: follow the robot" if self.pinned is not None else "the robot's; click a cell to inspect it"
        y = self._text(surf, f"Inspector: {where}", x0, y, self.bold)
        y = self._text(surf, f"({how}{'; h: heading' if model.n_layers > 1 else ''})", x0, y, self.small, DIM)
        if data is None:
            return self._text(surf, "an obstacle: no robot is ever there", x0, y + 4, self.font, DIM)
        if model.n_layers > 1 and s.full is not None:
            names = HEADINGS if model.n_layers == 4 else [str(i) for i in range(model.n_layers)]
            probs = "  ".join(f"{n} {_fmt(float(s.full[i, r, c]))}" for i, n in enumerate(names))
            y = self._text(surf, f"belief here by heading: {probs}", x0, y + 2, self.font)
        y += 4
        note = ""
        if model.kidnap_prob > 0:
            note = f"  (then kidnapped w.p. {model.kidnap_prob:g})"
        given = "cell, heading" if model.n_layers == 4 else "cell, layer" if model.n_layers > 1 else "cell"
        y = self._text(surf, f"P(next position | {given}, action)" + note, x0, y, self.font)
        y = self.draw_transitions(surf, data, (layer, r, c), x0, y + 2, width)
        y += 6
        given = given if model.sensor.layered else "cell"
        y = self._text(surf, f"P(reading | {given})", x0, y, self.font)
        if s.reading is not None and not isinstance(model.sensor, RingSensor):
            self._text(surf, "framed: the reading received", x0 + 200, y - self.font.get_linesize() + 2, self.small, DIM)
        return self.draw_readings(surf, data, (layer, r, c), x0, y + 2, width, s.reading)

    def draw_transitions(self, surf, data, state, x0: int, y: int, width: int) -> int:
        model = self.shown().model
        _, r, c = state
        n = model.n_actions
        reach = max([max(abs(r2 - r), abs(c2 - c)) for pos in data["positions"].values() for (r2, c2) in pos] + [1])
        side = 2 * reach + 1
        px = max(18, min(36, (width // n - 10) // side))
        y_top = y
        bottom = y
        for a in range(n):
            x = x0 + a * (side * px + 10)
            yy = self._text(surf, model.action_names[a], x, y_top, self.small, INK)
            values = np.full((side, side), np.nan)
            for i in range(side):
                for j in range(side):
                    rr, cc = r - reach + i, c - reach + j
                    if 0 <= rr < model.shape[0] and 0 <= cc < model.shape[1] and model.grid.free[rr, cc]:
                        values[i, j] = data["positions"][a].get((rr, cc), 0.0)
            yy = self._heat(surf, values, x, yy, px, centre=(reach, reach))
            if model.n_layers > 1:  # the next headings, as text
                for (l2, r2, c2), p in sorted(data["transitions"][a].items(), key=lambda kv: -kv[1])[:3]:
                    head = HEADINGS[l2] if model.n_layers == 4 else str(l2)
                    yy = self._text(surf, f"{head} ({r2},{c2}) {_fmt(p)}", x, yy, self.small, INK)
            bottom = max(bottom, yy)
        return bottom

    def draw_readings(self, surf, data, state, x0: int, y: int, width: int, current: int | None) -> int:
        from gym_gridloc.core.ring import RingSensor
        from gym_gridloc.core.sensors import ColourSensor, DepthSensor, WallSensor
        from gym_gridloc.rendering import COLOUR_RGB

        model = self.shown().model
        sensor = model.sensor
        _, r, c = state
        readings = data["readings"]
        if isinstance(sensor, RingSensor):
            h, w = model.shape
            values = np.full((5, 5), np.nan)
            for i in range(5):
                for j in range(5):
                    rr, cc = r - 2 + i, c - 2 + j
                    if 0 <= rr < h and 0 <= cc < w:
                        values[i, j] = readings.get(rr * w + cc, 0.0)
            y = self._text(surf, "reading the cell at each place round it:", x0, y, self.small, DIM)
            self._text(surf, f"nothing: {readings[sensor.nothing]:.4f}", x0 + 5 * 32 + 12, y + 2 * 32 + 8, self.font)
            return self._heat(surf, values, x0, y, 32, centre=(2, 2))
        if isinstance(sensor, ColourSensor):
            per_row = max(1, width // 100)
            for k, (z, p) in enumerate(readings.items()):
                i, j = divmod(k, per_row)
                x, yy = x0 + 2 + j * 100, y + 2 + i * 26
                colour = COLOUR_RGB.get(sensor.colours[z], (128, 128, 128))
                self.pg.draw.rect(surf, colour, (x, yy, 20, 20))
                if z == current:
                    self.pg.draw.rect(surf, INK, (x - 2, yy - 2, 24, 24), width=2)
                self._text(surf, f"{sensor.colours[z]} {_fmt(p)}", x + 24, yy + 2, self.font)
            return y + 2 + 26 * -(-len(readings) // per_row)
        if isinstance(sensor, WallSensor):
            y = self._text(surf, "bits W N E S (o = obstacle sensed):", x0, y, self.small, DIM)
            cols, colw = 4, min(110, width // 4)
            for z, p in readings.items():
                bits = "".join("o" if b else "-" for b in sensor.to_observation(z))
                i, j = divmod(z, cols)
                x, yy = x0 + j * colw, y + i * 24
                self.pg.draw.rect(surf, _shade(p), (x, yy, colw - 6, 21))
                if z == current:
                    self.pg.draw.rect(surf, (0, 200, 220), (x, yy, colw - 6, 21), width=2)
                a = np.sqrt(p) * 0.85
                self._text_on(surf, f"{bits} {_fmt(p)}", x + 4, yy + 3, (255, 255, 255) if a > 0.5 else INK)
            return y + 4 * 24
        # Depth and any other sensor: reading: probability, in columns.
        label = (lambda z: f"d={z}") if isinstance(sensor, DepthSensor) else sensor.describe
        items = list(readings.items())
        if len(items) > 24:
            items = [(z, p) for z, p in items if p > 0][:24]
        colw = 110
        per_row = max(1, width // colw)
        for k, (z, p) in enumerate(items):
            i, j = divmod(k, per_row)
            x, yy = x0 + j * colw, y + i * 24
            self.pg.draw.rect(surf, _shade(p), (x, yy, colw - 6, 21))
            if z == current:
                self.pg.draw.rect(surf, (0, 200, 220), (x, yy, colw - 6, 21), width=2)
            a = np.sqrt(p) * 0.85
            self._text_on(surf, f"{label(z)}: {_fmt(p)}", x + 4, yy + 3, (255, 255, 255) if a > 0.5 else INK)
        rows = -(-len(items) // per_row)
        return y + rows * 24

    def _text_on(self, surf, text: str, x: int, y: int, colour, font=None) -> None:
        """Text without a background (on a shaded box)."""
        font = font or self.font
        self.texts.append(text)
        surf.blit(font.render(text, True, colour), (x, y))

    def _heat(self, surf, values: np.ndarray, x: int, y: int, px: int, centre=None) -> int:
        """A small heatmap of probabilities with their numbers; NaN: not a free cell."""
        pg = self.pg
        for i in range(values.shape[0]):
            for j in range(values.shape[1]):
                rect = (x + j * px, y + i * px, px - 1, px - 1)
                v = values[i, j]
                if np.isnan(v):
                    pg.draw.rect(surf, OFF, rect)
                    continue
                pg.draw.rect(surf, _shade(v), rect)
                if v > 0:
                    a = np.sqrt(v) * 0.85
                    text = _fmt(v)
                    img = self.small.render(text, True, (255, 255, 255) if a > 0.5 else INK)
                    self.texts.append(text)
                    surf.blit(img, (rect[0] + (px - 1 - img.get_width()) // 2, rect[1] + (px - 1 - img.get_height()) // 2))
        if centre is not None:
            i, j = centre
            pg.draw.rect(surf, (255, 140, 0), (x + j * px - 1, y + i * px - 1, px + 1, px + 1), width=2)
        return y + values.shape[0] * px + 2

    # -- shared status lines ---------------------------------------------------------------------------
    def referee_lines(self, s: Shown, threshold: float) -> list[tuple[str, tuple[int, int, int]]]:
        info = s.info
        model = s.model
        est = tuple(info["estimate"])
        lines = [(f"reading: {model.sensor.describe(s.reading)}" if s.reading is not None else "reading: -", INK)]
        head = ""
        if "heading" in info:
            eh = info.get("estimate_heading")
            head = f", heading {HEADINGS[info['heading']] if model.n_layers == 4 else info['heading']}"
            lines.append((f"true pose {tuple(s.state[1:])}{head}; estimate {est}"
                          + (f" facing {HEADINGS[eh]}" if eh is not None and model.n_layers == 4 else ""), INK))
        else:
            lines.append((f"true position {tuple(s.state[1:])}; estimate {est}", INK))
        numbers = f"confidence {info['confidence']:.3f}   error {info['error']} (Manhattan)   entropy {info['entropy']:.2f} bits"
        lines.append((numbers, INK))
        if info["localised"]:
            verdict = "LOCALISED (right)" if info["success"] else "LOCALISED (on the wrong cell)"
            lines.append((f"referee: {verdict}, confidence >= {threshold:g}", GOOD if info["success"] else BAD))
        else:
            lines.append((f"referee: not localised (needs confidence >= {threshold:g})", DIM))
        return lines


# -- play -------------------------------------------------------------------------------------------
class PlayApp(App):
    """``gridloc play``: the arrow keys command the robot of a live environment."""

    command = "gridloc play"

    def __init__(self, pg, env, env_id: str, *, seed: int = 0, max_steps: int | None = None, **kwargs: Any) -> None:
        super().__init__(pg, env_id, **kwargs)
        self.env = env
        self.seed = seed
        self.max_steps = max_steps
        self.episode = -1
        self.keymap = self._keymap(env.unwrapped.model)
        self.reset()

    @staticmethod
    def _keymap(model) -> dict[str, int]:
        names = tuple(model.action_names)
        keys: dict[str, int] = {str(a): a for a in range(min(model.n_actions, 10))}
        if names == ("left", "right", "forward"):
            keys.update({"left": 0, "right": 1, "up": 2})
        elif names == ("N", "E", "S", "W"):
            keys.update({"up": 0, "right": 1, "down": 2, "left": 3})
        return keys

    def reset(self) -> None:
        self.episode += 1
        self.episode_seed = None if self.seed is None else self.seed + self.episode
        obs, self.info = self.env.reset(seed=self.episode_seed)
        self.observations = [obs["observation"]]  # this episode's sensor observations and actions
        self.actions: list[int] = []
        self.steps = 0
        self.action: int | None = None
        self.terminated = self.truncated = False
        self.keymap = self._keymap(self.env.unwrapped.model)

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated

    def act(self, action: int) -> None:
        if self.done:
            self.message = "the episode is over: r starts a new one"
            return
        obs, _, terminated, truncated, self.info = self.env.step(int(action))
        self.observations.append(obs["observation"])
        self.actions.append(int(action))
        self.steps += 1
        self.action = int(action)
        self.terminated = bool(terminated)
        self.truncated = bool(truncated) or (self.max_steps is not None and self.steps >= self.max_steps)

    def on_key(self, name: str) -> bool:
        if name == "r":
            self.reset()
            return True
        if name in self.keymap:
            self.act(self.keymap[name])
            return True
        return False

    def shown(self) -> Shown:
        u = self.env.unwrapped
        return Shown(u.model, u.posterior, u.state, u.last_reading, self.action, self.info,
                     estimate=tuple(self.info["estimate"]), full=self.env.filter.full_belief)

    def status(self, s: Shown):
        model = s.model
        act = "-" if s.action is None else model.action_names[s.action]
        seed = "" if self.episode_seed is None else f", seed {self.episode_seed}"
        lines: list[tuple[str, Any]] = [
            (f"{self.env_id}: play", None),
            (f"episode {self.episode + 1}{seed}   step {self.steps}   last action: {act}", INK),
        ]
        lines += self.referee_lines(s, self.env.unwrapped.localise_threshold)
        if self.terminated:
            lines.append(("episode over (localised): r starts a new one", DIM))
        elif self.truncated:
            lines.append(("episode over (step limit): r starts a new one", DIM))
        return lines

    def help_lines(self) -> list[str]:
        names = tuple(self.shown().model.action_names)
        if names == ("left", "right", "forward"):
            move = "left/right arrows: turn   up arrow: move forward"
        elif names == ("N", "E", "S", "W"):
            move = "arrows: move N / E / S / W (up / right / down / left)"
        else:
            move = f"digits: actions ({self.shown().model.action_legend})"
        return [move, "click: inspect a cell   right click: follow the robot", "r: new episode   esc: quit"]


# -- view -------------------------------------------------------------------------------------------
class ViewApp(App):
    """``gridloc view``: a recorded episode of a policy, stepped forwards and backwards."""

    command = "gridloc view"

    def __init__(self, pg, env, env_id: str, policy, policy_name: str, *, seed: int = 0, max_steps: int | None = None,
                 delay_ms: int = 600, smooth: bool = False, viterbi: bool = False, **kwargs: Any) -> None:
        super().__init__(pg, env_id, **kwargs)
        self.env = env
        self.policy = policy
        self.policy_name = policy_name
        self.max_steps = max_steps
        self.delay = delay_ms / 1000.0
        self.show_smooth = smooth
        self.show_viterbi = viterbi
        self.playing = False
        self._last_advance = 0.0
        self.run_episode(seed)

    def run_episode(self, seed: int) -> None:
        from gym_gridloc_agents.rollout import rollout

        from gym_gridloc.inference import forward_backward, viterbi

        self.seed = int(seed)
        ep = rollout(self.env, self.policy, self.seed, keep=True, max_steps=self.max_steps)
        self.ep = ep
        self.model = ep.model
        fb = forward_backward(self.model, ep.actions, ep.observations)
        self.filtered = fb.filtered_positions
        self.smoothed = fb.smoothed_positions
        self.full_filtered, self.full_smoothed = fb.filtered, fb.smoothed
        self.viterbi_path = [tuple(int(v) for v in p) for p in viterbi(self.model, ep.actions, ep.observations)[0]]
        self.readings = [self.model.sensor.to_reading(o) for o in ep.observations]
        self.k = 0
        self.playing = False

    @property
    def last(self) -> int:
        return self.ep.steps

    def on_key(self, name: str) -> bool:
        if name == "right":
            self.k = min(self.k + 1, self.last)
        elif name == "left":
            self.k = max(self.k - 1, 0)
        elif name == "home":
            self.k = 0
        elif name == "end":
            self.k = self.last
        elif name == "space":
            if not self.playing and self.k >= self.last:
                self.k = 0
            self.playing = not self.playing
            self._last_advance = time.monotonic()
        elif name == "s":
            self.show_smooth = not self.show_smooth
        elif name == "v":
            self.show_viterbi = not self.show_viterbi
        elif name == "r":
            self.k, self.playing = 0, False
        elif name == "n":
            self.run_episode(self.seed + 1)
        else:
            return False
        return True

    def tick(self, now: float) -> None:
        if self.playing and now - self._last_advance >= self.delay:
            self._last_advance = now
            if self.k < self.last:
                self.k += 1
                self.dirty = True
            if self.k >= self.last:
                self.playing = False
                self.dirty = True

    def shown(self) -> Shown:
        k = self.k
        belief = self.smoothed[k] if self.show_smooth else self.filtered[k]
        info = self.ep.infos[k]
        if self.show_smooth:
            est = tuple(int(v) for v in np.unravel_index(int(np.argmax(belief)), belief.shape))
        else:
            est = tuple(info["estimate"])
        return Shown(self.model, belief, self.ep.states[k], self.readings[k],
                     self.ep.actions[k - 1] if k > 0 else None, info, estimate=est,
                     path=self.viterbi_path[: k + 1] if self.show_viterbi else None,
                     full=(self.full_smoothed if self.show_smooth else self.full_filtered)[k])

    def status(self, s: Shown):
        k = self.k
        ep = self.ep
        act = "-" if s.action is None else s.model.action_names[s.action]
        end = "localised" if ep.terminated else "time limit" if ep.truncated else "stopped (--steps)"
        state = "playing" if self.playing else "paused"
        lines: list[tuple[str, Any]] = [
            (f"{self.env_id}: view, policy {self.policy_name}", None),
            (f"seed {self.seed}   step {k} / {self.last} ({end} at {self.last})   [{state}]", INK),
            (f"action into this step: {act}", INK),
        ]
        lines += self.referee_lines(s, self.env.unwrapped.localise_threshold)
        truth = tuple(s.state[1:])
        sm = self.smoothed[k]
        sm_est = tuple(int(v) for v in np.unravel_index(int(np.argmax(sm)), sm.shape))
        err = abs(sm_est[0] - truth[0]) + abs(sm_est[1] - truth[1])
        on = "ON, shown" if self.show_smooth else "off"
        lines.append((f"[s] smoothed ({on}): estimate {sm_est} p={sm.max():.3f} error {err}", INK if self.show_smooth else DIM))
        vp = self.viterbi_path[k]
        verr = abs(vp[0] - truth[0]) + abs(vp[1] - truth[1])
        on = "ON, shown" if self.show_viterbi else "off"
        lines.append((f"[v] Viterbi ({on}): at step {k} {vp}, error {verr}", INK if self.show_viterbi else DIM))
        return lines

    def help_lines(self) -> list[str]:
        return ["right/left arrows: step   space: play/pause   home/end: first/last",
                "s: smoothed belief   v: Viterbi path   n: new episode   r: rewind",
                "click: inspect a cell   right click: follow the robot   esc: quit"]


# -- the loop and the recording ---------------------------------------------------------------------
class Recorder:
    """The frames shown and how long each stayed on screen; written as GIF (Pillow) or MP4
    (imageio with its ffmpeg plugin)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []

    def add(self, image: np.ndarray, t: float) -> None:
        if self.frames and np.array_equal(self.frames[-1], image):
            return
        self.frames.append(image)
        self.times.append(t)

    def durations(self, end: float, hold: float) -> list[int]:
        ts = self.times + [max(end, self.times[-1]) + hold]
        return [int(min(10_000, max(60, 1000 * (b - a)))) for a, b in itertools.pairwise(ts)]

    def write(self, end: float, hold: float = 2.0) -> None:
        if not self.frames:
            return
        from gym_gridloc_agents.files import atomic_path

        durations = self.durations(end, hold)
        h = max(f.shape[0] for f in self.frames)
        w = max(f.shape[1] for f in self.frames)
        frames = [np.pad(f, ((0, h - f.shape[0]), (0, w - f.shape[1]), (0, 0)), constant_values=BG[0])
                  if f.shape[:2] != (h, w) else f for f in self.frames]  # a window that grew: one size
        if self.path.suffix.lower() == ".mp4":
            import imageio.v2 as imageio

            fps = 10
            with atomic_path(self.path) as tmp:
                writer = imageio.get_writer(tmp, fps=fps, macro_block_size=1)
                for img, d in zip(frames, durations):
                    h, w = img.shape[:2]
                    img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")  # even sides for H.264
                    for _ in range(max(1, round(d * fps / 1000))):
                        writer.append_data(img)
                writer.close()
            return
        from PIL import Image

        images = [Image.fromarray(f).quantize(colors=128, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
                  for f in frames]
        with atomic_path(self.path) as tmp:
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=durations,
                           loop=0, optimize=True, disposal=1)


def surface_array(pg, surf) -> np.ndarray:
    """(H, W, 3) uint8 of a surface."""
    return np.ascontiguousarray(pg.surfarray.array3d(surf).transpose(1, 0, 2))


class Loop:
    """Shows an app: in a window (``window=True``) or off screen; records what was shown."""

    def __init__(self, app: App, *, window: bool, record: str | Path | None = None, fps: int = 30) -> None:
        self.app = app
        self.pg = app.pg
        self.window = window
        self.fps = fps
        self.recorder = Recorder(record) if record else None
        self.screen = None
        self.clock = None
        self.surface = None  # the last drawn surface
        self.clock_now = time.monotonic
        if window:
            pg = self.pg
            pg.display.init()
            try:
                self.screen = pg.display.set_mode(app.size())
            except pg.error as exc:
                raise UsageError(f"cannot open a window ({exc}): set DISPLAY, or use --no-window with --record") from None
            pg.display.set_caption(f"{app.command} {app.env_id}")
            self.clock = pg.time.Clock()

    def show(self, now: float | None = None) -> None:
        """Redraw (the screen, if any) and record the frame."""
        pg = self.pg
        self.surface = self.app.draw()
        if self.screen is not None:
            if self.screen.get_size() != self.surface.get_size():
                self.screen = pg.display.set_mode(self.surface.get_size())
            self.screen.blit(self.surface, (0, 0))
            pg.display.flip()
        if self.recorder is not None:
            self.recorder.add(surface_array(pg, self.surface), self.clock_now() if now is None else now)

    def pump(self) -> None:
        """One iteration: take the queued pygame events, advance, redraw if anything changed."""
        for event in self.pg.event.get():
            self.app.handle_event(event)
        self.app.tick(self.clock_now())
        if self.app.dirty and self.app.running:
            self.show()

    def run(self) -> None:
        """Until the app stops (esc, closing the window)."""
        self.show()
        while self.app.running:
            self.pump()
            self.clock.tick(self.fps)

    def script(self, keys: Sequence[str], delay: float) -> None:
        """Press ``keys`` one after another (``delay`` seconds apart in the recording; on screen
        too when there is a window)."""
        t = 0.0
        self.show(now=t)
        for name in keys:
            if not self.app.running:
                break
            self.app.key(name)
            t += delay
            if self.app.dirty and self.app.running:
                self.show(now=t)
            if self.screen is not None:
                self.pg.event.pump()
                time.sleep(delay)
        self.end = t

    def finish(self, end: float | None = None) -> str | None:
        """Write the recording; returns a line saying what was written."""
        if self.recorder is None or not self.recorder.frames:
            return None
        end = self.clock_now() if end is None else end
        self.recorder.write(end)
        size = self.recorder.path.stat().st_size
        return f"wrote {self.recorder.path} ({len(self.recorder.frames)} frames, {size / 1024:.0f} KiB)"

    def close(self) -> None:
        if self.screen is not None:
            self.pg.display.quit()
            self.screen = None


# -- the commands ------------------------------------------------------------------------------------
def _play_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="gridloc play", description="drive the robot with the arrow keys and watch the exact belief")
    _common_arguments(p)
    return p


def _view_parser() -> argparse.ArgumentParser:
    from gym_gridloc_agents.policies import POLICY_NAMES

    p = _Parser(prog="gridloc view", description="step through an episode of a policy: belief, smoothing, Viterbi, inspector")
    _common_arguments(p)
    p.add_argument("--policy", default="greedy", choices=POLICY_NAMES, help="the policy (default greedy)")
    p.add_argument("--ppo-model", metavar="PATH", help="the model file of --policy ppo (default: the shipped one for ENV)")
    p.add_argument("--smooth", action="store_true", help="start with the smoothed belief shown (key s)")
    p.add_argument("--viterbi", action="store_true", help="start with the Viterbi path shown (key v)")
    return p


def play_app(argv: Sequence[str]) -> tuple[PlayApp, argparse.Namespace]:
    """Parse ``gridloc play``'s arguments and build the app (raises :class:`UsageError`)."""
    args = _play_parser().parse_args(list(argv))
    _checked(args)
    from gym_gridloc.wrappers import HMMBeliefWrapper

    pg = import_pygame("gridloc play")
    env = HMMBeliefWrapper(build_env(args.env, _env_kwargs(args)))  # its filter: the headings' belief
    app = PlayApp(pg, env, args.env, seed=args.seed, max_steps=args.steps, tile=args.tile, inspect=args.inspect)
    _check_inspect(app, args)
    return app, args


def view_app(argv: Sequence[str]) -> tuple[ViewApp, argparse.Namespace]:
    """Parse ``gridloc view``'s arguments, run the episode and build the app (raises :class:`UsageError`)."""
    from gym_gridloc_agents.policies import make_policy

    from gym_gridloc.wrappers import HMMBeliefWrapper

    args = _view_parser().parse_args(list(argv))
    _checked(args)
    if args.ppo_model is not None and args.policy not in ("ppo", "recurrent"):
        raise UsageError(f"--ppo-model is the model of --policy ppo, not of --policy {args.policy}")
    if args.ppo_model is not None and not Path(args.ppo_model).is_file():
        raise UsageError(f"--ppo-model: {args.ppo_model} is not a file")
    kwargs = _env_kwargs(args)
    pg = import_pygame("gridloc view")
    env = HMMBeliefWrapper(build_env(args.env, kwargs))
    try:
        policy = make_policy(args.policy, env.unwrapped.model, env_id=args.env, env_kwargs=kwargs, seed=args.seed,
                             path=args.ppo_model, pose=env.unwrapped.referee_pose)
    except (ValueError, FileNotFoundError, TypeError, ImportError) as exc:
        raise UsageError(f"--policy {args.policy}: {' '.join(str(exc).split())}") from None
    app = ViewApp(pg, env, args.env, policy, args.policy, seed=args.seed, max_steps=args.steps, delay_ms=args.delay,
                  smooth=args.smooth, viterbi=args.viterbi, tile=args.tile, inspect=args.inspect)
    _check_inspect(app, args)
    return app, args


def _check_inspect(app: App, args) -> None:
    if args.inspect is not None:
        h, w = app.shown().model.shape
        if not (0 <= args.inspect[0] < h and 0 <= args.inspect[1] < w):
            raise UsageError(f"--inspect {args.inspect[0]},{args.inspect[1]} is outside the {h}x{w} map")


def _random_keys(app: PlayApp, n: int, seed: int) -> list[str]:
    keys = [k for k in app.keymap if not k.isdigit()] or list(app.keymap)
    rng = np.random.default_rng(seed)
    return [keys[int(i)] for i in rng.integers(len(keys), size=n)]


def _run(command: str, build, argv: Sequence[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        app, args = build(argv)
    except UsageError as exc:
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    keys = args.keys
    if keys is None and args.no_window:
        if isinstance(app, ViewApp):
            keys = ["right"] * app.last
        elif args.steps is not None:
            keys = _random_keys(app, args.steps, args.seed)
        else:
            print(f"{command}: error: --no-window needs --keys K1,K2,... or --steps N (random arrow keys)", file=sys.stderr)
            return 2
    try:
        loop = Loop(app, window=not args.no_window, record=args.record)
    except UsageError as exc:
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        if keys is not None:
            loop.script(keys, args.delay / 1000.0)
            end = loop.end
        else:
            loop.run()
            end = None
    except KeyboardInterrupt:
        end = None
    finally:
        loop.close()
        app.env.close()
    done = loop.finish(end)
    if done:
        print(done)
    return 0


def play_main(argv: Sequence[str] | None = None) -> int:
    """``gridloc play ENV [options]``; returns the exit status (2: bad arguments)."""
    return _run("gridloc play", play_app, argv)


def view_main(argv: Sequence[str] | None = None) -> int:
    """``gridloc view ENV [options]``; returns the exit status (2: bad arguments)."""
    return _run("gridloc view", view_app, argv)
