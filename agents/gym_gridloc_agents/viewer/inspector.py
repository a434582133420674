"""The inspector: the seed documents' transition and sensor views of one hidden state, as numbers
(:meth:`Inspector.inspector`) and drawn in the side panel."""

from __future__ import annotations

from typing import Any

import numpy as np

from gym_gridloc.core.ring import RingSensor
from gym_gridloc.core.depth import DepthSensor
from gym_gridloc.core.sensors import ColourSensor, WallSensor
from gym_gridloc.rendering import BELIEF_RGB, COLOUR_RGB, absolute_shade
from gym_gridloc_agents.viewer.style import DIM, HEADINGS, INK, OFF, Shown, fmt_prob, shade


class Inspector:
    """The inspector part of :class:`~gym_gridloc_agents.viewer.app.App`: it reads the app's
    ``shown()``, ``pinned`` cell and layer, fonts and text helpers."""

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
        transitions = {a: {} for a in range(model.n_actions)}  # next (layer, row, col) -> probability
        positions = {a: {} for a in range(model.n_actions)}  # next (row, col) -> probability
        for a in range(model.n_actions):
            for (l2, r2, c2), p in model.outcomes((layer, r, c), a):
                key = (int(l2), int(r2), int(c2))
                transitions[a][key] = transitions[a].get(key, 0.0) + p
                positions[a][key[1:]] = positions[a].get(key[1:], 0.0) + p
        readings = {int(z): float(p) for z, p in zip(*model.sensor.distribution(r, c, layer))}
        return {"state": (layer, r, c), "transitions": transitions, "positions": positions, "readings": readings}

    def likelihood_view(self) -> np.ndarray | None:
        """P(the current reading | cell) over every cell, ``(H, W)`` (seed 003's observation-model
        view): the factor the filter's update multiplies the belief by.  A layered sensor (depth):
        for the inspected heading.  None before the first reading."""
        s = self.shown()
        if s.reading is None:
            return None
        lik = np.asarray(s.model.sensor.likelihood(int(s.reading)), dtype=np.float64)
        return lik[self.inspected()[0]] if lik.ndim == 3 else lik

    def draw_likelihood(self, surf, s: Shown, x0: int, y: int, width: int) -> int:
        """The likelihood view: a small map, navy with opacity P(reading | cell), obstacles grey,
        the robot's cell framed orange."""
        lik = self.likelihood_view()
        if lik is None:
            return y
        model = s.model
        facing = f", facing {HEADINGS[self.inspected()[0]]}" if model.sensor.layered and model.n_layers == 4 else ""
        y = self._text(surf, f"P(this reading | cell){facing}: reading {model.sensor.describe(int(s.reading))}", x0, y, self.font)
        h, w = model.shape
        px = int(max(2, min(24, (width - 150) // w, 150 // h)))
        pg = self.pg
        self.likelihood_at = (x0, y, px)  # where the last draw put it (for tests)
        colours = absolute_shade(BELIEF_RGB, lik)
        for r in range(h):
            for c in range(w):
                colour = OFF if not model.grid.free[r, c] else tuple(int(round(v)) for v in colours[r, c])
                pg.draw.rect(surf, colour, (x0 + c * px, y + r * px, px, px))
        _, tr, tc = s.state
        pg.draw.rect(surf, (255, 140, 0), (x0 + tc * px - 1, y + tr * px - 1, px + 2, px + 2), width=2)
        free = lik[model.grid.free]
        notes = [f"largest {fmt_prob(float(free.max()))}", f"smallest {fmt_prob(float(free.min()))}",
                 "white 0, navy 1 (absolute)", "orange: the robot"]
        for i, note in enumerate(notes):
            self._text(surf, note, x0 + w * px + 10, y + i * self.small.get_linesize(), self.small, DIM)
        return y + max(h * px, len(notes) * self.small.get_linesize()) + 2

    # -- drawing ------------------------------------------------------------------------------------
    def draw_inspector(self, surf, s: Shown, x0: int, y: int, width: int) -> int:
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
            probs = "  ".join(f"{n} {fmt_prob(float(s.full[i, r, c]))}" for i, n in enumerate(names))
            y = self._text(surf, f"belief here by heading: {probs}", x0, y + 2, self.font)
        y += 4
        note = f"  (then kidnapped w.p. {model.kidnap_prob:g})" if model.kidnap_prob > 0 else ""
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
        bottom = y
        for a in range(n):
            x = x0 + a * (side * px + 10)
            yy = self._text(surf, model.action_names[a], x, y, self.small, INK)
            pos = data["positions"][a]
            values = _window(r, c, reach, model.shape, lambda rr, cc: pos.get((rr, cc), 0.0), model.grid.free)
            yy = self._heat(surf, values, x, yy, px, centre=(reach, reach))
            if model.n_layers > 1:  # the next headings, as text
                for (l2, r2, c2), p in sorted(data["transitions"][a].items(), key=lambda kv: -kv[1])[:3]:
                    head = HEADINGS[l2] if model.n_layers == 4 else str(l2)
                    yy = self._text(surf, f"{head} ({r2},{c2}) {fmt_prob(p)}", x, yy, self.small, INK)
            bottom = max(bottom, yy)
        return bottom

    def draw_readings(self, surf, data, state, x0: int, y: int, width: int, current: int | None) -> int:
        model = self.shown().model
        sensor = model.sensor
        _, r, c = state
        readings = data["readings"]
        if isinstance(sensor, RingSensor):
            w = model.shape[1]
            values = _window(r, c, 2, model.shape, lambda rr, cc: readings.get(rr * w + cc, 0.0))
            y = self._text(surf, "reading the cell at each place round it:", x0, y, self.small, DIM)
            self._text(surf, f"nothing: {readings[sensor.nothing]:.4f}", x0 + 5 * 32 + 12, y + 2 * 32 + 8, self.font)
            return self._heat(surf, values, x0, y, 32, centre=(2, 2))
        if isinstance(sensor, ColourSensor):
            per_row = max(1, width // 100)
            for k, (z, p) in enumerate(readings.items()):
                i, j = divmod(k, per_row)
                x, yy = x0 + 2 + j * 100, y + 2 + i * 26
                self.pg.draw.rect(surf, COLOUR_RGB.get(sensor.colours[z], (128, 128, 128)), (x, yy, 20, 20))
                if z == current:
                    self.pg.draw.rect(surf, INK, (x - 2, yy - 2, 24, 24), width=2)
                self._text(surf, f"{sensor.colours[z]} {fmt_prob(p)}", x + 24, yy + 2, self.font)
            return y + 2 + 26 * -(-len(readings) // per_row)
        # Wall bits (all 16 readings, 4 a row), depth and any other sensor: shaded boxes in columns.
        items = list(readings.items())
        if isinstance(sensor, WallSensor):
            y = self._text(surf, "bits W N E S (o = obstacle sensed):", x0, y, self.small, DIM)
            per_row, colw = 4, min(110, width // 4)
            texts = ["".join("o" if b else "-" for b in sensor.to_observation(z)) + f" {fmt_prob(p)}" for z, p in items]
        else:  # reading: probability
            label = (lambda z: f"d={z}") if isinstance(sensor, DepthSensor) else sensor.describe
            if len(items) > 24:
                items = [(z, p) for z, p in items if p > 0][:24]
            per_row, colw = max(1, width // 110), 110
            texts = [f"{label(z)}: {fmt_prob(p)}" for z, p in items]
        for k, ((z, p), text) in enumerate(zip(items, texts)):
            i, j = divmod(k, per_row)
            self._box(surf, x0 + j * colw, y + i * 24, colw - 6, p, z == current, text)
        return y + -(-len(items) // per_row) * 24

    def _box(self, surf, x: int, y: int, width: int, p: float, framed: bool, text: str) -> None:
        """A box shaded by the probability ``p`` (framed: the reading received) with ``text`` on it."""
        self.pg.draw.rect(surf, shade(p), (x, y, width, 21))
        if framed:
            self.pg.draw.rect(surf, (0, 200, 220), (x, y, width, 21), width=2)
        self.texts.append(text)
        colour = (255, 255, 255) if np.sqrt(p) * 0.85 > 0.5 else INK
        surf.blit(self.font.render(text, True, colour), (x + 4, y + 3))

    def _heat(self, surf, values: np.ndarray, x: int, y: int, px: int, centre=None) -> int:
        """A small heatmap of probabilities with their numbers; NaN: not a free cell."""
        pg = self.pg
        for i in range(values.shape[0]):
            for j in range(values.shape[1]):
                rect = (x + j * px, y + i * px, px - 1, px - 1)
                v = values[i, j]
                pg.draw.rect(surf, OFF if np.isnan(v) else shade(v), rect)
                if v > 0:  # False for NaN too
                    text = fmt_prob(v)
                    img = self.small.render(text, True, (255, 255, 255) if np.sqrt(v) * 0.85 > 0.5 else INK)
                    self.texts.append(text)
                    surf.blit(img, (rect[0] + (px - 1 - img.get_width()) // 2, rect[1] + (px - 1 - img.get_height()) // 2))
        if centre is not None:
            i, j = centre
            pg.draw.rect(surf, (255, 140, 0), (x + j * px - 1, y + i * px - 1, px + 1, px + 1), width=2)
        return y + values.shape[0] * px + 2


def _window(r: int, c: int, reach: int, shape: tuple[int, int], value, free=None) -> np.ndarray:
    """The ``(2 reach + 1)``-square of values round cell ``(r, c)``: ``value(row, col)`` for each
    cell inside the map (and ``free``, where given), NaN elsewhere."""
    side = 2 * reach + 1
    values = np.full((side, side), np.nan)
    for i in range(side):
        for j in range(side):
            rr, cc = r - reach + i, c - reach + j
            if 0 <= rr < shape[0] and 0 <= cc < shape[1] and (free is None or free[rr, cc]):
                values[i, j] = value(rr, cc)
    return values
