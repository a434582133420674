"""Reproduce the numbers printed in the seed documents with gym_gridloc (``gridloc reproduce``).

    gridloc reproduce [--runs 20] [--steps 1000] [--seed 0] [--quiet]
    python -m gym_gridloc.reproduce ...          # the same, without the agents' extra

For every seed it prints the seed's table beside ours and the largest difference, then PASS or
FAIL per item; the exit status is 1 if any item fails.

* Seed 000: ColourGrid with ``slip=1.0``, uniform prior, predict-then-update each move.  The
  printout skips one step (an unprinted move that read Y after move 8); with that step all 11
  printed tables match within 0.00005, with the literal 11 readings moves 9-11 do not.
* Seed 004: WindyMaze, the seven tables (filter, predict N, filter, predict E, filter, predict E,
  filter) in percent within 0.01.
* Seed 001: the ring sensor's probability of "nothing" on 8x8 (exact).
* Seed 003: transition rows and reading distributions sum to 1; tracking on a 5x5 grid with the
  passive dynamics, 20 runs of 1000 steps: most probable position exactly right 28-33% of the time,
  mean Manhattan error 1.2-2.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gym_gridloc import engine
from gym_gridloc.core.validation import check_int
from gym_gridloc.filter import ForwardFilter
from gym_gridloc.models import colour_grid_model, ring_sensor_model, windy_maze_model
from gym_gridloc.seeds import (
    COLOUR_GRID_LAYOUT,
    SEED000_MOVES,
    SEED000_READINGS,
    SEED000_SKIPPED,
    SEED001_NOTHING,
    SEED003_ERROR_RANGE,
    SEED003_HIT_RANGE,
    SEED004_INITIAL,
    SEED004_TABLES,
    WINDY_MAZE_LAYOUT,
)

COLOURS = "RGBY"
SEED000_TOL = 0.00005
SEED004_TOL = 0.01  # percent
SEED001_TOL = 1e-12
SUM_TOL = 1e-12


class Report:
    """Collects PASS/FAIL lines."""

    def __init__(self) -> None:
        self.results: list[tuple[str, bool]] = []

    def check(self, name: str, ok: bool, detail: str) -> bool:
        self.results.append((name, bool(ok)))
        print(f"{'PASS' if ok else 'FAIL'}  {name}: {detail}")
        return bool(ok)


def side_by_side(left: list[str], right: list[str], titles: tuple[str, str], gap: int = 4) -> str:
    width = max(len(s) for s in [titles[0], *left])
    lines = [f"  {titles[0]:<{width}}{' ' * gap}{titles[1]}"]
    lines += [f"  {a:<{width}}{' ' * gap}{b}" for a, b in zip(left, right)]
    return "\n".join(lines)


def fmt_table(table, fmt, obstacle: str) -> list[str]:
    return [" ".join(obstacle if v is None else fmt(v) for v in row) for row in table]


# -- seed 000 --------------------------------------------------------------------------------------
def seed000_beliefs(readings: list[str]) -> list[np.ndarray]:
    """Position beliefs after each move: uniform prior, then predict-then-update per reading."""
    model = colour_grid_model(COLOUR_GRID_LAYOUT, slip=1.0)
    f = ForwardFilter(model).reset()
    out = []
    for colour in readings:
        f.step(0, COLOURS.index(colour))  # slip = 1: the action plays no part
        out.append(f.position_belief)
    return out


def seed000(report: Report, verbose: bool) -> None:
    print("=" * 100)
    print("Seed 000: ColourGrid, slip=1.0, uniform prior, predict-then-update; readings",
          " ".join(SEED000_READINGS[:8]), "(Y unprinted)", " ".join(SEED000_READINGS[9:]))
    printed = [b for i, b in enumerate(seed000_beliefs(SEED000_READINGS)) if i != SEED000_SKIPPED]
    worst = 0.0
    for k, ((colour, table), ours) in enumerate(zip(SEED000_MOVES, printed), start=1):
        diff = float(np.abs(ours - np.array(table)).max())
        worst = max(worst, diff)
        if verbose:
            print(f"Move {k:2d}, read {colour}")
            left = fmt_table(table, lambda v: f"{v:.4f}"[1:], "")
            right = fmt_table(ours.tolist(), lambda v: f"{v:.6f}", "")
            print(side_by_side(left, right, ("seed", "ours")))
        print(f"  move {k:2d} (read {colour}): largest |ours - seed| = {diff:.2e}")
    report.check("seed 000, 11 moves with the skipped step", worst <= SEED000_TOL,
                 f"largest difference {worst:.2e} (tolerance {SEED000_TOL})")

    literal = seed000_beliefs([c for c, _ in SEED000_MOVES])
    diffs = [float(np.abs(literal[k] - np.array(SEED000_MOVES[k][1])).max()) for k in range(11)]
    print("  literal 11 readings (no skipped step), largest difference per move:")
    print("   " + "  ".join(f"{k + 1}:{d:.1e}" for k, d in enumerate(diffs)))
    report.check("seed 000, literal readings match moves 1-8", max(diffs[:8]) <= SEED000_TOL,
                 f"largest difference {max(diffs[:8]):.2e}")
    report.check("seed 000, literal readings do NOT match moves 9-11", min(diffs[8:]) > SEED000_TOL,
                 "differences " + ", ".join(f"{d:.4f}" for d in diffs[8:]) + f" all > {SEED000_TOL}")


# -- seed 004 --------------------------------------------------------------------------------------
def seed004_beliefs() -> list[np.ndarray]:
    """Position beliefs (percent) after each of the seed's seven operations."""
    f = ForwardFilter(windy_maze_model(WINDY_MAZE_LAYOUT)).reset()
    out = [100.0 * f.position_belief]
    for kind, arg, _ in SEED004_TABLES:
        if kind == "filter":
            f.update(list(arg))
        else:
            f.predict("NESW".index(arg))
        out.append(100.0 * f.position_belief)
    return out


def seed004(report: Report, verbose: bool) -> None:
    print("=" * 100)
    print("Seed 004: WindyMaze, tables in percent (#### = obstacle)")
    worst = 0.0
    for (kind, arg, table), ours in zip([("initial", None, SEED004_INITIAL), *SEED004_TABLES], seed004_beliefs()):
        seed = np.array([[np.nan if v is None else v for v in row] for row in table], dtype=float)
        diff = float(np.nanmax(np.abs(ours - seed)))
        label = ("filter [" + ", ".join("o" if b else "-" for b in arg) + "] (W, N, E, S)" if kind == "filter"
                 else f"predict {arg}" if kind == "predict" else "initial (uniform)")
        if verbose:
            print(label)
            left = fmt_table(table, lambda v: f"{v:6.2f}", "  ####")
            right = fmt_table(np.where(np.isnan(seed), None, ours), lambda v: f"{v:6.2f}", "  ####")
            print(side_by_side(left, right, ("seed", "ours (rounded to 2 decimals)")))
        print(f"  {label:<40s} largest |ours - seed| = {diff:.4f} percent")
        if kind != "initial":
            worst = max(worst, diff)
    report.check("seed 004, seven tables", worst <= SEED004_TOL,
                 f"largest difference {worst:.4f} percent (tolerance {SEED004_TOL}; "
                 f"{'within' if worst <= 0.005 + 1e-9 else 'beyond'} the printout's rounding, 0.005)")


# -- seed 001 --------------------------------------------------------------------------------------
def seed001_expected(h: int = 8, w: int = 8) -> np.ndarray:
    return np.array([[SEED001_NOTHING[tuple(sorted((min(r, h - 1 - r, 2), min(c, w - 1 - c, 2))))] for c in range(w)]
                     for r in range(h)])


def seed001(report: Report, verbose: bool) -> None:
    print("=" * 100)
    print("Seed 001: RingSensor 8x8, P(nothing | position)")
    model = ring_sensor_model((8, 8))
    ours = model.likelihood(model.sensor.nothing)
    expected = seed001_expected()
    diff = float(np.abs(ours - expected).max())
    if verbose:
        print(side_by_side(fmt_table(expected.tolist(), lambda v: f"{v:.3f}", ""),
                           fmt_table(ours.tolist(), lambda v: f"{v:.3f}", ""), ("seed", "ours")))
    report.check("seed 001, P(nothing) on 8x8", diff <= SEED001_TOL, f"largest difference {diff:.1e}")


# -- seed 003 --------------------------------------------------------------------------------------
def max_sum_errors(model) -> tuple[float, float]:
    """Largest |row sum - 1| over every action's transition matrix (and the unknown action), and
    largest |sum of a state's reading distribution - 1|."""
    t_err = max(float(np.abs(np.asarray(engine.transition_matrix(model, a).sum(axis=1)).ravel() - 1.0).max())
                for a in [*range(model.n_actions), None])
    o_err = max(abs(float(model.sensor.distribution(int(r), int(c))[1].sum()) - 1.0) for r, c in model.grid.free_cells)
    return t_err, o_err


def track(model, runs: int, steps: int, seed: int) -> tuple[float, float]:
    """Simulate with the model and filter with ForwardFilter; return (fraction of steps whose most
    probable position is the true one, mean Manhattan error of that estimate)."""
    rng = np.random.default_rng(seed)
    w = model.shape[1]
    hits = error = 0
    for _ in range(runs):
        states = engine.sample_initial(model, 1, rng)
        f = ForwardFilter(model).reset()
        for _ in range(steps):
            states = engine.sample_next(model, states, 0, rng)
            f.step(0, int(engine.sample_readings(model, states, rng)[0]))
            er, ec = divmod(int(np.argmax(f.position_belief)), w)
            d = abs(er - int(states[0, 1])) + abs(ec - int(states[0, 2]))
            hits += d == 0
            error += d
    n = runs * steps
    return hits / n, error / n


def seed003(report: Report, runs: int, steps: int, seed: int) -> None:
    print("=" * 100)
    print("Seed 003: RingSensor, sums and tracking")
    for size in [(8, 8), (5, 5)]:
        for dynamics in ("passive", "commanded"):
            model = ring_sensor_model(size, dynamics=dynamics)
            t_err, o_err = max_sum_errors(model)
            report.check(
                f"seed 003, sums, {size[0]}x{size[1]} {dynamics} dynamics",
                t_err <= SUM_TOL and o_err <= SUM_TOL,
                f"{model.n_states} states; largest |transition row sum - 1| = {t_err:.1e}, "
                f"largest |reading distribution sum - 1| = {o_err:.1e}",
            )
    model = ring_sensor_model((5, 5), dynamics="passive")
    t0 = time.perf_counter()
    hit, err = track(model, runs, steps, seed)
    secs = time.perf_counter() - t0
    print(f"  tracking, 5x5 passive dynamics, {runs} runs x {steps} steps (rng seed {seed}, {secs:.1f} s): "
          f"exactly right {100 * hit:.2f}%, mean Manhattan error {err:.3f}")
    lo, hi = SEED003_HIT_RANGE
    report.check("seed 003, fraction exactly right", lo <= hit <= hi,
                 f"{100 * hit:.2f}% (seed: {100 * lo:.0f}-{100 * hi:.0f}%)")
    lo, hi = SEED003_ERROR_RANGE
    report.check("seed 003, mean Manhattan error", lo <= err <= hi, f"{err:.3f} (seed: {lo}-{hi})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="gridloc reproduce", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=20, help="seed 003: number of tracking runs (default 20)")
    parser.add_argument("--steps", type=int, default=1000, help="seed 003: steps per run (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed 003: random seed of the simulation (default 0)")
    parser.add_argument("--quiet", action="store_true", help="print the differences only, not the tables")
    args = parser.parse_args(argv)
    try:
        for flag, value in (("--runs", args.runs), ("--steps", args.steps)):
            check_int(flag, value)
    except ValueError as exc:
        parser.error(str(exc))
    if args.runs * args.steps > 10**8:  # the simulation's arrays must fit in memory
        parser.error(f"--runs x --steps must be at most 10**8, got {args.runs * args.steps}")
    if not 0 <= args.seed < 2**63:
        parser.error(f"--seed must be in 0..2**63-1, got {args.seed}")

    report = Report()
    for check_seed in (seed000, seed004, seed001):
        check_seed(report, not args.quiet)
    seed003(report, args.runs, args.steps, args.seed)
    failed = [name for name, ok in report.results if not ok]
    print("=" * 100)
    if failed:
        print(f"FAIL: {len(failed)} of {len(report.results)} checks failed: {', '.join(failed)}")
        return 1
    print(f"PASS: all {len(report.results)} checks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
