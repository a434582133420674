"""Draw one episode per environment as a strip of belief heatmaps (the env's rgb_array frames).

    .venv/bin/python scripts/render_episode.py              # writes results/episode.png
    .venv/bin/python scripts/render_episode.py --gif results/episode_windy.gif --env WindyMaze-v0

Each frame shows the cells (colours for ColourGrid, obstacles dark), the exact position belief as
blue intensity, the true position as an orange dot, and the last reading (the strip under the
grid: the colour read, the four obstacle bits W N E S, or the ring sensor's reported cell outlined
in cyan).  Actions are random (seeded), so the pictures show what the filter does on its own.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import gym_gridloc


def episode_frames(env_id: str, seed: int, max_frames: int) -> list[tuple[np.ndarray, str]]:
    env = gym.make(env_id, render_mode="rgb_array")
    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    frames = [(env.render(), f"reset  p={info['confidence']:.2f}")]
    t = 0
    while True:
        t += 1
        _, _, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        frames.append((env.render(), f"step {t}  p={info['confidence']:.2f}" + ("  localised" if terminated else "")))
        if terminated or truncated:
            break
    env.close()
    if len(frames) > max_frames:  # keep the first, the last, and evenly spaced ones between
        keep = np.unique(np.linspace(0, len(frames) - 1, max_frames).round().astype(int))
        frames = [frames[k] for k in keep]
    return frames


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", nargs="+", default=list(gym_gridloc.ENV_IDS), help="environment ids")
    parser.add_argument("--seed", type=int, default=3, help="episode seed")
    parser.add_argument("--frames", type=int, default=6, help="frames per environment")
    parser.add_argument("--out", default="results/episode.png", help="PNG to write")
    parser.add_argument("--gif", default=None, help="also write the first environment's whole episode as a GIF")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [episode_frames(env_id, args.seed, args.frames) for env_id in args.env]
    ncol = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.1 * ncol, 2.4 * len(rows)), squeeze=False)
    for i, (env_id, frames) in enumerate(zip(args.env, rows)):
        for j in range(ncol):
            ax = axes[i, j]
            ax.axis("off")
            if j < len(frames):
                ax.imshow(frames[j][0], interpolation="nearest")
                ax.set_title(frames[j][1], fontsize=8)
        axes[i, 0].text(-0.08, 0.5, env_id, transform=axes[i, 0].transAxes, rotation=90,
                        ha="right", va="center", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    if args.gif:
        from PIL import Image

        frames = episode_frames(args.env[0], args.seed, 10_000)
        images = [Image.fromarray(f) for f, _ in frames]
        images[0].save(args.gif, save_all=True, append_images=images[1:], duration=500, loop=0)
        print(f"wrote {args.gif} ({len(images)} frames)")


if __name__ == "__main__":
    main()
