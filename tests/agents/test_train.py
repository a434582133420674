"""Training: tiny runs save and reload; configs are validated; work is never lost or overwritten."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc_agents.cli import main
from gym_gridloc_agents.training.config import ConfigError, load_config, validate_config
from gym_gridloc_agents.policies import PPOPolicy, RecurrentPolicy
from gym_gridloc_agents.training.train import TrainingInterrupted, atomic_save_model, atomic_write_json, train

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


def test_existing_model_is_not_overwritten_without_force(tmp_path, capsys):
    out = tmp_path / "model.zip"
    precious = b"PK\x03\x04 an earlier model"  # a zip: a model, as the output checker judges files
    out.write_bytes(precious)
    with pytest.raises(FileExistsError, match=r"the model \S+model.zip exists \(model\); pass --force \(force=True\) to replace it"):
        train(tiny(tmp_path), progress_bar=False)
    assert out.read_bytes() == precious
    assert main(["train", str(_write_yaml(tmp_path, tiny(tmp_path))), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gridloc train: error: the model") and "--force" in err and len(err.strip().splitlines()) == 1
    assert out.read_bytes() == precious
    train(tiny(tmp_path), progress_bar=False, force=True)
    assert out.read_bytes() != precious
    assert not list(tmp_path.rglob("*rescued*"))


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
    import gym_gridloc_agents.training.train as t

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
    for bad in (3, True, 1.0):
        with pytest.raises(ConfigError, match="wrapper.lookahead must be 0, 1 or 2"):
            validate_config(tiny(tmp_path, wrapper={"lookahead": bad}))
    with pytest.raises(ConfigError, match="wrapper.lookahead need wrapper.belief: true"):
        validate_config(tiny(tmp_path, wrapper={"belief": False, "flatten": False, "lookahead": 1}))
    for algo in ("ppo", "a2c", "dqn"):  # a policy without memory is evaluated on the belief observation
        with pytest.raises(ConfigError, match=f"wrapper.belief: false .* needs algo: recurrent_ppo.*; {algo} acts on the belief"):
            validate_config(tiny(tmp_path, algo=algo, wrapper={"belief": False}))
    with pytest.raises(ConfigError, match="missing required key 'env_id'"):
        validate_config({"algo": "ppo"})
    with pytest.raises(ConfigError, match="'Nope-v0' is not a registered"):
        validate_config(tiny(tmp_path, env_id="Nope-v0"))
    with pytest.raises(ConfigError, match="algo must be one of"):
        validate_config(tiny(tmp_path, algo="sac"))


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
    with pytest.raises(ConfigError, match="total_timesteps must be at least 1"):
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
    from gym_gridloc_agents.loading import load_model
    from gym_gridloc_agents.training.evaluation import evaluate

    model, _ = load_model(tmp_path / "model.zip", env_id="ColourGrid-v0")
    cfg = validate_config(tiny(tmp_path))
    assert evaluate(model, cfg, 3)["mean_steps"] == pytest.approx(best["mean_steps"], abs=1e-3)


def test_tensorboard_logging(tmp_path):
    train(tiny(tmp_path), progress_bar=False, tensorboard_log=tmp_path / "tb")
    assert list((tmp_path / "tb").rglob("events.out.tfevents.*"))


# -- nothing lost (issue: finished work survives every failure) ---------------------------------------
def test_an_output_that_cannot_be_written_fails_before_any_training(tmp_path, capsys):
    blocker = tmp_path / "plain-file"
    blocker.write_text("I am a file")
    cfg = tiny(tmp_path, output=str(blocker / "sub" / "model.zip"))
    from gym_gridloc_agents.training.train import OutputError

    with pytest.raises(OutputError, match=r"plain-file is a file, not a directory"):
        train(cfg, progress_bar=False)
    assert not (tmp_path / "ckpt").exists(), "nothing may start before the outputs are checked"
    assert main(["train", str(_write_yaml(tmp_path, cfg)), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gridloc train: error: cannot write") and "Traceback" not in err
    # The checkpoint and TensorBoard directories are checked too.
    for key in ("checkpoint_dir", "tensorboard_log"):
        with pytest.raises(OutputError, match="plain-file is a file"):
            train(tiny(tmp_path, **{key: str(blocker / "x")}), progress_bar=False)


def test_a_file_of_another_kind_in_the_way_is_kept_even_with_force(tmp_path):
    from gym_gridloc_agents.training.train import OutputError

    js = tmp_path / "model.json"
    js.write_text('{"mine": true}')
    for force in (False, True):
        with pytest.raises(OutputError, match=r"the model's metadata \S+model.json exists and holds a file of another kind, "
                                              r"not model metadata: it would be replaced"):
            train(tiny(tmp_path), progress_bar=False, force=force)
    assert js.read_text() == '{"mine": true}'
    js.unlink()
    (tmp_path / "model.zip").write_text("my notes, not a model")
    with pytest.raises(OutputError, match=r"model.zip exists and holds a file of another kind, not model"):
        train(tiny(tmp_path), progress_bar=False, force=True)
    assert (tmp_path / "model.zip").read_text() == "my notes, not a model"
    assert not (tmp_path / "ckpt").exists(), "nothing may start before the outputs are checked"


def test_outputs_of_the_same_name_in_different_directories_never_share_checkpoints(tmp_path):
    from gym_gridloc_agents.training.train import default_checkpoint_dir

    a = default_checkpoint_dir({"output": str(tmp_path / "a" / "bench.zip")})
    b = default_checkpoint_dir({"output": str(tmp_path / "b" / "bench.zip")})
    assert a != b and a.name.startswith("bench-") and b.name.startswith("bench-")
    assert a == default_checkpoint_dir({"output": str(tmp_path / "a" / ".." / "a" / "bench.zip")})


def test_a_failed_final_write_saves_the_model_elsewhere_and_says_where(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.train as t
    from gym_gridloc_agents.training.train import OutputError

    real = t.atomic_save_model
    out = tmp_path / "model.zip"

    def failing(model, path):
        if Path(path) == out:
            raise OSError(28, "No space left on device")
        return real(model, path)

    monkeypatch.setattr(t, "atomic_save_model", failing)
    with pytest.raises(OutputError, match=r"cannot write the model .*model.zip: No space left on device; written to (\S+) instead") as exc:
        train(tiny(tmp_path), progress_bar=False)
    rescued = Path(str(exc.value).split("written to ")[1].split(" ")[0])
    assert rescued.is_file() and rescued.parent == tmp_path / "ckpt"
    meta = json.loads(rescued.with_suffix(".json").read_text())
    assert meta["rescued_from"] == str(out) and meta["num_timesteps"] >= 256
    assert not out.exists()


def _pretrain_cfg(tmp_path, **over):
    return tiny(tmp_path, **{"pretrain": {"expert": "greedy", "episodes": 6, "epochs": 3, "batch_size": 32}, **over})


def test_ctrl_c_while_the_expert_plays_keeps_its_episodes_and_resume_goes_on(tmp_path, monkeypatch):
    import gym_gridloc_agents.evaluation.rollout as r

    real, calls = r.rollout, []

    def interrupt_on_the_fourth(*a, **k):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(r, "rollout", interrupt_on_the_fourth)
    cfg = _pretrain_cfg(tmp_path)
    with pytest.raises(TrainingInterrupted, match="warm start interrupted") as exc:
        train(cfg, progress_bar=False)
    meta = json.loads(exc.value.checkpoint.with_suffix(".json").read_text())
    assert meta["warm_start"] == {"done": False, "episodes": 3, "epochs": 0, "rounds": 0}
    with np.load(tmp_path / "ckpt" / "expert.npz") as data:
        assert len(data["lengths"]) == 3
    calls.clear()
    info = train(cfg, progress_bar=False, resume=exc.value.checkpoint)
    assert len(calls) == 3, "only the episodes not yet played are played again"
    assert info["warm_start"] == {"done": True} and info["pretrain"]["episodes"] == 6
    assert (tmp_path / "model.zip").is_file()


def test_ctrl_c_during_cloning_epochs_resumes_at_the_next_epoch(tmp_path, monkeypatch):
    from stable_baselines3.common.policies import ActorCriticPolicy

    real, calls = ActorCriticPolicy.predict_values, []

    def interrupt_in_the_second_epoch(self, *a, **k):
        calls.append(1)
        if len(calls) == 3:  # 6 greedy episodes are under 32 samples: one batch per epoch
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(ActorCriticPolicy, "predict_values", interrupt_in_the_second_epoch)
    cfg = _pretrain_cfg(tmp_path)
    with pytest.raises(TrainingInterrupted) as exc:
        train(cfg, progress_bar=False)
    meta = json.loads(exc.value.checkpoint.with_suffix(".json").read_text())
    assert meta["warm_start"]["epochs"] == 2 and meta["warm_start"]["done"] is False
    monkeypatch.setattr(ActorCriticPolicy, "predict_values", real)
    info = train(cfg, progress_bar=False, resume=exc.value.checkpoint)
    assert info["pretrain"]["resumed_at_epoch"] == 2 and info["warm_start"]["done"] is True


def test_resume_keeps_the_evaluations_and_the_best_model_of_the_interrupted_run(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.train as t
    from stable_baselines3.common.callbacks import BaseCallback

    scores = iter([3.0, 9.0, 9.0, 9.0, 9.0, 9.0])
    import gym_gridloc_agents.training.evaluation as held_out

    monkeypatch.setattr(held_out, "evaluate", lambda model, cfg, episodes: {"mean_steps": next(scores), "accuracy": 0.0, "argmax_accuracy": 0.0})

    class CtrlC(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 300:
                raise KeyboardInterrupt
            return True

    cfg = tiny(tmp_path, total_timesteps=640, eval_freq=128, eval_episodes=2)
    with pytest.raises(TrainingInterrupted) as exc:
        train(cfg, progress_bar=False, callbacks=[CtrlC()])
    first = json.loads(exc.value.checkpoint.with_suffix(".json").read_text())["evaluations"]
    assert [e["mean_steps"] for e in first] == [3.0, 9.0]
    best_before = (tmp_path / "ckpt" / "best.zip").read_bytes()
    info = train(cfg, progress_bar=False, resume=exc.value.checkpoint)
    assert [e["mean_steps"] for e in info["evaluations"]][:2] == [3.0, 9.0]
    assert info["selected_timesteps"] == first[0]["num_timesteps"]
    assert (tmp_path / "ckpt" / "best.zip").read_bytes() == best_before


def test_temporaries_of_a_killed_write_are_recognisable_and_cleaned(tmp_path):
    from gym_gridloc_agents.files import TMP_MARK, atomic_write_json

    stale = tmp_path / f".model.json{TMP_MARK}abc123.json"
    stale.write_text("half")
    atomic_write_json(tmp_path / "model.json", {"a": 1})
    assert not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]


def test_a_metadata_file_that_is_not_a_json_object_is_named(tmp_path):
    from gym_gridloc_agents.files import read_metadata

    (tmp_path / "m.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"m.json: the model's metadata is not readable JSON"):
        read_metadata(tmp_path / "m.zip")
    (tmp_path / "m.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"m.json: the model's metadata must be a JSON object, got list"):
        read_metadata(tmp_path / "m.zip")


@pytest.mark.parametrize("line, message", [
    ("total_timesteps: .inf", "total_timesteps must be a finite number"),
    ("total_timesteps: .nan", "total_timesteps must be a finite number"),
    ("env_kwargs: {foo: 1}", "ColourGrid-v0 has no keyword 'foo' (its keywords: accuracy, kidnap_prob, layout,"),
    ("env_kwargs: {slip: 2}", "ColourGrid-v0 does not build with {'slip': 2}: slip must be a probability in [0, 1], got 2"),
    ("env_id: CartPole-v1", "CartPole-v1 is not a gym_gridloc environment"),
    ("hyperparams: {n_steps: -5}", "hyperparams.n_steps must be at least 1, got -5"),
    ("hyperparams: {batch_size: 0}", "hyperparams.batch_size must be at least 2, got 0"),
    ("hyperparams: {gamma: 1.5}", "hyperparams.gamma must be <= 1"),
    ("policy_kwargs: {net_arch: [64, -1]}", "net_arch must be a list of positive integers"),
    ("policy: MultiInputPolicy", "policy MultiInputPolicy needs Dict observations"),
    ("seed: 99999999999999999999999", "seed must be at least 0 and at most 4294967295"),
])
def test_bad_config_values_get_one_line_and_exit_status_2(tmp_path, capsys, line, message):
    import yaml

    cfg = tiny(tmp_path)
    cfg.update(yaml.safe_load(line))
    path = _write_yaml(tmp_path, cfg)
    assert main(["train", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_dagger_rounds_label_the_students_beliefs_with_the_experts_actions(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.pretrain as p

    seen = []
    real = p.dagger_round

    def spy(model, cfg, round_index, progress=True):
        out = real(model, cfg, round_index, progress)
        seen.append(out)
        return out

    monkeypatch.setattr(p, "dagger_round", spy)
    cfg = _pretrain_cfg(tmp_path, pretrain={"expert": "greedy", "episodes": 4, "epochs": 2, "batch_size": 32,
                                            "dagger_rounds": 2, "dagger_episodes": 3})
    info = train(cfg, progress_bar=False)
    assert len(seen) == 2 and all(len(r) == 3 for r in seen)
    assert info["pretrain"]["dagger_rounds"] == 2
    assert info["pretrain"]["dagger_samples"] == sum(len(e["targets"]) for r in seen for e in r) > 0
    # The labels are what greedy does in those beliefs (its ties broken by its own generator).
    from gym_gridloc_agents.policies import GreedyPolicy

    model = gym_gridloc.colour_grid_model()
    for episode in seen[0]:
        flat = episode["obs"]
        beliefs = flat[:, model.sensor.encoded_size:].reshape(-1, *model.shape)
        values = [GreedyPolicy(model).expected_entropies(b[None].astype(np.float64)) for b in beliefs]
        for v, target in zip(values, episode["targets"]):
            assert target.sum() == pytest.approx(1.0)
            assert np.all(v[target > 0] <= v.min() + 1e-6 * max(1.0, abs(v.min())))


def test_ctrl_c_in_a_dagger_round_resumes_at_that_round(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.pretrain as p

    real, calls = p.dagger_round, []

    def interrupt_second_round(model, cfg, round_index, progress=True):
        calls.append(round_index)
        if round_index == 1 and len(calls) == 2:
            raise KeyboardInterrupt
        return real(model, cfg, round_index, progress)

    monkeypatch.setattr(p, "dagger_round", interrupt_second_round)
    cfg = _pretrain_cfg(tmp_path, pretrain={"expert": "greedy", "episodes": 4, "epochs": 2, "batch_size": 32,
                                            "dagger_rounds": 2, "dagger_episodes": 2})
    with pytest.raises(TrainingInterrupted) as exc:
        train(cfg, progress_bar=False)
    meta = json.loads(exc.value.checkpoint.with_suffix(".json").read_text())
    assert meta["warm_start"] == {"done": False, "episodes": 4, "epochs": 2, "rounds": 1}
    info = train(cfg, progress_bar=False, resume=exc.value.checkpoint)
    assert calls == [0, 1, 1] and info["pretrain"]["resumed_at_round"] == 1 and info["warm_start"] == {"done": True}


def test_a_best_model_newer_than_the_resumed_checkpoint_stays_the_selection(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.train as t
    from stable_baselines3.common.callbacks import BaseCallback

    # Evaluations at 128, 256, 384 score 5, 2, 9; the run dies after 384 but resumes from the
    # checkpoint at 256 (before the evaluation at 384 and... after the best one at 256).
    scores = iter([5.0, 2.0, 9.0, 8.0, 8.0, 8.0, 8.0, 8.0])  # (the resumed run evaluates at 128, its checkpoint's step, too)
    import gym_gridloc_agents.training.evaluation as held_out

    monkeypatch.setattr(held_out, "evaluate", lambda model, cfg, episodes: {"mean_steps": next(scores), "accuracy": 0.0, "argmax_accuracy": 0.0})

    class Crash(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 400:
                raise KeyboardInterrupt
            return True

    cfg = tiny(tmp_path, total_timesteps=640, eval_freq=128, eval_episodes=2, checkpoint_freq=128)
    with pytest.raises(TrainingInterrupted):
        train(cfg, progress_bar=False, callbacks=[Crash()])
    best = json.loads((tmp_path / "ckpt" / "best.json").read_text())
    assert best["mean_steps"] == 2.0
    early = sorted((tmp_path / "ckpt").glob("step_*.zip"))[0]  # an older checkpoint than the best model
    assert json.loads(early.with_suffix(".json").read_text())["num_timesteps"] < best["num_timesteps"]
    info = train(cfg, progress_bar=False, resume=early)
    assert info["selected_timesteps"] == best["num_timesteps"]
    assert json.loads((tmp_path / "ckpt" / "best.json").read_text())["mean_steps"] == 2.0


def test_a_fresh_run_sets_an_old_best_model_aside(tmp_path):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "best.zip").write_bytes(b"old best")
    train(tiny(tmp_path, total_timesteps=256, eval_freq=128, eval_episodes=2), progress_bar=False)
    kept = list(ckpt.glob("best-before-*.zip"))
    assert len(kept) == 1 and kept[0].read_bytes() == b"old best"


def test_warm_start_cache_roundtrip_reads_each_array_once(tmp_path, monkeypatch):
    """The expert cache comes back as written, and loading it reads every stored array once (an
    access per episode decompressed a whole array each time: 2000 DepthMaze episodes took 23 GB)."""
    from gym_gridloc_agents.training import pretrain

    rng = np.random.default_rng(0)
    episodes = [{"obs": {"belief": rng.random((n, 4, 5, 5), dtype=np.float32), "observation": rng.integers(0, 5, n)},
                 "targets": rng.random((n, 3), dtype=np.float32), "returns": rng.random(n), "length": n} for n in (3, 1, 4, 2)]
    path = tmp_path / "expert.npz"
    pretrain._save_cache(path, "k", episodes)
    reads = []
    real = np.lib.npyio.NpzFile.__getitem__
    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", lambda self, key: reads.append(key) or real(self, key))
    back = pretrain._load_cache(path, "k")
    assert len(reads) == len(set(reads))
    assert len(back) == 4 and [e["length"] for e in back] == [3, 1, 4, 2]
    for a, b in zip(episodes, back):
        assert np.array_equal(a["obs"]["belief"], b["obs"]["belief"]) and np.array_equal(a["targets"], b["targets"])
        assert b["obs"]["belief"].base is None  # a copy, not a view keeping the whole array alive
    assert pretrain._load_cache(path, "another key") == []


def test_expert_episodes_are_shared_with_sibling_trainings(tmp_path, monkeypatch):
    """The expert's episodes do not depend on the training seed: a training whose checkpoint
    directory is new reuses a sibling's cache of the same data and plays none again."""
    import gym_gridloc_agents.evaluation.rollout as rollout_module
    from gym_gridloc_agents.training import pretrain
    from gym_gridloc_agents.training.config import load_config

    cfg = load_config("configs/distill_colourgrid.yml")
    cfg["pretrain"].update(expert="greedy", episodes=6, expert_kwargs={})
    first = pretrain.collect_expert(cfg, progress=False, cache=tmp_path / "seed0" / "expert.npz")
    other = dict(cfg, pretrain=dict(cfg["pretrain"], expert="greedy2"))  # another expert: not shared
    pretrain.collect_expert(other, progress=False, cache=tmp_path / "seed9" / "expert.npz")
    calls = []
    original = rollout_module.rollout
    monkeypatch.setattr(rollout_module, "rollout", lambda *a, **k: calls.append(a) or original(*a, **k))
    second = pretrain.collect_expert(cfg, progress=False, cache=tmp_path / "seed1" / "expert.npz")
    assert calls == []
    assert [e["length"] for e in second] == [e["length"] for e in first]
    assert all(np.array_equal(a["targets"], b["targets"]) for a, b in zip(first, second))
    assert (tmp_path / "seed1" / "expert.npz").is_file()
    cfg["pretrain"]["episodes"] = 8  # more than any sibling holds: the rest is played
    third = pretrain.collect_expert(cfg, progress=False, cache=tmp_path / "seed2" / "expert.npz")
    assert len(calls) == 2 and [e["length"] for e in third[:6]] == [e["length"] for e in first]


def test_recurrent_with_previous_action_trains_and_acts_on_it(tmp_path):
    """wrapper.previous_action: the model reads PreviousActionWrapper's observation in training,
    and the benchmark's RecurrentPolicy builds the same one (its own previous action)."""
    from gymnasium import spaces

    from gym_gridloc.wrappers import previous_action_space

    cfg = tiny(tmp_path, algo="recurrent_ppo", wrapper={"belief": False, "previous_action": True},
               policy_kwargs={"lstm_hidden_size": 8, "net_arch": [8]})
    train(cfg, progress_bar=False)
    model = gym_gridloc.colour_grid_model()
    policy = RecurrentPolicy(model, env_id="ColourGrid-v0", path=tmp_path / "model.zip")
    assert policy.previous_action
    assert policy.sb3.observation_space == previous_action_space(model.sensor.observation_space, spaces.Discrete(4))
    seen = []
    real_predict = policy.sb3.predict
    policy.sb3.predict = lambda obs, **kw: (seen.append(np.asarray(obs).copy()), real_predict(obs, **kw))[1]
    policy.reset(seed=0)
    actions = [policy.act(z) for z in (0, 1, 2)]
    assert all(a in range(4) for a in actions)
    np.testing.assert_array_equal(seen[0][4:], np.eye(5)[4])  # episode start: no action yet
    np.testing.assert_array_equal(seen[1][4:], np.eye(5)[actions[0]])
    np.testing.assert_array_equal(seen[2][:4], np.eye(4)[2])
    policy.reset(seed=1)
    policy.act(0)
    np.testing.assert_array_equal(seen[3][4:], np.eye(5)[4])  # forgotten at reset
    # without the option, the model reads the raw readings as before
    cfg = tiny(tmp_path / "raw", algo="recurrent_ppo", policy_kwargs={"lstm_hidden_size": 8, "net_arch": [8]})
    train(cfg, progress_bar=False)
    assert not RecurrentPolicy(model, env_id="ColourGrid-v0", path=tmp_path / "raw" / "model.zip").previous_action


@pytest.mark.parametrize("wrapper, vec_env, match", [
    ({"belief": True, "previous_action": True}, "dummy", "previous_action .* needs wrapper.belief: false"),
    ({"belief": False, "previous_action": True}, "native", "previous_action needs vec_env: dummy"),
    ({"belief": False, "previous_action": 1}, "dummy", "wrapper.previous_action must be true or false"),
])
def test_previous_action_config_errors(tmp_path, wrapper, vec_env, match):
    cfg = tiny(tmp_path, algo="recurrent_ppo", wrapper=wrapper, vec_env=vec_env, policy="MlpLstmPolicy")
    with pytest.raises(ConfigError, match=match):
        validate_config(cfg)
