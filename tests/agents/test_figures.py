"""Pictures of episodes (agents/gym_gridloc_agents/evaluation/figures.py): the strips of
``gridloc render`` hold the environments' frames pixel for pixel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gym_gridloc

Image = pytest.importorskip("PIL.Image")
pytest.importorskip("matplotlib")
from gym_gridloc_agents.evaluation import figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def frame_places(env_ids, seed, n_frames):
    """Where ``episode_strips`` puts each frame: ``(env_id, image, x, y)`` from the top left."""
    rows = [figures.episode_frames(e, seed, n_frames) for e in env_ids]
    col_w = max(image.shape[1] for row in rows for image, _ in row) + figures.GAP_PX
    top = 0
    for env_id, row in zip(env_ids, rows):
        for j, (image, _) in enumerate(row):
            yield env_id, image, figures.LABEL_PX + j * col_w, top + figures.CAPTION_PX
        top += max(image.shape[0] for image, _ in row) + figures.CAPTION_PX + figures.GAP_PX


def test_episode_strips_place_every_frame_unresampled(tmp_path):
    """Each frame is in the picture exactly, so its one-pixel grid lines are all there (a
    resampled frame loses some of them)."""
    env_ids = ("RingSensor8x8-v0", "DepthMaze-v0")
    out = tmp_path / "episode.png"
    figures.episode_strips(env_ids, 3, 3, out)
    with Image.open(out) as im:
        picture = np.asarray(im.convert("RGB"))
    places = list(frame_places(env_ids, 3, 3))
    assert len(places) == 6
    for env_id, image, x, y in places:
        h, w = image.shape[:2]
        assert np.array_equal(picture[y : y + h, x : x + w], image), env_id


def test_the_shipped_episode_picture_is_drawn_from_the_current_frames():
    """results/episode.png (``gridloc render``'s default, seed 3, 6 frames) holds every
    registered environment's frames as they are drawn now."""
    with Image.open(ROOT / "results" / "episode.png") as im:
        picture = np.asarray(im.convert("RGB"))
    for env_id, image, x, y in frame_places(gym_gridloc.ENV_IDS, 3, 6):
        h, w = image.shape[:2]
        assert np.array_equal(picture[y : y + h, x : x + w], image), env_id
