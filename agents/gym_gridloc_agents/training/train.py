"""Training from a validated config (see :mod:`gym_gridloc_agents.training.config`).

Training never loses work:

* every output (model, metadata JSON, checkpoint and TensorBoard directories) is checked before
  the first step (:func:`check_outputs`), an existing model is kept unless ``force=True``, and a
  second training into the same output or checkpoint directory is refused (:func:`exclusive`);
* a checkpoint every ``checkpoint_freq`` steps and one on Ctrl-C, also during the warm start (its
  expert episodes are cached), in a checkpoint directory of this output's own;
* ``resume=`` continues from a checkpoint to ``total_timesteps``, with the evaluations made
  before the interruption and the best model so far;
* files are written to a temporary file and renamed into place; if the final write still fails,
  the model is saved in the checkpoint directory (or the system's temporary directory) and the
  error says where.

Model zip files are pickles: load only files from a trusted source.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import os
import platform
import re
import sys
import time
from pathlib import Path
from typing import Any, Callable

import torch
from stable_baselines3.common.callbacks import BaseCallback

import gym_gridloc
from gym_gridloc.core.validation import check_int
from gym_gridloc_agents.training.config import ConfigError, activation, load_config, validate_config
from gym_gridloc_agents.envs import make_training_env
from gym_gridloc_agents.features import EXTRACTORS
from gym_gridloc_agents import files
from gym_gridloc_agents.files import (OutputError, atomic_save_model, atomic_write_json, locked, metadata_path, read_metadata,
                                     rescue_write, writable_directory)
from gym_gridloc_agents.loading import algo_class, load_model, model_method
from gym_gridloc_agents.training.pretrain import WarmStartInterrupted, behaviour_cloning
from gym_gridloc_agents.training.evaluation import EVAL_SEED_BASE, best_entry, record_evaluation, score


class TrainingInterrupted(Exception):
    """Raised by :func:`train` after Ctrl-C, once the checkpoint has been written."""

    def __init__(self, checkpoint: Path, num_timesteps: int, during: str = "training") -> None:
        super().__init__(f"{during} interrupted at {num_timesteps} steps; checkpoint saved to {checkpoint}")
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
    """The config's policy_kwargs with names looked up in fixed tables (never evaluated)."""
    pk = dict(cfg["policy_kwargs"])
    if "activation_fn" in pk:
        pk["activation_fn"] = activation(pk["activation_fn"])
    if "features_extractor" in pk:
        pk["features_extractor_class"] = EXTRACTORS[pk.pop("features_extractor")]
    return pk


def _scheduled(cfg: dict[str, Any]) -> tuple[dict[str, Any], list]:
    """The algorithm's keyword arguments with ``schedule``'s linear schedules in place, and the
    callbacks that anneal what SB3 takes only as a number (``ent_coef``).  The fraction of
    training done is ``num_timesteps / total_timesteps`` (SB3's own for the callables), so a
    resumed run continues the schedule where it stopped."""
    from stable_baselines3.common.utils import LinearSchedule

    hp, sched = dict(cfg["hyperparams"]), cfg.get("schedule") or {}
    for key in ("learning_rate", "clip_range"):
        if key in sched:
            hp[key] = LinearSchedule(float(hp[key]), float(sched[key]), 1.0)
    cbs = []
    if "ent_coef" in sched:
        start, final, total = float(hp["ent_coef"]), float(sched["ent_coef"]), int(cfg["total_timesteps"])

        class AnnealEntropy(BaseCallback):
            def _on_rollout_end(self) -> None:  # before the update that uses it
                self.model.ent_coef = start + min(1.0, self.model.num_timesteps / total) * (final - start)

            def _on_step(self) -> bool:
                return True

        cbs.append(AnnealEntropy())
    return hp, cbs


def default_checkpoint_dir(cfg: dict[str, Any]) -> Path:
    """``checkpoint_dir``, or ``runs/checkpoints/<stem>-<hash of the output's full path>``: two
    outputs of the same name in different directories never share checkpoints."""
    if cfg.get("checkpoint_dir"):
        return Path(cfg["checkpoint_dir"])
    out = Path(cfg["output"]).expanduser().resolve()
    return Path("runs") / "checkpoints" / f"{out.stem}-{hashlib.sha1(str(out).encode()).hexdigest()[:8]}"


#: The files a training writes in its checkpoint directory under names of their own (the model's
#: output there under one of these names would be replaced by a checkpoint).
CHECKPOINT_NAMES = re.compile(r"(?:interrupted_)?step_\d+\.zip|best(?:-before-.*)?\.zip")
#: How ``force`` is spelt in the messages (the command's flag, the library's keyword).
FORCE = "--force (force=True)"


def model_outputs(out: Path) -> list[tuple[Path, str, str]]:
    """The model ``out`` and its metadata as :func:`gym_gridloc_agents.files.check_outputs` takes them."""
    return [(out, files.MODEL, "model"), (metadata_path(out), files.MODEL_METADATA, "model's metadata")]


def check_outputs(cfg: dict[str, Any], ckpt_dir: Path, *, force: bool, inputs=()) -> None:
    """Everything training will write, checked before the first step: the model and its metadata
    by the checker every command shares (:func:`gym_gridloc_agents.files.check_outputs`; never
    one of ``inputs``, a file of another kind, a checkpoint of this run or its checkpoint or
    TensorBoard directory; an existing model only with ``force``), then those directories.
    :class:`OutputError` naming the path (``OutputExists``, a ``FileExistsError``, without ``force``)."""
    out = Path(cfg["output"])
    outputs = model_outputs(out)
    directories = [(ckpt_dir, "checkpoint directory")]
    if cfg.get("tensorboard_log"):
        directories.append((Path(cfg["tensorboard_log"]), "TensorBoard directory"))
    for directory, what in directories:
        for path, _, owhat in outputs:
            if directory.expanduser().resolve() == path.expanduser().resolve():
                raise OutputError(f"the {what} {directory} is also the {owhat}: give each output its own path")
    if out.expanduser().resolve().parent == ckpt_dir.expanduser().resolve() and CHECKPOINT_NAMES.fullmatch(out.name):
        raise OutputError(f"the model {out} has the name of a checkpoint in this run's checkpoint directory {ckpt_dir}: "
                          "a checkpoint would replace it; choose another --output")
    files.check_outputs(outputs, inputs=inputs, replace=force, flag=FORCE)
    for directory, what in directories:
        writable_directory(directory, what)


@contextlib.contextmanager
def exclusive(output: str | Path, ckpt_dir: Path):
    """The locks (:func:`gym_gridloc_agents.files.locked`, released when the process ends, even by
    ``kill -9``) that keep a training alone in its checkpoint directory and its output; an
    :class:`OutputError` naming what another process holds."""
    with locked(ckpt_dir, wait=False, what="checkpoint directory", directory=True), \
            locked(output, wait=False, what="model", directory=False):
        yield


def _every(freq: int, action: Callable[[Any], None]):
    """An SB3 callback that calls ``action(model)`` at the first step at or past each multiple of
    ``freq`` after the step where training (or a resumed training) starts."""
    class Every(BaseCallback):
        next_at = None

        def _on_step(self) -> bool:
            if self.next_at is not None and self.num_timesteps >= self.next_at:
                action(self.model)
            if self.next_at is None or self.num_timesteps >= self.next_at:  # the first step, or just acted
                self.next_at = (self.num_timesteps // freq + 1) * freq
            return True

    return Every()


# -- training -------------------------------------------------------------------------------------
def train(config: dict[str, Any] | str | Path, **kwargs: Any) -> dict[str, Any]:
    with contextlib.ExitStack() as locks:  # the checkpoint directory and the output: one training each (exclusive)
        return _train(config, locks=locks, **kwargs)


def _train(
    config: dict[str, Any] | str | Path,
    *,
    locks: contextlib.ExitStack,
    force: bool = False,
    resume: str | Path | None = None,
    output: str | Path | None = None,
    total_timesteps: int | None = None,
    tensorboard_log: str | Path | None = None,
    progress_bar: bool = True,
    torch_threads: int | None = 1,
    callbacks: list | None = None,
    command: str | None = None,
    on_evaluation: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Train the model a config describes; returns the metadata written beside it.

    ``output``, ``total_timesteps`` and ``tensorboard_log`` override the config.  Raises
    :class:`OutputError` before any training when an output cannot be written (see
    :func:`check_outputs`; a ``FileExistsError`` when the model exists and ``force`` is not given)
    or another training holds the checkpoint directory or the output, :class:`TrainingInterrupted`
    after Ctrl-C (the checkpoint is saved first).
    ``on_evaluation`` is called with each held-out evaluation (e.g. to report it to a tuner).
    """
    cfg = load_config(config) if isinstance(config, (str, Path)) else validate_config(config)
    if output is not None:
        cfg["output"] = str(output)
        if not cfg["output"].endswith(".zip"):
            raise ConfigError(f"--output must end in .zip, got {cfg['output']!r}")
    if total_timesteps is not None:
        cfg["total_timesteps"] = check_int("total_timesteps", total_timesteps, what="a whole number >= 1", error=ConfigError)
    if tensorboard_log is not None:
        cfg["tensorboard_log"] = str(tensorboard_log)
    ckpt_dir = default_checkpoint_dir(cfg)
    prev: dict[str, Any] = {}
    if resume is not None:
        resume = Path(resume)
        if not resume.is_file():
            raise FileNotFoundError(f"checkpoint {str(resume)!r} does not exist")
        prev = read_metadata(resume)
        if prev.get("env_id") not in (None, cfg["env_id"]) or prev.get("algo") not in (None, cfg["algo"]):
            raise ValueError(
                f"checkpoint {resume} was trained with {prev.get('algo')} on {prev.get('env_id')}, "
                f"but the config asks for {cfg['algo']} on {cfg['env_id']}"
            )
        check_resumed_config(resume, prev, cfg)
    inputs = [config if isinstance(config, (str, Path)) else None]
    if resume is not None:
        inputs += [resume, metadata_path(resume)]
    check_outputs(cfg, ckpt_dir, force=force, inputs=inputs)
    locks.enter_context(exclusive(cfg["output"], ckpt_dir))
    if resume is None and (ckpt_dir / "best.zip").exists():  # an earlier run's best: kept aside, not mixed in
        stamp = time.strftime("%Y%m%d-%H%M%S")
        for name in ("best.zip", "best.json"):
            if (ckpt_dir / name).exists():
                os.replace(ckpt_dir / name, ckpt_dir / name.replace("best", f"best-before-{stamp}"))

    if torch_threads:
        torch.set_num_threads(int(torch_threads))
    Algo = algo_class(cfg["algo"])
    hyperparams, schedule_callbacks = _scheduled(cfg)
    venv = make_training_env(cfg)
    if resume is not None:
        model = load_model(resume, algo=cfg["algo"], env=venv)[0]
        if cfg["tensorboard_log"]:
            model.tensorboard_log = cfg["tensorboard_log"]
    else:
        model = Algo(cfg["policy"], venv, seed=cfg["seed"], policy_kwargs=_policy_kwargs(cfg),
                     tensorboard_log=cfg["tensorboard_log"], device="cpu", verbose=0, **hyperparams)

    start, cpu_start = time.perf_counter(), time.process_time()
    evaluations: list[dict[str, Any]] = list(prev.get("evaluations") or [])
    state: dict[str, Any] = {"pretrain": prev.get("pretrain"), "warm_start": prev.get("warm_start")}

    def meta() -> dict[str, Any]:
        return {
            "algo": cfg["algo"],
            "method": model_method({"algo": cfg["algo"], "pretrain": cfg.get("pretrain")}),
            "deterministic": cfg.get("deterministic", True), "break_cycles": cfg.get("break_cycles", False),
            "env_id": cfg["env_id"], "env_kwargs": cfg["env_kwargs"], "wrapper": cfg["wrapper"],
            "observation_space": repr(venv.observation_space), "action_space": repr(venv.action_space),
            "seed": cfg["seed"], "total_timesteps": cfg["total_timesteps"], "num_timesteps": int(model.num_timesteps),
            "wall_time_seconds": round(float(prev.get("wall_time_seconds", 0.0)) + time.perf_counter() - start, 2),
            "cpu_seconds": round(float(prev.get("cpu_seconds", 0.0)) + time.process_time() - cpu_start, 2),
            "pretrain": state["pretrain"], "warm_start": state["warm_start"], "evaluations": list(evaluations),
            "torch_threads": torch.get_num_threads(), "cpu_count": os.cpu_count(), "versions": versions(),
            "config": cfg, "resumed_from": None if resume is None else str(resume),
            "command": command or " ".join(sys.argv),
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "package_version": gym_gridloc.__version__,
        }

    def evaluate_now(m) -> None:
        m_ = meta()
        record_evaluation(m, cfg, cfg["eval_episodes"], ckpt_dir, evaluations, on_evaluation,
                          clock={k: m_[k] for k in ("wall_time_seconds", "cpu_seconds")})

    def save(m, name: str, **extra: Any) -> Path:
        """A checkpoint ``name``: the model and its metadata (``meta()``, its ``num_timesteps`` is ``m``'s)."""
        atomic_save_model(m, ckpt_dir / name)
        atomic_write_json(metadata_path(ckpt_dir / name), {**meta(), **extra})
        return ckpt_dir / name

    def interrupted(during: str) -> TrainingInterrupted:
        path = save(model, f"interrupted_step_{int(model.num_timesteps)}.zip", interrupted=True)
        venv.close()
        return TrainingInterrupted(path, int(model.num_timesteps), during)

    # The warm start: from scratch, or continued where an interrupted one stopped.
    warm = state["warm_start"] or {}
    if cfg.get("pretrain") and (resume is None or not warm.get("done", True)):
        try:
            state["pretrain"] = behaviour_cloning(model, cfg, progress=progress_bar, cache=ckpt_dir / "expert.npz",
                                                  start_epoch=int(warm.get("epochs", 0)), start_round=int(warm.get("rounds", 0)))
            state["warm_start"] = {"done": True}
        except WarmStartInterrupted as exc:
            state["warm_start"] = {"done": False, "episodes": exc.episodes, "epochs": exc.epochs, "rounds": exc.rounds}
            raise interrupted("warm start") from None

    phase = "evaluation"  # Ctrl-C in any phase below: an interrupted checkpoint of the model trained so far
    try:
        if cfg["eval_freq"] > 0 and cfg.get("pretrain") and int(model.num_timesteps) == 0 and not evaluations:
            evaluate_now(model)  # the warm-started policy itself competes for "best" (PPO may not improve on it)
        if resume is not None and cfg["eval_freq"] > 0:  # the evaluation due at the checkpoint's own step
            due = int(model.num_timesteps) // cfg["eval_freq"] * cfg["eval_freq"]  # (it ran after the checkpoint was saved)
            if due > 0 and not any(e["num_timesteps"] >= due for e in evaluations):
                kept = best_entry(ckpt_dir)
                if kept is not None and kept["num_timesteps"] == int(model.num_timesteps):
                    evaluations.append(kept)
                else:
                    evaluate_now(model)
        cbs = list(callbacks or []) + schedule_callbacks
        if cfg["checkpoint_freq"] > 0:
            cbs.append(_every(cfg["checkpoint_freq"], lambda m: save(m, f"step_{m.num_timesteps}.zip")))
        if cfg["eval_freq"] > 0:
            cbs.append(_every(cfg["eval_freq"], evaluate_now))
        remaining, phase = cfg["total_timesteps"] - int(model.num_timesteps), "training"
        if remaining > 0:
            model.learn(remaining, callback=cbs or None, progress_bar=progress_bar, reset_num_timesteps=resume is None,
                        tb_log_name=f"{cfg['algo']}_{cfg['env_id']}_seed{cfg['seed']}")
        final, selected, phase = model, None, "final evaluation"
        if cfg["eval_freq"] > 0:
            # Keep the best of the held-out evaluations (the final model included), as rl-zoo's
            # best_model: PPO's evaluation curve is noisy from one update to the next.
            if not evaluations or evaluations[-1]["num_timesteps"] != int(model.num_timesteps):
                evaluate_now(model)
            best = best_entry(ckpt_dir) or min(evaluations, key=lambda h: score(cfg, h))
            if best not in evaluations:  # evaluated before the checkpoint this run resumed from was written
                evaluations.append({**best, "note": "evaluated before an interruption; kept as best.zip"})
            selected = best["num_timesteps"]
            final = Algo.load(ckpt_dir / "best.zip", device="cpu")
            final.num_timesteps = int(model.num_timesteps)
        # The final model is for acting: drop Adam's moment estimates (two thirds of the file); the
        # checkpoints keep them for resuming.
        final.policy.optimizer.state.clear()
        info = {**meta(), "interrupted": False, "selected_timesteps": selected,
                "eval_seeds": f"{EVAL_SEED_BASE}..{EVAL_SEED_BASE + cfg['eval_episodes'] - 1}" if evaluations else None,
                "optimizer_state": "dropped (checkpoints keep it)"}
        phase = "final write"
        save_final(final, info, Path(cfg["output"]), ckpt_dir, force=force)
    except KeyboardInterrupt:
        raise interrupted(phase) from None
    venv.close()
    return info


train.__doc__ = _train.__doc__


#: Config keys that define the model a checkpoint holds: a resumed training must not change them
#: (its metadata would describe a model it is not).
RESUME_KEYS = ("seed", "policy", "policy_kwargs", "hyperparams", "schedule", "wrapper", "pretrain")


def check_resumed_config(resume: Path, prev: dict[str, Any], cfg: dict[str, Any]) -> None:
    """``ValueError`` naming the first difference between the checkpoint's config and ``cfg`` in
    the environment's keywords (defaults filled in) or :data:`RESUME_KEYS`."""
    import json

    from gym_gridloc_agents.envs import default_kwargs

    def canon(value: Any) -> str:
        return json.dumps(value, sort_keys=True, default=str)

    old = prev.get("config") or {}
    if "env_kwargs" in prev:
        defaults = default_kwargs(cfg["env_id"])
        a, b = {**defaults, **prev["env_kwargs"]}, {**defaults, **cfg["env_kwargs"]}
        diff = sorted(k for k in set(a) | set(b) if canon(a.get(k)) != canon(b.get(k)))
        if diff:
            raise ValueError(f"checkpoint {resume} was trained with env_kwargs {prev['env_kwargs']}, the config asks for "
                             f"{cfg['env_kwargs']} (differs in {', '.join(diff)}): resume with the checkpoint's config")
    for key in RESUME_KEYS:
        if key in old and canon(old[key]) != canon(cfg.get(key)):
            raise ValueError(f"checkpoint {resume} was trained with {key} {canon(old[key])}, the config asks for "
                             f"{canon(cfg.get(key))}: the resumed model would not be what its metadata says; "
                             "resume with the checkpoint's config")


def save_final(model, info: dict[str, Any], out: Path, ckpt_dir: Path, *, force: bool) -> None:
    """Write the trained model and its metadata to ``out``; if that fails, or the outputs'
    check (the one made before training, :func:`gym_gridloc_agents.files.check_outputs`) now
    refuses them (a file appeared meanwhile), save them in the checkpoint directory (or
    elsewhere) and raise :class:`OutputError` saying where."""
    def write(target: Path) -> None:
        atomic_save_model(model, target)
        atomic_write_json(metadata_path(target), info if target == out else {**info, "rescued_from": str(out)})

    try:
        files.check_outputs(model_outputs(out), replace=force, flag=FORCE)
        problem = None
    except OutputError as exc:
        problem = f"at the end of training, {exc}"
    rescue_write(write, out, "model", places=(ckpt_dir,), problem=problem)
