"""Showing an app: in a window or off screen, with scripted keys, and recording what was shown
(GIF or MP4)."""

from __future__ import annotations

import contextlib
import itertools
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gym_gridloc_agents.viewer.app import App
from gym_gridloc_agents.viewer.args import UsageError
from gym_gridloc_agents.viewer.style import BG

class Recorder:
    """The frames shown and how long each stayed on screen; written as GIF (Pillow) or MP4
    (imageio with its ffmpeg plugin)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []

    def add(self, image: np.ndarray, t: float) -> None:
        if not self.frames or not np.array_equal(self.frames[-1], image):  # a frame like the last adds nothing
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
        h, w = map(max, zip(*(f.shape[:2] for f in self.frames)))
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


#: SDL's video drivers that show nothing (chosen on purpose through ``SDL_VIDEODRIVER``, e.g. by tests).
HEADLESS_DRIVERS = ("offscreen", "dummy")


def no_display(environ=os.environ, platform: str = sys.platform) -> str | None:
    """Why no window can open here, or None.  On Linux and the BSDs a window needs an X or Wayland
    display (``DISPLAY`` or ``WAYLAND_DISPLAY``), unless ``SDL_VIDEODRIVER`` names a driver; the
    check comes before SDL starts, which would otherwise print its own line and draw off screen."""
    if platform.startswith(("win", "darwin", "cygwin")) or environ.get("SDL_VIDEODRIVER"):
        return None
    if environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"):
        return None
    return "no display (DISPLAY and WAYLAND_DISPLAY are not set)"


@contextlib.contextmanager
def _quiet_stderr():
    """The process's standard error (file descriptor 2, where SDL writes) sent to the null device."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


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
        self.screen = self.clock = None
        self.surface = None  # the last drawn surface
        self.clock_now = time.monotonic
        if window:
            pg = self.pg
            reason = no_display()
            if reason is None:
                with _quiet_stderr():  # SDL prints what it tried (e.g. Wayland) on its own
                    pg.display.init()
                driver = pg.display.get_driver()
                if driver in HEADLESS_DRIVERS and not os.environ.get("SDL_VIDEODRIVER"):
                    pg.display.quit()  # SDL fell back to drawing nowhere: a window nobody sees, waiting for keys
                    reason = f"SDL found no display to open it on (only its {driver!r} driver)"
            if reason is not None:
                raise UsageError(f"cannot open a window: {reason}; run it where a desktop is, or draw off screen "
                                 f"with --no-window --steps N --record FILE.gif")
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

    def script(self, keys: Sequence[str], delay: float, *, until_done: bool = False) -> None:
        """Press ``keys`` one after another (``delay`` seconds apart in the recording; on screen
        too when there is a window); ``until_done``: stop when the episode is over."""
        t = 0.0
        self.show(now=t)
        for name in keys:
            if not self.app.running or (until_done and getattr(self.app, "done", False)):
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
        self.recorder.write(self.clock_now() if end is None else end)
        size = self.recorder.path.stat().st_size
        return f"wrote {self.recorder.path} ({len(self.recorder.frames)} frames, {size / 1024:.0f} KiB)"

    def close(self) -> None:
        if self.screen is not None:
            self.pg.display.quit()
            self.screen = None
