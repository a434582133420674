"""Tables and figures of benchmark rows (:mod:`gym_gridloc_agents.evaluation.bench`): the markdown table,
the localisation curves per environment, the speed/quality frontier, reading and merging the
rows of a results JSON."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

#: Keys every row of a bench JSON has.
ROW_KEYS = ("env", "policy", "episodes", "mean_steps", "success_rate")


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a bench JSON, or ``ValueError`` naming the file and what is wrong with it."""
    try:
        rows = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{path} is not a readable bench JSON ({exc}); --update merges into a file gridloc bench wrote") from None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and all(k in r for k in ROW_KEYS) for r in rows):
        raise ValueError(f"{path} is not a bench JSON (a list of rows with {', '.join(ROW_KEYS)}); --update merges into a file gridloc bench wrote")
    return rows


def public_row(row: dict[str, Any]) -> dict[str, Any]:
    """A row without its curves and its per-episode results (for tables)."""
    return {k: v for k, v in row.items() if not k.endswith("_curve") and k != "per_episode"}


def row_key(row: dict[str, Any]) -> tuple[str, str, str]:
    """What makes two rows the same measurement: the environment with its keyword arguments and
    maps, and the policy with its options."""
    env = f"{row['env']} {json.dumps(row.get('env_kwargs', {}), sort_keys=True)} {bool(row.get('test_set'))}"
    return env, row["policy"], json.dumps(row.get("options", {}), sort_keys=True)


def merge_rows(old: list[dict], new: list[dict]) -> list[dict]:
    """``old`` rows with ``new`` merged in (the same :func:`row_key`: replaced), in the order
    environment, then policy as in ``POLICY_NAMES``."""
    import gym_gridloc
    from gym_gridloc_agents.policies import POLICY_NAMES

    keyed = {row_key(r): r for r in old}
    keyed.update({row_key(r): r for r in new})
    envs = list(gym_gridloc.ENV_IDS)

    def order(key):
        env_key, pol, opts = key
        env = env_key.split(" ")[0]
        return (envs.index(env) if env in envs else len(envs), env_key,
                POLICY_NAMES.index(pol) if pol in POLICY_NAMES else len(POLICY_NAMES), opts)

    return [keyed[k] for k in sorted(keyed, key=order)]


def env_label(row: dict[str, Any]) -> str:
    """``WindyMaze-v0``, or with keyword arguments and test maps ``WindyMaze-v0 size=15, test maps``."""
    extra = [f"{k}={_short(v)}" for k, v in sorted(row.get("env_kwargs", {}).items())]
    if row.get("test_set"):
        extra.append("test maps")
    return row["env"] + (" " + ", ".join(extra) if extra else "")


def policy_label(row: dict[str, Any]) -> str:
    """The policy with its options and, across seeds, the seed count and IQM."""
    label = row["policy"]
    if row.get("options"):
        label += " (" + ", ".join(f"{k}={_short(v)}" for k, v in sorted(row["options"].items())) + ")"
    if "seeds" in row:  # below 4 seeds the IQM trims nothing: it is the mean, not worth a second number
        label += f" ({row['seeds']} seeds, IQM {row['mean_steps_iqm']:.2f})" if row["seeds"] >= 4 else f" ({row['seeds']} seeds)"
    return label


def _short(value: Any) -> str:
    if isinstance(value, (list, tuple)) and len(set(map(str, value))) == 1:
        return str(value[0])
    return str(value).replace(" ", "")


def _interval(lo: float, hi: float, digits: int = 2) -> str:
    return f"{lo:.{digits}f}-{hi:.{digits}f}"


def _or_dash(value: Any, spec: str) -> str:
    """``value`` formatted with ``spec``, ``-`` for None."""
    return "-" if value is None else format(value, spec)


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a markdown table.  Columns that no row has (accuracy at the episode length,
    the gap to the best planner, the normalised score) are left out."""
    budgets = list(rows[0]["accuracy_at"]) if rows else []
    with_L = any("accuracy_at_L" in r for r in rows)
    with_gap = any(r.get("gap_to_best_planner") is not None for r in rows)
    with_ms = any("ms_per_decision" in r for r in rows)
    with_score = any(r.get("normalised_score") is not None for r in rows)
    head = ["env", "policy", "episodes", "mean steps (95% CI)", "median", "success", "truncated", "correct if localised",
            *[f"acc@{b}" for b in budgets]]
    head += ["acc@L (95% CI)", "argmax acc@L", "L"] if with_L else []
    head += ["/ best planner"] if with_gap else []
    head += ["normalised score"] if with_score else []
    head += ["ms/decision"] if with_ms else []
    head += ["seconds"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * len(head)) + "|"]
    for r in rows:
        cells = [
            env_label(r), policy_label(r), str(r["episodes"]),
            f"{r['mean_steps']:.2f} ({_interval(*r['mean_steps_ci95'])})", f"{r['median_steps']:g}",
            f"{r['success_rate']:.3f}", f"{r['truncated_rate']:.3f}", _or_dash(r["localised_correct_rate"], ".3f"),
            *[f"{r['accuracy_at'][b]:.3f}" if b in r["accuracy_at"] else "-" for b in budgets],
        ]
        if with_L:
            if "accuracy_at_L" in r:
                cells += [f"{r['accuracy_at_L']:.3f} ({_interval(*r['accuracy_at_L_ci95'], 3)})",
                          f"{r['argmax_accuracy_at_L']:.3f}" if "argmax_accuracy_at_L" in r else "-", str(r["episode_length"])]
            else:
                cells += ["-", "-", "-"]
        if with_gap:
            cells.append(_or_dash(r.get("gap_to_best_planner"), ".3f"))
        if with_score:
            cells.append(_or_dash(r.get("normalised_score"), ".3f"))
        if with_ms:
            cells.append(_or_dash(r.get("ms_per_decision"), ".3g"))
        cells.append(f"{r['seconds']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: The width ``gridloc bench`` keeps its terminal table to.
TERMINAL_WIDTH = 100


def terminal_table(rows: Sequence[dict[str, Any]], width: int = TERMINAL_WIDTH) -> str:
    """The rows as a short, aligned markdown table that fits ``width`` characters: env, policy,
    mean steps (95% CI), success, acc@10, ms/decision, and, where rows have them, the gap to the
    best planner, the normalised score (``norm.``) and the accuracy at the episode length L.  The full table (every budget, median,
    truncated, ...) is :func:`markdown_table` (``gridloc bench --markdown PATH``; every number:
    ``--json PATH``).  To fit, long labels are shortened (``~`` marks the cut), then the optional
    columns dropped from the right (the gap first, acc@L last), then the labels shortened more."""
    with_L = any("accuracy_at_L" in r for r in rows)
    with_gap = any(r.get("gap_to_best_planner") is not None for r in rows)
    columns: list[tuple[str, Any]] = [
        ("env", env_label), ("policy", policy_label),
        ("mean steps (95% CI)", lambda r: f"{r['mean_steps']:.2f} ({_interval(*r['mean_steps_ci95'])})"),
        ("success", lambda r: f"{r['success_rate']:.3f}"),
        ("acc@10", lambda r: _or_dash(r["accuracy_at"].get("10"), ".3f")),
    ]
    optional: list[tuple[str, Any]] = []  # the first ones are kept longest
    if with_L:
        optional.append(("acc@L", lambda r: _or_dash(r.get("accuracy_at_L"), ".3f")))
    if any(r.get("normalised_score") is not None for r in rows):
        optional.append(("norm.", lambda r: _or_dash(r.get("normalised_score"), ".2f")))
    optional.append(("ms/dec", lambda r: _or_dash(r.get("ms_per_decision"), ".3g")))
    if with_gap:
        optional.append(("/ best", lambda r: _or_dash(r.get("gap_to_best_planner"), ".2f")))
    columns += optional

    def render(cols, cap: int | None) -> list[str]:
        cells = [[name for name, _ in cols]] + [[str(f(r)) for _, f in cols] for r in rows]
        if cap is not None:  # shorten the two labels
            cells = [[c if j > 1 or len(c) <= cap else c[: cap - 1] + "~" for j, c in enumerate(line)] for line in cells]
        widths = [max(len(line[j]) for line in cells) for j in range(len(cols))]
        out = ["| " + " | ".join(c.ljust(w) for c, w in zip(line, widths)) + " |" for line in cells]
        out.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
        return out

    def fits(lines: list[str]) -> bool:
        return max(map(len, lines)) <= width

    cols, cap = list(columns), None
    lines = render(cols, cap)
    for cap in (40, 32):  # long labels first (a policy's options, an environment's keywords) ...
        if fits(lines):
            break
        lines = render(cols, cap)
    while not fits(lines) and len(cols) > 6:  # ... then the optional columns from the right ...
        cols.pop()
        lines = render(cols, cap)
    while not fits(lines) and cap > 8:  # ... then the labels again
        cap -= 4
        lines = render(cols, cap)
    return "\n".join(lines)


def save_figure(fig, path: str | Path, title: str | None = None, **savefig: Any) -> None:
    """Give ``fig`` its ``title``, lay it out and write it atomically as a PNG; then close it."""
    import matplotlib.pyplot as plt

    from gym_gridloc_agents.files import FIGURE, atomic_path

    if title is not None:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    try:
        with atomic_path(path, FIGURE) as tmp:
            fig.savefig(tmp, format="png", **savefig)
    finally:
        plt.close(fig)


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files only, no window)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(rows: Sequence[dict[str, Any]], path: str | Path, *, title: str | None = None) -> None:
    """Fraction localised against steps (left) and accuracy against the step budget (right),
    one curve per policy, for the rows of ONE environment.  Written atomically."""
    plt = pyplot()
    envs = {env_label(r) for r in rows}
    if len(envs) != 1:
        raise ValueError(f"plot() takes the rows of one environment, got {sorted(envs)}")
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=90)
    counts = {r["episodes"] for r in rows}  # curves on different numbers of episodes: each says its own
    for r in rows:
        x = np.arange(len(r["localised_curve"]))
        episodes = "" if len(counts) == 1 else f", episodes {r.get('seed_start', 0)}-{r.get('seed_start', 0) + r['episodes'] - 1}"
        (line,) = ax1.plot(x, r["localised_curve"], label=f"{policy_label(r)} (mean {r['mean_steps']:.1f}{episodes})")
        ax2.plot(np.arange(len(r["accuracy_curve"])), r["accuracy_curve"], color=line.get_color(), label=r["policy"])
        ks = [int(k) for k in r["accuracy_at"]]
        ax2.plot(ks, [r["accuracy_at"][str(k)] for k in ks], "o", color=line.get_color(), ms=4)
    # Show the steps where the curves still move (short episodes would be squeezed to the left).
    curves = [np.asarray(r["localised_curve"]) for r in rows]
    last = max([int(np.searchsorted(c, 0.995 * c[-1])) if c[-1] > 0 else len(c) - 1 for c in curves], default=0)
    ax1.set_xlim(0, min(len(rows[0]["localised_curve"]) - 1, max(10, int(last * 1.15) + 1)))
    ax1.set_xlabel("steps from reset")
    ax1.set_ylabel("fraction of episodes localised")
    ax1.legend(fontsize=7, loc="lower right")
    ax2.set_xlabel("step budget")
    ax2.set_ylabel("P(most probable position = truth)")
    ax2.set_xlim(0, 60)
    for ax in (ax1, ax2):
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    same = f"the same {rows[0]['episodes']} episodes per policy" if len(counts) == 1 else "the first episodes of one seed list (legend)"
    save_figure(fig, path, title or f"{next(iter(envs))}: {same}")


def plot_frontier(rows: Sequence[dict[str, Any]], path: str | Path, *, title: str | None = None) -> None:
    """Mean steps to localise against milliseconds per decision (log scale), one panel per
    environment, one point per row with its 95% interval: what a step of planning buys.
    Written atomically."""
    plt = pyplot()
    rows = [r for r in rows if r.get("ms_per_decision")]
    if not rows:
        raise ValueError("plot_frontier() needs rows with ms_per_decision (a current gridloc bench)")
    envs = sorted({env_label(r) for r in rows})
    fig, axes = plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 3.6), dpi=90, squeeze=False)
    for ax, env in zip(axes[0], envs):
        mine = sorted((r for r in rows if env_label(r) == env), key=lambda r: r["ms_per_decision"])
        for r in mine:
            lo, hi = r["mean_steps_ci95"]
            ax.errorbar(r["ms_per_decision"], r["mean_steps"], yerr=[[r["mean_steps"] - lo], [hi - r["mean_steps"]]],
                        fmt="o", ms=5, capsize=2)
            ax.annotate(policy_label(r).split(" (")[0], (r["ms_per_decision"], r["mean_steps"]), fontsize=7,
                        textcoords="offset points", xytext=(4, 4))
        # the frontier: rows no faster-and-better row dominates (fewer steps than every faster row)
        faster_best = itertools.accumulate((r["mean_steps"] for r in mine), min, initial=math.inf)
        front = [r for r, best in zip(mine, faster_best) if r["mean_steps"] < best]
        ax.step([r["ms_per_decision"] for r in front], [r["mean_steps"] for r in front], where="post", color="grey",
                alpha=0.5, lw=1)
        ax.set_xscale("log")
        ax.set_xlabel("ms per decision")
        ax.set_ylabel("mean steps to localise")
        ax.set_title(env, fontsize=9)
        ax.grid(alpha=0.3, which="both")
    save_figure(fig, path, title or "speed against quality: lower left is better")


__all__ = ["ROW_KEYS", "env_label", "markdown_table", "merge_rows", "plot", "plot_frontier", "plot_training",
           "policy_label", "public_row", "read_rows", "row_key"]


def plot_training(models: Sequence[str | Path], path: str | Path, *, title: str | None = None) -> list[str]:
    """The training curves of models (``.zip`` files with their metadata JSON beside them): the
    held-out evaluations made while training (step 0 is the warm-started policy before PPO),
    accuracy on fixed-length episodes (``episode_length``) and mean steps otherwise, with the
    evaluation the training kept circled; one panel per environment (with its keywords: curves of
    different tasks are never drawn on one axis).  Written atomically; returns the panels' titles."""
    from gym_gridloc_agents.files import read_metadata

    plt = pyplot()
    metas = []
    for m in models:
        meta = read_metadata(Path(m))
        if not meta.get("evaluations"):
            raise ValueError(f"{m}: its metadata has no evaluations (trained with eval_freq: 0?)")
        metas.append((Path(m), meta))
    labels = [env_label({"env": meta.get("env_id", "?"), "env_kwargs": meta.get("env_kwargs") or {}}) for _, meta in metas]
    panels = list(dict.fromkeys(labels))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.8 * len(panels), 3.6), dpi=90, squeeze=False)
    for (m, meta), label in zip(metas, labels):
        ax = axes[0][panels.index(label)]
        proto = bool((meta.get("env_kwargs") or {}).get("episode_length"))
        evals = sorted(meta["evaluations"], key=lambda e: e["num_timesteps"])
        key = "accuracy" if proto else "mean_steps"
        (line,) = ax.plot([e["num_timesteps"] for e in evals], [e[key] for e in evals], "o-", ms=3, label=m.stem)
        for e in evals:
            if e["num_timesteps"] == meta.get("selected_timesteps"):  # the evaluation the training kept
                ax.plot([e["num_timesteps"]], [e[key]], "o", ms=10, mfc="none", color=line.get_color())
        ax.xaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v / 1000:g}k" if v else "0"))
        ax.set_xlabel("PPO steps (0 = the warm-started policy)")
        ax.set_ylabel("accuracy at L (validation maps)" if proto else "mean steps (held-out episodes)")
        if len(panels) > 1:
            ax.set_title(label, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    save_figure(fig, path, title or "training curves: held-out evaluations (circled: the model kept)")
    return panels
