"""Nothing lost: one test per class of hostile input (several inputs each)."""

from __future__ import annotations

import json
import select
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gym_gridloc_agents.cli import main

MODEL = Path(__file__).resolve().parents[2] / "agents" / "gym_gridloc_agents" / "models" / "ColourGrid-v0-distilled.zip"
BENCH = ["bench", "--env", "ColourGrid-v0", "--episodes", "2", "--no-progress"]


def fails(capsys, argv, says):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "error:" in err and says in err, err
    return err


# -- 1. outputs never replace finished work ------------------------------------------------------------
def test_outputs_that_would_replace_other_work_are_refused_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copy(MODEL, tmp_path / "M.zip")
    rows = tmp_path / "rows.json"
    assert main([*BENCH, "--policies", "random", "--json", str(rows)]) == 0
    kept = rows.read_bytes()
    capsys.readouterr()
    fails(capsys, [*BENCH, "--policies", "random", "--json", "X", "--plot", "X"], "also the results JSON")
    fails(capsys, [*BENCH, "--policies", "random", "--json", "a.json", "--plot", "p.png", "--frontier", "p.png"], "also")
    fails(capsys, [*BENCH, "--policies", "random", "--json", "M.json"], "metadata file of the model")
    fails(capsys, [*BENCH, "--policies", "random", "--json", str(rows)], "--update or --force")
    fails(capsys, [*BENCH, "--policies", "random", "--plot", "M.zip"], "holds model")
    fails(capsys, ["bound", "ColourGrid-v0", "--depth", "1", "--json", str(rows)], "holds bench results")
    fails(capsys, ["plot", "--training", "M.zip", "--out", "M.zip"], "input of this command")
    (tmp_path / "notes.txt").write_text("my notes")
    fails(capsys, [*BENCH, "--policies", "random", "--json", "notes.txt"], "another kind")
    assert rows.read_bytes() == kept and (tmp_path / "notes.txt").read_text() == "my notes"
    assert not (tmp_path / "X").exists() and not (tmp_path / "M.json").exists()
    # --force replaces results of the same kind; --all puts its table and figures beside its JSON
    assert main([*BENCH, "--policies", "random", "--json", str(rows), "--force"]) == 0
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "bench_table.json").write_text("precious")
    from gym_gridloc_agents.evaluation import bench_command

    monkeypatch.setattr(bench_command, "RESULTS", tmp_path / "results")
    import gym_gridloc_agents.evaluation.bench as b
    monkeypatch.setattr(b, "BENCH_ENV_IDS", ("ColourGrid-v0",))
    assert main(["bench", "--all", "--policies", "random", "--episodes", "2", "--no-progress",
                 "--json", str(tmp_path / "else" / "e.json")]) == 0
    assert (tmp_path / "results" / "bench_table.json").read_text() == "precious"
    assert (tmp_path / "else" / "e_table.json").is_file() and (tmp_path / "else" / "bench_ColourGrid-v0.png").is_file()
    assert not (tmp_path / "bench_ColourGrid-v0.png").exists()


def test_sweep_output_with_unrelated_files_is_refused(tmp_path):
    from gym_gridloc_agents.sweeps.sweep import SweepError, run

    for name in ("best.zip", "summary.md", "results", "models"):
        out = tmp_path / name.replace(".", "_")
        out.mkdir()
        (out / name).mkdir() if "." not in name else (out / name).write_text("someone's")
        with pytest.raises(SweepError, match=name.replace(".", r"\.")):
            run({"output": str(out), "search": None}, cpus=1)
        assert not (out / "sweep.json").exists()


def test_train_outputs_never_replace_its_inputs_or_its_checkpoints(tmp_path, capsys, monkeypatch):
    """train judges its model and metadata with the shared checker: refused before any work, --force or not."""
    from tests.agents.test_train import _write_yaml, tiny

    monkeypatch.chdir(tmp_path)
    cfg = tiny(tmp_path)
    conf = tmp_path / "model.json"  # a JSON config beside the output: the model's metadata would replace it
    conf.write_text(json.dumps(cfg))
    yml = _write_yaml(tmp_path, cfg)
    (tmp_path / "old.zip").write_bytes(b"PK\x03\x04 a checkpoint")
    (tmp_path / "old.json").write_text(json.dumps({"algo": "ppo", "env_id": "ColourGrid-v0", "num_timesteps": 64}))
    kept = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for force in ([], ["--force"]):
        fails(capsys, ["train", str(conf), "--no-progress", *force], "model.json is an input of this command")
        fails(capsys, ["train", str(yml), "--resume", "old.zip", "--output", "old.zip", *force], "old.zip is an input of this command")
        for name in ("best.zip", "step_64.zip", "interrupted_step_70.zip"):
            fails(capsys, ["train", str(yml), "--output", str(tmp_path / "ckpt" / name), *force], "the name of a checkpoint")
        fails(capsys, ["train", str(yml), "--tensorboard", str(tmp_path / "model.json"), *force],
              "TensorBoard directory")
    with pytest.raises(OSError, match="checkpoint directory .*model.zip is also the model"):
        from gym_gridloc_agents.training.train import train

        train(tiny(tmp_path, checkpoint_dir=str(tmp_path / "model.zip")), progress_bar=False, force=True)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == kept, "nothing may be written before the outputs are checked"


def test_a_file_that_appears_during_training_is_kept_and_the_model_rescued(tmp_path):
    """The final write is checked again, by the same checker: with --force an existing model would be
    replaced, but a file of another kind that appeared meanwhile is kept and the model saved beside it."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tests.agents.test_train import tiny

    from gym_gridloc_agents.files import OutputError
    from gym_gridloc_agents.training.train import train

    out = tmp_path / "model.zip"

    class Appear(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 64 and not out.exists():
                out.write_text("someone's notes")
            return True

    with pytest.raises(OutputError, match=r"at the end of training, the model \S+model.zip exists and holds a file of another "
                                          r"kind, not model: .*; written to (\S+) instead") as exc:
        train(tiny(tmp_path, total_timesteps=128), progress_bar=False, force=True, callbacks=[Appear()])
    assert out.read_text() == "someone's notes"
    rescued = Path(str(exc.value).split("written to ")[1].split(" ")[0])
    assert rescued.parent == tmp_path / "ckpt" and json.loads(rescued.with_suffix(".json").read_text())["rescued_from"] == str(out)


# -- 2. interruptions and late checks lose no finished row -----------------------------------------------
def test_ctrl_c_in_a_later_policy_writes_the_finished_rows(tmp_path, capsys, monkeypatch):
    import gym_gridloc_agents.evaluation.bench as b

    real = b.simulate

    def sim(task, *a, **k):
        if task.policy == "greedy":
            raise KeyboardInterrupt
        return real(task, *a, **k)

    monkeypatch.setattr(b, "simulate", sim)
    out = tmp_path / "r.json"
    assert main([*BENCH, "--policies", "random,greedy", "--json", str(out)]) == 130
    err = capsys.readouterr().err
    assert "interrupted after 1 of 2 rows" in err and "Traceback" not in err
    assert [r["policy"] for r in json.loads(out.read_text())] == ["random"]


@pytest.mark.parametrize("argv, says", [
    (["--env", "DepthMaze-v0", "--policies", "random,optimal", "--env-kwarg", "p_move_fail=0.1"], "not deterministic"),
    (["--env", "ColourGrid-v0", "--policies", "random,expectimax", "--option", "expectimax.bogus=1"], "bogus"),
    (["--env", "ColourGrid-v0", "--policies", "random,greedy", "--option", "greedy.depth=3"], "takes no option"),
])
def test_every_policy_and_option_is_built_before_the_first_episode(capsys, monkeypatch, argv, says):
    import gym_gridloc_agents.evaluation.bench as b

    monkeypatch.setattr(b, "simulate", lambda *a, **k: pytest.fail("an episode ran before every policy was checked"))
    fails(capsys, ["bench", *argv, "--episodes", "2", "--no-progress"], says)


def test_concurrent_updates_merge_under_a_lock(tmp_path, capsys, monkeypatch):
    """The second --update finishes while the first runs: the first re-reads the file under the lock."""
    import gym_gridloc_agents.evaluation.bench as b

    out = tmp_path / "r.json"
    real = b.run_benchmark
    calls = []

    def run(*a, **k):
        rows = real(*a, **k)
        if not calls:  # another process's --update lands while this one runs
            calls.append(1)
            assert main([*BENCH, "--policies", "greedy", "--json", str(out), "--update"]) == 0
        return rows

    monkeypatch.setattr(b, "run_benchmark", run)
    assert main([*BENCH, "--policies", "random", "--json", str(out), "--update"]) == 0
    assert sorted(r["policy"] for r in json.loads(out.read_text())) == ["greedy", "random"]


# -- 3. no silently wrong result ---------------------------------------------------------------------------
@pytest.mark.parametrize("argv, says", [
    (["--env", "DepthMaze-v0", "--episode-length", "150"], "max_episode_steps"),
    (["--env", "DepthMaze-v0", "--size", "7", "--test-set", "--env-kwarg", "map_seed=3"], "map_seed"),
    (["--env", "ColourGrid-v0", "--size", "5", "--test-set", "--env-kwarg", "obstacle_density=0.3"], "obstacle_density"),
    (["--env", "ColourGrid-v0", "--env-kwarg", "size=[5, 6]", "--test-set"], "square"),
    (["--env", "ColourGrid-v0", "--ppo-model", str(MODEL)], "not among the benchmarked"),
])
def test_bench_refuses_what_its_row_would_misreport(capsys, argv, says):
    fails(capsys, ["bench", *argv, "--policies", "random", "--episodes", "2", "--no-progress"], says)


def test_a_checkpoint_directory_is_not_several_seeds(tmp_path):
    from gym_gridloc_agents.loading import expand_models

    for name in ("step_128.zip", "step_256.zip", "best.zip"):
        shutil.copy(MODEL, tmp_path / name)
    with pytest.raises(ValueError, match="checkpoint"):
        expand_models([str(tmp_path)])
    other = tmp_path / "seeds"
    other.mkdir()
    for name in ("a.zip", "b.zip"):
        shutil.copy(MODEL, other / name)
        (other / name).with_suffix(".json").write_text(json.dumps({"seed": 3}))
    with pytest.raises(ValueError, match="same seed 3"):
        expand_models([str(other)])


def test_bound_refuses_a_map_redrawn_at_every_reset(capsys):
    fails(capsys, ["bound", "ColourGrid-v0", "--depth", "1", "--env-kwarg", "size=5", "--env-kwarg",
                   "new_map_each_reset=true"], "new map at every reset")
    fails(capsys, ["bound", "WindyMaze-v0", "--depth", "1", "--env-kwarg", "new_map_each_reset=true"], "new map")


def test_resume_refuses_another_model_and_evaluates_at_its_own_step(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.train as t
    from tests.agents.test_train import tiny

    from gym_gridloc_agents.training.train import TrainingInterrupted, train
    from stable_baselines3.common.callbacks import BaseCallback

    import gym_gridloc_agents.training.evaluation as held_out

    monkeypatch.setattr(held_out, "evaluate", lambda model, cfg, episodes: {"mean_steps": 5.0, "accuracy": 0.0, "argmax_accuracy": 0.0})

    class CtrlC(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 300:
                raise KeyboardInterrupt
            return True

    cfg = tiny(tmp_path, total_timesteps=512, eval_freq=256, checkpoint_freq=256, eval_episodes=2)
    with pytest.raises(TrainingInterrupted):
        train(cfg, progress_bar=False, callbacks=[CtrlC()])
    ckpt = tmp_path / "ckpt" / "step_256.zip"
    for change in ({"env_kwargs": {"slip": 0.3}}, {"policy_kwargs": {"net_arch": [32, 32]}},
                   {"hyperparams": {**cfg["hyperparams"], "learning_rate": 0.1}}):
        with pytest.raises(ValueError, match="resume with the checkpoint's config"):
            train({**cfg, **change}, progress_bar=False, resume=ckpt)
    (tmp_path / "ckpt" / "best.zip").unlink()  # the evaluation at 256 is the checkpoint's own step
    info = train(cfg, progress_bar=False, resume=ckpt)
    assert 256 in [e["num_timesteps"] for e in info["evaluations"]]


def test_grid_values_that_print_the_same_get_two_names():
    from gym_gridloc_agents.sweeps.sweep_spec import config_label

    for a, b in ((1, "1"), (True, "true"), (None, "null"), (0.5, "0.5")):
        assert config_label({"k": a}, ["k"]) != config_label({"k": b}, ["k"])
    assert config_label({"k": "relu"}, ["k"]) == "k=relu"


# -- 4. concurrency -------------------------------------------------------------------------------------
def test_two_trainings_into_one_output_never_share_files(tmp_path):
    from gym_gridloc_agents.files import OutputError, atomic_path, clean_stale_temporaries, locked, rescue_write
    from tests.agents.test_train import tiny

    from gym_gridloc_agents.training.train import train

    cfg = tiny(tmp_path)
    with locked(tmp_path / "ckpt", what="x", directory=True):  # another training holds the checkpoint directory
        with pytest.raises(OutputError, match="another process"):
            train(cfg, progress_bar=False)
    with locked(tmp_path / "model.zip", what="x"):  # ... or the output
        with pytest.raises(OutputError, match="another process"):
            train(cfg, progress_bar=False)
    with atomic_path(tmp_path / "m.zip") as tmp:  # a live temporary survives another writer's clean-up
        Path(tmp).write_text("half")
        assert clean_stale_temporaries(tmp_path) == [] and Path(tmp).exists()
    seen = []
    for _ in range(2):  # two rescues in the same second: two files
        with pytest.raises(OutputError, match="instead"):
            rescue_write(lambda p: (seen.append(p), p.write_text("w")) if "rescued" in p.name else (_ for _ in ()).throw(OSError("no")),
                         tmp_path / "out.zip", "model", places=(tmp_path,))
    assert len(set(seen)) == 2


def test_a_trial_lock_shuts_out_a_twin_trial_but_not_the_training_inside_it(tmp_path):
    """``gridloc sweep`` runs a trial under a lock of its own on the checkpoint directory (Optuna can
    propose one configuration twice): the training inside takes the directory's own lock beside it."""
    from gym_gridloc_agents.files import OutputError, locked

    ckpt = tmp_path / "ckpt"
    with locked(ckpt, what="trial", directory=True, name=".trial.lock"):
        with locked(ckpt, wait=False, what="checkpoint directory", directory=True):
            pass
        with pytest.raises(OutputError, match="another process is writing the trial"):
            with locked(ckpt, wait=False, what="trial", directory=True, name=".trial.lock"):
                pass
    assert sorted(p.name for p in ckpt.iterdir()) == [".gridloc-lock", ".trial.lock"]


#: A training in its own process that stops after its first checkpoint, holding its locks, until its
#: standard input closes.
HOLDER = """
import json, sys
from stable_baselines3.common.callbacks import BaseCallback
from gym_gridloc_agents.training.train import train

class Hold(BaseCallback):
    held = False

    def _on_step(self):
        if self.num_timesteps >= 100 and not self.held:
            self.held = True
            print("holding", flush=True)
            sys.stdin.readline()
        return True

train(json.loads(sys.argv[1]), progress_bar=False, callbacks=[Hold()])
print("done", flush=True)
"""
#: ``gridloc train ARGS`` in its own process, started at once (its imports take seconds on a busy
#: machine) and run when a line arrives on its standard input.
GRIDLOC = """
import sys
import gym_gridloc_agents.training.train
from gym_gridloc_agents.cli import main

sys.stdin.readline()
sys.exit(main(sys.argv[1:]))
"""


def _line(proc: subprocess.Popen, timeout: float = 120) -> str:
    ready = select.select([proc.stdout], [], [], timeout)[0]
    line = proc.stdout.readline().strip() if ready else ""
    assert line, proc.stderr.read()[-3000:] if proc.poll() is not None else f"no line in {timeout} s"
    return line


def test_a_second_training_process_is_refused_while_the_first_runs(tmp_path):
    """Real processes: the first trains (and holds its locks) while a second `gridloc train` into
    the same output and checkpoint directory starts; the second is refused with one line, and the
    first's checkpoint and final model are its own."""
    from tests.agents.test_train import _write_yaml, tiny

    from gym_gridloc_agents.files import OutputError
    from gym_gridloc_agents.training.train import train

    ckpt = tmp_path / "ckpt"
    second = _write_yaml(tmp_path, tiny(tmp_path, seed=2))  # another seed, the same output and checkpoints
    pipes = {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, "cwd": tmp_path}
    first = subprocess.Popen([sys.executable, "-c", HOLDER, json.dumps(tiny(tmp_path, total_timesteps=128, checkpoint_freq=64))],
                             **pipes)
    gridloc = subprocess.Popen([sys.executable, "-c", GRIDLOC, "train", str(second), "--no-progress"], **pipes)
    try:
        assert _line(first) == "holding"
        kept = {p.name: p.read_bytes() for p in ckpt.iterdir()}
        assert "step_64.zip" in kept and not (tmp_path / "model.zip").exists()
        out, err = gridloc.communicate("go\n", timeout=120)
        assert gridloc.returncode == 2, err[-3000:]
        assert err.startswith(f"gridloc train: error: another process is writing the checkpoint directory {ckpt}"), err
        assert len(err.strip().splitlines()) == 1 and "choose another output" in err
        # each lock on its own: the same output with other checkpoints, another output with the same checkpoints
        with pytest.raises(OutputError, match=f"another process is writing the model {tmp_path / 'model.zip'}"):
            train(tiny(tmp_path, seed=2, checkpoint_dir=str(tmp_path / "ckpt2")), progress_bar=False)
        with pytest.raises(OutputError, match="another process is writing the checkpoint directory"):
            train(tiny(tmp_path, seed=2, output=str(tmp_path / "other.zip")), progress_bar=False)
        assert {p.name: p.read_bytes() for p in ckpt.iterdir()} == kept, "the first training's checkpoints were touched"
        assert not (tmp_path / "model.zip").exists() and not (tmp_path / "other.zip").exists()
        out, err = first.communicate(timeout=120)  # closes its standard input: the first goes on and finishes
        assert first.returncode == 0 and "done" in out, err[-3000:]
    finally:
        for proc in (first, gridloc):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["seed"] == 1 and meta["num_timesteps"] == 128 and meta["resumed_from"] is None
    assert (ckpt / "step_64.zip").read_bytes() == kept["step_64.zip"] and not list(tmp_path.rglob("*rescued*"))


# -- 5. sizes that pass a check but cannot run -------------------------------------------------------------
def test_sizes_are_capped_before_any_work(tmp_path, capsys):
    import gymnasium as gym

    import gym_gridloc  # noqa: F401
    from gym_gridloc_agents.planners import lower_bound
    from gym_gridloc_agents.sweeps.sweep import SweepError, prepare

    for size in (203, 401, 4095):
        with pytest.raises(ValueError, match="size must be .* at most 201"):
            gym.make("DepthMaze-v0", size=size)
    fails(capsys, [*BENCH, "--policies", "random", "--episodes", "4000000000"], "--episodes")
    fails(capsys, ["bound", "ColourGrid-v0", "--depth", str(10**20)], "--depth")
    with pytest.raises(ValueError, match="depth"):
        lower_bound(gym_gridloc.colour_grid_model(), 10**20)
    from tests.agents.test_sweep import tiny_config

    cfg = tiny_config(tmp_path)
    for kw in ({"seeds": 2**32}, {"seeds": 1001}, {"seeds": 200, "grid": ["hyperparams.n_epochs=1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19,20,21,22,23,24,25,26,27,28,29,30,31,32,33,34,35,36,37,38,39,40,41,42,43,44,45,46,47,48,49,50,51"]}):
        with pytest.raises(SweepError, match="seeds"):
            prepare(cfg, output=tmp_path / "out", **kw)
    assert not (tmp_path / "out").exists()


# -- 6. no tracebacks -------------------------------------------------------------------------------------
def test_no_tracebacks(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("x")
    for argv, says in ((["render", "--env", "Nope-v0"], "not a registered"), (["render", "--env", "CartPole-v1"], "not a gym_gridloc"),
                       (["render", "--seed", "-1"], "--seed"), (["render", "--out", "file/a.png"], "is a file"),
                       (["reproduce", "--seed", "-1"], "--seed"), (["play", "ColourGrid-v0", "--seed", "-1", "--no-window"], "--seed"),
                       (["view", "ColourGrid-v0", "--seed", "-1", "--no-window"], "--seed")):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's error (reproduce)
            code = exc.code
        err = capsys.readouterr().err
        assert code == 2 and says in err and "Traceback" not in err, (argv, err)
    # gridloc plot on its own results: keywords and test maps as separate figures; a table is named
    rows = tmp_path / "rows.json"
    assert main([*BENCH, "--policies", "random", "--json", str(rows)]) == 0
    assert main(["bench", "--env", "ColourGrid-v0", "--env-kwarg", "slip=0.2", "--episodes", "2", "--no-progress",
                 "--policies", "random", "--json", str(rows), "--update"]) == 0
    capsys.readouterr()
    assert main(["plot", str(rows)]) == 0
    assert len(list(tmp_path.glob("bench_ColourGrid-v0*.png"))) == 2
    table = tmp_path / "t.json"
    table.write_text(json.dumps([{k: v for k, v in r.items() if not k.endswith("_curve")} for r in json.loads(rows.read_text())]))
    fails(capsys, ["plot", str(table)], "without their curves")


def test_configs_that_do_not_read_are_named(tmp_path):
    from gym_gridloc_agents.training.config import ConfigError, load_config
    from gym_gridloc_agents.sweeps.sweep import SweepError, prepare

    bad = tmp_path / "latin1.yml"
    bad.write_bytes("env_id: Colour\xe9\n".encode("latin-1"))
    deep = tmp_path / "deep.yml"
    deep.write_text("a: " + "[" * 10_000 + "]" * 10_000 + "\n")
    block = tmp_path / "block.yml"
    block.write_text("".join(" " * i + f"k{i}:\n" for i in range(3000)))
    for path in (bad, deep, block):
        with pytest.raises(ConfigError, match=path.name):
            load_config(path)
        with pytest.raises((ConfigError, SweepError), match=path.name):
            prepare(path, output=tmp_path / "out")


def test_sweep_resume_over_a_record_that_is_not_an_object(tmp_path):
    from gym_gridloc_agents.sweeps.sweep import SweepError, run

    (tmp_path / "sweep.json").write_text("[1, 2]")
    with pytest.raises(SweepError, match="not a sweep's record"):
        run({"output": str(tmp_path)}, resume=True)


# -- 7. minor, same promise -----------------------------------------------------------------------------------
def test_minor_cases(tmp_path, capsys):
    fails(capsys, ["view", "ColourGrid-v0", "--no-window", "--keys", "right,nope"], "unknown key")
    fails(capsys, ["play", "ColourGrid-v0", "--no-window", "--keys", "up,xyz"], "unknown key")
    from gym_gridloc_agents.viewer.commands import play_app
    from gym_gridloc_agents.viewer.loop import Loop

    app, _ = play_app(["ColourGrid-v0", "--no-window", "--steps", "200"])
    loop = Loop(app, window=False, record=None)
    loop.script(["1"] * 200, 0.001, until_done=True)
    assert app.steps < 200 and app.done
    loop.close()


def test_a_recording_never_replaces_another_kind_of_file(tmp_path):
    """``view``/``play --record X.gif``: an existing X.gif that is not a picture (a model zip or a
    JSON saved under that name) is refused before the window opens; a picture is redrawn."""
    from gym_gridloc_agents.cli import main

    for content in (b"PK\x03\x04 a model", b'[{"env": "WindyMaze-v0", "policy": "random"}]'):
        target = tmp_path / "x.gif"
        target.write_bytes(content)
        assert main(["view", "WindyMaze-v0", "--no-window", "--steps", "2", "--record", str(target)]) == 2
        assert target.read_bytes() == content
