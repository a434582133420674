"""scripts/ppo_fixed_point.py: a trained PPO model continued with PPO's update from the reward."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gym_gridloc_agents.files import read_metadata
from gym_gridloc_agents.learned import default_model_path
from gym_gridloc_agents.loading import model_method
from tests.helpers import load_module

ROOT = Path(__file__).resolve().parents[2]


FIXED_POINT = load_module(ROOT / "scripts" / "ppo_fixed_point.py")
CONFIG = ROOT / "configs" / "ppo_windymaze.yml"


def test_continued_model_is_scored_saved_and_keeps_its_method(tmp_path):
    source = default_model_path("WindyMaze-v0", "distilled")
    rows = FIXED_POINT.continue_ppo(source, CONFIG, tmp_path, learning_rate=1e-3, steps=512, chunk=256, n_steps=8,
                                    batch_size=64, n_epochs=1, episodes=20, progress=False)
    assert [r["steps"] for r in rows] == [0, 256, 512]
    assert all(1.0 <= r["mean_steps"] <= 100 and 0.0 <= r["accuracy"] <= 1.0 for r in rows)
    saved = sorted(tmp_path.glob("*.zip"))
    assert [p.name for p in saved] == [f"{source.stem}-256.zip", f"{source.stem}-512.zip"]
    meta = read_metadata(saved[-1])
    assert meta["method"] == model_method(read_metadata(source)) == "distilled"  # a warm start stays what it was
    assert meta["continued"]["steps"] == 512 and meta["continued"]["learning_rate"] == 1e-3
    assert meta["continued"]["n_steps"] == 8 and meta["continued"]["gamma"] == 1.0  # (the config's return)


def test_the_model_as_given_scores_the_same_as_its_policy(tmp_path):
    """Step 0 is the model itself: the same number as training's held-out evaluation of it."""
    from stable_baselines3 import PPO

    from gym_gridloc_agents.training.config import load_config
    from gym_gridloc_agents.training.evaluation import evaluate

    source = default_model_path("WindyMaze-v0", "ppo")
    rows = FIXED_POINT.continue_ppo(source, CONFIG, tmp_path, learning_rate=1e-4, steps=32, chunk=32, n_steps=1,
                                    batch_size=32, n_epochs=1, episodes=30, progress=False)
    assert rows[0]["mean_steps"] == evaluate(PPO.load(source, device="cpu"), load_config(CONFIG), 30)["mean_steps"]


def test_refuses_a_model_of_another_algorithm_or_environment(tmp_path, capsys):
    recurrent = default_model_path("WindyMaze-v0", "recurrent")
    with pytest.raises(ValueError, match="recurrent_ppo model of WindyMaze-v0"):
        FIXED_POINT.continue_ppo(recurrent, CONFIG, tmp_path, learning_rate=1e-4, steps=8, chunk=8)
    other = default_model_path("ColourGrid-v0", "ppo")
    assert FIXED_POINT.main(["--model", str(other), "--config", str(CONFIG), "--out", str(tmp_path),
                             "--learning-rate", "1e-4", "--no-progress"]) == 2
    assert "ppo model of ColourGrid-v0" in capsys.readouterr().err
    with pytest.raises(ValueError, match="steps and chunk must be positive"):
        FIXED_POINT.continue_ppo(default_model_path("WindyMaze-v0", "ppo"), CONFIG, tmp_path, learning_rate=1e-4,
                                 steps=0, chunk=8)


def test_main_writes_the_scores_as_json(tmp_path, capsys):
    out = tmp_path / "scores.json"
    code = FIXED_POINT.main(["--model", str(default_model_path("WindyMaze-v0", "ppo")), "--config", str(CONFIG),
                             "--out", str(tmp_path / "ckpt"), "--learning-rate", "1e-5", "--steps", "40", "--chunk", "8",
                             "--n-steps", "1", "--batch-size", "32", "--n-epochs", "1", "--episodes", "10",
                             "--json", str(out), "--no-progress"])
    assert code == 0
    data = json.loads(out.read_text())
    assert [r["steps"] for r in data["rows"]] == [0, 32, 64]  # (whole rollouts of 32 envs x 1 step) and data["model"].endswith("WindyMaze-v0-ppo.zip")
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == data["rows"]
