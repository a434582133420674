"""What one environment step costs: the wrapped single step against Gymnasium's ``FrozenLake-v1``,
and the native vector env against ``SyncVectorEnv`` over the wrapper.

* ``wrapped``: ``HMMBeliefWrapper(gym.make(ENV))`` (the Dict belief observation), random actions,
  the mean time of one ``step`` over ``--steps`` steps (resets between episodes not timed);
  ``FrozenLake-v1`` (``gym.make``, the same wrappers Gymnasium adds) timed the same way, in
  the same run, interleaved in rounds so that background load hits both alike.
* ``vector``: ``gym.make_vec(ENV, num_envs=N, vectorization_mode="vector_entry_point")`` against
  ``gym.make_vec(ENV, num_envs=N, vectorization_mode="sync", wrappers=[HMMBeliefWrapper])``,
  environment steps per second, random actions, timed in alternating rounds as above (the
  sync env does a tenth of the vector steps).  With maps redrawn at reset (``DepthMaze-v0``),
  ``--warmup`` untimed vector steps come first, so that both are timed with the models of the
  small maps kept (as they run for the hours of a training); both share what is kept.  (64
  DepthMaze envs have drawn all 192 7x7 mazes after about 600 steps; after the 300 this took
  before, about a dozen models were still built in the timed rounds, at about 0.5 ms each.)
* Each timed round runs without the garbage collector, after a full collection (as ``timeit``
  times): a full collection of the process's objects (tens of ms) falling in one env's rounds and
  not the other's would decide a ratio.

Targets: a wrapped step at most 2 x FrozenLake for WindyMaze-v0, ColourGrid-v0 and
RingSensor8x8-v0, at most 3 x for DepthMaze-v0 (7x7); the native vector env at least 40 x
SyncVectorEnv at 64 envs.  (SyncVectorEnv steps the single environment, itself the compiled step
of one robot: a faster single step makes this ratio harder to reach.)

    .venv/bin/python scripts/bench_step.py
    .venv/bin/python scripts/bench_step.py --steps 20000 --num-envs 64
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import time

import gymnasium as gym
import numpy as np

import gym_gridloc

TARGETS = {"WindyMaze-v0": 2.0, "ColourGrid-v0": 2.0, "RingSensor8x8-v0": 2.0, "DepthMaze-v0": 3.0}
#: The native vector env's target: at least this many times SyncVectorEnv's steps per second.
VECTOR_TARGET = 40.0


@contextlib.contextmanager
def no_gc():
    """A timed section without the garbage collector (as ``timeit`` times): one full collection
    of the process's objects (tens of ms) falling inside one env's timed rounds and not the
    other's would decide a ratio."""
    gc.collect()
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def step_seconds(env, steps: int, rng: np.random.Generator, seed: int) -> float:
    """Seconds spent in ``env.step`` over ``steps`` random actions (resets not counted)."""
    n_actions = env.action_space.n
    actions = rng.integers(0, n_actions, size=steps).tolist()
    env.reset(seed=seed)
    clock = time.perf_counter
    spent = 0.0
    for a in actions:
        t0 = clock()
        _, _, terminated, truncated, _ = env.step(a)
        spent += clock() - t0
        if terminated or truncated:
            seed += 1
            env.reset(seed=seed)
    return spent


def wrapped_ratios(env_ids, steps: int, rounds: int) -> list[tuple[str, float, float]]:
    """``(env id, mean µs per wrapped step, mean µs per FrozenLake step)`` per environment."""
    lake = gym.make("FrozenLake-v1")
    rng = np.random.default_rng(0)
    out = []
    for env_id in env_ids:
        env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id))
        step_seconds(env, 200, rng, 10**6)  # warm up (compilation, caches)
        step_seconds(lake, 200, rng, 10**6)
        ours = theirs = 0.0
        per = max(1, steps // rounds)
        for r in range(rounds):
            with no_gc():
                ours += step_seconds(env, per, rng, 1000 * r)
            with no_gc():
                theirs += step_seconds(lake, per, rng, 1000 * r)
        out.append((env_id, 1e6 * ours / (per * rounds), 1e6 * theirs / (per * rounds)))
        env.close()
    return out


def vector_seconds(env, actions: np.ndarray, steps: int, start: int) -> float:
    """Seconds spent in ``steps`` vector steps (actions ``start``, ``start + 1``, ... cyclically)."""
    clock = time.perf_counter
    t0 = clock()
    for t in range(start, start + steps):
        env.step(actions[t % len(actions)])
    return clock() - t0


def vector_rates(native, sync, n: int, steps: int, rounds: int, seed: int = 0, warmup: int = 5) -> tuple[float, float]:
    """Environment steps per second of ``native`` and ``sync``, timed in alternating rounds (so
    that background load hits both alike); ``sync`` does a tenth of the vector steps.  Each
    first takes ``warmup`` vector steps (sync: a tenth), not timed."""
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, native.single_action_space.n, size=(256, n))
    spent = [0.0, 0.0]
    counts = [max(1, steps // rounds), max(1, steps // (10 * rounds))]
    for k, env in enumerate((native, sync)):
        env.reset(seed=seed)
        vector_seconds(env, actions, warmup if k == 0 else max(1, warmup // 10), 0)  # warm up (compilation, kept models)
    for r in range(rounds):
        for k, env in enumerate((native, sync)):
            with no_gc():
                spent[k] += vector_seconds(env, actions, counts[k], r * counts[k])
    return counts[0] * rounds * n / spent[0], counts[1] * rounds * n / spent[1]


def map_build_bound(native, n: int, sync_rate: float, steps: int = 200, builds: int = 100) -> str | None:
    """For a vector env that draws a new map at every reset: how many maps a vector step builds,
    what one costs (the map, its model and the engine's tables), and the largest native / sync
    ratio that leaves (the sync env builds the same maps, so the native step can never cost less
    than its maps).  None when the maps are fixed."""
    from gym_gridloc import derived, engine

    factory = native.unwrapped.template.map_factory
    if factory is None:
        return None
    rng = np.random.default_rng(1)
    native.reset(seed=1)
    ended = 0
    for _ in range(steps):
        _, _, term, trunc, _ = native.step(rng.integers(0, native.single_action_space.n, size=n))
        ended += int((term | trunc).sum())
    t0 = time.perf_counter()
    for _ in range(builds):
        model = factory(rng)
        engine.plan(model), derived.of(model).first_table(now=True)  # (what the step's tables are made of, kept per model)
    each = (time.perf_counter() - t0) / builds
    per_step = ended / steps
    bound = (n / sync_rate) / (per_step * each)
    return (f"{per_step:.2f} new maps per vector step at {1e3 * each:.3f} ms each (map drawn, its model kept or built): "
            f"native / sync <= {bound:.1f}x however fast the rest")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", nargs="+", default=list(TARGETS), choices=gym_gridloc.ENV_IDS, help="environment ids")
    p.add_argument("--steps", type=int, default=10000, help="wrapped steps timed per environment (and FrozenLake)")
    p.add_argument("--rounds", type=int, default=5, help="alternations between ours and FrozenLake")
    p.add_argument("--num-envs", type=int, default=64, help="N of the vector comparison (0: skip)")
    p.add_argument("--vector-steps", type=int, default=1000, help="native vector steps timed (x N environment steps; sync: a tenth)")
    p.add_argument("--warmup", type=int, default=1000,
                   help="untimed native vector steps first when maps are redrawn at reset (sync: a tenth)")
    args = p.parse_args(argv)

    print(f"Mean time of one step over {args.steps} steps, random actions (resets not timed)")
    print(f"{'env':<18} | {'wrapped':>10} {'FrozenLake':>11} | {'ratio':>6} {'target':>7}")
    for env_id, ours, lake in wrapped_ratios(args.envs, args.steps, args.rounds):
        ratio, target = ours / lake, TARGETS.get(env_id)
        verdict = "" if target is None else f"<= {target:g}x: {'met' if ratio <= target else 'NOT met'}"
        print(f"{env_id:<18} | {ours:>8.1f}us {lake:>9.1f}us | {ratio:>5.1f}x {verdict}")

    if args.num_envs > 0:
        n = args.num_envs
        print(f"\nVector env, N = {n}, environment steps per second ({args.vector_steps} vector steps)")
        print(f"{'env':<18} | {'native':>10} {'sync':>10} | {'native / sync':>13}")
        for env_id in args.envs:
            native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
            sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", wrappers=[gym_gridloc.HMMBeliefWrapper])
            redrawn = native.unwrapped.template.map_factory is not None
            # maps redrawn: warm up until the small maps' models are kept (a 7x7 DepthMaze has 192
            # mazes; both envs share what redraw keeps), so that both are timed as they run for hours
            a, b = vector_rates(native, sync, n, args.vector_steps, args.rounds, warmup=args.warmup if redrawn else 5)
            ratio = a / b
            verdict = f">= {VECTOR_TARGET:g}x: {'met' if ratio >= VECTOR_TARGET else 'NOT met'}"
            print(f"{env_id:<18} | {a:>8.0f}/s {b:>8.0f}/s | {ratio:>12.1f}x {verdict}")
            bound = map_build_bound(native, n, b)
            if bound is not None:
                print(f"{'':<18} | {bound}")
            native.close()
            sync.close()


if __name__ == "__main__":
    main()
