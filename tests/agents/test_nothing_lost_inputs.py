"""Nothing lost, the values that reach a library: every option, keyword and config value is
checked first (one error naming it), model metadata is read defensively, and learning curves
count seeds and baselines only where they are what they say."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401 - registers the environments
from gym_gridloc_agents.cli import main
from gym_gridloc_agents.policies import POLICY_NAMES, make_policy


def fails(capsys, argv, says, status=2):
    assert main(argv) == status
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "error:" in err and says in err, err
    return err


@pytest.mark.parametrize("name", POLICY_NAMES)
def test_every_policy_refuses_an_unknown_option(name):
    model = gym.make("ColourGrid-v0").unwrapped.model
    with pytest.raises(ValueError, match="takes no option 'bogus'"):
        make_policy(name, model, env_id="ColourGrid-v0", bogus=1)


@pytest.mark.skipif(importlib.util.find_spec("pomdp_py") is None, reason="needs pomdp_py (the planning extra)")
def test_a_fractional_particle_count_is_refused():
    from gym_gridloc.interop import to_pomdp_py

    env = gym.make("ColourGrid-v0")
    env.reset(seed=0)
    pp = to_pomdp_py(env.unwrapped.model, seed=0)
    belief = env.unwrapped.exact_filter.full_belief
    for n in (1.5, 0, -2, "3", True):
        with pytest.raises(ValueError, match="n must be a whole number >= 1"):
            pp.particles(belief, n)
    assert len(pp.particles(belief, 3).particles) == 3 and len(pp.particles(belief, 2.0).particles) == 2


def _config(tmp_path, **over):
    cfg = {"algo": "ppo", "env_id": "ColourGrid-v0", "n_envs": 2, "seed": 1, "total_timesteps": 256,
           "policy_kwargs": {"net_arch": [16]}, "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
           "output": str(tmp_path / "model.zip"), "checkpoint_dir": str(tmp_path / "ckpt")}
    cfg.update(over)
    return cfg


@pytest.mark.parametrize("algo, key", [("ppo", "learning_rate"), ("ppo", "clip_range"), ("ppo", "gamma"), ("ppo", "n_epochs"),
                                       ("ppo", "n_steps"), ("ppo", "gae_lambda"), ("ppo", "normalize_advantage"),
                                       ("dqn", "buffer_size"), ("recurrent_ppo", "batch_size")])
def test_a_null_hyperparameter_is_named_not_handed_to_the_algorithm(tmp_path, algo, key):
    from gym_gridloc_agents.training.config import ConfigError, validate_config

    wrapper = {"belief": False} if algo == "recurrent_ppo" else {"belief": True, "flatten": True}
    with pytest.raises(ConfigError, match=f"hyperparams.{key} must not be null"):
        validate_config(_config(tmp_path, algo=algo, wrapper=wrapper, hyperparams={key: None}))
    validate_config(_config(tmp_path, hyperparams={"target_kl": None}))  # (its default is null)


@pytest.mark.parametrize("algo, hyperparams, says", [
    ("ppo", {"n_steps": 10**9}, r"hyperparams.n_steps x n_envs = 2_000_000_000 rows .* GiB, more than this machine's memory"),
    ("recurrent_ppo", {"n_steps": 10**9}, r"hyperparams.n_steps x n_envs = 2_000_000_000 rows .* GiB"),
    ("dqn", {"buffer_size": 10**11}, r"hyperparams.buffer_size = 100_000_000_000 rows"),
])
def test_buffers_that_cannot_fit_in_memory_are_refused_before_any_allocation(tmp_path, algo, hyperparams, says):
    from gym_gridloc_agents.training.config import ConfigError, validate_config

    wrapper = {"belief": False} if algo == "recurrent_ppo" else {"belief": True, "flatten": True}
    with pytest.raises(ConfigError, match=says):
        validate_config(_config(tmp_path, algo=algo, wrapper=wrapper, hyperparams=hyperparams))


@pytest.mark.parametrize("algo, policy_kwargs, says", [
    ("recurrent_ppo", {"lstm_hidden_size": None}, "policy_kwargs.lstm_hidden_size must be a number, got None"),
    ("recurrent_ppo", {"n_lstm_layers": 0}, "policy_kwargs.n_lstm_layers"),
    ("recurrent_ppo", {"shared_lstm": None}, "policy_kwargs.shared_lstm must be true or false"),
    ("ppo", {"ortho_init": "yes"}, "policy_kwargs.ortho_init must be true or false"),
    ("ppo", {"log_std_init": None}, "policy_kwargs.log_std_init must be a number"),
    ("ppo", {"net_arch": [10**6, 10**6]}, "GiB to train, more than this machine's memory"),
    ("recurrent_ppo", {"lstm_hidden_size": 10**6}, "GiB to train, more than this machine's memory"),
])
def test_policy_values_are_checked_before_the_library_sees_them(tmp_path, algo, policy_kwargs, says):
    from gym_gridloc_agents.training.config import ConfigError, validate_config

    wrapper = {"belief": False} if algo == "recurrent_ppo" else {"belief": True, "flatten": True}
    with pytest.raises(ConfigError, match=re.escape(says)):
        validate_config(_config(tmp_path, algo=algo, wrapper=wrapper, policy_kwargs=policy_kwargs))


def test_a_reading_cell_extractor_must_have_the_sensors_height_and_width(tmp_path):
    from gym_gridloc_agents.training.config import ConfigError, validate_config

    base = _config(tmp_path, algo="recurrent_ppo", env_id="RingSensor8x8-v0", wrapper={"belief": False}, hyperparams={})
    for env_kwargs, sides in (({}, {"height": 4, "width": 16}), ({"size": (4, 16)}, {"height": 8, "width": 8}),
                              ({"size": (4, 16)}, {})):
        cfg = {**base, "env_kwargs": env_kwargs,
               "policy_kwargs": {"features_extractor": "reading_cell", "features_extractor_kwargs": sides}}
        with pytest.raises(ConfigError, match=r"reading_cell .* of a \d+x\d+ grid.* on a \d+x\d+ grid"):
            validate_config(cfg)
    for env_kwargs, sides in (({}, {}), ({"size": (4, 16)}, {"height": 4, "width": 16})):
        validate_config({**base, "env_kwargs": env_kwargs,
                         "policy_kwargs": {"features_extractor": "reading_cell", "features_extractor_kwargs": sides}})


@pytest.mark.parametrize("wrapper, policy", [({"belief": True, "flatten": False}, "MultiInputLstmPolicy"),
                                             ({"belief": True, "flatten": True}, "MlpLstmPolicy")])
def test_a_recurrent_policy_on_the_belief_is_refused_before_training(tmp_path, wrapper, policy):
    from gym_gridloc_agents.training.config import ConfigError
    from gym_gridloc_agents.training.train import train

    cfg = _config(tmp_path, algo="recurrent_ppo", wrapper=wrapper, policy=policy, eval_freq=128, eval_episodes=2,
                  policy_kwargs={"lstm_hidden_size": 8, "net_arch": [8]})
    with pytest.raises(ConfigError, match="recurrent_ppo reads the raw readings"):
        train(cfg, progress_bar=False)
    assert not (tmp_path / "ckpt").exists() and not (tmp_path / "model.zip").exists()


def test_ctrl_c_in_the_final_evaluation_saves_an_interrupted_checkpoint(tmp_path, monkeypatch, capsys):
    import yaml

    import gym_gridloc_agents.training.train as t

    real = t.record_evaluation

    def ctrl_c_at_the_end(model, cfg, *args, **kwargs):
        if int(model.num_timesteps) >= cfg["total_timesteps"]:
            raise KeyboardInterrupt
        return real(model, cfg, *args, **kwargs)

    monkeypatch.setattr(t, "record_evaluation", ctrl_c_at_the_end)
    cfg = _config(tmp_path, eval_freq=192, eval_episodes=2)  # (at 192 during training; at 256 after it)
    with pytest.raises(t.TrainingInterrupted, match="final evaluation interrupted at 256 steps") as exc:
        t.train(cfg, progress_bar=False)
    ckpt = exc.value.checkpoint
    assert ckpt.name == "interrupted_step_256.zip" and ckpt.is_file()
    assert json.loads(ckpt.with_suffix(".json").read_text())["interrupted"] is True
    assert not (tmp_path / "model.zip").exists()
    (tmp_path / "cfg.yml").write_text(yaml.safe_dump({**cfg, "output": str(tmp_path / "cli.zip"),
                                                      "checkpoint_dir": str(tmp_path / "cli")}))
    assert main(["train", str(tmp_path / "cfg.yml"), "--no-progress"]) == 130
    err = capsys.readouterr().err
    assert "final evaluation interrupted" in err and "--resume" in err and "Traceback" not in err
    assert (tmp_path / "cli" / "interrupted_step_256.zip").is_file()
    monkeypatch.setattr(t, "record_evaluation", real)  # and the resumed run finishes with the model
    info = t.train(cfg, progress_bar=False, resume=ckpt)
    assert info["num_timesteps"] == 256 and (tmp_path / "model.zip").is_file()


def test_resume_refuses_another_schedule(tmp_path):
    from gym_gridloc_agents.training.train import train

    cfg = _config(tmp_path, hyperparams={"n_steps": 64, "batch_size": 64, "n_epochs": 1, "learning_rate": 1e-3},
                  schedule={"learning_rate": 1e-4})
    train(cfg, progress_bar=False)
    other = {**cfg, "schedule": {"learning_rate": 5e-4}, "output": str(tmp_path / "other.zip")}
    with pytest.raises(ValueError, match=r"trained with schedule \{\"learning_rate\": 0.0001\}.*asks for \{\"learning_rate\": 0.0005\}"):
        train(other, progress_bar=False, resume=tmp_path / "model.zip")
    assert not (tmp_path / "other.zip").exists()


# -- model metadata and learning curves --------------------------------------------------------------
def _models(directory, metas):
    """Model files (a few bytes: only their metadata is read) with these metadata beside them."""
    directory.mkdir(parents=True, exist_ok=True)
    for name, meta in metas.items():
        (directory / f"{name}.zip").write_bytes(b"model")
        (directory / f"{name}.json").write_text(meta if isinstance(meta, str) else json.dumps(meta))
    return directory


def _run(seed, env_kwargs=None, **config):
    evals = [{"num_timesteps": s, "mean_steps": 9.0 - s / 1000 + 0.1 * seed, "wall_time_seconds": s / 100} for s in (1000, 2000, 3000)]
    cfg = {"algo": "ppo", "env_id": "WindyMaze-v0", "env_kwargs": env_kwargs or {}, "seed": seed,
           "output": f"m/seed{seed}.zip", "hyperparams": {"learning_rate": 3e-4}, **config}
    return {"algo": "ppo", "env_id": "WindyMaze-v0", "env_kwargs": env_kwargs or {}, "seed": seed, "pretrain": None,
            "evaluations": evals, "config": cfg}


def test_model_metadata_is_read_defensively(tmp_path, capsys):
    from gym_gridloc_agents.files import read_metadata
    from gym_gridloc_agents.loading import expand_models

    deep = _models(tmp_path / "deep", {"a": "[" * 100_000 + "]" * 100_000, "b": {"seed": 2}})
    with pytest.raises(ValueError, match="a.json: the model's metadata is not readable JSON \\(nested more than 50"):
        read_metadata(deep / "a.zip")
    with pytest.raises(ValueError, match="nested more than 50"):
        expand_models([str(deep)])
    fails(capsys, ["plot", "--curves", str(deep / "a.zip"), "--out", str(tmp_path / "c.png")], "nested more than 50")
    listed = _models(tmp_path / "listed", {"a": {"seed": [1]}, "b": {"seed": [1]}})
    with pytest.raises(ValueError, match=r"a.json: the model's metadata has seed = \[1\], not a whole number or null"):
        expand_models([str(listed)])
    fails(capsys, [*["bench", "--env", "ColourGrid-v0", "--episodes", "2", "--no-progress"], "--policies", "ppo",
                   "--ppo-model", str(listed)], "seed = [1], not a whole number or null")
    for meta, says in (({"evaluations": [{"num_timesteps": None, "mean_steps": 3.0}]}, "evaluations[0].num_timesteps = null"),
                       ({"evaluations": [{"num_timesteps": 10, "mean_steps": "3"}]}, "evaluations[0].mean_steps = \"3\", not a number"),
                       ({"evaluations": {"num_timesteps": 10}}, "evaluations = {"), ({"env_kwargs": [1]}, "env_kwargs = [1], not an object"),
                       ({"seed": True}, "seed = true"), ({"num_timesteps": 1.5}, "num_timesteps = 1.5")):
        bad = _models(tmp_path / "bad", {"m": {**_run(0), **meta}})
        with pytest.raises(ValueError, match="m.json: the model's metadata has " + re.escape(says)):
            read_metadata(bad / "m.zip")
        fails(capsys, ["plot", "--curves", str(bad / "m.zip"), "--out", str(tmp_path / "c.png")], says)
    assert not (tmp_path / "c.png").exists()


def test_runs_are_seeds_only_of_one_configuration(tmp_path, capsys):
    from gym_gridloc_agents.evaluation import curves

    ok = _models(tmp_path / "ok", {"seed0": _run(0), "seed1": _run(1, output="elsewhere.zip", description="x")})
    assert [r["seed"] for r in curves.load_runs(ok)] == [0, 1]
    same_seed = _models(tmp_path / "same", {"a": _run(3), "b": _run(3, hyperparams={"learning_rate": 1e-3})})
    ckpts = _models(tmp_path / "ckpt", {"step_1000": _run(5), "step_2000": _run(5), "best": _run(5)})
    other = _models(tmp_path / "other", {"a": _run(0), "b": _run(1, hyperparams={"learning_rate": 1e-3})})
    for runs, says in ((same_seed, "were trained with the same seed 3"), (ckpts, "were trained with the same seed 5"),
                       (other, "are two configurations (they differ in hyperparams)")):
        with pytest.raises(ValueError, match=re.escape(says)):
            curves.load_runs(runs)
        fails(capsys, ["plot", "--curves", str(runs), "--out", str(tmp_path / "c.png")], says)
    assert not (tmp_path / "c.png").exists()


def test_baselines_of_another_task_are_refused(tmp_path, capsys):
    from gym_gridloc_agents.evaluation import curves

    random9 = {"size": 9, "new_map_each_reset": True}
    runs = _models(tmp_path / "r9", {"seed0": _run(0, random9), "seed1": _run(1, random9)})
    bench = tmp_path / "bench.json"
    rows = [{"env": "WindyMaze-v0", "policy": p, "mean_steps": v, "episodes": 10, "success_rate": 1.0, "localised_curve": [0.0]}
            for p, v in (("greedy2", 5.0), ("random", 11.0))]
    bench.write_text(json.dumps(rows))
    assert curves.baselines(rows, "WindyMaze-v0", "mean_steps", True, random9) == {}
    assert curves.baselines(rows, "WindyMaze-v0", "mean_steps", True, {}) == {"greedy2": 5.0, "random": 11.0}
    fails(capsys, ["plot", "--curves", str(runs), "--baselines", str(bench), "--out", str(tmp_path / "c.png")],
          "rows are of other tasks than the curves'")
    assert not (tmp_path / "c.png").exists()
    mine = [{**r, "env_kwargs": dict(random9), "mean_steps": r["mean_steps"] + 1} for r in rows]
    bench.write_text(json.dumps(rows + mine))
    js = tmp_path / "c.json"
    assert main(["plot", "--curves", str(runs), "--baselines", str(bench), "--out", str(tmp_path / "c.png"),
                 "--curves-json", str(js)]) == 0
    assert json.loads(js.read_text())["baselines"] == {"greedy2": 6.0, "random": 12.0}


@pytest.mark.skipif(any(importlib.util.find_spec(m) is None for m in ("ray", "optuna")),
                    reason="gridloc sweep needs the sweep extra (ray[tune], optuna)")
def test_grid_values_that_make_one_configuration_are_refused(tmp_path, capsys, monkeypatch):
    import yaml

    monkeypatch.chdir(tmp_path)
    (tmp_path / "cfg.yml").write_text(yaml.safe_dump(_config(tmp_path)))
    for grid, says in (("description=1,'1'", "description must be text (quote a number: '1'), got 1"),
                       ("hyperparams.n_epochs=1,1.0", "n_epochs=1 and n_epochs=1.0 are one configuration"),
                       ("description=1", "description must be text")):
        fails(capsys, ["sweep", "cfg.yml", "--seeds", "1", "--grid", grid, "--output", str(tmp_path / "sw")], says)
    assert not (tmp_path / "sw").exists()
    from gym_gridloc_agents.sweeps.sweep_spec import checked_configs, prepare

    spec = prepare("cfg.yml", seeds=1, grid=["description='1','2'"], output=str(tmp_path / "sw"))
    assert [c["description"] for c in checked_configs(spec)] == ["1", "2"]


# -- outputs --------------------------------------------------------------------------------------------
BENCH = ["bench", "--env", "ColourGrid-v0", "--episodes", "2", "--no-progress", "--policies", "random"]


def test_an_output_that_is_not_a_regular_file_is_refused(tmp_path, capsys):
    import os
    import stat

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    fails(capsys, [*BENCH, "--json", str(fifo)], "is not a regular file")
    fails(capsys, [*BENCH, "--json", str(fifo), "--force"], "is not a regular file")
    fails(capsys, ["bound", "ColourGrid-v0", "--depth", "1", "--json", str(fifo), "--force"], "is not a regular file")
    fails(capsys, [*BENCH, "--markdown", str(fifo)], "is not a regular file")
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    if os.geteuid() == 0:  # a character device (the numbers of /dev/null), made here: never /dev/null itself
        device = tmp_path / "null"
        os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        fails(capsys, [*BENCH, "--json", str(device), "--force"], "is not a regular file")
        assert stat.S_ISCHR(device.lstat().st_mode)


def test_a_file_that_appears_during_the_run_is_judged_again_at_the_replace(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.evaluation.bench as b

    real = b.run_benchmark
    out = tmp_path / "X.json"

    def run(*a, **k):
        rows = real(*a, **k)
        (tmp_path / "X.zip").write_bytes(b"PK a model")  # a training saved X.zip and its metadata meanwhile
        out.write_text(json.dumps({"algo": "ppo", "env_id": "ColourGrid-v0", "seed": 0}))
        return rows

    monkeypatch.setattr(b, "run_benchmark", run)
    err = fails(capsys, [*BENCH, "--json", str(out)], "is the metadata file of the model")
    assert "(it changed while the command ran); written to" in err
    assert json.loads(out.read_text())["algo"] == "ppo"
    rescued = Path(err.rsplit("written to ", 1)[1].split(" instead")[0])
    assert rescued.parent == tmp_path and [r["policy"] for r in json.loads(rescued.read_text())] == ["random"]


def test_an_update_target_that_became_unreadable_keeps_the_rows_beside_it(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.evaluation.bench as b

    out = tmp_path / "r.json"
    assert main([*BENCH, "--json", str(out)]) == 0
    capsys.readouterr()
    real = b.run_benchmark

    def run(*a, **k):
        rows = real(*a, **k)
        out.write_text("[{ cut short")  # the target is damaged while the rows are computed
        return rows

    monkeypatch.setattr(b, "run_benchmark", run)
    err = fails(capsys, [*BENCH[:-1], "greedy", "--json", str(out), "--update"], "(it changed during the run); written to")
    assert out.read_text() == "[{ cut short"
    rescued = Path(err.rsplit("written to ", 1)[1].split(" instead")[0])
    assert rescued.parent == tmp_path and [r["policy"] for r in json.loads(rescued.read_text())] == ["greedy"]


def test_a_depth_maze_layout_too_large_is_one_line_in_bench(tmp_path, capsys):
    rows = ["#" * 603] + ["#" + "O" * 601 + "#"] * 601 + ["#" * 603]
    (tmp_path / "big.txt").write_text("\n".join(rows) + "\n")
    fails(capsys, ["bench", "--env", "DepthMaze-v0", "--policies", "random", "--episodes", "2", "--no-progress",
                   "--env-kwarg", f"layout={tmp_path / 'big.txt'}"], "layout is a 603x603 maze; a DepthMaze side is at most 201")


def test_the_shipped_curves_keep_their_baselines():
    """A benchmark of held-out test maps is the task of a training on maps redrawn at each reset."""
    from gym_gridloc_agents.evaluation import curves
    from gym_gridloc_agents.evaluation.report import read_rows

    root = Path(__file__).resolve().parents[2]
    shipped = sorted((root / "results").glob("curves_*.json"))
    assert len(shipped) >= 4
    for path in shipped:
        data = json.loads(path.read_text())
        c = data["curves"][0]
        rows = read_rows(root / data["baselines_source"])
        assert curves.baselines(rows, c["env_id"], c["metric"], c["lower_is_better"], c["env_kwargs"]) == data["baselines"], path
    fixed9 = {"size": 9}  # one generated 9x9 map: not the task of the held-out maps' rows
    rows = [{"env": "WindyMaze-v0", "policy": "greedy2", "mean_steps": 5.0, "env_kwargs": {"size": 9}, "test_set": True}]
    assert curves.baselines(rows, "WindyMaze-v0", "mean_steps", True, fixed9) == {}
    assert curves.baselines(rows, "WindyMaze-v0", "mean_steps", True, {**fixed9, "new_map_each_reset": True}) == {"greedy2": 5.0}
