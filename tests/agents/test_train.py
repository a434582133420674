"""Training: tiny runs save and reload; configs are validated; work is never lost or overwritten."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc_agents.cli import main
from gym_gridloc_agents.config import ConfigError, load_config, validate_config
from gym_gridloc_agents.policies import PPOPolicy, RecurrentPolicy
from gym_gridloc_agents.train import TrainingInterrupted, atomic_save_model, atomic_write_json, train

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def tiny(tmp_path, **over):
    cfg = {
        "algo": "ppo",
        "env_id": "ColourGrid-v0",
        "n_envs": 2,
        "seed": 1,
        "total_timesteps": 256,
        "policy_kwargs": {"net_arch": [16, 16]},
        "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
        "output": str(tmp_path / "model.zip"),
        "checkpoint_dir": str(tmp_path / "ckpt"),
    }
    cfg.update(over)
    return cfg


def test_tiny_ppo_run_saves_and_reloads(tmp_path):
    info = train(tiny(tmp_path), progress_bar=False)
    out = tmp_path / "model.zip"
    assert out.is_file() and out.with_suffix(".json").is_file()
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["env_id"] == "ColourGrid-v0" and meta["seed"] == 1 and meta["num_timesteps"] >= 256
    assert {"config", "versions", "wall_time_seconds", "command"} <= set(meta)
    assert meta["versions"]["stable-baselines3"] != "not installed"
    assert info["num_timesteps"] == meta["num_timesteps"]
    policy = PPOPolicy(gym_gridloc.colour_grid_model(), env_id="ColourGrid-v0", path=out)
    b = gym_gridloc.colour_grid_model().prior()
    assert policy.act(0, b) in range(4)
    assert not list(tmp_path.glob(".*tmp*")), "temporary files left behind"


def test_tiny_recurrent_run_saves_and_reloads(tmp_path):
    cfg = tiny(tmp_path, algo="recurrent_ppo", policy_kwargs={"lstm_hidden_size": 8, "net_arch": [8]})
    train(cfg, progress_bar=False)
    policy = RecurrentPolicy(gym_gridloc.colour_grid_model(), env_id="ColourGrid-v0", path=tmp_path / "model.zip")
    policy.reset(seed=0)
    assert [policy.act(z) in range(4) for z in (0, 1, 2)] == [True] * 3


def test_existing_model_is_not_overwritten_without_force(tmp_path):
    out = tmp_path / "model.zip"
    out.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="--force"):
        train(tiny(tmp_path), progress_bar=False)
    assert out.read_bytes() == b"precious"
    assert main(["train", str(_write_yaml(tmp_path, tiny(tmp_path))), "--no-progress"]) == 2
    assert out.read_bytes() == b"precious"
    train(tiny(tmp_path), progress_bar=False, force=True)
    assert out.read_bytes() != b"precious"


def _write_yaml(tmp_path, cfg, name="cfg.yml"):
    import yaml

    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_periodic_checkpoints(tmp_path):
    train(tiny(tmp_path, total_timesteps=512, checkpoint_freq=128), progress_bar=False)
    saved = sorted((tmp_path / "ckpt").glob("step_*.zip"))
    assert len(saved) >= 3
    assert json.loads(saved[0].with_suffix(".json").read_text())["env_id"] == "ColourGrid-v0"


def test_ctrl_c_saves_a_checkpoint_and_resume_finishes(tmp_path):
    from stable_baselines3.common.callbacks import BaseCallback

    class CtrlC(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 256:
                raise KeyboardInterrupt
            return True

    cfg = tiny(tmp_path, total_timesteps=640)
    with pytest.raises(TrainingInterrupted) as exc:
        train(cfg, progress_bar=False, callbacks=[CtrlC()])
    ckpt = exc.value.checkpoint
    assert ckpt.is_file() and exc.value.num_timesteps >= 256
    assert json.loads(ckpt.with_suffix(".json").read_text())["interrupted"] is True
    assert not (tmp_path / "model.zip").exists()
    info = train(cfg, progress_bar=False, resume=ckpt)
    assert info["num_timesteps"] == 640 and info["resumed_from"] == str(ckpt)
    assert (tmp_path / "model.zip").is_file()


def test_resume_refuses_a_checkpoint_of_another_environment(tmp_path):
    train(tiny(tmp_path), progress_bar=False)
    other = tiny(tmp_path, env_id="WindyMaze-v0", output=str(tmp_path / "windy.zip"))
    with pytest.raises(ValueError, match="ColourGrid-v0"):
        train(other, progress_bar=False, resume=tmp_path / "model.zip")


def test_cli_ctrl_c_exit_code(tmp_path, monkeypatch, capsys):
    import gym_gridloc_agents.train as t

    def interrupted(*a, **k):
        raise TrainingInterrupted(tmp_path / "ckpt" / "interrupted_step_5.zip", 5)

    monkeypatch.setattr(t, "train", interrupted)
    assert main(["train", str(_write_yaml(tmp_path, tiny(tmp_path)))]) == 130
    assert "--resume" in capsys.readouterr().err


class _HalfSaver:
    """A model whose save() dies halfway through writing."""

    def save(self, path):
        Path(path).write_bytes(b"half")
        raise OSError("disk full")


def test_model_and_json_writes_are_atomic(tmp_path):
    out = tmp_path / "model.zip"
    out.write_bytes(b"old model")
    with pytest.raises(OSError, match="disk full"):
        atomic_save_model(_HalfSaver(), out)
    assert out.read_bytes() == b"old model"
    assert [p.name for p in tmp_path.iterdir()] == ["model.zip"]
    js = tmp_path / "r.json"
    atomic_write_json(js, {"a": 1})
    with pytest.raises(TypeError):
        atomic_write_json(js, {"a": object()})
    assert json.loads(js.read_text()) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip", "r.json"]


# -- validation ------------------------------------------------------------------------------------
def test_unknown_keys_are_named(tmp_path):
    with pytest.raises(ConfigError, match="'learning_rat'"):
        validate_config({**tiny(tmp_path), "learning_rat": 1e-3})
    with pytest.raises(ConfigError, match="hyperparams: 'n_stepz'"):
        validate_config(tiny(tmp_path, hyperparams={"n_stepz": 64}))
    with pytest.raises(ConfigError, match="policy_kwargs: 'features_extractor_class'"):
        validate_config(tiny(tmp_path, policy_kwargs={"features_extractor_class": "os.system"}))
    with pytest.raises(ConfigError, match="wrapper: 'flaten'"):
        validate_config(tiny(tmp_path, wrapper={"flaten": True}))
    with pytest.raises(ConfigError, match="missing required key 'env_id'"):
        validate_config({"algo": "ppo"})
    with pytest.raises(ConfigError, match="'Nope-v0' is not a registered"):
        validate_config(tiny(tmp_path, env_id="Nope-v0"))
    with pytest.raises(ConfigError, match="algo must be one of"):
        validate_config(tiny(tmp_path, algo="dqn"))


def test_strings_are_never_evaluated(tmp_path):
    evil = "__import__('os').system('touch " + str(tmp_path / "pwned") + "')"
    with pytest.raises(ConfigError, match="activation_fn must be one of"):
        validate_config(tiny(tmp_path, policy_kwargs={"activation_fn": evil}))
    with pytest.raises(ConfigError, match="strings are not evaluated"):
        validate_config(tiny(tmp_path, hyperparams={"learning_rate": evil}))
    assert not (tmp_path / "pwned").exists()


def test_yaml_is_safe_loaded(tmp_path):
    path = tmp_path / "evil.yml"
    path.write_text(f"algo: !!python/object/apply:os.system ['touch {tmp_path / 'pwned'}']\nenv_id: ColourGrid-v0\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(path)
    assert not (tmp_path / "pwned").exists()
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.yml")


def test_bad_values_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="total_timesteps must be >= 1"):
        validate_config(tiny(tmp_path, total_timesteps=0))
    with pytest.raises(ConfigError, match="n_envs must be a whole number"):
        validate_config(tiny(tmp_path, n_envs=2.5))
    with pytest.raises(ConfigError, match="output must be a path ending in .zip"):
        validate_config(tiny(tmp_path, output="model.pkl"))
    with pytest.raises(ConfigError, match="net_arch"):
        validate_config(tiny(tmp_path, policy_kwargs={"net_arch": "64,64"}))


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yml")), ids=lambda p: p.name)
def test_shipped_configs_are_valid(path):
    cfg = load_config(path)
    assert Path(cfg["output"]).name.startswith(cfg["env_id"])
    assert np.isfinite(cfg["total_timesteps"])


def test_held_out_evaluation_keeps_the_best_model(tmp_path):
    info = train(tiny(tmp_path, total_timesteps=384, eval_freq=128, eval_episodes=3), progress_bar=False)
    ev = info["evaluations"]
    assert len(ev) >= 3 and ev[-1]["num_timesteps"] == info["num_timesteps"]
    best = min(ev, key=lambda h: h["mean_steps"])
    assert info["selected_timesteps"] == best["num_timesteps"]
    assert info["eval_seeds"].startswith("2000000..")
    from gym_gridloc_agents.train import evaluate, load_model

    model, _ = load_model(tmp_path / "model.zip", env_id="ColourGrid-v0")
    cfg = validate_config(tiny(tmp_path))
    assert evaluate(model, cfg, 3) == pytest.approx(best["mean_steps"], abs=1e-3)


def test_tensorboard_logging(tmp_path):
    train(tiny(tmp_path), progress_bar=False, tensorboard_log=tmp_path / "tb")
    assert list((tmp_path / "tb").rglob("events.out.tfevents.*"))
