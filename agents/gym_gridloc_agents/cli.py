"""``gridloc``: train agents, run the localisation-speed benchmark, reproduce the seeds, draw.

    gridloc train configs/ppo_windymaze.yml [--force] [--resume CKPT] [--tensorboard DIR]
    gridloc bench --env WindyMaze-v0 --policies random,greedy,greedy2,ppo --episodes 200 \\
                  --json out.json --plot out.png
    gridloc bench --all            # the README's table: 3 environments x 5 policies x 1000 episodes
    gridloc reproduce [--quiet]    # the seed documents' numbers (needs only the core install)
    gridloc render [--env ...] [--out results/episode.png] [--gif EP.gif]
    gridloc bench --env DepthMaze-v0 --size 7 --test-set --episode-length 15 --episodes 1000
    gridloc bench --env WindyMaze-v0 --policies greedy2,expectimax,ppo --option expectimax.depth=3 --frontier f.png
    gridloc bound ColourGrid-v0 --depth 5   # no policy can localise faster than this
    gridloc plot [results/bench.json]
    gridloc view WindyMaze-v0 --policy ppo       # step through an episode (the render extra: pygame-ce)
    gridloc play DepthMaze-v0                    # drive the robot with the arrow keys
    gridloc sweep configs/ppo_colourgrid.yml --seeds 5 --grid hyperparams.learning_rate=1e-4,3e-4 \
                  [--search optuna --trials N] [--address HEAD:PORT] [--cpus N] [--output DIR] [--resume]

Each subcommand lives in its module; this one parses and dispatches.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from gym_gridloc_agents.evaluation.bench_command import RESULTS, bench_main, bound_main, fail
from gym_gridloc_agents.files import OutputError
from gym_gridloc_agents.policies import DEFAULT_POLICIES


def build_parser() -> argparse.ArgumentParser:
    """The ``gridloc`` command line: its sub-commands and their arguments."""
    p = argparse.ArgumentParser(prog="gridloc", description="gym_gridloc agents: training and the localisation benchmark")
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train a policy from a YAML config (see configs/)")
    t.add_argument("config", help="a YAML config, e.g. configs/ppo_windymaze.yml")
    t.add_argument("--force", action="store_true",
                   help="replace an existing model and its metadata (never a file of another kind, an input or a checkpoint)")
    t.add_argument("--resume", metavar="CKPT", help="continue from a checkpoint .zip up to total_timesteps")
    t.add_argument("--output", metavar="PATH", help="model file to write (.zip; overrides the config)")
    t.add_argument("--timesteps", type=int, metavar="N", help="total timesteps (overrides the config)")
    t.add_argument("--tensorboard", metavar="DIR", help="log to TensorBoard in DIR")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.add_argument("--torch-threads", type=int, default=1, metavar="N", help="torch threads (default 1: fastest for small MLPs)")

    b = sub.add_parser("bench", help="benchmark policies on the same episode seeds")
    b.add_argument("--env", metavar="ENV_ID", help="environment id, e.g. WindyMaze-v0")
    b.add_argument("--all", action="store_true",
                   help="all three environments, every policy, 1000 episodes; writes results/bench.json and results/bench_<env>.png")
    b.add_argument("--policies", default=None, help=f"comma-separated policy names (default: {','.join(DEFAULT_POLICIES)})")
    b.add_argument("--episodes", type=int, default=None, help="episodes per policy (default 200; 1000 with --all)")
    b.add_argument("--seed", type=int, default=0, help="seed of episode 0 (episode i uses seed+i)")
    b.add_argument("--json", metavar="PATH", help="write the rows as JSON (every number)")
    b.add_argument("--markdown", metavar="PATH", help="write the full table as markdown (the terminal shows a short one)")
    b.add_argument("--plot", metavar="PATH.png", help="write the plot (one environment)")
    b.add_argument("--ppo-model", metavar="PATH", nargs="+",
                   help="benchmark this PPO model instead of the shipped one; several files, a directory (its *.zip) or a "
                        "glob: one model per seed, the ppo row is then the aggregate across seeds (e.g. a sweep's "
                        "models/<configuration>)")
    b.add_argument("--distilled-model", metavar="PATH", nargs="+",
                   help="benchmark this planner-distilled model (policy distilled) instead of the shipped one; several "
                        "files, a directory or a glob as --ppo-model")
    b.add_argument("--recurrent-model", metavar="PATH", help="benchmark this RecurrentPPO model instead of the shipped one")
    b.add_argument("--size", type=int, metavar="N", help="map size (the size keyword of the environment, e.g. 7 for DepthMaze 7x7)")
    b.add_argument("--test-set", action="store_true",
                   help="run on the held-out test maps of gym_gridloc.maps.test_set (episode i: map i and its start pose; needs --size)")
    b.add_argument("--episode-length", type=int, metavar="L",
                   help="fixed-length episodes of L steps (the research protocol): the table adds accuracy at L")
    b.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="another keyword of gym.make (a YAML scalar, e.g. n_colours=4); repeat for several")
    b.add_argument("--option", action="append", default=[], metavar="POLICY.KEY=VALUE",
                   help="an option of one policy (a YAML scalar), e.g. expectimax.depth=3 or mcts.simulations=2000")
    b.add_argument("--frontier", metavar="PATH.png", help="write the speed-quality plot: mean steps against ms per decision")
    b.add_argument("--jobs", type=int, default=1, help="parallel processes, each running chunks of episodes (default 1)")
    b.add_argument("--address", metavar="ADDRESS",
                   help="run the chunks of episodes as Ray tasks on this running Ray cluster (HOST:PORT, or auto; the 'sweep' "
                        "extra): the same rows as a local run, each saying where its chunks ran (docs/cluster.md)")
    b.add_argument("--update", action="store_true",
                   help="merge the new rows into the existing JSON file (the same environment, policy and options: replaced) and plot the merged rows")
    b.add_argument("--force", action="store_true", help="replace an existing results JSON (default: refused; see --update)")
    b.add_argument("--torch-threads", type=int, default=1, metavar="N",
                   help="torch threads of the learned policies, per process (default 1: fastest for these small networks)")
    b.add_argument("--no-progress", action="store_true", help="no progress bars")

    # Their options are their modules' own (main() hands them over unparsed).
    sub.add_parser("reproduce", help="reproduce the seed documents' numbers (PASS/FAIL per check; --help for options)")
    sub.add_parser("view", help="step through an episode under a policy in a window, with the model inspector (--help)")
    sub.add_parser("play", help="drive the robot with the arrow keys in a window (--help)")

    d = sub.add_parser("render", help="draw one episode per environment as belief heatmaps (and a GIF)")
    d.add_argument("--env", nargs="+", default=None, help="environment ids (default: every registered one, the four of gym_gridloc.ENV_IDS)")
    d.add_argument("--seed", type=int, default=3, help="episode seed (actions are random, seeded)")
    d.add_argument("--frames", type=int, default=6, help="frames per environment")
    d.add_argument("--out", default=str(RESULTS / "episode.png"), help="PNG to write")
    d.add_argument("--gif", default=None, help="also write the first environment's whole episode as a GIF")

    w = sub.add_parser("sweep", help="train seeds and hyperparameter grids of a config on Ray Tune (the 'sweep' extra)")
    w.add_argument("config", help="a YAML config, e.g. configs/ppo_colourgrid.yml")
    w.add_argument("--seeds", type=int, default=1, metavar="N", help="seeds per configuration: the config's seed + 0..N-1 (default 1)")
    w.add_argument("--grid", nargs="+", action="extend", metavar="KEY=V1,V2",
                   help="config keys as dotted paths and their values, e.g. hyperparams.learning_rate=1e-4,3e-4 (YAML scalars)")
    w.add_argument("--search", choices=("optuna",), help="let Optuna choose among the --grid values (with --trials), ASHA pruning")
    w.add_argument("--trials", type=int, metavar="N", help="configurations Optuna tries (each with every seed)")
    w.add_argument("--address", metavar="ADDRESS", help="join this running Ray cluster (default: start Ray on this machine)")
    w.add_argument("--cpus", type=int, metavar="N", help="CPUs of the Ray started on this machine (default: all); 1 per trial")
    w.add_argument("--output", metavar="DIR", help="where everything goes (default runs/sweeps/<config stem>)")
    w.add_argument("--resume", action="store_true", help="continue the interrupted sweep in --output (same arguments)")

    lb = sub.add_parser("bound", help="a lower bound on any policy's mean steps to localise (exhaustive search to depth K)")
    lb.add_argument("env", metavar="ENV_ID", help="environment id, e.g. ColourGrid-v0")
    lb.add_argument("--depth", type=int, default=3, metavar="K", help="search depth (default 3; the cost grows about |A x Z|^K)")
    lb.add_argument("--prune", type=float, default=0.0, metavar="P",
                    help="drop readings below this probability (keeps it a bound, a looser one; default 0)")
    lb.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE", help="a keyword of gym.make (repeatable)")
    lb.add_argument("--json", metavar="PATH", help="write the bound as JSON")
    lb.add_argument("--force", action="store_true", help="replace an existing bound JSON")

    q = sub.add_parser("plot", help="redraw the benchmark figures from a results JSON")
    q.add_argument("json", nargs="?", default=str(RESULTS / "bench.json"), help="a bench JSON (default results/bench.json)")
    q.add_argument("--training", nargs="+", metavar="MODEL.zip",
                   help="instead: plot these models' training curves (their held-out evaluations) to --out")
    q.add_argument("--curves", nargs="+", metavar="RUNS",
                   help="instead: learning curves across seeds to --out, one curve per RUNS (a sweep's --output directory, a "
                        "directory of models or model files): the IQM of the seeds' held-out evaluations with a bootstrap "
                        "95%% interval, against environment steps and wall time")
    q.add_argument("--baselines", metavar="BENCH.json",
                   help="with --curves: benchmark rows of the curves' task whose random, greedy2 and best planner are drawn "
                        "as lines (default results/bench.json, where it holds that task's rows)")
    q.add_argument("--curves-json", metavar="PATH.json", help="with --curves: also write the curves and sample efficiency as JSON")
    q.add_argument("--out", metavar="PATH.png", default=None,
                   help="the --training or --curves plot (default results/training.png, results/curves.png)")
    return p


def _render(args) -> int:
    import gym_gridloc
    from gym_gridloc.core.validation import check_int
    from gym_gridloc_agents.evaluation.figures import episode_frames, episode_strips, write_gif

    from gym_gridloc_agents import files
    from gym_gridloc_agents.envs import check_environment

    envs = args.env or list(gym_gridloc.ENV_IDS)
    try:
        check_int("--frames", args.frames)
        if not 0 <= args.seed < 2**63:
            raise ValueError(f"--seed must be in 0..2**63-1, got {args.seed}")
        for e in envs:
            check_environment(e, {}, what=f"--env {e}", error=ValueError)
        files.check_outputs([(args.out, files.FIGURE, "picture"), (args.gif, files.FIGURE, "GIF")])
    except (ValueError, OutputError) as exc:
        return fail("render", str(exc))
    episode_strips(envs, args.seed, args.frames, args.out)
    print(f"wrote {args.out}")
    if args.gif:
        frames = [f for f, _ in episode_frames(envs[0], args.seed, 10_000)]
        write_gif(frames, args.gif)
        print(f"wrote {args.gif} ({len(frames)} frames)")
    return 0


def _plot(args) -> int:
    from gym_gridloc_agents import files
    from gym_gridloc_agents.evaluation.report import env_label, plot, plot_frontier, plot_training, read_rows

    if args.curves and args.training:
        return fail("plot", "give --curves or --training, not both")
    if args.curves:
        return _plot_curves(args)
    args.out = args.out or str(RESULTS / "training.png")
    if args.training:
        try:
            for m in args.training:
                if not Path(m).is_file():
                    raise ValueError(f"--training {m}: no such model file")
            files.check_outputs([(args.out, files.FIGURE, "plot")], inputs=args.training)
            plot_training(args.training, args.out)
        except (ValueError, OutputError) as exc:
            return fail("plot", str(exc))
        print(f"wrote {args.out}")
        return 0
    src = Path(args.json)
    if not src.is_file():
        return fail("plot", f"{src} does not exist; run `gridloc bench --all` first")
    try:
        rows = read_rows(src)
        if not all("localised_curve" in r and "accuracy_curve" in r for r in rows):
            raise ValueError(f"{src} holds rows without their curves (a table such as bench_table.json): "
                             "plot the results JSON gridloc bench wrote")
        # one figure per environment with its keywords and maps (bench.json: bench_<env>.png)
        groups = {label: [r for r in rows if env_label(r) == label] for label in sorted({env_label(r) for r in rows})}
        names = {label: "bench_" + re.sub(r"[^A-Za-z0-9._=+-]+", "_", label).strip("_") + ".png" for label in groups}
        outs = [(src.parent / names[label], files.FIGURE, f"plot of {label}") for label in groups]
        frontier = src.parent / f"{src.stem}_frontier.png" if any(r.get("ms_per_decision") for r in rows) else None
        files.check_outputs([*outs, (frontier, files.FIGURE, "frontier plot")], inputs=[src])
    except (ValueError, OutputError) as exc:
        return fail("plot", str(exc))
    for (out, _, _), group in zip(outs, groups.values()):
        plot(group, out)
        print(f"wrote {out}")
    if frontier is not None:  # bench.json: bench_frontier.png
        plot_frontier(rows, frontier)
        print(f"wrote {frontier}")
    return 0


def _plot_curves(args) -> int:
    from gym_gridloc_agents.evaluation import curves
    from gym_gridloc_agents import files
    from gym_gridloc_agents.evaluation.report import read_rows

    out = args.out or str(RESULTS / "curves.png")
    try:
        made = []
        for item in args.curves:
            runs = curves.load_runs(item)
            label = Path(item).name if Path(item).is_dir() else Path(item).stem
            made.append(curves.curve(runs, label=label))
        if len({(c["env_id"], repr(sorted(c["env_kwargs"].items()))) for c in made}) > 1:
            raise ValueError("--curves: the runs are of different tasks; plot one task per figure")
        source = args.baselines or str(RESULTS / "bench.json")
        rows = read_rows(source) if Path(source).is_file() else []
        env_id, env_kwargs = made[0]["env_id"], made[0]["env_kwargs"]
        lines = curves.baselines(rows, env_id, made[0]["metric"], made[0]["lower_is_better"], env_kwargs)
        if not lines and any(r.get("env") == env_id for r in rows):  # rows of another task: no line, no sample efficiency
            note = (f"--baselines {source}: its {env_id} rows are of other tasks than the curves' ({env_id} with {env_kwargs}); "
                    "give the results of a benchmark of this task")
            if args.baselines:
                raise ValueError(note)
            print(f"gridloc plot: {note}; no baseline drawn", file=sys.stderr)
        files.check_outputs([(out, files.FIGURE, "plot"), (args.curves_json, files.CURVES, "curves JSON")],
                            inputs=[*args.curves, source], replace=True)
    except (ValueError, OutputError) as exc:
        return fail("plot", str(exc))
    curves.plot_curves(made, lines, out)
    print(curves.curves_table(made, lines))
    print(f"wrote {out}")
    if args.curves_json:
        from gym_gridloc_agents.files import atomic_write_json

        atomic_write_json(Path(args.curves_json), {"baselines": lines, "baselines_source": source,
                                                   "curves": [{**c, "sample_efficiency": curves.sample_efficiency(c, lines)}
                                                              for c in made]})
        print(f"wrote {args.curves_json}")
    return 0


def _train(args) -> int:
    from gym_gridloc.core.validation import check_int
    from gym_gridloc_agents.training.config import ConfigError
    from gym_gridloc_agents.training.train import OutputError, TrainingInterrupted, train

    try:
        if args.timesteps is not None:
            check_int("--timesteps", args.timesteps)
        check_int("--torch-threads", args.torch_threads)
    except ValueError as exc:
        return fail("train", str(exc))
    try:
        info = train(
            args.config,
            force=args.force,
            resume=args.resume,
            output=args.output,
            total_timesteps=args.timesteps,
            tensorboard_log=args.tensorboard,
            progress_bar=not args.no_progress,
            torch_threads=args.torch_threads,
            command="gridloc " + " ".join(sys.argv[1:]),
        )
    except TrainingInterrupted as exc:
        print(f"gridloc train: {exc}; resume with: gridloc train {args.config} --resume {exc.checkpoint}", file=sys.stderr)
        return 130
    except (ConfigError, OutputError, FileExistsError, FileNotFoundError, ValueError) as exc:
        return fail("train", str(exc))
    out = info["config"]["output"]
    print(f"saved {out} ({info['num_timesteps']} steps, {info['wall_time_seconds']:.0f} s) and {Path(out).with_suffix('.json')}")
    return 0


def _sweep(args) -> int:
    from gym_gridloc_agents.training.config import ConfigError
    from gym_gridloc_agents.sweeps.sweep import SweepError, prepare, run, summary_table

    try:
        spec = prepare(args.config, seeds=args.seeds, grid=args.grid, search=args.search, trials=args.trials,
                       output=args.output, address=args.address, cpus=args.cpus)
        summary = run(spec, address=args.address, cpus=args.cpus, resume=args.resume)
    except (SweepError, ConfigError) as exc:
        return fail("sweep", " ".join(str(exc).split()))
    print(summary_table(summary))
    print(f"\nwrote {summary['output']}/summary.md, summary.json and results/", file=sys.stderr)
    failed = summary["statuses"].get("error", 0)
    if summary["pending"] or failed:
        print(f"gridloc sweep: {summary['pending']} trial(s) unfinished, {failed} failed; continue with: "
              f"{spec['command']} --resume", file=sys.stderr)
        return 1
    return 0 if summary["best"] else 1


#: What ``gridloc`` needs beyond the core install (the ``rl`` extra), by import name.
RL_MODULES = ("tqdm", "yaml", "matplotlib", "torch", "stable_baselines3", "sb3_contrib")
#: The modules each subcommand needs beyond the core install.
NEEDS = {"train": RL_MODULES, "bench": RL_MODULES, "render": ("matplotlib",), "plot": ("matplotlib",), "reproduce": (),
         "bound": ("yaml",), "sweep": (*RL_MODULES, "ray", "optuna")}
COMMANDS = {"train": "_train", "bench": "bench_main", "render": "_render", "plot": "_plot", "sweep": "_sweep", "bound": "bound_main"}


def missing_modules(command: str) -> list[str]:
    import importlib.util

    return [m for m in NEEDS.get(command, RL_MODULES) if importlib.util.find_spec(m) is None]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["reproduce"]:
        from gym_gridloc import reproduce

        return reproduce.main(argv[1:])
    if argv[:1] in (["view"], ["play"]):
        from gym_gridloc_agents import viewer

        return (viewer.view_main if argv[0] == "view" else viewer.play_main)(argv[1:])
    args = build_parser().parse_args(argv)
    missing = missing_modules(args.command)
    if missing:  # sweep: its own extra too, without the note on torch
        sweep = args.command == "sweep"
        extras, them, names = ("'rl' and 'sweep' extras", "them", "rl,sweep") if sweep else ("'rl' extra", "it", "rl")
        print(f"gridloc {args.command} needs the {extras} (missing: {', '.join(missing)}). Install {them} with\n"
              f"  pip install torch==2.13.0 && pip install 'gym_gridloc[{names}]'"
              + ("" if sweep else "\n(torch first and pinned: an unpinned torch resolves to a multi-GB CUDA build)."),
              file=sys.stderr)
        return 2
    return globals()[COMMANDS[args.command]](args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
