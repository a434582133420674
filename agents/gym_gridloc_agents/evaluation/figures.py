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


def episode_strips(env_ids: Sequence[str], seed: int, n_frames: int, out: str | Path) -> None:
    """One row of ``n_frames`` frames per environment, written to the PNG ``out`` (atomically)."""
    from gym_gridloc_agents.evaluation.report import pyplot, save_figure

    plt = pyplot()
    rows = [episode_frames(env_id, seed, n_frames) for env_id in env_ids]
    ncol = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.1 * ncol, 2.4 * len(rows)), squeeze=False)
    for i, (env_id, frames) in enumerate(zip(env_ids, rows)):
        for j in range(ncol):
            ax = axes[i, j]
            ax.axis("off")
            if j < len(frames):
                ax.imshow(frames[j][0], interpolation="nearest")
                ax.set_title(frames[j][1], fontsize=8)
        axes[i, 0].text(-0.08, 0.5, env_id, transform=axes[i, 0].transAxes, rotation=90,
                        ha="right", va="center", fontsize=9)
    save_figure(fig, out, dpi=80)


def write_gif(frames: Sequence[np.ndarray], out: str | Path, *, duration_ms: int = 500) -> None:
    """An animated GIF of RGB frames (Pillow), written atomically."""
    from PIL import Image

    from gym_gridloc_agents.files import atomic_path

    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    with atomic_path(out) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)
