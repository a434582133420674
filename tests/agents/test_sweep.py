"""``gridloc sweep`` on Ray Tune (real, tiny sweeps), its statistics, and ``gridloc bench`` over
several models (one per seed).

The Ray tests start Ray on this machine (2 CPUs) or a local head node; each sweep is a few
thousand PPO steps on ColourGrid-v0 (a 16-unit net, 2 envs, 5-episode evaluations).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from gym_gridloc_agents.evaluation import stats
from gym_gridloc_agents.cli import main
from tests.helpers import kill_session

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "agents" / "gym_gridloc_agents" / "models" / "ColourGrid-v0-ppo.zip"
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None or importlib.util.find_spec("optuna") is None,
    reason="needs the sweep extra (ray[tune], optuna)",
)
if importlib.util.find_spec("ray") is not None:
    # Imported here, not first inside a test that captures output: Ray's log handler keeps the
    # stderr it sees at import, and a test's capture is closed after the test.
    import ray  # noqa: F401


def tiny_config(tmp_path: Path, name: str = "tiny.yml", **over) -> Path:
    import yaml

    cfg = {
        "algo": "ppo", "env_id": "ColourGrid-v0", "n_envs": 2, "seed": 3, "total_timesteps": 2048,
        "policy_kwargs": {"net_arch": [16]},
        "hyperparams": {"n_steps": 128, "batch_size": 64, "n_epochs": 2, "learning_rate": 1e-3},
        "eval_freq": 1024, "eval_episodes": 5, "checkpoint_freq": 512,
        "output": "never-written.zip",  # the sweep puts every model under --output
    }
    cfg.update(over)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg))
    return path


def snapshot(path: Path) -> tuple[int, str]:
    return path.stat().st_mtime_ns, hashlib.sha256(path.read_bytes()).hexdigest()


# -- the statistics, against hand-computed values --------------------------------------------------
def test_iqm_drops_a_quarter_at_each_end():
    assert stats.iqm([1, 2, 3, 4, 100]) == 3.0          # floor(5/4) = 1 dropped each end: mean(2, 3, 4)
    assert stats.iqm([8, 1, 7, 2, 6, 3, 5, 4]) == 4.5   # 2 dropped each end: mean(3, 4, 5, 6)
    assert stats.iqm([1, 3]) == 2.0 == stats.mean([1, 3])  # fewer than 4: nothing dropped
    assert stats.iqm([5.0]) == 5.0
    from scipy.stats import trim_mean

    x = [3.1, 9.0, 4.4, 0.2, 7.7, 5.5, 6.1, 2.9, 8.8]
    assert stats.iqm(x) == pytest.approx(trim_mean(x, 0.25))  # rliable's definition


def test_bootstrap_interval_of_the_mean():
    # Two seeds: a resample's mean is 1, 2 or 3 with probabilities 1/4, 1/2, 1/4.
    assert stats.bootstrap_ci([1.0, 3.0]) == [1.0, 3.0]
    # [0, 0, 0, 10]: a resample's mean is 2.5 K, K ~ Binomial(4, 1/4): P(K = 0) = 0.316 > 2.5%, and
    # P(K <= 2) = 0.949 < 97.5% < P(K <= 3) = 0.996.
    assert stats.bootstrap_ci([0, 0, 0, 10]) == [0.0, 7.5]
    assert stats.bootstrap_ci([4.0]) == [4.0, 4.0]
    x = [3.0, 5.5, 4.25, 7.0, 6.0]
    assert stats.bootstrap_ci(x) == stats.bootstrap_ci(list(x))  # a fixed bootstrap seed
    lo, hi = stats.bootstrap_ci(x)
    assert min(x) <= lo < np.mean(x) < hi <= max(x)
    agg = stats.aggregate(x)
    assert agg["n"] == 5 and agg["mean"] == pytest.approx(5.15) and agg["iqm"] == pytest.approx(5.25)  # mean(4.25, 5.5, 6)
    assert agg["ci95"] == [lo, hi] and agg["values"] == x
    with pytest.raises(ValueError):
        stats.aggregate([])


def test_median_seed_rule():
    assert stats.median_index([5.2, 3.8]) == 1          # even count: the lower median
    assert stats.median_index([3.0, 1.0, 2.0]) == 2
    assert stats.median_index([4.0, 1.0, 3.0, 2.0]) == 3  # sorted 1 2 3 4: the lower median is 2
    assert stats.median_index([2.0, 2.0, 2.0]) == 1       # ties keep the order


# -- arguments --------------------------------------------------------------------------------------
@pytest.mark.parametrize("args, says", [
    (["--seeds", "0"], "--seeds"),
    (["--grid", "nokey"], "KEY=V1,V2"),
    (["--grid", "hyperparams.n_steps="], "needs values"),
    (["--grid", "hyperparams.n_steps=64,"], "needs values"),
    (["--grid", "hyperparams.no_such_key=1,2"], "no_such_key"),
    (["--grid", "no_such_section.key=1"], "no_such_section"),
    (["--grid", "hyperparams.n_steps=64", "hyperparams.n_steps=128"], "twice"),
    (["--grid", "seed=1,2"], "--seeds"),
    (["--grid", "hyperparams.learning_rate=1e-4", "--search", "optuna"], "--trials"),
    (["--trials", "3"], "--search optuna"),
    (["--search", "optuna", "--trials", "2"], "--grid"),
    (["--cpus", "0"], "--cpus"),
    (["--cpus", "2", "--address", "127.0.0.1:1"], "--address"),
    (["--resume"], "no sweep"),
    (["--address", "not-an-address"], "is not an address"),
    (["--address", "127.0.0.1:1"], "cannot join the Ray cluster at 127.0.0.1:1: nothing answers there"),
])
@needs_ray  # without the extra, every sweep command stops at "needs the sweep extra" (test_sweep_needs_its_extra)
def test_bad_arguments_one_line_exit_2(tmp_path, capsys, args, says):
    cfg = tiny_config(tmp_path)
    assert main(["sweep", str(cfg), "--output", str(tmp_path / "out"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("gridloc sweep: error:") and says in err, err
    assert not (tmp_path / "out" / "tune").exists() and not (tmp_path / "out" / "sweep.json").exists()


def test_grid_values_parse_like_yaml_scalars():
    from gym_gridloc_agents.sweeps.sweep import config_label, parse_grid

    grid = parse_grid(["hyperparams.learning_rate=1e-4,3.0e-4,0.001", "hyperparams.n_steps=64,128",
                       "policy_kwargs.net_arch=[16,16],[32]", "wrapper.flatten=true,false", "policy_kwargs.activation_fn=tanh,relu"])
    assert grid["hyperparams.learning_rate"] == [1e-4, 3e-4, 1e-3]
    assert all(isinstance(v, float) for v in grid["hyperparams.learning_rate"])
    assert grid["hyperparams.n_steps"] == [64, 128] and all(type(v) is int for v in grid["hyperparams.n_steps"])
    assert grid["policy_kwargs.net_arch"] == [[16, 16], [32]]
    assert grid["wrapper.flatten"] == [True, False]
    assert grid["policy_kwargs.activation_fn"] == ["tanh", "relu"]
    keys = ["hyperparams.learning_rate", "policy_kwargs.net_arch"]
    a = config_label({"hyperparams.learning_rate": 1e-4, "policy_kwargs.net_arch": [16, 16]}, keys)
    b = config_label({"hyperparams.learning_rate": 1e-4, "policy_kwargs.net_arch": [16, 16, 16]}, keys)
    assert a.startswith("learning_rate=0.0001_net_arch=16_16-") and a != b
    assert config_label({}, []) == "base"


def test_sweep_needs_its_extra(monkeypatch, capsys, tmp_path):
    import importlib.util as u

    real = u.find_spec
    monkeypatch.setattr(u, "find_spec", lambda name, *a: None if name in ("ray", "optuna") else real(name, *a))
    assert main(["sweep", str(tiny_config(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert "gym_gridloc[rl,sweep]" in err and "ray" in err


def test_ray_is_imported_only_by_the_sweep():
    code = ("import sys, gym_gridloc, gym_gridloc_agents.cli, gym_gridloc_agents.training.train, gym_gridloc_agents.evaluation.bench, "
            "gym_gridloc_agents.sweeps.sweep, gym_gridloc_agents.evaluation.stats, gym_gridloc_agents.evaluation.bench_command, gym_gridloc_agents.evaluation.bench_cluster; "
            "bad = [m for m in ('ray', 'optuna') if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert any(d.startswith("ray[tune]") for d in project["optional-dependencies"]["sweep"])
    assert any(d.startswith("optuna") for d in project["optional-dependencies"]["sweep"])
    for deps in (project["dependencies"], project["optional-dependencies"]["rl"]):
        assert not any(d.startswith(("ray", "optuna")) for d in deps)


@needs_ray
def test_optuna_search_is_a_repeater_over_optuna_with_asha(tmp_path):
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import Repeater
    from ray.tune.search.optuna import OptunaSearch

    from gym_gridloc_agents.sweeps.sweep import param_space, prepare, tune_config

    spec = prepare(tiny_config(tmp_path), seeds=3, grid=["hyperparams.learning_rate=1e-3,3e-4"], search="optuna", trials=4,
                   output=tmp_path / "out")
    tc = tune_config(spec)
    assert isinstance(tc.search_alg, Repeater) and isinstance(tc.search_alg.searcher, OptunaSearch)
    assert tc.search_alg.repeat == 3 and tc.num_samples == 12 and (tc.metric, tc.mode) == ("score", "min")
    assert isinstance(tc.scheduler, ASHAScheduler) and tc.scheduler._time_attr == "num_timesteps"
    assert tc.scheduler._max_t > 2048  # never stops a trial at its last evaluation, before the final report
    assert set(param_space(spec)["overrides"]) == {"hyperparams.learning_rate"}


# -- real sweeps ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def embedded_ray():
    """One Ray on this machine (2 CPUs) for the in-process sweeps of this module, started as
    ``gridloc sweep`` starts it (``run`` uses a Ray that is already up, and leaves it up); the
    killed sweep's subprocess starts its own through the command itself."""
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield
    ray.shutdown()


def _results(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


@needs_ray
def test_sweep_two_configurations_two_seeds(tmp_path, monkeypatch, capsys, embedded_ray):
    cfg = tiny_config(tmp_path)
    out = tmp_path / "out"
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)  # nothing may land in the working directory (the repository, usually)
    home_results = Path.home() / "ray_results"
    had_home_results = home_results.exists()
    start = time.perf_counter()
    rc = main(["sweep", str(cfg), "--seeds", "2", "--grid", "hyperparams.learning_rate=1e-3,3e-4",
               "--cpus", "2", "--output", str(out)])
    seconds = time.perf_counter() - start
    printed = capsys.readouterr().out
    with capsys.disabled():
        print(f"\n[sweep of 2 configurations x 2 seeds x 2048 steps: {seconds:.1f} s, load average {os.getloadavg()[0]:.1f}]")
    assert rc == 0
    assert list(cwd.iterdir()) == [] and home_results.exists() == had_home_results
    # Ray Tune's own boxes stay quiet (gridloc sweep --verbose shows them): the table is what is printed
    assert "Configuration for experiment" not in printed and "Trial status" not in printed and "|" in printed

    s = _results(out)
    assert s["statuses"] == {"done": 4} and s["trials"] == 4
    assert [c["label"] for c in s["configurations"]] != [] and len(s["configurations"]) == 2
    for c in s["configurations"]:
        assert c["complete"] and [r["seed"] for r in c["seeds"]] == [3, 4]
        scores = [r["score"] for r in c["seeds"]]
        assert c["aggregate"]["score"]["mean"] == pytest.approx(np.mean(scores))
        assert c["aggregate"]["score"]["iqm"] == pytest.approx(stats.iqm(scores))
        assert c["aggregate"]["score"]["ci95"] == stats.bootstrap_ci(scores)
        for r in c["seeds"]:
            assert r["score"] == r["mean_steps"]  # no episode_length: the score is the mean steps
            meta = json.loads(Path(r["model"]).with_suffix(".json").read_text())
            assert meta["seed"] == r["seed"] and meta["config"]["hyperparams"]["learning_rate"] == c["overrides"]["hyperparams.learning_rate"]
            assert meta["num_timesteps"] == 2048 and len(meta["evaluations"]) == 2 and meta["interrupted"] is False
        table = (out / "results" / f"{c['label']}.md").read_text()
        assert "IQM" in table and "95% CI" in table and table.count("| done |") == 2
        assert json.loads((out / "results" / f"{c['label']}.json").read_text())["aggregate"] == c["aggregate"]

    # The best configuration: the best mean score; its model: the median seed's, not the best seed's.
    best = min(s["configurations"], key=lambda c: c["aggregate"]["score"]["mean"])
    assert s["best"]["label"] == best["label"] == s["configurations"][0]["label"]
    med = best["seeds"][stats.median_index([r["score"] for r in best["seeds"]])]
    assert s["best"]["seed"] == med["seed"]
    assert (out / "best.zip").read_bytes() == Path(med["model"]).read_bytes()
    best_meta = json.loads((out / "best.json").read_text())
    assert best_meta["seed"] == med["seed"] and best_meta["sweep"]["label"] == best["label"]
    assert "median" in best_meta["sweep"]["median_rule"]
    assert "best" in printed and best["label"] in printed

    # The best model is a normal model of this repository (its metadata beside it).
    import gym_gridloc
    from gym_gridloc_agents.policies import PPOPolicy

    policy = PPOPolicy(gym_gridloc.colour_grid_model(), env_id="ColourGrid-v0", path=out / "best.zip")
    assert policy.act(0, gym_gridloc.colour_grid_model().prior()) in range(4)

    # The same command again: refused (never mixes two sweeps); --resume with other arguments too.
    assert main(["sweep", str(cfg), "--seeds", "2", "--grid", "hyperparams.learning_rate=1e-3,3e-4", "--output", str(out)]) == 2
    assert main(["sweep", str(cfg), "--seeds", "3", "--grid", "hyperparams.learning_rate=1e-3,3e-4", "--output", str(out),
                 "--resume"]) == 2
    assert "same arguments" in capsys.readouterr().err

    # A sweep killed while Tune copied its state to --output leaves a truncated file there, which
    # Tune's restore cannot load: --resume keeps that directory aside and runs Tune again, and
    # every finished model is reused, not trained again.
    from gym_gridloc_agents.sweeps.sweep import unreadable_state

    assert unreadable_state(out / "tune") == []
    state = max((out / "tune").glob("basic-variant-state-*.json"))
    state.write_bytes(b"")
    assert unreadable_state(out / "tune") == [state]
    models = {Path(r["model"]): snapshot(Path(r["model"])) for c in s["configurations"] for r in c["seeds"]}
    assert main(["sweep", str(cfg), "--seeds", "2", "--grid", "hyperparams.learning_rate=1e-3,3e-4", "--cpus", "2",
                 "--output", str(out), "--resume"]) == 0
    err = capsys.readouterr().err
    assert state.name in err and "tune.unreadable-1" in err
    assert len(list((out / "tune.unreadable-1").glob("*/params.json"))) == 4
    again = _results(out)
    assert again["statuses"] == {"done": 4} and again["best"] == s["best"]
    assert {m: snapshot(m) for m in models} == models


def _finished_trials(exp: Path) -> dict[str, Path]:
    """Trials whose last line in Tune's result.json is the sweep's final report: their model paths."""
    done = {}
    for res in exp.glob("*/result.json"):
        with contextlib.suppress(OSError, ValueError):
            lines = [json.loads(line) for line in res.read_text().splitlines() if line.strip().endswith("}")]
            finals = [r for r in lines if r.get("final")]
            if finals:
                done[res.parent.name] = Path(finals[-1]["model"])
    return done


@needs_ray
def test_killed_sweep_resumes_without_rerunning_finished_trials(tmp_path, embedded_ray):
    from gym_gridloc_agents.sweeps.sweep import latest_checkpoint

    cfg = tiny_config(tmp_path, total_timesteps=1536, eval_freq=768, checkpoint_freq=256)
    out = tmp_path / "out"
    args = ["sweep", str(cfg), "--seeds", "2", "--grid", "hyperparams.learning_rate=1e-3,3e-4", "--output", str(out)]

    def training_checkpoints() -> dict[Path, int]:
        """The latest checkpoint (steps) of every training that has not saved its final model."""
        found = {}
        for ck in (out / "checkpoints").glob("*/seed*"):
            model = out / "models" / ck.parent.name / f"{ck.name}.zip"
            latest = latest_checkpoint(ck)
            if not model.exists() and latest is not None:
                found[model] = int(latest.stem.rsplit("_", 1)[1])
        return found

    # One trial at a time, Tune's experiment state saved every second (TUNE_GLOBAL_CHECKPOINT_S):
    # kill the driver, the Ray it started and Ray's workers (all of its session: a worker left alive
    # would finish its training after the kill) once Tune's files show a finished trial and the
    # next trial has a training checkpoint.
    log = open(tmp_path / "first.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "gym_gridloc_agents.cli", *args, "--cpus", "1"], stdout=log,
                            stderr=subprocess.STDOUT, cwd=tmp_path, start_new_session=True,
                            env={**os.environ, "TUNE_GLOBAL_CHECKPOINT_S": "1"})
    try:
        deadline, finished_at = time.monotonic() + 150, None
        while time.monotonic() < deadline and proc.poll() is None:
            if finished_at is None and _finished_trials(out / "tune"):
                finished_at = time.monotonic()
            if finished_at is not None and (training_checkpoints() or time.monotonic() > finished_at + 10):
                break
            time.sleep(0.1)
        assert finished_at is not None and proc.poll() is None, \
            f"no trial finished, or all did (exit {proc.poll()}): {(tmp_path / 'first.log').read_text()[-3000:]}"
        kill_session(proc.pid)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            kill_session(proc.pid)
            proc.wait(30)
        log.close()
    finished = _finished_trials(out / "tune")  # what Tune recorded before the kill
    assert 0 < len(finished) < 4
    before = {p: (snapshot(p), snapshot(p.with_suffix(".json"))) for p in finished.values()}
    interrupted = training_checkpoints()

    assert main([*args, "--cpus", "2", "--resume"]) == 0
    s = _results(out)
    assert s["statuses"] == {"done": 4} and s["trials"] == 4
    assert len(list((out / "tune").glob("*/params.json"))) == 4  # no trial was added
    for model, (zip_before, json_before) in before.items():  # finished trials were not trained again
        assert (snapshot(model), snapshot(model.with_suffix(".json"))) == (zip_before, json_before)
    for model, steps in interrupted.items():  # an interrupted training continued from its checkpoint
        meta = json.loads(model.with_suffix(".json").read_text())
        assert meta["resumed_from"] is not None and int(Path(meta["resumed_from"]).stem.rsplit("_", 1)[1]) >= steps
        assert meta["num_timesteps"] == 1536
    assert (out / "best.zip").is_file()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@needs_ray
def test_sweep_on_a_running_ray_cluster(tmp_path):
    """``--address``: the command, unchanged, on a head node started here (its own temp dir, so
    that no other Ray user of this machine sees it; token authentication with a token made for
    this test, passed as Ray clients take it: RAY_AUTH_MODE=token, RAY_AUTH_TOKEN).  The head is
    stopped by ending the ``ray start --block`` process this test started, which stops that
    node's processes -- not with ``ray stop``, which stops every Ray process on the machine,
    other people's included."""
    import uuid

    ray_bin = Path(sys.executable).parent / "ray"
    start = time.monotonic()
    port = _free_port()
    temp = Path(tempfile.mkdtemp(prefix="glray-", dir="/tmp"))  # short: Ray's socket paths have a length limit
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": uuid.uuid4().hex}
    env.pop("RAY_ADDRESS", None)
    log = open(tmp_path / "head.log", "w")
    head = subprocess.Popen(
        [str(ray_bin), "start", "--head", "--block", "--node-ip-address", "127.0.0.1", "--port", str(port),
         "--num-cpus", "2", "--include-dashboard=false", "--temp-dir", str(temp), "--disable-usage-stats"],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=env,
    )
    try:
        deadline = time.monotonic() + 60
        while not (temp / "ray_current_cluster").exists():
            assert head.poll() is None and time.monotonic() < deadline, (tmp_path / "head.log").read_text()[-2000:]
            time.sleep(0.2)
        up = time.monotonic()
        cfg = tiny_config(tmp_path, total_timesteps=1024, eval_freq=512)
        out = tmp_path / "out"
        run = subprocess.run([sys.executable, "-m", "gym_gridloc_agents.cli", "sweep", str(cfg), "--seeds", "2",
                              "--address", f"127.0.0.1:{port}", "--output", str(out)],
                             check=False, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=150)
        swept = time.monotonic()
        assert run.returncode == 0, run.stderr[-3000:]
        s = _results(out)
        assert s["statuses"] == {"done": 2} and s["best"]["label"] == "base" and (out / "best.zip").is_file()
        assert [r["seed"] for r in s["configurations"][0]["seeds"]] == [3, 4]
        assert "Best configuration: base" in run.stdout
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(40)
        except subprocess.TimeoutExpired:
            kill_session(head.pid)
            head.wait(10)
        log.close()
        shutil.rmtree(temp, ignore_errors=True)
    print(f"[--address: head up {up - start:.1f} s, sweep {swept - up:.1f} s, head stopped {time.monotonic() - swept:.1f} s]")


# -- bench over several models ---------------------------------------------------------------------
def test_bench_aggregates_models_across_seeds(tmp_path, capsys):
    from gym_gridloc_agents.evaluation.bench import run_benchmark
    from gym_gridloc_agents.loading import expand_models
    from gym_gridloc_agents.training.train import train

    seeds = tmp_path / "seeds"
    seeds.mkdir()
    for i, name in enumerate(("a", "b")):  # the shipped model twice, as two "seeds" (two seeds in its metadata)
        shutil.copy(SHIPPED, seeds / f"seed_{name}.zip")
        meta = json.loads(SHIPPED.with_suffix(".json").read_text())
        (seeds / f"seed_{name}.json").write_text(json.dumps({**meta, "seed": 100 + i}))
    train({"algo": "ppo", "env_id": "ColourGrid-v0", "n_envs": 2, "seed": 1, "total_timesteps": 256,
           "policy_kwargs": {"net_arch": [16]}, "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
           "output": str(seeds / "seed_c.zip"), "checkpoint_dir": str(tmp_path / "ckpt")}, progress_bar=False)
    assert expand_models([seeds]) == expand_models([str(seeds / "seed_*.zip")]) == sorted(seeds.glob("*.zip"))

    js = tmp_path / "bench.json"
    assert main(["bench", "--env", "ColourGrid-v0", "--policies", "random,ppo", "--episodes", "5", "--ppo-model", str(seeds),
                 "--json", str(js), "--no-progress"]) == 0
    table = capsys.readouterr().out
    rows = json.loads(js.read_text())
    random_row, ppo = rows
    assert random_row["policy"] == "random" and "seeds" not in random_row
    assert ppo["policy"] == "ppo" and ppo["seeds"] == 3 and ppo["episodes"] == 5 and ppo["episodes_total"] == 15
    per = [r["mean_steps"] for r in ppo["per_seed"]]
    assert ppo["per_seed"][0]["mean_steps"] == ppo["per_seed"][1]["mean_steps"]  # the same model twice
    assert ppo["mean_steps"] == pytest.approx(np.mean(per))
    assert ppo["mean_steps_iqm"] == pytest.approx(stats.iqm(per))
    lo, hi = ppo["mean_steps_ci95"]  # over the seeds and then their episodes, not over the seeds' means alone
    assert lo <= ppo["mean_steps"] <= hi and ppo["mean_steps_seed_range"] == [min(per), max(per)]
    assert ppo["success_rate"] == pytest.approx(np.mean([r["success_rate"] for r in ppo["per_seed"]]))
    assert [Path(m).name for m in ppo["model"]] == ["seed_a.zip", "seed_b.zip", "seed_c.zip"]
    assert "ppo (3 seeds" in table

    # Each seed's own number is what that model alone gives; the single-model row is unchanged.
    single = run_benchmark(["ColourGrid-v0"], ["ppo"], 5, ppo_model=str(seeds / "seed_a.zip"), progress=False)[0]
    assert "seeds" not in single and single["mean_steps"] == per[0]
    shipped = run_benchmark(["ColourGrid-v0"], ["ppo"], 5, ppo_model=[str(SHIPPED)], progress=False)[0]
    assert {k: v for k, v in shipped.items() if k not in ("seconds", "model", "ms_per_decision")} == \
        {k: v for k, v in single.items() if k not in ("seconds", "model", "ms_per_decision")}
    # Files, a directory or a glob: the same models, the same row.
    files = run_benchmark(["ColourGrid-v0"], ["ppo"], 5, ppo_model=sorted(seeds.glob("*.zip")), progress=False)[0]

    def timeless(row):  # (a seed's normalised score needs the run's random row)
        return [{k: v for k, v in r.items() if k not in ("seconds", "normalised_score")} for r in row["per_seed"]]

    assert files["mean_steps"] == ppo["mean_steps"] and timeless(files) == timeless(ppo)

    assert main(["bench", "--env", "ColourGrid-v0", "--ppo-model", str(tmp_path / "nothing*.zip")]) == 2
    assert main(["bench", "--all", "--ppo-model", str(seeds)]) == 2
    assert main(["bench", "--env", "ColourGrid-v0", "--ppo-model", str(seeds / "seed_a.zip"), str(seeds / "seed_a.zip")]) == 2


def test_optuna_with_several_grid_keys_is_checked_key_by_key(tmp_path):
    from gym_gridloc_agents.sweeps.sweep_spec import config_label, prepare

    spec = prepare(tiny_config(tmp_path), search="optuna", trials=2, output=tmp_path / "out",
                   grid=["hyperparams.learning_rate=1e-4,1e-3", "hyperparams.n_steps=64,128"])
    assert sorted(spec["grid"]) == ["hyperparams.learning_rate", "hyperparams.n_steps"]
    keys = list(spec["grid"])
    assert config_label({"hyperparams.n_steps": 64}, keys) == "n_steps=64"
    assert config_label({"hyperparams.learning_rate": 1e-3, "hyperparams.n_steps": 64}, keys) == "learning_rate=0.001_n_steps=64"


@needs_ray
def test_ray_that_fails_to_start_gives_one_line(tmp_path, capsys, monkeypatch):
    """Ray raises a bare Exception when its node times out starting (seen on a machine loaded by
    trainings): one line, exit 2, nothing written."""
    import ray

    def timed_out(*args, **kwargs):
        raise Exception("The current node timed out during startup. This could happen because ...")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", timed_out)
    cfg = tiny_config(tmp_path)
    assert main(["sweep", str(cfg), "--output", str(tmp_path / "out"), "--cpus", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot start Ray on this machine" in err and "less busy" in err, err
    assert not (tmp_path / "out" / "sweep.json").exists()
