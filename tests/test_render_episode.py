"""scripts/render_episode.py draws the README's belief heatmaps from the environments' frames."""

import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "render_episode.py"


def load():
    spec = importlib.util.spec_from_file_location("render_episode", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_episode_frames_end_when_the_episode_ends():
    frames = load().episode_frames("WindyMaze-v0", seed=3, max_frames=10_000)
    assert frames[0][1].startswith("reset")
    assert frames[-1][1].endswith("localised") or len(frames) == 101
    assert all(f.dtype == np.uint8 and f.ndim == 3 for f, _ in frames)


def test_writes_png_and_gif(tmp_path):
    png, gif = tmp_path / "e.png", tmp_path / "e.gif"
    load().main(["--env", "ColourGrid-v0", "WindyMaze-v0", "--frames", "3", "--out", str(png), "--gif", str(gif)])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
