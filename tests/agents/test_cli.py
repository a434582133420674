"""The ``gridloc`` command's first hour: --version, help texts that list what they take, readable
output, "did you mean" for mistyped names, and no file rewritten unasked."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

import gym_gridloc
from gym_gridloc.core.validation import did_you_mean, unknown_names
from gym_gridloc_agents.cli import build_parser, main
from gym_gridloc_agents.evaluation.bench import BENCH_ENV_IDS
from gym_gridloc_agents.policies import POLICY_NAMES

ROOT = Path(__file__).resolve().parents[2]


def help_text(capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([*argv, "--help"])
    assert exc.value.code == 0
    return " ".join(capsys.readouterr().out.split())


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"gridloc (gym_gridloc {gym_gridloc.__version__})"


def test_bench_help_lists_the_policies_and_the_environments_of_all(capsys):
    text = help_text(capsys, "bench")
    assert "three" not in text
    for name in POLICY_NAMES:
        assert name in text, name
    assert f"the {len(BENCH_ENV_IDS)} fixed-map environments, {', '.join(BENCH_ENV_IDS)}" in text
    assert all(e in text for e in gym_gridloc.ENV_IDS)


def test_subcommands_describe_themselves_and_render_says_its_defaults(capsys):
    for command in ("train", "bench", "render", "sweep", "bound", "plot"):
        text = help_text(capsys, command)
        usage, _, rest = text.partition(" options: ")
        assert len(usage.split("]")[-1].strip()) > 20, command  # a description after the usage lines
    text = help_text(capsys, "render")
    for option in ("--env", "--seed", "--frames", "--shading", "--out", "--gif"):
        after = text.split(option + " ", 2)[-1].split(" --")[0]
        assert "default" in after, option


def test_bound_prints_a_readable_line_and_json_only_with_json(tmp_path, capsys):
    assert main(["bound", "ColourGrid-v0", "--depth", "1"]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines() == [out.strip()] and out.startswith("no policy localises ColourGrid-v0 in fewer than")
    assert "{" not in out and " W " not in err and "first reading 1 of" in err
    js = tmp_path / "b.json"
    assert main(["bound", "ColourGrid-v0", "--depth", "1", "--json", str(js)]) == 0
    assert {"bound", "per_reading", "reading_probs"} <= set(json.loads(js.read_text()))


def test_one_seed_is_one_seed():
    from gym_gridloc_agents.evaluation.curves import legend_label
    from gym_gridloc_agents.sweeps.sweep_results import config_table

    assert legend_label({"label": "ppo", "seeds": [0]}) == "ppo (1 seed)"
    assert legend_label({"label": "ppo", "seeds": [0, 1, 2]}) == "ppo (IQM of 3 seeds)"
    agg = {k: {"mean": 1.0, "iqm": 1.0, "ci95": [1.0, 1.0], "n": 1} for k in ("mean_steps", "accuracy", "argmax_accuracy", "score")}
    seed = {"seed": 0, "status": "done", "num_timesteps": 1, "selected_timesteps": 1, "mean_steps": 1.0, "accuracy": 1.0,
            "argmax_accuracy": 1.0, "score": 1.0}
    table = config_table({"label": "c", "overrides": {}, "score": "mean_steps", "evaluation": "e", "seeds": [seed],
                          "aggregate": agg, "median_seed": 0, "median_model": "m.zip", "complete": True})
    assert "(1 seed)" in table and "1 seeds" not in table


# -- did you mean ---------------------------------------------------------------------------------------
def test_did_you_mean_names_the_closest_allowed_name():
    assert did_you_mean("lerning_rate", ["gamma", "learning_rate"]) == " (did you mean 'learning_rate'?)"
    assert did_you_mean("zzz", ["gamma", "learning_rate"]) == ""
    assert unknown_names(["slipp", "qq"], ["slip", "accuracy"]) == "'slipp' (did you mean 'slip'?), 'qq'"


@pytest.mark.parametrize("argv, says", [
    (["bench", "--env", "ColourGrid-v0", "--policies", "random", "--env-kwarg", "slipp=0.2"], "'slipp' (did you mean 'slip'?)"),
    (["bench", "--env", "ColourGrid-v0", "--policies", "random,expectimax", "--option", "expectimax.dept=2"],
     "'dept' (did you mean 'depth'?)"),
    (["bench", "--env", "ColourGrid-v0", "--policies", "random,expectimax", "--option", "expectimx.depth=2"],
     "'expectimx' (did you mean 'expectimax'?)"),
    (["bench", "--env", "ColourGrid-v0", "--policies", "randm"], "'randm' (did you mean 'random'?)"),
    (["bound", "ColourGrid-v0", "--env-kwarg", "acuracy=0.9"], "'acuracy' (did you mean 'accuracy'?)"),
])
def test_a_mistyped_name_gets_a_did_you_mean(argv, says, capsys):
    assert main([*argv, "--episodes", "1"] if argv[0] == "bench" else argv) == 2
    assert says in capsys.readouterr().err


def test_a_mistyped_config_key_gets_a_did_you_mean(tmp_path, capsys):
    cfg = {"algo": "ppo", "env_id": "ColourGrid-v0", "total_timesteps": 64, "hyperparams": {"lerning_rate": 1e-3},
           "output": str(tmp_path / "m.zip")}
    (tmp_path / "c.yml").write_text(yaml.safe_dump(cfg))
    assert main(["train", str(tmp_path / "c.yml")]) == 2
    assert "'lerning_rate' (did you mean 'learning_rate'?)" in capsys.readouterr().err
    cfg = {**cfg, "hyperparams": {}, "totl_timesteps": 64}
    (tmp_path / "c.yml").write_text(yaml.safe_dump(cfg))
    assert main(["train", str(tmp_path / "c.yml")]) == 2
    assert "'totl_timesteps' (did you mean 'total_timesteps'?)" in capsys.readouterr().err


# -- plot writes what it is asked to, one panel per environment -----------------------------------------
def test_plot_without_arguments_draws_nothing_and_says_what_to_pass(tmp_path, monkeypatch, capsys):
    (tmp_path / "results").mkdir()
    shutil.copy(ROOT / "results" / "bench.json", tmp_path / "results" / "bench.json")
    monkeypatch.chdir(tmp_path)
    assert main(["plot"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gridloc plot: error: name what to draw") and "--training" in err and "--curves" in err
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["bench.json"]


def test_plot_training_gives_each_environment_its_panel(tmp_path, capsys):
    models = []
    for name, env_id, kwargs in [("a", "WindyMaze-v0", {}), ("b", "ColourGrid-v0", {}), ("c", "WindyMaze-v0", {})]:
        (tmp_path / f"{name}.zip").write_bytes(b"")
        meta = {"algo": "ppo", "env_id": env_id, "env_kwargs": kwargs, "selected_timesteps": 0,
                "evaluations": [{"num_timesteps": t, "accuracy": 0.0, "mean_steps": 5.0 - t / 1000} for t in (0, 500)]}
        (tmp_path / f"{name}.json").write_text(json.dumps(meta))
        models.append(str(tmp_path / f"{name}.zip"))
    out = tmp_path / "t.png"
    assert main(["plot", "--training", *models, "--out", str(out)]) == 0
    assert "one panel per environment: WindyMaze-v0; ColourGrid-v0" in capsys.readouterr().out
    from PIL import Image

    with Image.open(out) as im:
        two = im.size[0]
    assert main(["plot", "--training", models[0], models[2], "--out", str(out)]) == 0
    assert "panel" not in capsys.readouterr().out
    with Image.open(out) as im:
        assert im.size[0] * 1.5 < two  # one panel


# -- sweep and train options --------------------------------------------------------------------------------
def test_sweep_quiets_ray_tunes_tables_unless_verbose(tmp_path, monkeypatch, capsys):
    pytest.importorskip("ray")
    import gym_gridloc_agents.sweeps.sweep as sweep

    seen = []
    summary = {"output": str(tmp_path), "statuses": {}, "pending": 0, "best": {"model": "m.zip"}}
    monkeypatch.setattr(sweep, "prepare", lambda *a, **k: {"command": "gridloc sweep"})
    monkeypatch.setattr(sweep, "run", lambda spec, **k: seen.append(k["verbose"]) or summary)
    monkeypatch.setattr(sweep, "summary_table", lambda s: "table")
    cfg = tmp_path / "c.yml"
    cfg.write_text("algo: ppo\n")
    assert main(["sweep", str(cfg)]) == 0
    assert main(["sweep", str(cfg), "--verbose"]) == 0
    assert seen == [0, 1]


def test_pretrain_episodes_scales_the_warm_start(tmp_path, monkeypatch, capsys):
    import gym_gridloc_agents.training.train as t
    from gym_gridloc_agents.training.config import load_config
    from gym_gridloc_agents.training.pretrain import with_episodes

    cfg = load_config(ROOT / "configs" / "distill_windymaze.yml")
    quick = with_episodes(cfg, 50)
    assert quick["pretrain"]["episodes"] == 50 and cfg["pretrain"]["episodes"] == 30000
    assert quick["pretrain"]["dagger_episodes"] == round(2500 * 50 / 30000) == 4
    assert with_episodes(cfg, 1)["pretrain"]["dagger_episodes"] == 1  # at least one
    got = []
    monkeypatch.setattr(t, "train", lambda config, **k: got.append((config, k)) or {
        "config": {"output": "m.zip"}, "num_timesteps": 1, "wall_time_seconds": 0.0})
    assert main(["train", str(ROOT / "configs" / "distill_windymaze.yml"), "--pretrain-episodes", "50", "--timesteps", "256"]) == 0
    (config, kwargs), = got
    assert config["pretrain"]["episodes"] == 50 and config["pretrain"]["dagger_episodes"] == 4
    assert kwargs["total_timesteps"] == 256
    no_warm = {"algo": "ppo", "env_id": "ColourGrid-v0", "total_timesteps": 64, "output": str(tmp_path / "m.zip")}
    (tmp_path / "c.yml").write_text(yaml.safe_dump(no_warm))
    assert main(["train", str(tmp_path / "c.yml"), "--pretrain-episodes", "5"]) == 2
    assert "no warm start" in capsys.readouterr().err
