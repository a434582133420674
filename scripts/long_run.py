#!/usr/bin/env python
"""Long runs of the exact forward filter with sharp sensors: does the belief stay finite and sum
to 1, and does memory stay flat, over a million steps?

For each environment's model (built by ``gym.make`` with sharp sensor parameters, so the model is
the one the environment simulates), the script simulates the hidden robot with the model's own
sampler under uniformly random actions, and runs a :class:`gym_gridloc.ForwardFilter` on the
readings, one step per move, never resetting.  Every step (or every ``--check-every`` steps, so
that the filter's own loop runs undisturbed in between) it checks that the belief is finite,
non-negative and sums to 1 (within 1e-9).  It records the smallest normaliser (the probability
of a reading given the past), the smallest non-zero belief entry (to see whether values sink
into the subnormal range), the resident memory (``resource.getrusage``) and the memory traced by
``tracemalloc`` after a warm-up and at the end.

    .venv/bin/python scripts/long_run.py                     # 1,000,000 steps per model
    .venv/bin/python scripts/long_run.py --steps 20000 --models colour,windy
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
import tracemalloc

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import gym_gridloc  # noqa: F401  (registers the environments)
from gym_gridloc import ForwardFilter, engine

#: Sharp-sensor versions of every environment: (env id, keyword arguments).
SHARP = {
    "colour": ("ColourGrid-v0", {"accuracy": 0.999}),
    "windy": ("WindyMaze-v0", {"p_detect": 0.999, "p_false_alarm": 0.001}),
    "ring": ("RingSensor8x8-v0", {"p_true": 0.99, "p_ring1": 0.00125, "p_ring2": 0.0}),
    "ring-seed": ("RingSensor8x8-v0", {"dynamics": "passive", "p_true": 0.99, "p_ring1": 0.00125, "p_ring2": 0.0}),
}


def max_rss_mib() -> float:
    """Peak resident set size of this process in MiB (Linux reports KiB)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def long_run(name: str, steps: int, seed: int = 0, warmup: int = 5000, trace_from: float = 0.5,
             check_every: int = 1, progress: bool = True) -> dict:
    """Run ``steps`` filter steps on the sharp version of ``name``'s model; return the numbers.

    ``tracemalloc`` (which slows Python down several times) runs from step ``trace_from * steps``;
    its first reading is taken ``warmup`` steps later (once the filter's buffers are in steady
    state), its second at the end, so a leak shows as growth between the two.  The resident set
    size is read after the first ``warmup`` steps and at the end."""
    env_id, kwargs = SHARP[name]
    model = gym.make(env_id, **kwargs).unwrapped.model
    rng = np.random.default_rng(seed)
    sensor = model.sensor
    filt = ForwardFilter(model)
    states = engine.sample_initial(model, 1, rng)
    filt.reset(sensor.to_observation(int(engine.sample_readings(model, states, rng)[0])))
    warmup = min(warmup, steps // 4)
    trace_start = max(warmup, int(trace_from * steps))
    trace_first = min(trace_start + warmup, steps - 1)
    min_z = min_positive = np.inf
    max_sum_error = 0.0
    hits = checks = 0
    rss_after_warmup = traced_after_warmup = traced_end = traced_peak = None
    start = time.perf_counter()
    for t in tqdm(range(1, steps + 1), desc=f"{name:>9}", unit="step", mininterval=2.0, disable=not progress,
                  file=sys.stderr):
        action = int(rng.integers(model.n_actions))
        states = engine.sample_next(model, states, action, rng)
        obs = sensor.to_observation(int(engine.sample_readings(model, states, rng)[0]))
        ll_before = filt.log_likelihood
        filt.step(action, obs)
        min_z = min(min_z, filt.log_likelihood - ll_before)
        if t == warmup:
            rss_after_warmup = max_rss_mib()
        if t == trace_start:
            tracemalloc.start()
        if t == trace_first:
            traced_after_warmup = tracemalloc.get_traced_memory()[0]
        if t % check_every:
            continue
        checks += 1
        b = filt.full_belief
        total = float(b.sum())
        if not (np.isfinite(b).all() and (b >= 0).all() and abs(total - 1.0) <= 1e-9):
            raise AssertionError(f"{name}: bad belief at step {t}: sum {total!r}, finite {np.isfinite(b).all()}")
        max_sum_error = max(max_sum_error, abs(total - 1.0))
        min_positive = min(min_positive, float(b[b > 0].min()))
        estimate = np.unravel_index(int(np.argmax(b.sum(axis=0))), model.shape)
        hits += estimate == (int(states[0, 1]), int(states[0, 2]))
    elapsed = time.perf_counter() - start
    if tracemalloc.is_tracing():
        traced_end, traced_peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return {
        "model": name,
        "env": env_id,
        "kwargs": kwargs,
        "steps": steps,
        "seconds": elapsed,
        "us_per_step": 1e6 * elapsed / steps,
        "max_abs_sum_error": max_sum_error,
        "min_log_normaliser": float(min_z),
        "min_positive_belief": min_positive,
        "subnormal_seen": bool(min_positive < np.finfo(np.float64).tiny),
        "check_every": check_every,
        "map_accuracy": hits / max(checks, 1),
        "max_rss_mib_after_warmup": rss_after_warmup,
        "max_rss_mib_end": max_rss_mib(),
        "traced_steps": (trace_first, steps),
        "traced_kib_after_warmup": None if traced_after_warmup is None else traced_after_warmup / 1024,
        "traced_kib_end": None if traced_end is None else traced_end / 1024,
        "traced_kib_peak": None if traced_peak is None else traced_peak / 1024,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=1_000_000, help="filter steps per model (default 1,000,000)")
    parser.add_argument("--models", default=",".join(SHARP), help=f"comma-separated, from {', '.join(SHARP)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trace-from", type=float, default=0.5,
                        help="start tracemalloc at this fraction of the steps (it slows the run; default 0.5)")
    parser.add_argument("--check-every", type=int, default=1,
                        help="read and check the belief every N steps (default 1: every step)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    names = [n.strip() for n in args.models.split(",") if n.strip()]
    unknown = [n for n in names if n not in SHARP]
    if unknown:
        parser.error(f"unknown model(s) {unknown}; choose from {', '.join(SHARP)}")
    if args.steps < 2:
        parser.error(f"--steps must be at least 2, got {args.steps}")
    rows = [long_run(n, args.steps, args.seed, trace_from=args.trace_from,
                     check_every=args.check_every, progress=not args.no_progress) for n in names]
    print(f"{'model':>9} {'steps':>9} {'us/step':>8} {'max|sum-1|':>10} {'min log z':>9} {'min b>0':>9} "
          f"{'MAP acc':>7} {'max RSS MiB':>14} {'traced KiB':>12} {'traced steps':>17}")
    for r in rows:
        rss = f"{r['max_rss_mib_after_warmup']:.1f}→{r['max_rss_mib_end']:.1f}"
        traced = f"{r['traced_kib_after_warmup']:.1f}→{r['traced_kib_end']:.1f}"
        window = f"{r['traced_steps'][0]}→{r['traced_steps'][1]}"
        print(f"{r['model']:>9} {r['steps']:>9} {r['us_per_step']:>8.1f} {r['max_abs_sum_error']:>10.1e} "
              f"{r['min_log_normaliser']:>9.2f} {r['min_positive_belief']:>9.1e} {r['map_accuracy']:>7.3f} "
              f"{rss:>14} {traced:>12} {window:>17}")
    growth = max(r["traced_kib_end"] - r["traced_kib_after_warmup"] for r in rows)
    rss_growth = max(r["max_rss_mib_end"] - r["max_rss_mib_after_warmup"] for r in rows)
    print(f"all {sum(r['steps'] // r['check_every'] for r in rows):,} beliefs checked finite, non-negative and summing to 1 within 1e-9; "
          f"largest growth: traced {growth:+.1f} KiB, max RSS {rss_growth:+.1f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
