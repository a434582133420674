"""What the trials of a ``gridloc sweep`` produced, and its report: a trial's finished model and
the evaluation (and score) of the model ``train`` kept; one record per Tune trial with its status;
the configurations aggregated across seeds, the best configuration and its median seed
(``results/``, ``summary.md``/``.json``, ``best.zip``) and their tables.

No Ray here: :func:`collect` only reads the results Ray Tune returns and its saved state.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from gym_gridloc_agents.evaluation import stats
from gym_gridloc_agents.files import atomic_path, atomic_write_json, atomic_write_text, read_metadata
from gym_gridloc_agents.sweeps.sweep_spec import (
    canonical,
    config_label,
    configurations,
    trial_config,
)

#: Per-seed evaluation metrics (those ``train`` reports) and the score.
METRICS = ("score", "mean_steps", "accuracy", "argmax_accuracy")

MEDIAN_RULE = ("the seed whose score is the median of the configuration's seeds (the lower median for an even "
               "count, ties to the lower seed), not the best seed")
BEST_RULE = "the configuration with the best (lowest) mean score across seeds, among those whose seeds all finished"


# -- one trial's model -----------------------------------------------------------------------------
def _comparable(cfg: dict[str, Any]) -> str:
    return canonical({k: v for k, v in cfg.items() if k not in ("output", "checkpoint_dir", "tensorboard_log")})


def completed_metadata(cfg: dict[str, Any]) -> dict[str, Any] | None:
    """The metadata of this trial's finished model, if it exists and was trained with this config."""
    out = Path(cfg["output"])
    try:
        meta = read_metadata(out) if out.is_file() else {}  # (no model: {}, so None below)
    except ValueError:
        return None
    if meta.get("interrupted") is not False or not isinstance(meta.get("config"), dict):
        return None
    return meta if _comparable(meta["config"]) == _comparable(json.loads(json.dumps(cfg))) else None


def selected_evaluation(meta: dict[str, Any]) -> dict[str, Any]:
    """The held-out evaluation of the model ``train`` kept (its best evaluation)."""
    evals = meta.get("evaluations") or []
    chosen = [e for e in evals if e.get("num_timesteps") == meta.get("selected_timesteps")]
    if not chosen and not evals:
        raise ValueError("the model's metadata holds no evaluation")
    return dict((chosen or evals)[-1])


def score(cfg: dict[str, Any], entry: dict[str, Any]) -> float:
    """A trial's number, lower is better: :func:`gym_gridloc_agents.training.evaluation.score` (imported
    when called: this module does not pull torch)."""
    from gym_gridloc_agents.training import evaluation

    return float(evaluation.score(cfg, entry))

# -- Tune's trials ---------------------------------------------------------------------------------
def saved_statuses(exp_dir: Path) -> dict[str, str]:
    """Trial id -> status in Tune's last saved experiment state (what ``Tuner.restore`` resumes
    from): after Ctrl-C the interrupted trials are RUNNING or PENDING there, while in memory Tune
    has already stopped them (TERMINATED, like a trial the pruner stopped).  ``{}`` if unreadable."""
    try:
        latest = max(Path(exp_dir).glob("experiment_state-*.json"), key=lambda p: p.stat().st_mtime)
        items = json.loads(latest.read_text(encoding="utf-8"))["trial_data"]
        states = [json.loads(item[0]) if isinstance(item[0], str) else item[0] for item in items]
        return {str(state["trial_id"]): str(state["status"]) for state in states}
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return {}


def _status(result, trial_id: str | None, status: str | None, saved: dict[str, str], search: str | None) -> str:
    if (result.metrics or {}).get("final"):
        return "done"
    if result.error is not None or status == "ERROR":
        return "error"
    # TERMINATED in the saved state: stopped by the pruner (a grid sweep has none)
    return "stopped" if saved.get(str(trial_id), status) == "TERMINATED" and search == "optuna" else "unfinished"


def collect(results, exp_dir: Path, search: str | None = None) -> list[dict[str, Any]]:
    """One record per Tune trial: its configuration, seed index, status and last report."""
    trials = list(getattr(getattr(results, "_experiment_analysis", None), "trials", None) or [])
    saved = saved_statuses(exp_dir)
    records = []
    for i, result in enumerate(results):
        trial = trials[i] if i < len(trials) else None
        config = getattr(trial, "config", None) or result.config or {}  # a trial that never ran has no result config
        metrics = {k: v for k, v in (result.metrics or {}).items() if k != "config"}
        trial_id = getattr(trial, "trial_id", None) or metrics.get("trial_id")
        records.append({
            "trial_id": trial_id,
            "overrides": {k: json.loads(v) for k, v in (config.get("overrides") or {}).items()},
            "index": int(config.get("seed_index", config.get("__trial_index__", 0))),
            "status": _status(result, trial_id, getattr(trial, "status", None), saved, search),
            "metrics": metrics,
            "error": None if result.error is None else " ".join(str(result.error).split())[:500],
        })
    return records


# -- results ----------------------------------------------------------------------------------------
_PRIORITY = {"done": 0, "stopped": 1, "error": 2, "unfinished": 3}


def summarise(spec: dict[str, Any], records: list[dict[str, Any]]) -> dict[str, Any]:
    """Group the trials by configuration, aggregate across seeds, pick the best configuration and
    its median seed; write the tables, JSON files and ``best.zip``; return the summary."""
    out = Path(spec["output"])
    keys = list(spec["grid"])
    order = configurations(spec["grid"]) if spec["search"] != "optuna" else []
    groups: dict[str, dict[str, Any]] = {canonical(o): {"overrides": o, "seeds": {}} for o in order}
    for r in sorted(records, key=lambda r: (_PRIORITY[r["status"]], str(r["trial_id"]))):
        g = groups.setdefault(canonical(r["overrides"]), {"overrides": r["overrides"], "seeds": {}})
        g["seeds"].setdefault(r["index"], r)  # one record per seed: a finished one first (Optuna may repeat a configuration)
    configs = []
    for g in groups.values():
        overrides = g["overrides"]
        cfg0 = trial_config(spec, overrides, 0)
        label = config_label(overrides, keys)
        rows = []
        for index in range(spec["seeds"]):
            r = g["seeds"].get(index)
            m = (r or {}).get("metrics") or {}
            rows.append({
                "seed": cfg0["seed"] + index, "status": r["status"] if r else "not run",
                **{k: m.get(k) for k in (*METRICS, "selected_timesteps", "num_timesteps")},
                "model": m.get("model") if r and r["status"] == "done" else None,
                "trial_id": r["trial_id"] if r else None, "error": r["error"] if r else None,
            })
        done = [row for row in rows if row["status"] == "done"]
        entry: dict[str, Any] = {
            "label": label, "overrides": overrides, "seeds": rows, "complete": len(done) == len(rows),
            "score": "minus the accuracy (fixed-length episodes)" if cfg0["env_kwargs"].get("episode_length")
            else "mean steps to localise (lower is better)",
            "evaluation": f"held-out validation episodes (seeds 2000000+i, {cfg0['eval_episodes']} per evaluation); "
                          "each seed's number is the evaluation of the model train kept (its best evaluation)",
            "aggregate": {k: stats.aggregate([row[k] for row in done]) for k in METRICS} if done else None,
            "median_seed": None, "median_model": None,
        }
        if done:
            med = done[stats.median_index([row["score"] for row in done])]
            entry["median_seed"], entry["median_model"] = med["seed"], med["model"]
        configs.append(entry)
    configs.sort(key=lambda c: (not c["complete"], c["aggregate"]["score"]["mean"] if c["aggregate"] else float("inf")))
    # Trials still to run (an interrupted sweep): no best model until --resume has run them.
    if spec["search"] == "optuna":
        pending = max(0, spec["trials"] * spec["seeds"] - sum(r["status"] in ("done", "stopped", "error") for r in records))
    else:
        pending = sum(r["status"] in ("unfinished", "not run") for c in configs for r in c["seeds"])
    best = None if pending else next((c for c in configs if c["complete"]), None)
    summary: dict[str, Any] = {
        "output": str(out), "command": spec["command"], "seeds": spec["seeds"], "grid": spec["grid"],
        "search": spec["search"], "trials": len(records), "pending": pending,
        "statuses": {s: sum(1 for r in records if r["status"] == s) for s in _PRIORITY if any(r["status"] == s for r in records)},
        "best_rule": BEST_RULE, "median_rule": MEDIAN_RULE,
        "best": None, "configurations": configs,
    }
    for c in configs:
        atomic_write_json(out / "results" / f"{c['label']}.json", c)
        atomic_write_text(out / "results" / f"{c['label']}.md", config_table(c) + "\n")
    if best is not None:
        src = Path(best["median_model"])
        best_info = {"label": best["label"], "overrides": best["overrides"], "seed": best["median_seed"],
                     "source": str(src), "aggregate": best["aggregate"], "best_rule": BEST_RULE, "median_rule": MEDIAN_RULE}
        if src.is_file():
            with atomic_path(out / "best.zip") as tmp:
                shutil.copyfile(src, tmp)
            atomic_write_json(out / "best.json", {**read_metadata(src), "sweep": best_info})
            best_info["model"] = str(out / "best.zip")
        else:
            best_info.update(model=None, problem=f"{src} is not on this machine: on a cluster, --output must be a "
                                                 "directory every node reaches at the same path (a shared file system)")
        summary["best"] = best_info
    atomic_write_json(out / "summary.json", summary)
    atomic_write_text(out / "summary.md", summary_table(summary) + "\n")
    return summary


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def config_table(c: dict[str, Any]) -> str:
    """One configuration: a row per seed, then the mean, IQM and bootstrap 95% interval across seeds."""
    over = ", ".join(f"{k}={json.dumps(v)}" for k, v in c["overrides"].items()) or "the config as it is"
    lines = [f"## {c['label']}", "", f"Overrides: {over}. Score: {c['score']}. {c['evaluation']}.", "",
             "| seed | status | steps trained | model kept at | mean steps | accuracy | argmax accuracy | score |",
             "|---|---|---|---|---|---|---|---|"]
    for r in c["seeds"]:
        lines.append(f"| {r['seed']} | {r['status']} | {_f(r['num_timesteps'])} | {_f(r['selected_timesteps'])} | "
                     f"{_f(r['mean_steps'])} | {_f(r['accuracy'])} | {_f(r['argmax_accuracy'])} | {_f(r['score'])} |")
    a = c["aggregate"]
    if a:
        n = a["score"]["n"]
        for name, key in (("mean", "mean"), ("IQM", "iqm")):
            lines.append(f"| **{name}** ({n} seed{'' if n == 1 else 's'}) | | | | {_f(a['mean_steps'][key])} | {_f(a['accuracy'][key])} | "
                         f"{_f(a['argmax_accuracy'][key])} | {_f(a['score'][key])} |")
        ci = {k: "{:.3f}-{:.3f}".format(*a[k]["ci95"]) for k in METRICS}
        lines.append(f"| **95% CI of the mean** (bootstrap) | | | | {ci['mean_steps']} | {ci['accuracy']} | "
                     f"{ci['argmax_accuracy']} | {ci['score']} |")
        lines += ["", f"Median seed: {c['median_seed']} ({c['median_model']})."]
    if not c["complete"]:
        lines += ["", "Not every seed finished training: this configuration cannot be the best one."]
    return "\n".join(lines)


def summary_table(s: dict[str, Any]) -> str:
    """Every configuration, best first: the score's mean, IQM and 95% interval across seeds."""
    lines = ["| configuration | seeds done | score mean | score IQM | score 95% CI | mean steps | accuracy | |",
             "|---|---|---|---|---|---|---|---|"]
    best = (s.get("best") or {}).get("label")
    for c in s["configurations"]:
        a = c["aggregate"]
        done = sum(r["status"] == "done" for r in c["seeds"])
        cells = [_f(a["score"]["mean"]), _f(a["score"]["iqm"]), "{:.3f}-{:.3f}".format(*a["score"]["ci95"]),
                 _f(a["mean_steps"]["mean"]), _f(a["accuracy"]["mean"])] if a else ["-"] * 5
        mark = "best" if c["label"] == best else ("" if c["complete"] else "incomplete")
        lines.append(f"| {c['label']} | {done}/{len(c['seeds'])} | " + " | ".join(cells) + f" | {mark} |")
    if b := s.get("best"):
        where = b["model"] or b.get("problem")
        lines += ["", f"Best configuration: {b['label']}; its median seed {b['seed']}: {where}."]
    elif s.get("pending"):
        lines += ["", f"The sweep is unfinished ({s['pending']} trial(s) to run): continue it with --resume."]
    else:
        lines += ["", "No configuration finished every seed: no best model."]
    return "\n".join(lines)
