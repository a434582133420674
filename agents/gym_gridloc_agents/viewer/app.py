"""What ``gridloc play`` and ``gridloc view`` share: the grid picture, the side panel, the
events (:class:`App`)."""

from __future__ import annotations


import numpy as np

from gym_gridloc import rendering
from gym_gridloc.core.depth import DepthSensor
from gym_gridloc.core.ring import RingSensor
from gym_gridloc.core.sensors import ColourSensor, WallSensor
from gym_gridloc_agents.viewer.inspector import Inspector
from gym_gridloc_agents.viewer.style import (BAD, BG, BUTTON, BUTTON_ON, DIM, GOOD, GRID_PX, HEADINGS, INK, MIN_H, PAD,
                                             PANEL_W, Shown, load_font, percent)

class App(Inspector):
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
        self.show_numbers = False  # each cell's probability in percent on the grid (key p)
        self.button_rects: list[tuple[tuple[int, int, int, int], str]] = []  # the last draw's buttons: rect, key
        self.font = load_font(pg, 14)
        self.small = load_font(pg, 12)
        self.bold = load_font(pg, 15, bold=True)

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

    def buttons(self) -> list[tuple[str, str, bool]]:
        """The panel's buttons: ``(label, key it presses, shown as on)``."""
        return [("% numbers", "p", self.show_numbers)]

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
        elif name == "p":
            self.show_numbers = not self.show_numbers
        elif not self.on_key(name):
            return
        self.dirty = True

    def click(self, x: int, y: int, button: int = 1) -> None:
        for (bx, by, bw, bh), name in self.button_rects if button == 1 else ():
            if bx <= x < bx + bw and by <= y < by + bh:
                self.key(name)
                return
        if button == 3:
            self.pinned = None
        elif button == 1 and (cell := self.cell_at(x, y)) is not None:
            s = self.shown()
            self.pinned_layer = s.state[0]
            if s.full is not None and s.full.shape[0] > 1 and s.full[:, cell[0], cell[1]].max() > 0:
                self.pinned_layer = int(np.argmax(s.full[:, cell[0], cell[1]]))  # the most probable heading there
            self.pinned = cell
        else:
            return
        self.dirty = True

    # -- drawing ---------------------------------------------------------------------------------------
    def frame_image(self, s: Shown) -> np.ndarray:
        t = self.tile(s.model)
        heading = s.model.n_layers == 4
        frame = rendering.Frame(s.model, s.belief, s.state, s.reading, s.action, estimate=s.estimate,
                                path=s.path, heading=heading, tile=t, shading="absolute",
                                headings=s.full if heading else None)
        image = rendering.rgb_frame(frame)
        grid_h = s.model.shape[0] * t
        if np.all(image[grid_h:] == 255):  # no reading yet: no strip
            return image[:grid_h]
        if isinstance(s.model.sensor, DepthSensor):  # the depth's row of cells, whole
            return image
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
        if self.show_numbers:
            self.draw_numbers(surf, s)
        if self.pinned is not None:  # the pinned cell: a thin frame in the grid
            x, y, tw, th = self.cell_rect(*self.pinned)
            pg.draw.rect(surf, (255, 140, 0), (x, y, tw + 1, th + 1), width=2)
        y = PAD + h + 6
        for line in [self.reading_label(s), *self.legend(s)]:
            y = self._text(surf, line, PAD, y, self.small, DIM)
        self.draw_panel(surf, s, PAD * 2 + w, PAD)
        if not self.fits:  # a taller panel than any before: a taller window
            self.grow += self.short
            return self.draw()
        self.dirty = False
        return surf

    def reading_label(self, s: Shown) -> str:
        sensor = s.model.sensor
        if isinstance(sensor, ColourSensor):
            return "strip under the grid: the colour read"
        if isinstance(sensor, WallSensor):
            return "strip under the grid: the bits read, W N E S (dark = obstacle sensed)"
        if isinstance(sensor, RingSensor):
            return "strip under the grid: cyan = a cell was reported, white = nothing"
        if isinstance(sensor, DepthSensor):
            return "strip under the grid: the depth read (robot, free cells, wall)"
        return "the reading is in the panel"

    def draw_numbers(self, surf, s: Shown) -> None:
        """Each free cell's probability in percent, centred on the cell (nothing on a cell of
        probability 0)."""
        font = self.small if self.tile(s.model) < 40 else self.font
        for r, c in zip(*np.nonzero(s.model.grid.free)):
            p = float(s.belief[r, c])
            if p <= 0.0:
                continue
            text = percent(p)
            x, y, t, _ = self.cell_rect(int(r), int(c))
            img = font.render(text, True, (255, 255, 255) if p > 0.5 else INK)
            self.texts.append(text)
            surf.blit(img, (x + (t - img.get_width()) // 2, y + t - img.get_height() - max(1, t // 12)))

    def legend(self, s: Shown) -> list[str]:
        own = "its map colour" if isinstance(s.model.sensor, ColourSensor) else "navy"
        lines = [f"each cell: {own}, opacity = its probability",
                 "(absolute: p = 1 full colour, 0.5 half, 0 white)",
                 "p or '% numbers': each cell's probability in percent",
                 "orange: the true position" + (" and heading" if s.model.n_layers == 4 else ""),
                 *(["triangles at a cell's sides: its headings' probabilities"] if s.model.n_layers == 4 else []),
                 "grey square: the estimate (most probable position)"]
        if s.path is not None:
            lines.append("magenta: the Viterbi path up to now (ringed)")
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
        y = self.draw_buttons(surf, x0, y + 6, width)
        y = self.draw_likelihood(surf, s, x0, y + 4, width)
        y += 6
        pg.draw.line(surf, (200, 200, 200), (x0, y), (x0 + width, y))
        y = self.draw_inspector(surf, s, x0, y + 6, width)
        bottom = surf.get_height() - PAD - len(self.help_lines()) * self.small.get_linesize()
        self.short = max(0, y + 6 - bottom)  # pixels the window lacks for the help lines
        self.fits = self.short == 0
        y = max(y + 6, bottom)
        for line in self.help_lines():
            y = self._text(surf, line, x0, y, self.small, DIM)

    def draw_buttons(self, surf, x0: int, y: int, width: int) -> int:
        """The clickable buttons in rows; each presses its key (:meth:`click`)."""
        pg = self.pg
        self.button_rects = []
        x, h = x0, self.small.get_linesize() + 8
        for label, name, on in self.buttons():
            img = self.small.render(label, True, INK)
            w = img.get_width() + 16
            if x > x0 and x + w > x0 + width:
                x, y = x0, y + h + 4
            rect = (x, y, w, h)
            pg.draw.rect(surf, BUTTON_ON if on else BUTTON, rect, border_radius=4)
            pg.draw.rect(surf, DIM, rect, width=1, border_radius=4)
            surf.blit(img, (x + 8, y + 4))
            self.texts.append(label)
            self.button_rects.append((rect, name))
            x += w + 6
        return y + h

    # -- shared status lines ---------------------------------------------------------------------------
    def referee_lines(self, s: Shown, threshold: float) -> list[tuple[str, tuple[int, int, int]]]:
        info = s.info
        model = s.model
        est = tuple(info["estimate"])
        lines = [(f"reading: {model.sensor.describe(s.reading)}" if s.reading is not None else "reading: -", INK)]
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
