"""Is a policy a resting point of PPO from the reward?  Continue a trained model with PPO's update,
from the environment's reward alone, under update settings of your choice, and score it on the
held-out validation episodes every ``--chunk`` steps.

A policy that PPO's update keeps where it is, at a given learning rate and batch, is one PPO can
stay at; one it moves away from, it cannot.  Started from a planner-distilled model (near the
optimum) and from a pure-PPO model, this tells apart a noise floor (PPO leaves the optimum) from a
local optimum (PPO stays where it is, optimum or not).

The environment, its wrapper and the vector env are those of ``--config`` (a training config);
the network is the model's own.  Each checkpoint is written to ``--out`` with the model's
metadata beside it (``"continued"`` added: the settings and steps), so ``gridloc bench`` loads it
as the model it continues (a distilled model stays ``distilled``: it was warm-started from a
planner).

    .venv/bin/python scripts/ppo_fixed_point.py --model agents/gym_gridloc_agents/models/WindyMaze-v0-distilled.zip \\
        --config configs/ppo_windymaze.yml --learning-rate 1e-4 --steps 1000000 --chunk 200000 --out runs/fixed_point
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from tqdm.auto import tqdm

from gym_gridloc_agents.envs import make_training_env
from gym_gridloc_agents.files import atomic_write_json, metadata_path, read_metadata
from gym_gridloc_agents.loading import load_model, model_method
from gym_gridloc_agents.training.config import load_config
from gym_gridloc_agents.training.evaluation import evaluate


def continue_ppo(model_path: Path, config: Path, out: Path, *, learning_rate: float, steps: int, chunk: int,
                 n_steps: int | None = None, batch_size: int | None = None, n_epochs: int | None = None,
                 ent_coef: float = 0.0, clip_range: float = 0.2, episodes: int = 2000, seed: int = 0,
                 progress: bool = True) -> list[dict]:
    """Continue ``model_path`` (a PPO model) with PPO from the reward for ``steps`` steps, a
    checkpoint and a validation score (``episodes`` held-out episodes) every ``chunk`` steps
    (rounded up to whole rollouts), the first at step 0 (the model as given).  Update settings: a constant ``learning_rate``,
    ``ent_coef`` and ``clip_range``; ``n_steps``, ``batch_size``, ``n_epochs`` (default: the
    config's), ``gamma`` and ``gae_lambda`` the config's.  Returns one row per checkpoint."""
    if steps < 1 or chunk < 1:
        raise ValueError(f"steps and chunk must be positive, got {steps} and {chunk}")
    meta = read_metadata(model_path)
    cfg = load_config(config)
    if meta.get("algo") != "ppo" or meta.get("env_id") != cfg["env_id"]:
        raise ValueError(f"{model_path} is a {meta.get('algo')} model of {meta.get('env_id')}; "
                         f"{config} trains ppo on {cfg['env_id']}")
    hp = cfg["hyperparams"]
    settings = {"learning_rate": float(learning_rate), "n_steps": int(n_steps or hp["n_steps"]),
                "batch_size": int(batch_size or hp["batch_size"]), "n_epochs": int(n_epochs or hp.get("n_epochs", 10)),
                "gamma": float(hp.get("gamma", 0.99)), "gae_lambda": float(hp.get("gae_lambda", 0.95)),
                "ent_coef": float(ent_coef), "clip_range": float(clip_range), "seed": int(seed), "config": str(config)}
    torch.set_num_threads(1)
    venv = make_training_env(cfg)
    lr, clip = settings["learning_rate"], settings["clip_range"]
    model = load_model(model_path, algo="ppo", env_id=cfg["env_id"], env_kwargs=cfg["env_kwargs"], env=venv, custom_objects={
        "learning_rate": lr, "lr_schedule": lambda _: lr, "clip_range": lambda _: clip,
        **{k: settings[k] for k in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "ent_coef")}})[0]
    model.set_random_seed(seed)
    eval_cfg = {**meta["config"], "env_id": cfg["env_id"], "env_kwargs": cfg["env_kwargs"]} if meta.get("config") else cfg
    out.mkdir(parents=True, exist_ok=True)
    rows, done, start = [], 0, int(model.num_timesteps)
    with tqdm(total=steps, unit="step", disable=not progress, desc=model_path.stem) as bar:
        while True:
            row = {"steps": done, **evaluate(model, eval_cfg, episodes)}
            rows.append(row)
            bar.write(f"{done:>9} steps: {row['mean_steps']:.3f} mean steps on {episodes} validation episodes")
            if done >= steps:
                break
            n = min(chunk, steps - done)
            model.learn(n, reset_num_timesteps=False)  # (whole rollouts: n_steps x n_envs at a time)
            bar.update(int(model.num_timesteps) - start - done)
            done = int(model.num_timesteps) - start
            target = out / f"{model_path.stem}-{done}.zip"
            model.save(target)
            atomic_write_json(metadata_path(target), {**meta, "method": model_method(meta), "continued": {**settings, "from": str(model_path), "steps": done}})
    venv.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, required=True, help="the PPO model to continue (.zip, its metadata beside it)")
    p.add_argument("--config", type=Path, required=True, help="a training config: the environment, wrapper and vector env")
    p.add_argument("--out", type=Path, required=True, help="directory for the checkpoints")
    p.add_argument("--learning-rate", type=float, required=True, help="the constant learning rate")
    p.add_argument("--steps", type=int, default=1_000_000, help="environment steps in all (default 1M)")
    p.add_argument("--chunk", type=int, default=200_000, help="steps between checkpoints (default 200k)")
    p.add_argument("--n-steps", type=int, help="rollout length per env (default: the config's)")
    p.add_argument("--batch-size", type=int, help="minibatch (default: the config's)")
    p.add_argument("--n-epochs", type=int, help="epochs per rollout (default: the config's)")
    p.add_argument("--ent-coef", type=float, default=0.0, help="entropy bonus (default 0)")
    p.add_argument("--clip-range", type=float, default=0.2, help="PPO's clip range (default 0.2)")
    p.add_argument("--episodes", type=int, default=2000, help="validation episodes per score (default 2000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, help="write the scores as JSON")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    try:
        rows = continue_ppo(a.model, a.config, a.out, learning_rate=a.learning_rate, steps=a.steps, chunk=a.chunk,
                            n_steps=a.n_steps, batch_size=a.batch_size, n_epochs=a.n_epochs, ent_coef=a.ent_coef,
                            clip_range=a.clip_range, episodes=a.episodes, seed=a.seed, progress=not a.no_progress)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.json:
        atomic_write_json(a.json, {"model": str(a.model), "rows": rows})
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
