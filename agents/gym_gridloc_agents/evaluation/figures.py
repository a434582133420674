"""Pictures of episodes: strips of belief heatmaps and GIFs from the environments' ``rgb_array``
frames (``gridloc render``)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np


def episode_frames(env_id: str, seed: int, max_frames: int, env_kwargs: dict | None = None) -> list[tuple[np.ndarray, str]]:
    """``(frame, caption)`` of one episode under random (seeded) actions, at most ``max_frames``:
    the first, the last and evenly spaced ones between."""
    import gymnasium as gym

    from gym_gridloc_agents.policies import RandomPolicy
    from gym_gridloc_agents.evaluation.rollout import rollout

    env = gym.make(env_id, render_mode="rgb_array", **(env_kwargs or {}))
    ep = rollout(env, RandomPolicy(env.unwrapped.model), seed, keep=True, frames=True)
    env.close()
    last = len(ep.frames) - 1
    frames = [(image, ("reset" if t == 0 else f"step {t}") + f"  p={info['confidence']:.2f}"
               + ("  localised" if t == last and ep.terminated else ""))
              for t, (image, info) in enumerate(zip(ep.frames, ep.infos))]
    if len(frames) > max_frames:
        keep = np.unique(np.linspace(0, len(frames) - 1, max_frames).round().astype(int))
        frames = [frames[k] for k in keep]
    return frames


#: The strips' layout, in pixels: the environment's name on the left, a caption above each frame.
LABEL_PX, CAPTION_PX, GAP_PX, STRIP_DPI = 24, 18, 8, 100


def episode_strips(env_ids: Sequence[str], seed: int, n_frames: int, out: str | Path, *,
                   env_kwargs: dict | None = None) -> None:
    """One row of ``n_frames`` frames per environment, written to the PNG ``out`` (atomically);
    ``env_kwargs``: keywords of every environment (e.g. ``render_shading``).

    Each frame is placed pixel for pixel (``figimage``, never resampled), so its grid lines stay
    one pixel wide in every cell; the figure is as large as its frames need."""
    from gym_gridloc_agents.evaluation.report import pyplot
    from gym_gridloc_agents.files import atomic_path

    plt = pyplot()
    rows = [episode_frames(env_id, seed, n_frames, env_kwargs) for env_id in env_ids]
    col_w = max(image.shape[1] for row in rows for image, _ in row) + GAP_PX
    row_h = [max(image.shape[0] for image, _ in row) + CAPTION_PX + GAP_PX for row in rows]
    width, height = LABEL_PX + col_w * max(len(r) for r in rows), sum(row_h)
    fig = plt.figure(figsize=(width / STRIP_DPI, height / STRIP_DPI), dpi=STRIP_DPI, facecolor="white")
    top = height
    for env_id, frames, h in zip(env_ids, rows, row_h):
        for j, (image, caption) in enumerate(frames):
            x = LABEL_PX + j * col_w
            y = top - CAPTION_PX - image.shape[0]  # figimage: pixels from the bottom left
            fig.figimage(image, xo=x, yo=y, origin="upper")
            fig.text((x + image.shape[1] / 2) / width, (top - CAPTION_PX / 2) / height, caption,
                     ha="center", va="center", fontsize=8)
        fig.text(LABEL_PX / 2 / width, (top - h / 2) / height, env_id, rotation=90, ha="center", va="center", fontsize=9)
        top -= h
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format="png", dpi=STRIP_DPI)
    finally:
        plt.close(fig)


def write_gif(frames: Sequence[np.ndarray], out: str | Path, *, duration_ms: int = 500) -> None:
    """An animated GIF of RGB frames (Pillow), written atomically."""
    from PIL import Image

    from gym_gridloc_agents.files import atomic_path

    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    with atomic_path(out) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)
