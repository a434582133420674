"""Held-out evaluation during training: the validation episodes (seeds ``EVAL_SEED_BASE + i``
and, on random maps, :func:`gym_gridloc.maps.validation_set`; never the benchmark's episodes or
the test set), a model's score on them, and the record of every evaluation with the best model
kept as ``best.zip``.  These records are the learning curves of ``gridloc plot --curves``."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import torch

from gym_gridloc import maps
from gym_gridloc_agents.envs import make_env, served_env
from gym_gridloc_agents.files import atomic_save_model, atomic_write_json, metadata_path, read_metadata
from gym_gridloc_agents.policies import PPOPolicy, RecurrentPolicy

EVAL_SEED_BASE = 2_000_000


def evaluation_episodes(env, cfg: dict[str, Any], episodes: int) -> list[tuple[int, dict[str, Any] | None]]:
    """``(seed, reset options)`` of the held-out evaluation episodes: seeds ``EVAL_SEED_BASE + i``
    (disjoint from the benchmark's ``0..N-1``); where the environment draws a new map at every
    reset, also the validation maps of :func:`gym_gridloc.maps.validation_set` (never the test set)."""
    unwrapped = env.unwrapped
    if unwrapped.map_factory is not None and cfg["env_id"] in maps.families():
        # (DepthMaze's validation mazes drawn as its mazes are: generator, symmetric ones rejected or not)
        held = maps.validation_set(cfg["env_id"], unwrapped.model.shape[0], episodes, **getattr(unwrapped, "map_options", {}))
        return [(EVAL_SEED_BASE + m.index, {"map": m.grid, "state": m.state}) for m in held]
    return [(EVAL_SEED_BASE + i, None) for i in range(episodes)]


def evaluate(model, cfg: dict[str, Any], episodes: int) -> dict[str, float]:
    """``model`` (acting as ``cfg["deterministic"]`` and ``cfg["break_cycles"]`` say; sampled actions are seeded per episode
    and leave training's torch generator as it was) on the held-out evaluation episodes: mean steps to localise (a
    truncated episode counts at its length), the fraction that end collapsed onto the truth
    (``accuracy``) and the fraction whose most probable state is the truth at the end."""
    from gym_gridloc_agents.evaluation.rollout import rollout

    env = make_env(cfg["env_id"], cfg["env_kwargs"])
    cls = RecurrentPolicy if cfg["algo"] == "recurrent_ppo" else PPOPolicy  # (RecurrentPolicy ignores the wrapper)
    policy = cls(env.unwrapped.model, sb3_model=model, wrapper=cfg["wrapper"], deterministic=cfg.get("deterministic", True),
                 break_cycles=cfg.get("break_cycles", False),
                 env_id=cfg["env_id"], env_kwargs=cfg["env_kwargs"])
    env = served_env(env, policy)
    with torch.random.fork_rng():
        eps = [rollout(env, policy, seed, reset_options=opts) for seed, opts in evaluation_episodes(env, cfg, episodes)]
    env.close()
    n = len(eps)
    return {"mean_steps": sum(e.steps for e in eps) / n, "accuracy": sum(e.collapsed[-1] for e in eps) / n,
            "argmax_accuracy": sum(e.correct[-1] for e in eps) / n}


def score(cfg: dict[str, Any], entry: dict[str, Any]) -> float:
    """Lower is better: mean steps, or minus the accuracy for fixed-length (protocol) episodes."""
    return -entry["accuracy"] if cfg["env_kwargs"].get("episode_length") else entry["mean_steps"]


def best_entry(directory: Path) -> dict[str, Any] | None:
    """The evaluation of the model in ``best.zip`` (its ``best.json``), if there is one: it may
    be newer than the checkpoint a run resumes from."""
    try:
        entry = read_metadata(directory / "best.zip") if (directory / "best.zip").is_file() else {}
    except ValueError:
        return None
    return entry if "num_timesteps" in entry else None


def record_evaluation(model, cfg, episodes, directory: Path, history: list, on_evaluation=None,
                      clock: dict[str, float] | None = None) -> None:
    """Evaluate, append to ``history`` (which may hold the evaluations of an interrupted run) and
    keep the best model so far as ``best.zip`` with its evaluation in ``best.json``.  ``clock``
    (``wall_time_seconds``, ``cpu_seconds`` of training so far) is stored with the evaluation, for
    learning curves against wall time."""
    result = evaluate(model, cfg, episodes)
    kept = best_entry(directory)
    best = min((score(cfg, h) for h in [*history, *([kept] if kept else [])]), default=float("inf"))
    entry = {"num_timesteps": int(model.num_timesteps), **{k: round(v, 4) for k, v in result.items()},
             **{k: round(v, 2) for k, v in (clock or {}).items()}}
    history.append(entry)
    print(f"evaluation at {entry['num_timesteps']} steps on {episodes} held-out episodes: mean steps {entry['mean_steps']:.3f}, "
          f"accuracy {entry['accuracy']:.3f}, argmax accuracy {entry['argmax_accuracy']:.3f}"
          + ("  (best so far)" if score(cfg, entry) < best else ""), file=sys.stderr, flush=True)
    if score(cfg, entry) < best:
        atomic_save_model(model, directory / "best.zip")
        atomic_write_json(metadata_path(directory / "best.zip"), entry)
    if on_evaluation is not None:
        on_evaluation(dict(entry))
