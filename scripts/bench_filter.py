"""Filter steps per second on generated ColourGrid maps, beside a dense and a CSR computation.

For each grid size the same trajectory (actions and readings sampled from the model) is filtered
five ways, all exact:

* ``stencil``: ``ForwardFilter.step`` (predict over shifted arrays, update, normalise; the
  public call, observation checks included), with the model's default kernel;
* ``fused``: the same on a large model with the fused compiled step (``GYM_GRIDLOC_NUMBA=all``,
  :class:`gym_gridloc.kernels.FusedPlan`: the numpy plan's numbers, checked bit for bit), where
  numba is available and the default kernel is the numpy plan;
* ``csr step``: the same step with ``scipy.sparse`` CSR ``T_a^T @ f`` for the prediction;
* ``csr product``: the bare CSR product ``T_a^T @ f`` alone (no update);
* ``dense step``: ``O T_a^T f`` with dense S x S matrices, where they fit in ``--dense-max-gib``.

Ratios are measured in this one run (best of ``--repeats`` timings); ``path`` is the kernel the
model's filter uses by default (``numba`` or ``numpy``, see ``gym_gridloc/kernels.py``); ``fused / csr
prod`` is the fused step's time over the bare CSR product's.  A last part measures
the peak resident memory (VmHWM) of a 512 x 512 environment with its ``HMMBeliefWrapper`` belief
after a reset and 20 steps, per model, each in a fresh process, and whether numba was loaded.

    .venv/bin/python scripts/bench_filter.py            # 8, 32, 64, 128, 512
    .venv/bin/python scripts/bench_filter.py --sizes 8 64 --no-memory
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np
from tqdm import tqdm

import gym_gridloc
from gym_gridloc import engine, kernels
from gym_gridloc.generators import colour_map

MEMORY_SNIPPET = """
import sys
import gymnasium as gym, gym_gridloc
def status(key):
    return next(int(l.split()[1]) for l in open("/proc/self/status").read().splitlines() if l.startswith(key)) / 1024
base = status("VmRSS:")
env = gym_gridloc.HMMBeliefWrapper(gym.make({env_id!r}, **{kwargs!r}))
env.reset(seed=0)
for t in range(20):
    env.step(t % env.action_space.n)
print(base, status("VmHWM:"), "numba" in sys.modules)
"""


def best_times(fns: dict, steps: dict, repeats: int) -> dict:
    """Seconds per step of each ``fns[name]`` (which runs ``steps[name]`` steps): the best of
    ``repeats`` rounds, the methods taking turns within a round so that a busy machine slows
    them alike."""
    best = {name: np.inf for name in fns}
    for _ in tqdm(range(repeats), desc="rounds", file=sys.stderr):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    return {name: best[name] / steps[name] for name in fns}


def trajectory(model, steps: int, rng: np.random.Generator):
    _, actions, readings = engine.simulate(model, steps, rng)
    return int(readings[0]), actions.tolist(), readings[1:].tolist()


def setup_size(side: int, steps: int, dense_max_gib: float) -> tuple[dict, dict, dict]:
    """``(row, fns, counts)``: the size's facts and the timed functions with their step counts."""
    model = gym_gridloc.colour_grid_model(colour_map((side, side), obstacle_density=0.2, seed=0))
    S = model.n_states
    rng = np.random.default_rng(side)
    first, actions, readings = trajectory(model, steps, rng)
    obs = [model.sensor.to_observation(r) for r in readings]
    lik = np.stack([model.likelihood_vector(r) for r in range(model.sensor.n_readings)])

    f = gym_gridloc.ForwardFilter(model)

    def stencil():
        f.reset(model.sensor.to_observation(first))
        for a, o in zip(actions, obs):
            f.step(a, o)

    Tt = [engine.transition_matrix(model, a).T.tocsr() for a in range(model.n_actions)]
    v0 = model.to_vector(model.prior()) * lik[first]
    v0 /= v0.sum()

    def csr_step():
        v = v0
        for a, r in zip(actions, readings):
            v = Tt[a] @ v
            v *= lik[r]
            v /= v.sum()
        return v

    def csr_product():
        v = v0
        for a in actions:
            v = Tt[a] @ v
        return v

    # The three are the same filter: check before timing.
    ref = csr_step()
    stencil()
    err = float(np.abs(f.belief_vector - ref).max())
    if err > 1e-12:
        raise AssertionError(f"{side}x{side}: stencil and CSR filters differ by {err:.3g}")
    fns = {"stencil": stencil, "csr_step": csr_step, "csr_product": csr_product}
    out = {"side": side, "S": S, "path": engine.path(model), "err": err, "dense": None, "fused": None}
    if engine.path(model) == "numpy" and kernels.AVAILABLE:
        fused_model = gym_gridloc.colour_grid_model(model.grid)
        kernels.NUMBA_LARGE = True  # (for this model: its plan is made now, once)
        try:
            assert engine.path(fused_model) == "fused"
        finally:
            kernels.NUMBA_LARGE = False
        g = gym_gridloc.ForwardFilter(fused_model)

        def fused():
            g.reset(model.sensor.to_observation(first))
            for a, o in zip(actions, obs):
                g.step(a, o)

        fused()
        if g.full_belief.tobytes() != f.full_belief.tobytes() or g.log_likelihood != f.log_likelihood:
            raise AssertionError(f"{side}x{side}: the fused step's numbers are not the numpy plan's")
        fns["fused"] = fused
    counts = dict.fromkeys(fns, steps)
    dense_bytes = model.n_actions * S * S * 8
    out["dense_gib"] = dense_bytes / 2**30
    if dense_bytes <= dense_max_gib * 2**30:
        D = [m.toarray() for m in Tt]
        dense_steps = max(2, min(steps, int(2e9 // (S * S * 8)) + 2))

        def dense_step():
            v = v0
            for a, r in zip(actions[:dense_steps], readings[:dense_steps]):
                v = D[a] @ v
                v = v * lik[r]
                v /= v.sum()

        fns["dense"] = dense_step
        counts["dense"] = dense_steps
    return out, fns, counts


def memory(env_id: str, kwargs: dict, numba: bool) -> tuple[float, float, bool]:
    """(resident MiB after the imports, peak resident MiB, numba loaded) in a fresh process."""
    import os

    env = dict(os.environ)
    env.pop("GYM_GRIDLOC_NO_NUMBA", None)
    if not numba:
        env["GYM_GRIDLOC_NO_NUMBA"] = "1"
    code = MEMORY_SNIPPET.format(env_id=env_id, kwargs=kwargs)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    base, peak, used = res.stdout.strip().splitlines()[-1].split()
    return float(base), float(peak), used == "True"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[8, 32, 64, 128, 512], help="grid sides")
    p.add_argument("--steps", type=int, default=200, help="filter steps per timing")
    p.add_argument("--repeats", type=int, default=9, help="timings per method; the best counts")
    p.add_argument("--dense-max-gib", type=float, default=1.0, help="largest dense matrices to build")
    p.add_argument("--no-memory", action="store_true", help="skip the 512x512 memory part")
    args = p.parse_args(argv)
    for s in args.sizes:
        if s < 2:
            p.error(f"--sizes: each side must be at least 2, got {s}")
    for name in ("steps", "repeats"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be at least 1, got {getattr(args, name)}")

    rows, fns, counts = [], {}, {}
    for side in tqdm(args.sizes, desc="set up", file=sys.stderr):
        row, f, c = setup_size(side, args.steps, args.dense_max_gib)
        rows.append(row)
        fns.update({(side, k): v for k, v in f.items()})
        counts.update({(side, k): v for k, v in c.items()})
    # Every size and method takes its turn in each round, so a busy machine slows them alike
    # (the growth from 128x128 to 512x512 compares timings made side by side).
    times = best_times(fns, counts, args.repeats)
    for row in rows:
        row.update({name: t for (side, name), t in times.items() if side == row["side"]})

    print(f"Filter step on generated ColourGrid maps (obstacle_density 0.2, map_seed 0); best of {args.repeats}")
    print(f"{'grid':>9} {'states':>7} {'path':>5} | {'stencil':>11} {'fused':>11} {'csr step':>11} {'csr prod':>11} "
          f"{'dense':>11} | {'x csr step':>10} {'x csr prod':>10} {'x dense':>9} | {'fused / csr prod':>16}")
    for r in rows:
        rate = lambda t: f"{1.0 / t:9.0f}/s" if t else f"{'n/a':>11}"  # noqa: E731
        dense_ratio = f"{r['dense'] / r['stencil']:9.1f}" if r["dense"] else f"{'n/a':>9}"
        fused_ratio = f"{r['fused'] / r['csr_product']:16.2f}" if r["fused"] else f"{'n/a':>16}"
        print(
            f"{r['side']:>4}x{r['side']:<4} {r['S']:>7} {r['path']:>5} | {rate(r['stencil'])} {rate(r['fused'])} "
            f"{rate(r['csr_step'])} {rate(r['csr_product'])} {rate(r['dense'])} | {r['csr_step'] / r['stencil']:10.2f} "
            f"{r['csr_product'] / r['stencil']:10.2f} {dense_ratio} | {fused_ratio}"
        )
    print("(steps per second; 'x ...' = how many times faster the stencil step is; dense n/a where "
          f"S x S matrices exceed {args.dense_max_gib} GiB; fused n/a where the default is numba, or without numba)")
    by_side = {r["side"]: r for r in rows}
    if 128 in by_side and 512 in by_side:
        g = by_side[512]["stencil"] / by_side[128]["stencil"]
        cells = by_side[512]["S"] / by_side[128]["S"]
        print(f"128x128 -> 512x512: {cells:.1f}x the states, stencil step time x{g:.1f}")
        if by_side[128]["fused"] and by_side[512]["fused"]:
            gf = by_side[512]["fused"] / by_side[128]["fused"]
            print(f"128x128 -> 512x512: {cells:.1f}x the states, fused step time x{gf:.1f}")
    print(f"largest |stencil - csr| belief difference: {max(r['err'] for r in rows):.2e}")
    verdict = lambda ok: "met" if ok else "NOT met"  # noqa: E731
    if 64 in by_side and by_side[64]["dense"]:
        x = by_side[64]["dense"] / by_side[64]["stencil"]
        print(f"target 64x64 at least 100x the dense step: x{x:.0f}, {verdict(x >= 100)}")
    if 128 in by_side and 512 in by_side:
        print(f"target 128x128 -> 512x512 step time at most x20: x{g:.1f}, {verdict(g <= 20)}")
        if by_side[128]["fused"] and by_side[512]["fused"]:
            print(f"target 128x128 -> 512x512 fused step time at most x20: x{gf:.1f}, {verdict(gf <= 20)}")
    worst = min(rows, key=lambda r: r["csr_product"] / r["stencil"])
    x = worst["csr_product"] / worst["stencil"]
    print(f"target at least the CSR product's speed at every size: lowest x{x:.2f} ({worst['side']}x{worst['side']}), "
          f"{verdict(x >= 1)}")
    fused_rows = [r for r in rows if r["fused"]]
    if fused_rows:
        worst = max(fused_rows, key=lambda r: r["fused"] / r["csr_product"])
        y = worst["fused"] / worst["csr_product"]
        print(f"target fused step at most 0.5x the CSR product's time: highest {y:.2f}x ({worst['side']}x{worst['side']}), "
              f"{verdict(y <= 0.5)}")

    if not args.no_memory:
        print("\nPeak resident memory (VmHWM), 512x512 environment + HMMBeliefWrapper, reset and 20 steps,")
        print("each in a fresh process; 'imports' = resident after importing gymnasium and gym_gridloc;")
        print("1 MiB = 1.049 MB (target: under 200 MB):")
        cases = [
            ("ColourGrid-v0", {"size": (512, 512)}),
            ("WindyMaze-v0", {"size": (512, 512)}),
            ("RingSensor8x8-v0", {"size": (512, 512)}),
            ("RingSensor8x8-v0", {"size": (512, 512), "dynamics": "passive"}),
        ]
        print(f"  {'environment':<32} {'default install':>38} {'GYM_GRIDLOC_NO_NUMBA=1':>24}")
        for env_id, kwargs in tqdm(cases, desc="memory", file=sys.stderr):
            cols = []
            for numba in (True, False):
                base, peak, loaded = memory(env_id, kwargs, numba)
                note = f", numba {'loaded' if loaded else 'not loaded'}" if numba else ""
                cols.append(f"{peak * 1.048576:4.0f} MB (imports {base * 1.048576:3.0f}){note}")
            name = env_id + (" passive dynamics" if kwargs.get("dynamics") == "passive" else "")
            print(f"  {name:<32} {cols[0]:>38} {cols[1]:>24}")


if __name__ == "__main__":
    main()
