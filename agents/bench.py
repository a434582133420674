"""The localisation-speed benchmark.

Every policy runs behind :class:`gym_gridloc.HMMBeliefWrapper` on the same episode seeds (episode
``i`` uses ``seed_start + i`` for the environment and for the policy's own generator).  Per
(environment, policy) row:

- ``success_rate``: episodes that ended by localising on the right cell;
- ``truncated_rate``: episodes that hit ``max_episode_steps`` without localising;
- ``mean_steps``, ``median_steps``, ``mean_steps_ci95`` (normal approximation,
  mean +- 1.96 sd / sqrt(n)): steps to localise, counted from reset, a truncated episode counted at
  the step limit;
- ``accuracy_at``: for budgets k (5, 10, 25, 50), the fraction of episodes whose most probable
  position is right after k steps.  An episode that ended before k steps (localised, or truncated
  by a shorter limit) keeps its estimate at its end;
- ``localised_correct_rate``: among episodes that ended by localising, the fraction whose estimate
  was right (the threshold promises at least ``localise_threshold``);
- ``seconds``: wall time of the row.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from agents.policies import POLICY_NAMES, make_policy

BUDGETS = (5, 10, 25, 50)


def _make_env(env_id: str, env_kwargs: dict[str, Any] | None):
    import gymnasium as gym

    import gym_gridloc

    return gym_gridloc.HMMBeliefWrapper(gym.make(env_id, **(env_kwargs or {})))


def run_episodes(
    env_id: str,
    policy_name: str,
    episodes: int,
    *,
    seed_start: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    model_path: str | Path | None = None,
    budgets: Sequence[int] = BUDGETS,
    progress: bool = True,
) -> dict[str, Any]:
    """Run one policy for ``episodes`` episodes; returns one benchmark row (with curves)."""
    from tqdm.auto import tqdm

    if int(episodes) < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes!r}")
    env = _make_env(env_id, env_kwargs)
    max_steps = env.spec.max_episode_steps if env.spec is not None else None
    if not max_steps:
        raise ValueError(f"{env_id} has no max_episode_steps; the benchmark needs a step limit")
    model = env.unwrapped.model
    policy = make_policy(policy_name, model, env_id=env_id, path=model_path)
    steps = np.zeros(episodes, dtype=np.int64)
    localised = np.zeros(episodes, dtype=bool)
    success = np.zeros(episodes, dtype=bool)
    truncated_flags = np.zeros(episodes, dtype=bool)
    horizon = max(max_steps, max(budgets))
    correct_at = np.zeros((episodes, horizon + 1), dtype=bool)
    start = time.perf_counter()
    bar = tqdm(range(episodes), desc=f"{env_id} {policy_name}", unit="ep", disable=not progress, leave=False)
    for i in bar:
        seed = seed_start + i
        obs, info = env.reset(seed=seed)
        policy.reset(seed=seed)
        history = [info["error"] == 0]
        t = 0
        while True:
            action = policy.act(obs["observation"], env.filter.full_belief)
            obs, _, terminated, truncated, info = env.step(action)
            t += 1
            history.append(info["error"] == 0)
            if terminated or truncated:
                break
        localised[i] = bool(terminated)
        success[i] = bool(terminated and info["success"])
        truncated_flags[i] = bool(truncated and not terminated)
        steps[i] = t if terminated else max_steps
        correct_at[i, : len(history)] = history
        correct_at[i, len(history):] = history[-1]
    seconds = time.perf_counter() - start
    env.close()
    n = episodes
    mean = float(steps.mean())
    sd = float(steps.std(ddof=1)) if n > 1 else 0.0
    half = 1.96 * sd / math.sqrt(n)
    localised_curve = [float(np.mean(localised & (steps <= s))) for s in range(max_steps + 1)]
    row = {
        "env": env_id,
        "policy": policy_name,
        "episodes": int(n),
        "success_rate": float(success.mean()),
        "truncated_rate": float(truncated_flags.mean()),
        "localised_rate": float(localised.mean()),
        "localised_correct_rate": float(success.sum() / localised.sum()) if localised.any() else None,
        "mean_steps": mean,
        "median_steps": float(np.median(steps)),
        "mean_steps_ci95": [mean - half, mean + half],
        "std_steps": sd,
        "accuracy_at": {str(k): float(correct_at[:, k].mean()) for k in budgets},
        "max_episode_steps": int(max_steps),
        "seed_start": int(seed_start),
        "seconds": round(seconds, 3),
        "model": str(getattr(policy, "path", "")) or None,
        "localised_curve": localised_curve,
        "accuracy_curve": [float(x) for x in correct_at[:, : max_steps + 1].mean(axis=0)],
    }
    return row


def _row_job(args: tuple) -> dict[str, Any]:
    env_id, name, episodes, kwargs = args
    return run_episodes(env_id, name, episodes, **kwargs)


def run_benchmark(
    env_ids: Sequence[str],
    policies: Sequence[str],
    episodes: int,
    *,
    seed_start: int = 0,
    ppo_model: str | Path | None = None,
    recurrent_model: str | Path | None = None,
    progress: bool = True,
    jobs: int = 1,
) -> list[dict[str, Any]]:
    """Rows for every environment x policy, in that order."""
    for name in policies:
        if name not in POLICY_NAMES:
            raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICY_NAMES)}")
    if len(set(policies)) != len(policies):
        raise ValueError(f"policies must not repeat, got {list(policies)}")
    tasks = []
    for env_id in env_ids:
        for name in policies:
            path = ppo_model if name == "ppo" else recurrent_model if name == "recurrent" else None
            tasks.append((env_id, name, int(episodes), {"seed_start": seed_start, "model_path": path, "progress": progress}))
    # Fail before any long run if a model is missing or does not fit.
    for env_id, name, _, kw in tasks:
        if name in ("ppo", "recurrent"):
            make_policy(name, _make_env(env_id, None).unwrapped.model, env_id=env_id, path=kw["model_path"])
    if jobs <= 1 or len(tasks) == 1:
        return [_row_job(t) for t in tasks]
    import multiprocessing as mp

    from tqdm.auto import tqdm

    ctx = mp.get_context("spawn")
    quiet = [(e, n, k, {**kw, "progress": False}) for e, n, k, kw in tasks]
    with ctx.Pool(min(jobs, len(tasks))) as pool:
        results = list(tqdm(pool.imap(_row_job, quiet), total=len(tasks), desc="benchmark rows", disable=not progress))
    return results


def public_row(row: dict[str, Any]) -> dict[str, Any]:
    """A row without its curves (for tables)."""
    return {k: v for k, v in row.items() if not k.endswith("_curve")}


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    budgets = list(rows[0]["accuracy_at"]) if rows else [str(b) for b in BUDGETS]
    head = ["env", "policy", "episodes", "mean steps (95% CI)", "median", "success", "truncated",
            "correct if localised", *[f"acc@{b}" for b in budgets], "seconds"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * len(head)) + "|"]
    for r in rows:
        lo, hi = r["mean_steps_ci95"]
        lc = r["localised_correct_rate"]
        cells = [
            r["env"], r["policy"], str(r["episodes"]),
            f"{r['mean_steps']:.2f} ({lo:.2f}-{hi:.2f})", f"{r['median_steps']:g}",
            f"{r['success_rate']:.3f}", f"{r['truncated_rate']:.3f}",
            "-" if lc is None else f"{lc:.3f}",
            *[f"{r['accuracy_at'][b]:.3f}" for b in budgets],
            f"{r['seconds']:.1f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(rows: Sequence[dict[str, Any]], path: str | Path, *, title: str | None = None) -> None:
    """Fraction localised against steps (left) and accuracy against the step budget (right),
    one curve per policy, for the rows of ONE environment.  Written atomically."""
    import os
    import tempfile

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = {r["env"] for r in rows}
    if len(envs) != 1:
        raise ValueError(f"plot() takes the rows of one environment, got {sorted(envs)}")
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=90)
    for r in rows:
        x = np.arange(len(r["localised_curve"]))
        (line,) = ax1.plot(x, r["localised_curve"], label=f"{r['policy']} (mean {r['mean_steps']:.1f})")
        ax2.plot(np.arange(len(r["accuracy_curve"])), r["accuracy_curve"], color=line.get_color(), label=r["policy"])
        ks = [int(k) for k in r["accuracy_at"]]
        ax2.plot(ks, [r["accuracy_at"][str(k)] for k in ks], "o", color=line.get_color(), ms=4)
    ax1.set_xlabel("steps from reset")
    ax1.set_ylabel("fraction of episodes localised")
    ax1.set_ylim(0, 1.02)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7, loc="lower right")
    ax2.set_xlabel("step budget")
    ax2.set_ylabel("P(most probable position = truth)")
    ax2.set_ylim(0, 1.02)
    ax2.set_xlim(0, max(60, 1))
    ax2.grid(alpha=0.3)
    fig.suptitle(title or f"{next(iter(envs))}: {rows[0]['episodes']} episodes per policy", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png")
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.unlink(tmp)
