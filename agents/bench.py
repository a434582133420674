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

Several PPO models (one per training seed, e.g. a sweep's ``models/<configuration>/``) give one
``ppo`` row across seeds: every model plays the same episodes; ``mean_steps`` is the mean of the
per-seed mean steps, ``mean_steps_iqm`` their interquartile mean and ``mean_steps_ci95`` a
bootstrap 95% interval across seeds (:mod:`gym_gridloc_agents.stats`; so are ``success_rate_ci95``
and ``accuracy_at_ci95``); rates, curves and ``median_steps`` pool the episodes of all seeds;
``per_seed`` holds each model's own numbers.
"""

from __future__ import annotations

import glob
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc_agents.envs import make_env
from gym_gridloc_agents.policies import POLICY_DIR, POLICY_NAMES, make_policy
from gym_gridloc_agents.rollout import rollout

BUDGETS = (5, 10, 25, 50)
#: The environments of ``gridloc bench --all`` (fixed maps, shipped policies).
BENCH_ENV_IDS = ("ColourGrid-v0", "RingSensor8x8-v0", "WindyMaze-v0")
#: The policies ``gridloc bench`` runs when ``--policies`` is not given.
DEFAULT_POLICIES = ("random", "greedy", "greedy2", "ppo", "recurrent")


def simulate(
    env_id: str,
    policy_name: str,
    seeds: Sequence[int],
    *,
    env_kwargs: dict[str, Any] | None = None,
    model_path: str | Path | None = None,
    budgets: Sequence[int] = BUDGETS,
    progress: bool = True,
) -> dict[str, Any]:
    """Run one policy on the given episode seeds; returns per-episode arrays."""
    from tqdm.auto import tqdm

    env = make_env(env_id, env_kwargs)
    max_steps = env.spec.max_episode_steps if env.spec is not None else None
    if not max_steps:
        raise ValueError(f"{env_id} has no max_episode_steps; the benchmark needs a step limit")
    policy = make_policy(policy_name, env.unwrapped.model, env_id=env_id, env_kwargs=dict(env_kwargs or {}),
                         path=model_path, pose=env.unwrapped.referee_pose)
    n = len(seeds)
    steps = np.zeros(n, dtype=np.int64)
    localised = np.zeros(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    truncated_flags = np.zeros(n, dtype=bool)
    horizon = max(max_steps, max(budgets))
    correct_at = np.zeros((n, horizon + 1), dtype=bool)
    start = time.perf_counter()
    bar = tqdm(seeds, desc=f"{env_id} {policy_name}", unit="ep", disable=not progress, leave=False)
    for i, seed in enumerate(bar):
        ep = rollout(env, policy, int(seed))
        localised[i] = ep.terminated
        success[i] = ep.success
        truncated_flags[i] = ep.truncated and not ep.terminated
        steps[i] = ep.steps if ep.terminated else max_steps
        correct_at[i, : len(ep.correct)] = ep.correct
        correct_at[i, len(ep.correct):] = ep.correct[-1]
    env.close()
    return {
        "steps": steps, "localised": localised, "success": success, "truncated": truncated_flags,
        "correct_at": correct_at, "max_steps": int(max_steps), "seconds": time.perf_counter() - start,
        "model": _model_name(getattr(policy, "path", None)),
    }


def _model_name(path) -> str | None:
    """How a results file names a model: shipped ones as ``agents/policies/<file>`` (not this
    machine's install path), a user's as given."""
    if not path:
        return None
    p = Path(path)
    if p.resolve().parent == POLICY_DIR:
        return f"agents/policies/{p.name}"
    return str(path)


def wilson_ci95(successes: int, n: int) -> list[float]:
    """The Wilson score 95% interval of a proportion ``successes / n``."""
    if n <= 0:
        return [0.0, 1.0]
    z = 1.959963984540054
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact ends, no rounding residue
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return [lo, hi]


def summarise(env_id: str, policy_name: str, parts: Sequence[dict[str, Any]], *, seed_start: int,
              budgets: Sequence[int] = BUDGETS) -> dict[str, Any]:
    """One benchmark row from the per-episode arrays of one or more :func:`simulate` runs."""
    steps = np.concatenate([p["steps"] for p in parts])
    localised = np.concatenate([p["localised"] for p in parts])
    success = np.concatenate([p["success"] for p in parts])
    truncated = np.concatenate([p["truncated"] for p in parts])
    correct_at = np.concatenate([p["correct_at"] for p in parts])
    max_steps = parts[0]["max_steps"]
    n = len(steps)
    mean = float(steps.mean())
    sd = float(steps.std(ddof=1)) if n > 1 else 0.0
    half = 1.96 * sd / math.sqrt(n)
    return {
        "env": env_id,
        "policy": policy_name,
        "episodes": int(n),
        "success_rate": float(success.mean()),
        "truncated_rate": float(truncated.mean()),
        "localised_rate": float(localised.mean()),
        "localised_correct_rate": float(success.sum() / localised.sum()) if localised.any() else None,
        "mean_steps": mean,
        "median_steps": float(np.median(steps)),
        "mean_steps_ci95": [mean - half, mean + half],
        "std_steps": sd,
        "accuracy_at": {str(k): float(correct_at[:, k].mean()) for k in budgets},
        "accuracy_at_ci95": {str(k): wilson_ci95(int(correct_at[:, k].sum()), n) for k in budgets},
        "success_rate_ci95": wilson_ci95(int(success.sum()), n),
        "max_episode_steps": int(max_steps),
        "seed_start": int(seed_start),
        "seconds": round(sum(p["seconds"] for p in parts), 3),
        "model": parts[0]["model"],
        "localised_curve": [float(np.mean(localised & (steps <= s))) for s in range(max_steps + 1)],
        "accuracy_curve": [float(x) for x in correct_at[:, : max_steps + 1].mean(axis=0)],
    }


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
    """Run one policy for ``episodes`` episodes (seeds ``seed_start + i``); returns one row."""
    if int(episodes) < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes!r}")
    seeds = range(seed_start, seed_start + int(episodes))
    part = simulate(env_id, policy_name, seeds, env_kwargs=env_kwargs, model_path=model_path,
                    budgets=budgets, progress=progress)
    return summarise(env_id, policy_name, [part], seed_start=seed_start, budgets=budgets)


def expand_models(items: Sequence[str | Path]) -> list[Path]:
    """The model files of ``--ppo-model``: a file as given, a directory's ``*.zip`` (not its
    subdirectories), a glob pattern's matches, each sorted by name; ``ValueError`` for a directory
    or pattern without a model, or a file given twice."""
    models: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(path.glob("*.zip"))
            if not found:
                raise ValueError(f"--ppo-model {item}: the directory holds no .zip model")
        elif glob.has_magic(str(item)):
            found = sorted(Path(p) for p in glob.glob(str(item)) if Path(p).is_file())
            if not found:
                raise ValueError(f"--ppo-model {item}: no file matches")
        else:
            found = [path]
        models += found
    seen = set()
    for m in models:
        key = m.resolve()
        if key in seen:
            raise ValueError(f"--ppo-model: {m} is given twice (each model is one seed)")
        seen.add(key)
    return models


def seed_aggregate(env_id: str, policy_name: str, runs: Sequence[Sequence[dict[str, Any]]], *, seed_start: int,
                   budgets: Sequence[int] = BUDGETS) -> dict[str, Any]:
    """One row across seeds from the :func:`simulate` parts of several models (``runs[i]``: model
    ``i``'s parts, every model on the same episodes); see the module docstring."""
    from gym_gridloc_agents import stats

    per = [summarise(env_id, policy_name, parts, seed_start=seed_start, budgets=budgets) for parts in runs]
    row = summarise(env_id, policy_name, [p for parts in runs for p in parts], seed_start=seed_start, budgets=budgets)
    means = [r["mean_steps"] for r in per]
    agg = stats.aggregate(means)
    row.update({
        "episodes": per[0]["episodes"],
        "episodes_total": row["episodes"],
        "seeds": len(per),
        "mean_steps": agg["mean"],
        "mean_steps_iqm": agg["iqm"],
        "mean_steps_ci95": agg["ci95"],
        "ci95": "bootstrap 95% interval across seeds (mean_steps, success_rate, accuracy_at)",
        "success_rate_ci95": stats.bootstrap_ci([r["success_rate"] for r in per]),
        "accuracy_at_ci95": {k: stats.bootstrap_ci([r["accuracy_at"][k] for r in per]) for k in row["accuracy_at"]},
        "model": [r["model"] for r in per],
        "per_seed": [{k: r[k] for k in ("model", "mean_steps", "median_steps", "mean_steps_ci95", "success_rate",
                                        "truncated_rate", "localised_correct_rate", "accuracy_at", "seconds")} for r in per],
    })
    return row


def _chunk_job(args: tuple) -> dict[str, Any]:
    env_id, name, seeds, model_path = args
    return simulate(env_id, name, seeds, model_path=model_path, progress=False)


def run_benchmark(
    env_ids: Sequence[str],
    policies: Sequence[str],
    episodes: int,
    *,
    seed_start: int = 0,
    ppo_model: str | Path | Sequence[str | Path] | None = None,
    recurrent_model: str | Path | None = None,
    progress: bool = True,
    jobs: int = 1,
) -> list[dict[str, Any]]:
    """Rows for every environment x policy, in that order.  With ``jobs > 1`` the episodes are
    split into chunks run in parallel processes (the same seeds, so the same numbers).  Several
    ``ppo_model`` files (one per seed) make the ``ppo`` row the aggregate across seeds
    (:func:`seed_aggregate`)."""
    several = None
    if isinstance(ppo_model, (list, tuple)):
        if not ppo_model:
            raise ValueError("ppo_model: an empty list of models")
        several = list(ppo_model) if len(ppo_model) > 1 else None
        ppo_model = ppo_model[0]
    for name in policies:
        if name not in POLICY_NAMES:
            raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICY_NAMES)}")
    if len(set(policies)) != len(policies):
        raise ValueError(f"policies must not repeat, got {list(policies)}")
    if int(episodes) < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes!r}")
    pairs = []
    for env_id in env_ids:
        for name in policies:
            path = ppo_model if name == "ppo" else recurrent_model if name == "recurrent" else None
            if name == "ppo" and several:
                pairs += [(env_id, name, m) for m in several]
            else:
                pairs.append((env_id, name, path))
    # Fail before any long run if a model is missing or does not fit.
    for env_id, name, path in pairs:
        if name in ("ppo", "recurrent"):
            make_policy(name, make_env(env_id).unwrapped.model, env_id=env_id, env_kwargs={}, path=path)
    if several:
        return _several_models(pairs, episodes, seed_start=seed_start, progress=progress, jobs=jobs)
    if jobs <= 1:
        return [run_episodes(e, n, episodes, seed_start=seed_start, model_path=p, progress=progress) for e, n, p in pairs]
    import multiprocessing as mp

    from tqdm.auto import tqdm

    chunk = max(1, math.ceil(episodes / (4 * jobs)))
    tasks = []
    for e, n, p in pairs:
        for lo in range(0, episodes, chunk):
            tasks.append((e, n, range(seed_start + lo, seed_start + min(episodes, lo + chunk)), p))
    ctx = mp.get_context("spawn")
    with ctx.Pool(jobs) as pool:
        parts = list(tqdm(pool.imap(_chunk_job, tasks), total=len(tasks), desc="benchmark chunks", disable=not progress))
        pool.close()  # let the workers exit on their own (``with`` alone terminates them)
        pool.join()
    rows = []
    for e, n, _ in pairs:
        mine = [part for task, part in zip(tasks, parts) if task[0] == e and task[1] == n]
        rows.append(summarise(e, n, mine, seed_start=seed_start))
    return rows


def _several_models(pairs: list[tuple], episodes: int, *, seed_start: int, progress: bool, jobs: int) -> list[dict[str, Any]]:
    """:func:`run_benchmark` when the ``ppo`` policy has one model per seed: the same episodes for
    every pair, then one row per (environment, policy), the ``ppo`` ones across seeds."""
    seeds = range(seed_start, seed_start + int(episodes))
    if jobs <= 1:
        parts = [[simulate(e, n, seeds, model_path=p, progress=progress)] for e, n, p in pairs]
    else:
        import multiprocessing as mp

        from tqdm.auto import tqdm

        chunk = max(1, math.ceil(episodes / (4 * jobs)))
        tasks = [(i, (e, n, seeds[lo: lo + chunk], p)) for i, (e, n, p) in enumerate(pairs) for lo in range(0, episodes, chunk)]
        with mp.get_context("spawn").Pool(jobs) as pool:
            done = list(tqdm(pool.imap(_chunk_job, [t for _, t in tasks]), total=len(tasks), desc="benchmark chunks",
                             disable=not progress))
            pool.close()
            pool.join()
        parts = [[part for (j, _), part in zip(tasks, done) if j == i] for i in range(len(pairs))]
    rows: list[dict[str, Any]] = []
    i = 0
    while i < len(pairs):
        e, n, _ = pairs[i]
        k = i
        while k < len(pairs) and pairs[k][:2] == (e, n):
            k += 1
        if n == "ppo":
            rows.append(seed_aggregate(e, n, parts[i:k], seed_start=seed_start))
        else:
            rows += [summarise(e, n, parts[j], seed_start=seed_start) for j in range(i, k)]
        i = k
    return rows


#: Keys every benchmark row has (what ``--update`` checks an existing file for).
ROW_KEYS = ("env", "policy", "episodes", "mean_steps", "success_rate")


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a bench JSON, or ``ValueError`` naming the file and what is wrong with it."""
    import json

    try:
        rows = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path} is not a readable bench JSON ({exc}); --update merges into a file gridloc bench wrote") from None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and all(k in r for k in ROW_KEYS) for r in rows):
        raise ValueError(f"{path} is not a bench JSON (a list of rows with {', '.join(ROW_KEYS)}); --update merges into a file gridloc bench wrote")
    return rows


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
        policy = r["policy"] if "seeds" not in r else f"{r['policy']} ({r['seeds']} seeds, IQM {r['mean_steps_iqm']:.2f})"
        cells = [
            r["env"], policy, str(r["episodes"]),
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
    # Show the steps where the curves still move (short episodes would be squeezed to the left).
    last = 0
    for r in rows:
        c = np.asarray(r["localised_curve"])
        last = max(last, int(np.searchsorted(c, 0.995 * c[-1])) if c[-1] > 0 else len(c) - 1)
    ax1.set_xlim(0, min(len(rows[0]["localised_curve"]) - 1, max(10, int(last * 1.15) + 1)))
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
    from gym_gridloc_agents.files import atomic_path

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
