"""Learning curves across seeds, as reinforcement-learning research reports them.

Each training evaluates its policy on held-out validation episodes every ``eval_freq``
environment steps (:func:`gym_gridloc_agents.training.evaluation.record_evaluation`; the metadata beside the
model keeps them, with the training's wall time at each).  A *curve* gathers the runs of one
configuration (the seeds of a sweep) and gives, at every evaluated step they share:

* the interquartile mean (IQM) across seeds (:func:`gym_gridloc_agents.evaluation.stats.iqm`, robust to one
  outlying seed; Agarwal et al. 2021, "Deep Reinforcement Learning at the Edge of the Statistical
  Precipice") and its percentile-bootstrap 95% interval (seeds resampled with replacement);
* the median wall time of training at that step, to plot the same curve against wall time;
* sample efficiency: the first step at which the IQM reaches a baseline's score (greedy2's, or
  the random walk's when it never reaches greedy2's).

The metric is the mean number of steps to localise (lower is better), or the accuracy at the
end of fixed-length episodes (``episode_length``: the research protocol, higher is better).

    gridloc plot --curves runs/sweeps/ppo_windymaze --baselines results/bench_10k.json --out curves.png
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc_agents.evaluation import stats
from gym_gridloc_agents.files import metadata_path, read_metadata
from gym_gridloc_agents.loading import model_method
from gym_gridloc_agents.policies import PLANNER_POLICIES

#: The baselines drawn as horizontal lines, and the policies counted as planners ("best planner").
BASELINES = ("random", "greedy2")
PLANNERS = PLANNER_POLICIES


def run_files(path: str | Path) -> list[Path]:
    """The model metadata files (``.json``) of one curve: a sweep directory (its
    ``models/<configuration>/*.json``; one configuration only), a directory of models, or one
    model file (``.zip`` or ``.json``)."""
    path = Path(path)
    if path.is_dir():
        if (path / "models").is_dir():
            configs = sorted(p for p in (path / "models").iterdir() if p.is_dir())
            if len(configs) != 1:
                raise ValueError(f"{path}: a sweep of {len(configs)} configurations; give one of "
                                 f"{', '.join(str(c) for c in configs) or '(none)'}")
            path = configs[0]
        found = sorted(p for p in path.glob("*.json") if p.with_suffix(".zip").is_file())
        if not found:
            raise ValueError(f"{path}: no trained model (.zip with its .json) in this directory")
        return found
    if path.suffix in (".zip", ".json") and metadata_path(path).is_file():
        return [metadata_path(path)]
    raise ValueError(f"{path}: not a sweep directory, a directory of models or a model with its .json")


def load_runs(path: str | Path) -> list[dict[str, Any]]:
    """The runs of one curve: per model, its seed, environment, method and evaluations."""
    runs = []
    for js in run_files(path):
        meta = read_metadata(js.with_suffix(".zip"))
        evals = [e for e in meta.get("evaluations") or [] if "num_timesteps" in e and "note" not in e]
        if not evals:
            raise ValueError(f"{js}: no held-out evaluations (train with eval_freq > 0)")
        runs.append({"path": str(js.with_suffix(".zip")), "seed": meta.get("seed"), "env_id": meta.get("env_id"),
                     "env_kwargs": meta.get("env_kwargs") or {}, "method": model_method(meta),
                     "evaluations": evals, "wall_time_seconds": meta.get("wall_time_seconds"),
                     "config": meta.get("config") or {}})
    envs = {(r["env_id"], repr(sorted(r["env_kwargs"].items()))) for r in runs}
    if len(envs) != 1:
        raise ValueError(f"{path}: the runs were trained on different environments ({sorted(envs)}); a curve is one task")
    one_configuration(runs)
    return runs


#: Config keys in which the seeds of one configuration differ (where each training writes, its text).
PER_SEED_KEYS = ("seed", "output", "checkpoint_dir", "tensorboard_log", "description")


def one_configuration(runs: Sequence[dict[str, Any]]) -> None:
    """Runs are seeds of a curve only when they are trainings of one configuration with different
    seeds: ``ValueError`` naming two runs of one seed (two configurations, or one training's
    checkpoints) or two runs of different configurations (and the keys they differ in)."""
    import json

    seen: dict[str, dict[str, Any]] = {}
    for r in runs:
        key = json.dumps(r["seed"])
        if r["seed"] is None or key in seen:
            raise ValueError(f"{r['path']}" + (" records no seed" if r["seed"] is None else
                             f" and {seen[key]['path']} were trained with the same seed {r['seed']} (two configurations, "
                             "or one training's checkpoints)") + ": a curve's runs are the seeds of one configuration")
        seen[key] = r
    first = runs[0]
    for r in runs[1:]:
        keys = sorted(set(first["config"]) | set(r["config"]))
        diff = [k for k in keys if k not in PER_SEED_KEYS and json.dumps(first["config"].get(k), sort_keys=True)
                != json.dumps(r["config"].get(k), sort_keys=True)]
        if diff:
            raise ValueError(f"{first['path']} and {r['path']} are two configurations (they differ in {', '.join(diff)}), "
                             "not two seeds of one: give each configuration as its own --curves RUNS")


def task_of(env_id: str, env_kwargs: dict[str, Any], test_set: bool = False) -> tuple[str, str, Any, bool]:
    """What a row or a curve measures: the environment's model (its keywords, defaults filled in), its
    episode length and whether its maps are drawn anew (at each reset, or a benchmark's held-out
    test maps: ``test_set``)."""
    import gymnasium as gym

    from gym_gridloc_agents.envs import default_kwargs
    from gym_gridloc_agents.loading import model_kwargs

    full = {**(default_kwargs(env_id) if env_id in gym.registry else {}), **dict(env_kwargs)}
    redrawn = True if test_set else full.get("new_map_each_reset")
    if redrawn is None:  # (DepthMaze: a new maze at each reset unless a layout or a map_seed fixes one)
        redrawn = full.get("layout") is None and full.get("map_seed") is None
    return env_id, model_kwargs(env_id, env_kwargs), full.get("episode_length"), bool(redrawn)


def metric_of(env_kwargs: dict[str, Any]) -> tuple[str, bool]:
    """``(evaluation key, lower is better)``: mean steps, or the accuracy for fixed-length episodes."""
    return ("accuracy", False) if env_kwargs.get("episode_length") else ("mean_steps", True)


def curve(runs: Sequence[dict[str, Any]], *, label: str = "", resamples: int = stats.BOOTSTRAP_RESAMPLES) -> dict[str, Any]:
    """The IQM curve of ``runs`` at the steps every run evaluated, with bootstrap 95% intervals,
    the median wall time at each step and each seed's own values."""
    if not runs:
        raise ValueError("no runs to aggregate")
    key, lower = metric_of(runs[0]["env_kwargs"])
    by_run = [{int(e["num_timesteps"]): e for e in r["evaluations"]} for r in runs]
    steps = sorted(set.intersection(*(set(b) for b in by_run)))
    if not steps:
        raise ValueError("the runs share no evaluated step (different eval_freq?)")
    values = np.array([[b[s][key] for b in by_run] for s in steps], dtype=float)  # (steps, seeds)
    walls = [[b[s].get("wall_time_seconds") for b in by_run] for s in steps]
    wall = [float(np.median(w)) if all(v is not None for v in w) else None for w in walls]
    return {
        "label": label, "env_id": runs[0]["env_id"], "env_kwargs": runs[0]["env_kwargs"],
        "methods": sorted({r["method"] for r in runs}), "metric": key, "lower_is_better": lower,
        "seeds": [r["seed"] for r in runs], "steps": steps, "wall_time_seconds": wall,
        "iqm": [stats.iqm(v) for v in values],
        "ci95": [stats.bootstrap_ci(v, statistic=stats.iqm, resamples=resamples) for v in values],
        "per_seed": values.T.tolist(),
    }


def baselines(rows: Sequence[dict[str, Any]], env_id: str, metric: str, lower: bool,
              env_kwargs: dict[str, Any] | None = None) -> dict[str, float]:
    """The horizontal lines of a curve from benchmark rows of its task (:func:`task_of`: ``env_id``
    and ``env_kwargs``, the curve's; a row of the default map is no line of a curve on random
    9x9 maps, a row at ``episode_length`` 30 none of a curve at 15): ``random``, ``greedy2`` and
    ``best planner`` (the best of the planners' rows); the rows' ``mean_steps`` or ``accuracy_at_L``."""
    col = "mean_steps" if metric == "mean_steps" else "accuracy_at_L"
    task = task_of(env_id, env_kwargs or {})
    mine = [r for r in rows if r.get("env") == env_id and r.get(col) is not None
            and isinstance(r.get("env_kwargs") or {}, dict) and task_of(env_id, r.get("env_kwargs") or {}, bool(r.get("test_set"))) == task]
    out = {r["policy"]: float(r[col]) for r in mine if r["policy"] in BASELINES}
    planners = [float(r[col]) for r in mine if r["policy"] in PLANNERS]
    if planners:
        out["best planner"] = min(planners) if lower else max(planners)
    return out


def sample_efficiency(c: dict[str, Any], lines: dict[str, float]) -> dict[str, Any] | None:
    """The first evaluated step at which the IQM reaches greedy2's score (or, if it never does,
    the random walk's): ``{"baseline", "score", "steps", "wall_time_seconds"}``, or None."""
    better = (lambda a, b: a <= b) if c["lower_is_better"] else (lambda a, b: a >= b)
    for name in ("greedy2", "random"):
        if name not in lines:
            continue
        for i, value in enumerate(c["iqm"]):
            if better(value, lines[name]):
                return {"baseline": name, "score": lines[name], "steps": c["steps"][i],
                        "wall_time_seconds": c["wall_time_seconds"][i]}
    return None


def plot_curves(curves: Sequence[dict[str, Any]], lines: dict[str, float], out: str | Path, *, title: str = "") -> None:
    """IQM curves with their 95% bands against environment steps (left) and wall time (right),
    the baselines as horizontal lines; the legend says which episodes each uses (the curves: the
    trainings' validation episodes; the lines: the benchmark's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    # the y range: the curves' bands and the lines near them (a line far off is named, not drawn)
    band = [v for c in curves for pair in c["ci95"] for v in pair] + [v for c in curves for v in c["iqm"]]
    span = (max(band) - min(band)) if band else 0.0
    near = [v for name, v in lines.items()  # greedy2 and the best planner always; the random walk if near
            if name != "random" or (band and min(band) - span <= v <= max(band) + span)]
    lo_y, hi_y = min(band + near, default=0.0), max(band + near, default=1.0)
    pad = 0.08 * (hi_y - lo_y or abs(hi_y) or 1.0)
    lo_y, hi_y = lo_y - pad, hi_y + pad
    styles = {"random": ("0.5", ":"), "greedy2": ("tab:green", "--"), "best planner": ("tab:red", "-.")}
    for ax, xkey, xlabel in ((axes[0], "steps", "environment steps"), (axes[1], "wall_time_seconds", "training wall time (s)")):
        for c in curves:
            x = c[xkey]
            keep = [i for i, v in enumerate(x) if v is not None]
            if not keep:
                continue
            xs = np.array([x[i] for i in keep], dtype=float)
            lo = [c["ci95"][i][0] for i in keep]
            hi = [c["ci95"][i][1] for i in keep]
            line, = ax.plot(xs, [c["iqm"][i] for i in keep], marker=".", label=f"{legend_label(c)}, validation episodes")
            ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
        for name, value in lines.items():
            colour, style = styles.get(name, ("black", ":"))
            if lo_y <= value <= hi_y:
                ax.axhline(value, color=colour, linestyle=style, linewidth=1.2, label=f"{name} {value:.4g} (benchmark episodes)")
            else:  # far off the curves (the random walk, usually): named at the edge, not drawn
                ax.annotate(f"{name} {value:.4g} ({'above' if value > hi_y else 'below'})", xy=(0.99, 0.98 if value > hi_y else 0.02),
                            xycoords="axes fraction", ha="right", va="top" if value > hi_y else "bottom", color=colour, fontsize=8)
        ax.set_ylim(lo_y, hi_y)
        if xkey == "steps":  # 500k, 1M: no run-together tick labels
            from matplotlib.ticker import EngFormatter

            ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    metric = curves[0]["metric"] if curves else "mean_steps"
    axes[0].set_ylabel("mean steps to localise (validation)" if metric == "mean_steps" else "accuracy at L (validation)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title or (curves[0]["env_id"] if curves else ""))
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def legend_label(curve: dict[str, Any]) -> str:
    """``label (IQM of 3 seeds)``, or ``label (1 seed)``: one seed's curve is its own."""
    n = len(curve["seeds"])
    return f"{curve['label']} ({'1 seed' if n == 1 else f'IQM of {n} seeds'})"


def curves_table(curves: Sequence[dict[str, Any]], lines: dict[str, float]) -> str:
    """A markdown line per curve: final IQM and interval, each seed's final value, sample efficiency."""
    out = ["| curve | seeds | steps | final IQM (95% CI) | per seed | reaches | at steps | at wall time |",
           "| --- | ---: | ---: | --- | --- | --- | ---: | ---: |"]
    for c in curves:
        eff = sample_efficiency(c, lines)
        lo, hi = c["ci95"][-1]
        wall = eff and eff["wall_time_seconds"]
        out.append(f"| {c['label']} | {len(c['seeds'])} | {c['steps'][-1]} | {c['iqm'][-1]:.3f} ({lo:.3f}-{hi:.3f}) | "
                   f"{', '.join(f'{v[-1]:.3f}' for v in c['per_seed'])} | "
                   f"{eff['baseline'] + ' ' + format(eff['score'], '.3f') if eff else 'neither greedy2 nor random'} | "
                   f"{eff['steps'] if eff else '-'} | {'-' if not wall or math.isnan(wall) else f'{wall:.0f} s'} |")
    return "\n".join(out)
