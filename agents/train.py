"""Training from a validated config (see :mod:`agents.config`), and safe model loading.

Training never loses work: a checkpoint every ``checkpoint_freq`` steps and one on Ctrl-C (both in
``checkpoint_dir``), ``resume=`` continues from a checkpoint to ``total_timesteps``; an existing
model file is not overwritten unless ``force=True``; the model and its metadata JSON are written to
a temporary file and renamed into place, so a crash never leaves half a file.

Model zip files are pickles: load only files from a trusted source.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Callable

from gym_gridloc_agents.config import ConfigError, activation, algo_class, validate_config
from gym_gridloc_agents.envs import make_env, make_training_env
from gym_gridloc_agents.files import atomic_save_model, atomic_write_json, load_model, metadata_path, read_metadata


class TrainingInterrupted(Exception):
    """Raised by :func:`train` after Ctrl-C, once the checkpoint has been written."""

    def __init__(self, checkpoint: Path, num_timesteps: int) -> None:
        super().__init__(f"training interrupted at {num_timesteps} steps; checkpoint saved to {checkpoint}")
        self.checkpoint = checkpoint
        self.num_timesteps = num_timesteps


def versions() -> dict[str, str]:
    """Versions of the packages a model depends on."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in ("gym_gridloc", "gymnasium", "stable-baselines3", "sb3-contrib", "torch", "numpy"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _policy_kwargs(cfg: dict[str, Any]) -> dict[str, Any]:
    pk = dict(cfg["policy_kwargs"])
    if "activation_fn" in pk:
        pk["activation_fn"] = activation(pk["activation_fn"])
    return pk


def default_checkpoint_dir(cfg: dict[str, Any]) -> Path:
    if cfg.get("checkpoint_dir"):
        return Path(cfg["checkpoint_dir"])
    return Path("runs") / "checkpoints" / Path(cfg["output"]).stem


# -- evaluation on held-out seeds -------------------------------------------------------------------
EVAL_SEED_BASE = 2_000_000


def evaluate(model, cfg: dict[str, Any], episodes: int) -> float:
    """Mean steps to localise of ``model`` (deterministic) on seeds ``EVAL_SEED_BASE + i``, which
    are disjoint from the benchmark's ``0..N-1``; a truncated episode counts at the step limit."""
    from gym_gridloc_agents.policies import PPOPolicy, RecurrentPolicy
    from gym_gridloc_agents.rollout import rollout

    env = make_env(cfg["env_id"], cfg["env_kwargs"])
    cls = RecurrentPolicy if cfg["algo"] == "recurrent_ppo" else PPOPolicy
    policy = cls(env.unwrapped.model, sb3_model=model)
    total = sum(rollout(env, policy, EVAL_SEED_BASE + i).steps for i in range(episodes))
    env.close()
    return total / episodes


def _eval_callback(cfg: dict[str, Any], directory: Path, history: list):
    from stable_baselines3.common.callbacks import BaseCallback

    freq, episodes = cfg["eval_freq"], cfg["eval_episodes"]

    class Eval(BaseCallback):
        next_at = None

        def _on_step(self) -> bool:
            if self.next_at is None:
                self.next_at = (self.num_timesteps // freq + 1) * freq
            if self.num_timesteps >= self.next_at:
                record_evaluation(self.model, cfg, episodes, directory, history)
                self.next_at = (self.num_timesteps // freq + 1) * freq
            return True

    return Eval()


def record_evaluation(model, cfg, episodes, directory: Path, history: list) -> None:
    mean = evaluate(model, cfg, episodes)
    best = min((h["mean_steps"] for h in history), default=float("inf"))
    history.append({"num_timesteps": int(model.num_timesteps), "mean_steps": round(mean, 4)})
    if mean < best:
        atomic_save_model(model, directory / "best.zip")


# -- training -------------------------------------------------------------------------------------
def _checkpoint_callback(freq: int, directory: Path, meta: Callable[[], dict[str, Any]]):
    from stable_baselines3.common.callbacks import BaseCallback

    class Checkpoint(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_at = None
            self.saved: list[Path] = []

        def _on_step(self) -> bool:
            if self.next_at is None:
                self.next_at = (self.num_timesteps // freq + 1) * freq
            if self.num_timesteps >= self.next_at:
                path = directory / f"step_{self.num_timesteps}.zip"
                atomic_save_model(self.model, path)
                atomic_write_json(metadata_path(path), {**meta(), "num_timesteps": int(self.num_timesteps)})
                self.saved.append(path)
                self.next_at = (self.num_timesteps // freq + 1) * freq
            return True

    return Checkpoint()


def train(
    config: dict[str, Any] | str | Path,
    *,
    force: bool = False,
    resume: str | Path | None = None,
    output: str | Path | None = None,
    total_timesteps: int | None = None,
    tensorboard_log: str | Path | None = None,
    progress_bar: bool = True,
    torch_threads: int | None = 1,
    callbacks: list | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """Train the model a config describes; returns the metadata written beside it.

    ``output``, ``total_timesteps`` and ``tensorboard_log`` override the config.  Raises
    :class:`FileExistsError` if the output exists and ``force`` is false (before any training),
    :class:`TrainingInterrupted` after Ctrl-C (the checkpoint is saved first).
    """
    from gym_gridloc_agents.config import load_config

    cfg = load_config(config) if isinstance(config, (str, Path)) else validate_config(config)
    if output is not None:
        cfg["output"] = str(output)
        if not cfg["output"].endswith(".zip"):
            raise ConfigError(f"--output must end in .zip, got {cfg['output']!r}")
    if total_timesteps is not None:
        if int(total_timesteps) < 1:
            raise ConfigError(f"total_timesteps must be >= 1, got {total_timesteps!r}")
        cfg["total_timesteps"] = int(total_timesteps)
    if tensorboard_log is not None:
        cfg["tensorboard_log"] = str(tensorboard_log)
    out = Path(cfg["output"])
    if out.exists() and not force:
        raise FileExistsError(f"{out} exists; pass --force (force=True) to overwrite it")

    import torch

    if torch_threads:
        torch.set_num_threads(int(torch_threads))
    Algo = algo_class(cfg["algo"])
    venv = make_training_env(cfg)
    ckpt_dir = default_checkpoint_dir(cfg)
    previous_wall = previous_cpu = 0.0
    prev_pretrain = None
    resumed_from = None
    if resume is not None:
        resume = Path(resume)
        if not resume.is_file():
            raise FileNotFoundError(f"checkpoint {str(resume)!r} does not exist")
        prev = read_metadata(resume)
        if prev:
            if prev.get("env_id") not in (None, cfg["env_id"]) or prev.get("algo") not in (None, cfg["algo"]):
                raise ValueError(
                    f"checkpoint {resume} was trained with {prev.get('algo')} on {prev.get('env_id')}, "
                    f"but the config asks for {cfg['algo']} on {cfg['env_id']}"
                )
        model = load_model(resume, algo=cfg["algo"], env=venv)[0]
        previous_wall = float(prev.get("wall_time_seconds", 0.0))
        previous_cpu = float(prev.get("cpu_seconds", 0.0))
        prev_pretrain = prev.get("pretrain")
        resumed_from = str(resume)
        if cfg["tensorboard_log"]:
            model.tensorboard_log = cfg["tensorboard_log"]
    else:
        model = Algo(
            cfg["policy"],
            venv,
            seed=cfg["seed"],
            policy_kwargs=_policy_kwargs(cfg),
            tensorboard_log=cfg["tensorboard_log"],
            device="cpu",
            verbose=0,
            **cfg["hyperparams"],
        )

    start = time.perf_counter()
    cpu_start = time.process_time()
    pretrain_info = None
    if cfg.get("pretrain") and resume is None:
        from gym_gridloc_agents.pretrain import behaviour_cloning

        pretrain_info = behaviour_cloning(model, cfg, progress=progress_bar)

    def meta() -> dict[str, Any]:
        return {
            "algo": cfg["algo"],
            "env_id": cfg["env_id"],
            "env_kwargs": cfg["env_kwargs"],
            "wrapper": cfg["wrapper"],
            "observation_space": repr(venv.observation_space),
            "action_space": repr(venv.action_space),
            "seed": cfg["seed"],
            "total_timesteps": cfg["total_timesteps"],
            "num_timesteps": int(model.num_timesteps),
            "wall_time_seconds": round(previous_wall + time.perf_counter() - start, 2),
            "cpu_seconds": round(previous_cpu + time.process_time() - cpu_start, 2),
            "pretrain": pretrain_info if resume is None else prev_pretrain,
            "torch_threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(),
            "versions": versions(),
            "config": cfg,
            "resumed_from": resumed_from,
            "command": command or " ".join(sys.argv),
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        }

    cbs = list(callbacks or [])
    if cfg["checkpoint_freq"] > 0:
        cbs.append(_checkpoint_callback(cfg["checkpoint_freq"], ckpt_dir, meta))
    evaluations: list[dict[str, Any]] = []
    if cfg["eval_freq"] > 0:
        cbs.append(_eval_callback(cfg, ckpt_dir, evaluations))
    remaining = cfg["total_timesteps"] - int(model.num_timesteps)
    try:
        if remaining > 0:
            model.learn(
                remaining,
                callback=cbs or None,
                progress_bar=progress_bar,
                reset_num_timesteps=resume is None,
                tb_log_name=f"{cfg['algo']}_{cfg['env_id']}_seed{cfg['seed']}",
            )
    except KeyboardInterrupt:
        path = ckpt_dir / f"interrupted_step_{int(model.num_timesteps)}.zip"
        atomic_save_model(model, path)
        atomic_write_json(metadata_path(path), {**meta(), "interrupted": True})
        venv.close()
        raise TrainingInterrupted(path, int(model.num_timesteps)) from None
    selected = None
    if cfg["eval_freq"] > 0:
        # Keep the best of the held-out evaluations (the final model included), as rl-zoo's
        # best_model: PPO's evaluation curve is noisy from one update to the next.
        if not evaluations or evaluations[-1]["num_timesteps"] != int(model.num_timesteps):
            record_evaluation(model, cfg, cfg["eval_episodes"], ckpt_dir, evaluations)
        best = min(evaluations, key=lambda h: h["mean_steps"])
        selected = best["num_timesteps"]
        final_timesteps = int(model.num_timesteps)
        model = Algo.load(ckpt_dir / "best.zip", device="cpu")
        model.num_timesteps = final_timesteps
    info = {**meta(), "interrupted": False, "evaluations": evaluations, "selected_timesteps": selected,
            "eval_seeds": f"{EVAL_SEED_BASE}..{EVAL_SEED_BASE + cfg['eval_episodes'] - 1}" if evaluations else None}
    if out.exists() and not force:  # appeared while training
        raise FileExistsError(f"{out} appeared during training; pass --force to overwrite it")
    # The final model is for acting: drop Adam's moment estimates (two thirds of the file); the
    # checkpoints keep them for resuming.
    model.policy.optimizer.state.clear()
    info["optimizer_state"] = "dropped (checkpoints keep it)"
    atomic_save_model(model, out)
    atomic_write_json(metadata_path(out), info)
    venv.close()
    return info
