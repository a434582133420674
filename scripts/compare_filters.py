"""Compare the exact filter, fixed-lag smoothers and particle filters on the same episodes; and
how fast the exact filter recovers from kidnapping with and without the mixing option.

Part 1 (tracking).  On each default environment, ``--episodes`` episodes of ``--steps`` random
actions (the same episodes, actions and readings for every method; the episode is not stopped at
localisation).  For each method and step k, the estimate of the position at k is the most
probable cell of its belief about X_k: the exact filter's ``P(X_k | e_0:k)``; the fixed-lag
smoother's ``P(X_k | e_0:k+d)`` (reported d steps later); the particle filter's weighted
histogram; and, as a reference, full offline smoothing ``P(X_k | e_0:T)``.  Reported: mean
Manhattan error and accuracy (estimate == truth) over k = 0..steps, accuracy at a few k, and the
wall-clock time per step of each online method.

Part 2 (the kidnapped robot).  The environments with ``kidnap_prob`` on; ``--kidnap-episodes``
episodes of ``--kidnap-steps`` random actions.  A kidnap is a step whose true state cannot be
reached from the previous one by the motion alone (a teleport onto a reachable cell changes
nothing).  Counted for each filter are the kidnaps that find it localised (most probable
position right, with confidence >= 0.5, at the step before: the classic kidnapped robot).  Steps
to recover = steps after the kidnap until it is localised again; not recovered within ``--cap``
steps counts as ``cap + 1``; events cut short by the next kidnap or the episode's end are left
out.  Also reported: accuracy and mean error over all steps of the kidnap episodes.  Filters: the
exact filter with the mixing option (its model's kidnap probability equals the simulator's),
the exact filter without it (kidnap probability 0; an observation it calls impossible restarts it
from the prior, as ``HMMBeliefWrapper(on_impossible="reset")`` does), and a particle filter with
1000 particles and the mixing.

    .venv/bin/python scripts/compare_filters.py                 # a few minutes on one core
    .venv/bin/python scripts/compare_filters.py --episodes 20 --kidnap-episodes 3   # quick look

Writes ``<out>.md`` (the tables), ``<out>.json`` (every number) and ``<out>.png`` (the plot).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import gym_gridloc
from gym_gridloc import FixedLagSmoother, ForwardFilter, ImpossibleObservationError, ParticleFilter, smooth
from gym_gridloc.recording import kidnap_steps, steps_to_recover
from gym_gridloc_agents.policies import RandomPolicy
from gym_gridloc_agents.evaluation.rollout import rollout

LAGS = (1, 3, 5)
PARTICLES = (50, 200, 1000)
METHODS = ("exact filter", *(f"fixed-lag d={d}" for d in LAGS), *(f"particles N={n}" for n in PARTICLES), "smoothing (offline)")
REPORT_AT = (0, 5, 10, 25, 50)


@dataclass
class Episode:
    actions: list[int]
    observations: list
    positions: list[tuple[int, int]]
    states: list[tuple[int, int, int]]


def run_episode(env, n_steps: int, seed: int) -> Episode:
    """Random actions on an unwrapped environment, not stopped at localisation."""
    ep = rollout(env, RandomPolicy(env.model), seed, keep=True, max_steps=n_steps, until_truncated=True,
                 policy_seed=[seed, 7])
    return Episode(ep.actions, ep.observations, [i["position"] for i in ep.infos], ep.states)


def estimate(belief: np.ndarray) -> tuple[tuple[int, int], float]:
    k = int(np.argmax(belief))
    return divmod(k, belief.shape[1]), float(belief.flat[k])


def track(model, ep: Episode, method: str, seed: int) -> tuple[list[tuple[int, int]], float]:
    """Estimates of X_0..X_T by ``method`` and its time per step (seconds)."""
    acts, obs = ep.actions, ep.observations
    t0 = time.perf_counter()
    if method == "smoothing (offline)":
        beliefs = smooth(model, acts, obs)
    elif method.startswith("fixed-lag"):
        s = FixedLagSmoother(model, int(method.split("=")[1]))
        beliefs = [b for b in (s.reset(obs[0]), *(s.step(a, o) for a, o in zip(acts, obs[1:]))) if b is not None]
    elif method == "exact filter" or method.startswith("particles"):
        f = ForwardFilter(model) if method == "exact filter" else ParticleFilter(
            model, int(method.split("=")[1]), rng=np.random.default_rng([seed, 11]))
        f.reset(obs[0])
        beliefs = [f.position_belief, *(f.step(a, o).position_belief for a, o in zip(acts, obs[1:]))]
    else:
        raise ValueError(f"unknown method {method!r}")
    dt = time.perf_counter() - t0
    if method.startswith("fixed-lag"):
        beliefs = [*beliefs, *s.flush()]  # the last d steps: smoothed with what there is (not timed)
    return [estimate(p)[0] for p in beliefs], dt / len(obs)


def compare(env_id: str, episodes: int, steps: int, seed: int, pbar) -> dict:
    env = gym.make(env_id).unwrapped
    model = env.model
    # Evaluate k = 0..steps; run `max(LAGS)` steps more so that every fixed-lag estimate of
    # X_k, k <= steps, has its d later readings.
    errors = {m: np.zeros((episodes, steps + 1)) for m in METHODS}
    secs = {m: [] for m in METHODS}
    warm = run_episode(env, 3 + max(LAGS), seed)  # untimed: compilation and first calls stay out of the timings
    for m in METHODS:
        track(model, warm, m, seed)
    for e in range(episodes):
        ep = run_episode(env, steps + max(LAGS), seed + e)
        truth = np.array(ep.positions[: steps + 1])
        for m in METHODS:
            est, dt = track(model, ep, m, seed + e)
            errors[m][e] = np.abs(np.array(est[: steps + 1]) - truth).sum(axis=1)
            secs[m].append(dt)
        pbar.update(1)
    env.close()
    out = {}
    for m in METHODS:
        err = errors[m]
        acc_k = (err == 0).mean(axis=0)
        out[m] = {
            "mean_error": float(err.mean()),
            "accuracy": float((err == 0).mean()),
            "accuracy_at": {str(k): float(acc_k[k]) for k in REPORT_AT if k <= steps},
            "error_curve": err.mean(axis=0).tolist(),
            "accuracy_curve": acc_k.tolist(),
            "us_per_step": 1e6 * float(np.mean(secs[m])),
        }
    return out


def kidnap_experiment(env_id: str, p: float, episodes: int, steps: int, cap: int, seed: int, pbar) -> dict:
    env = gym.make(env_id, kidnap_prob=p).unwrapped
    model = env.model  # kidnap_prob = p: the simulator's model
    filters = {
        "exact, mixing": lambda: ForwardFilter(model),
        "exact, no mixing": lambda: ForwardFilter(model, kidnap_prob=0.0),
        "particles N=1000, mixing": lambda: ParticleFilter(model, 1000, rng=np.random.default_rng([seed, e, 3])),
    }
    results = {name: [] for name in filters}
    restarts = {name: 0 for name in filters}
    errors = {name: [] for name in filters}
    n_kidnaps = 0
    for e in range(episodes):
        ep = run_episode(env, steps, seed + 1000 + e)
        kidnaps = kidnap_steps(model.with_kidnapping(0.0), ep.states, ep.actions)
        n_kidnaps += len(kidnaps)
        for name, make in filters.items():
            f = make().reset(ep.observations[0])
            pairs = [estimate(f.position_belief)]
            for a, o in zip(ep.actions, ep.observations[1:]):
                try:
                    f.step(a, o)
                except ImpossibleObservationError:  # restart from the prior and this reading
                    f.reset(o)
                    restarts[name] += 1
                pairs.append(estimate(f.position_belief))
            ests, confs = map(list, zip(*pairs))
            results[name].extend(steps_to_recover(ests, confs, ep.positions, kidnaps, cap=cap))
            errors[name].extend(np.abs(np.array(ests) - np.array(ep.positions)).sum(axis=1))
        pbar.update(1)
    env.close()
    out = {"kidnaps": n_kidnaps}
    for name, r in results.items():
        measured = np.array([x for x in r if x is not None])
        out[name] = {
            "events": int(len(measured)),
            "cut_short": int(sum(x is None for x in r)),
            "recovered_within_cap": float((measured <= cap).mean()) if len(measured) else float("nan"),
            "median_steps": float(np.median(measured)) if len(measured) else float("nan"),
            "mean_steps": float(measured.mean()) if len(measured) else float("nan"),
            "restarts": restarts[name],
            "accuracy_all_steps": float((np.array(errors[name]) == 0).mean()),
            "mean_error_all_steps": float(np.mean(errors[name])),
        }
    return out


def tables(res: dict, args) -> str:
    lines = [
        f"### Tracking: {args.episodes} episodes x {args.steps} random steps per environment (seed {args.seed})",
        "",
        "| env | method | mean error | accuracy | " + " | ".join(f"acc@{k}" for k in REPORT_AT if k <= args.steps) + " | us/step |",
        "| --- | --- | ---: | ---: | " + " | ".join("---:" for k in REPORT_AT if k <= args.steps) + " | ---: |",
    ]
    for env_id, per in res["tracking"].items():
        for m, r in per.items():
            accs = " | ".join(f"{r['accuracy_at'][str(k)]:.2f}" for k in REPORT_AT if k <= args.steps)
            lines.append(f"| {env_id} | {m} | {r['mean_error']:.3f} | {r['accuracy']:.3f} | {accs} | {r['us_per_step']:.0f} |")
    lines += [
        "",
        f"### Kidnapped robot: kidnap_prob={args.kidnap_prob}, {args.kidnap_episodes} episodes x {args.kidnap_steps} random steps, cap {args.cap}",
        "",
        "| env | kidnaps | filter | events (localised before) | recovered <= cap | median steps | mean steps | restarts | accuracy, all steps | mean error, all steps |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for env_id, per in res["kidnap"].items():
        for name, r in per.items():
            if name == "kidnaps":
                continue
            lines.append(
                f"| {env_id} | {per['kidnaps']} | {name} | {r['events']} | {r['recovered_within_cap']:.2f} | "
                f"{r['median_steps']:.1f} | {r['mean_steps']:.1f} | {r['restarts']} | "
                f"{r['accuracy_all_steps']:.3f} | {r['mean_error_all_steps']:.3f} |"
            )
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = list(res["tracking"])
    fig, axes = plt.subplots(2, len(envs), figsize=(5 * len(envs), 7), squeeze=False)
    cmap = matplotlib.colormaps["tab10"]
    for j, env_id in enumerate(envs):
        for i, m in enumerate(METHODS):
            r = res["tracking"][env_id][m]
            style = "--" if m.startswith("particles") else (":" if "offline" in m else "-")
            axes[0, j].plot(r["accuracy_curve"], style, color=cmap(i), label=m)
            axes[1, j].plot(r["error_curve"], style, color=cmap(i), label=m)
        axes[0, j].set_title(env_id)
        axes[0, j].set_ylabel("accuracy (estimate == truth)")
        axes[1, j].set_ylabel("mean Manhattan error")
        axes[1, j].set_xlabel("step k")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", default=",".join(gym_gridloc.ENV_IDS), help="comma-separated env ids")
    ap.add_argument("--episodes", type=int, default=200, help="tracking episodes per environment")
    ap.add_argument("--steps", type=int, default=50, help="steps per tracking episode (estimates at k = 0..steps)")
    ap.add_argument("--kidnap-prob", type=float, default=0.01, help="kidnap probability per step in part 2")
    ap.add_argument("--kidnap-episodes", type=int, default=50, help="kidnap episodes per environment")
    ap.add_argument("--kidnap-steps", type=int, default=1000, help="steps per kidnap episode")
    ap.add_argument("--cap", type=int, default=50, help="steps after a kidnap after which it counts as not recovered")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/compare_filters", help="output path without extension")
    args = ap.parse_args(argv)
    envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    for name in ("episodes", "steps", "kidnap_episodes", "kidnap_steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    if not 0.0 < args.kidnap_prob <= 1.0:
        ap.error(f"--kidnap-prob must be in (0, 1], got {args.kidnap_prob}")
    unknown = [e for e in envs if e not in gym_gridloc.ENV_IDS]
    if unknown:
        ap.error(f"unknown env id(s) {unknown}; allowed: {', '.join(gym_gridloc.ENV_IDS)}")

    res: dict = {"args": vars(args), "tracking": {}, "kidnap": {}}
    with tqdm(total=len(envs) * args.episodes, desc="tracking") as pbar:
        for env_id in envs:
            pbar.set_postfix_str(env_id)
            res["tracking"][env_id] = compare(env_id, args.episodes, args.steps, args.seed, pbar)
    with tqdm(total=len(envs) * args.kidnap_episodes, desc="kidnapping") as pbar:
        for env_id in envs:
            pbar.set_postfix_str(env_id)
            res["kidnap"][env_id] = kidnap_experiment(
                env_id, args.kidnap_prob, args.kidnap_episodes, args.kidnap_steps, args.cap, args.seed, pbar
            )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = tables(res, args)
    out.with_suffix(".md").write_text(text)
    out.with_suffix(".json").write_text(json.dumps(res, indent=1))
    plot(res, out.with_suffix(".png"))
    print(text)
    print(f"wrote {out.with_suffix('.md')}, {out.with_suffix('.json')}, {out.with_suffix('.png')}")
    return res


if __name__ == "__main__":
    main()
