"""Learning curves across seeds (``gridloc plot --curves``), the pure-RL configs, and schedules."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats as sps

from gym_gridloc_agents.evaluation import curves, stats
from gym_gridloc_agents.cli import main

ROOT = Path(__file__).resolve().parents[2]


def fake_sweep(tmp_path: Path, finals=(4.9, 4.7, 5.3, 4.6, 4.8), steps=(1000, 2000, 3000), env_kwargs=None) -> Path:
    """A sweep directory with one model per seed: metadata with held-out evaluations only."""
    d = tmp_path / "sweep" / "models" / "base"
    d.mkdir(parents=True)
    for seed, final in enumerate(finals):
        evals = [{"num_timesteps": s, "mean_steps": final + 2.0 * (len(steps) - 1 - i) + 0.1 * seed,
                  "accuracy": 0.5 + 0.1 * i, "wall_time_seconds": 10.0 * (i + 1) + seed}
                 for i, s in enumerate(steps)]
        evals.append({"num_timesteps": steps[-1] + 7 * (seed + 1), "mean_steps": 99.0})  # a last step only this seed has
        (d / f"seed{seed}.zip").write_bytes(b"model")
        (d / f"seed{seed}.json").write_text(json.dumps({
            "algo": "ppo", "env_id": "WindyMaze-v0", "env_kwargs": env_kwargs or {}, "seed": seed,
            "pretrain": None, "evaluations": evals}))
    return tmp_path / "sweep"


def test_curve_is_the_iqm_with_a_bootstrap_interval_checked_against_scipy(tmp_path):
    runs = curves.load_runs(fake_sweep(tmp_path))
    c = curves.curve(runs, label="x", resamples=2000)
    assert c["steps"] == [1000, 2000, 3000] and c["metric"] == "mean_steps" and c["lower_is_better"]
    assert c["methods"] == ["ppo"] and c["seeds"] == [0, 1, 2, 3, 4]
    for i, step in enumerate(c["steps"]):
        values = np.array([r["evaluations"][i]["mean_steps"] for r in runs])
        assert c["iqm"][i] == pytest.approx(sps.trim_mean(values, 0.25))
        ref = sps.bootstrap((values,), lambda x, axis: sps.trim_mean(x, 0.25, axis=axis), n_resamples=2000,
                            method="percentile", rng=np.random.default_rng(stats.BOOTSTRAP_SEED), vectorized=True)
        assert c["ci95"][i] == pytest.approx([ref.confidence_interval.low, ref.confidence_interval.high])
        assert c["ci95"][i][0] <= c["iqm"][i] <= c["ci95"][i][1]
    # the final IQM: the middle three of 4.6..5.3 (+ 0.1 x seed) after dropping one at each end
    assert c["iqm"][-1] == pytest.approx(np.mean(sorted([4.9, 4.8, 5.5, 4.9, 5.2])[1:4]))
    assert c["wall_time_seconds"] == [12.0, 22.0, 32.0]  # the median across seeds


def test_iqm_interval_known_values():
    # Four equal values: no spread, a point interval; the IQM bootstrap of [0, 0, 0, 10] never
    # exceeds the largest trimmed mean (5, from a resample holding 10 twice or more in the middle).
    assert stats.bootstrap_ci([2.0, 2.0, 2.0, 2.0], statistic=stats.iqm) == [2.0, 2.0]
    lo, hi = stats.bootstrap_ci([0, 0, 0, 10], statistic=stats.iqm)
    assert lo == 0.0 and hi <= 10.0
    x = [3.0, 5.5, 4.25, 7.0, 6.0]
    ref = sps.bootstrap((np.array(x),), np.mean, n_resamples=stats.BOOTSTRAP_RESAMPLES, method="percentile",
                        rng=np.random.default_rng(stats.BOOTSTRAP_SEED))
    assert stats.bootstrap_ci(x) == pytest.approx([ref.confidence_interval.low, ref.confidence_interval.high])


def test_sample_efficiency_and_baselines():
    rows = [{"env": "WindyMaze-v0", "policy": "random", "mean_steps": 11.8},
            {"env": "WindyMaze-v0", "policy": "greedy2", "mean_steps": 4.65},
            {"env": "WindyMaze-v0", "policy": "expectimax", "mean_steps": 4.52},
            {"env": "WindyMaze-v0", "policy": "mcts", "mean_steps": 4.57},
            {"env": "ColourGrid-v0", "policy": "greedy2", "mean_steps": 3.2}]
    lines = curves.baselines(rows, "WindyMaze-v0", "mean_steps", True)
    assert lines == {"random": 11.8, "greedy2": 4.65, "best planner": 4.52}
    c = {"steps": [10, 20, 30], "iqm": [9.0, 4.7, 4.6], "wall_time_seconds": [1.0, 2.0, 3.0], "lower_is_better": True}
    assert curves.sample_efficiency(c, lines) == {"baseline": "greedy2", "score": 4.65, "steps": 30, "wall_time_seconds": 3.0}
    c["iqm"] = [12.0, 11.0, 5.0]  # never greedy2: the step at which it beats the random walk
    assert curves.sample_efficiency(c, lines)["baseline"] == "random" and curves.sample_efficiency(c, lines)["steps"] == 20
    c["iqm"] = [12.0, 12.5, 13.0]
    assert curves.sample_efficiency(c, lines) is None
    # accuracy (fixed-length episodes): higher is better
    acc = curves.baselines([{"env": "DepthMaze-v0", "policy": "greedy2", "accuracy_at_L": 0.63},
                            {"env": "DepthMaze-v0", "policy": "optimal", "accuracy_at_L": 0.93}], "DepthMaze-v0", "accuracy", False)
    assert acc == {"greedy2": 0.63, "best planner": 0.93}
    protocol = [{"env": "DepthMaze-v0", "policy": "greedy2", "accuracy_at_L": 0.63, "env_kwargs": {"size": 7, "episode_length": 15}},
                {"env": "DepthMaze-v0", "policy": "greedy2", "accuracy_at_L": 0.79, "env_kwargs": {"size": 7, "episode_length": 30}}]
    assert curves.baselines(protocol, "DepthMaze-v0", "accuracy", False,
                            {"size": 7, "episode_length": 15, "reward": "belief"}) == {"greedy2": 0.63}
    assert curves.sample_efficiency({"steps": [1, 2], "iqm": [0.5, 0.7], "wall_time_seconds": [None, None],
                                     "lower_is_better": False}, acc)["steps"] == 2


def test_cli_plot_curves(tmp_path, capsys):
    sweep = fake_sweep(tmp_path)
    bench = tmp_path / "bench.json"
    bench.write_text(json.dumps([{"env": "WindyMaze-v0", "policy": "greedy2", "mean_steps": 5.0, "episodes": 10, "success_rate": 1.0},
                                 {"env": "WindyMaze-v0", "policy": "random", "mean_steps": 11.0, "episodes": 10, "success_rate": 1.0}]))
    out, js = tmp_path / "c.png", tmp_path / "c.json"
    assert main(["plot", "--curves", str(sweep), "--baselines", str(bench), "--out", str(out), "--curves-json", str(js)]) == 0
    assert out.stat().st_size > 10_000 and out.read_bytes()[:4] == b"\x89PNG"
    data = json.loads(js.read_text())
    assert data["baselines"] == {"random": 11.0, "greedy2": 5.0}
    assert data["curves"][0]["sample_efficiency"]["steps"] == 3000  # IQM 4.9 at the last step, 6.9 before
    assert "| sweep | 5 | 3000 |" in capsys.readouterr().out
    # mixed tasks and bad inputs: one line, exit 2
    other = fake_sweep(tmp_path / "o", env_kwargs={"slip": 0.2})
    assert main(["plot", "--curves", str(sweep), str(other), "--out", str(tmp_path / "d.png")]) == 2
    assert main(["plot", "--curves", str(tmp_path / "nothing"), "--out", str(tmp_path / "d.png")]) == 2
    assert "not a sweep directory" in capsys.readouterr().err


PURE = sorted((ROOT / "configs").glob("ppo_*.yml"))


def test_pure_configs_have_no_planner():
    from gym_gridloc_agents.training.config import load_config

    assert {p.stem for p in PURE} >= {"ppo_windymaze", "ppo_colourgrid", "ppo_ringsensor"}
    for path in PURE:
        raw = yaml.safe_load(path.read_text())
        assert "pretrain" not in raw, path
        cfg = load_config(path)
        assert cfg["pretrain"] is None and cfg["algo"] == "ppo"
        assert "Pure reinforcement learning" in path.read_text()  # the header says the recipe
    for path in sorted((ROOT / "configs").glob("distill_*.yml")):
        assert load_config(path)["pretrain"], path  # the distilled recipes keep their planner


def test_a_pure_config_never_calls_the_pretraining_code(tmp_path, monkeypatch):
    import gym_gridloc_agents.training.pretrain as pretrain
    import gym_gridloc_agents.training.train as train_module
    from gym_gridloc_agents.training.config import load_config

    def forbidden(*args, **kwargs):
        raise AssertionError("the pretraining code ran")

    for name in ("behaviour_cloning", "collect_expert"):
        monkeypatch.setattr(pretrain, name, forbidden)
    monkeypatch.setattr(train_module, "behaviour_cloning", forbidden)
    cfg = load_config(ROOT / "configs" / "ppo_colourgrid.yml")
    cfg.update(total_timesteps=512, n_envs=2, eval_freq=256, eval_episodes=3, checkpoint_freq=0,
               output=str(tmp_path / "pure.zip"), checkpoint_dir=str(tmp_path / "ck"))
    cfg["hyperparams"].update(n_steps=128, batch_size=64, n_epochs=1)
    info = train_module.train(cfg, progress_bar=False)
    assert info["method"] == "ppo" and info["pretrain"] is None
    assert all("wall_time_seconds" in e and "cpu_seconds" in e for e in info["evaluations"])


def test_linear_schedules(tmp_path):
    from stable_baselines3 import PPO

    from gym_gridloc_agents.training.config import ConfigError, validate_config
    from gym_gridloc_agents.training.train import train

    base = {"algo": "ppo", "env_id": "ColourGrid-v0", "n_envs": 2, "seed": 0, "total_timesteps": 1024,
            "policy_kwargs": {"net_arch": [8]}, "output": str(tmp_path / "s.zip"), "checkpoint_dir": str(tmp_path / "ck"),
            "hyperparams": {"n_steps": 128, "batch_size": 64, "n_epochs": 1, "learning_rate": 1e-3, "ent_coef": 0.02},
            "schedule": {"learning_rate": 1e-4, "ent_coef": 0.0}}
    seen = []

    class Spy:  # records the entropy coefficient each update uses
        def __call__(self):
            from stable_baselines3.common.callbacks import BaseCallback

            class CB(BaseCallback):
                def _on_rollout_start(self) -> None:
                    seen.append((self.model.num_timesteps, self.model.ent_coef, self.model.lr_schedule(self.model._current_progress_remaining)))

                def _on_step(self) -> bool:
                    return True

            return CB()

    info = train(base, progress_bar=False, callbacks=[Spy()()])
    # 4 rollouts of 256 steps: the entropy bonus and the learning rate fall linearly with the steps done
    assert [round(e, 6) for _, e, _ in seen[1:]] == [round(0.02 * (1 - n / 1024), 6) for n, _, _ in seen[1:]]
    assert seen[-1][2] < seen[1][2] < 1e-3
    assert PPO.load(tmp_path / "s.zip").lr_schedule(0.0) == pytest.approx(1e-4)
    assert info["config"]["schedule"] == {"learning_rate": 1e-4, "ent_coef": 0.0}
    for bad, says in [({"gamma": 0.5}, "unknown key"), ({"clip_range": 0.1}, "needs hyperparams.clip_range"),
                      ({"learning_rate": -1.0}, "schedule.learning_rate must be > 0")]:
        with pytest.raises(ConfigError, match=says):
            validate_config({**base, "schedule": bad})
    with pytest.raises(ConfigError, match="schedule.ent_coef: dqn has no ent_coef"):
        validate_config({**base, "algo": "dqn", "policy_kwargs": {}, "hyperparams": {"learning_rate": 1e-3},
                         "schedule": {"ent_coef": 0.0}})


@pytest.mark.parametrize("algo, hyperparams", [
    ("a2c", {"n_steps": 8, "learning_rate": 1e-3, "ent_coef": 0.01}),
    ("dqn", {"learning_starts": 64, "buffer_size": 1000, "train_freq": 4, "learning_rate": 1e-3}),
])
def test_another_sb3_algorithm_trains_from_the_same_config_format(tmp_path, algo, hyperparams):
    """A2C and DQN: the same YAML keys as PPO, the same held-out evaluations (learning curves),
    metadata that names the algorithm as the method (from the reward alone, no planner)."""
    from gym_gridloc_agents.loading import algo_class
    from gym_gridloc_agents.training.train import train

    path = tmp_path / f"{algo}.yml"
    path.write_text(yaml.safe_dump({
        "algo": algo, "env_id": "ColourGrid-v0", "n_envs": 2, "seed": 1, "total_timesteps": 256,
        "wrapper": {"belief": True, "flatten": True},
        "policy_kwargs": {"net_arch": [16], "features_extractor": "belief_log", "features_extractor_kwargs": {"readings": 4}},
        "hyperparams": hyperparams, "schedule": {"learning_rate": 1e-4},
        "eval_freq": 128, "eval_episodes": 3, "output": str(tmp_path / f"{algo}.zip"), "checkpoint_dir": str(tmp_path / "ck")}))
    info = train(path, progress_bar=False)
    assert info["algo"] == algo and info["method"] == algo and len(info["evaluations"]) >= 2
    assert isinstance(algo_class(algo).load(tmp_path / f"{algo}.zip"), algo_class(algo))
    runs = curves.load_runs(tmp_path / f"{algo}.zip")
    assert runs[0]["method"] == algo and curves.curve(runs)["steps"]


def test_sampled_acting_is_seeded_per_episode_and_read_from_the_metadata(tmp_path):
    """A model whose config says ``deterministic: false`` samples its actions; a seeded episode is
    the same every time (torch's generator seeded at reset), so benchmark rows stay reproducible."""
    import shutil

    from gym_gridloc_agents.envs import make_env
    from gym_gridloc_agents.policies import POLICY_DIR, make_policy
    from gym_gridloc_agents.evaluation.rollout import rollout

    env = make_env("RingSensor8x8-v0")
    shipped = POLICY_DIR / "RingSensor8x8-v0-recurrent.zip"
    meta = json.loads(shipped.with_suffix(".json").read_text())
    assert make_policy("recurrent", env.unwrapped.model, env_id="RingSensor8x8-v0").deterministic is meta.get("deterministic", True)
    greedy = tmp_path / "greedy.zip"
    shutil.copy(shipped, greedy)
    greedy.with_suffix(".json").write_text(json.dumps({**meta, "deterministic": True}))
    assert make_policy("recurrent", env.unwrapped.model, env_id="RingSensor8x8-v0", path=greedy).deterministic is True
    sampled = tmp_path / "sampled.zip"
    shutil.copy(shipped, sampled)
    sampled.with_suffix(".json").write_text(json.dumps({**meta, "deterministic": False}))
    policy = make_policy("recurrent", env.unwrapped.model, env_id="RingSensor8x8-v0", path=sampled)
    assert policy.deterministic is False  # read from the metadata
    first = [rollout(env, policy, s, keep=True, max_steps=30).actions for s in range(3)]
    again = [rollout(env, policy, s, keep=True, max_steps=30).actions for s in range(3)]
    assert first == again and first[0] != first[1]
    det = make_policy("recurrent", env.unwrapped.model, env_id="RingSensor8x8-v0", path=greedy)
    assert [rollout(env, det, s, keep=True, max_steps=30).actions for s in range(3)] != first
