"""``gridloc``: train agents, run the localisation-speed benchmark, reproduce the seeds, draw.

    gridloc train configs/ppo_windymaze.yml [--force] [--resume CKPT] [--tensorboard DIR]
    gridloc bench --env WindyMaze-v0 --policies random,greedy,greedy2,ppo --episodes 200 \\
                  --json out.json --plot out.png
    gridloc bench --all            # the README's table: the 3 fixed-map environments x the default policies x 1000 episodes
    gridloc reproduce [--quiet]    # the seed documents' numbers (needs only the core install)
    gridloc render [--env ...] [--out results/episode.png] [--gif EP.gif]
    gridloc bench --env DepthMaze-v0 --size 7 --test-set --episode-length 15 --episodes 1000
    gridloc bench --env WindyMaze-v0 --policies greedy2,expectimax,ppo --option expectimax.depth=3 --frontier f.png
    gridloc bound ColourGrid-v0 --depth 5   # no policy can localise faster than this
    gridloc plot results/bench.json   # or --training MODEL.zip ... / --curves RUNS ...
    gridloc suite --episodes 1000 --jobs 2 # every task of the benchmark into results/suite.json (resumable)
    gridloc report [--check]               # the result tables of README.md and docs/results.md from results/
    gridloc view WindyMaze-v0 --policy ppo       # step through an episode (the render extra: pygame-ce)
    gridloc play DepthMaze-v0                    # drive the robot with the arrow keys
    gridloc sweep configs/ppo_colourgrid.yml --seeds 5 --grid hyperparams.learning_rate=1e-4,3e-4 \
                  [--search optuna --trials N] [--address HEAD:PORT] [--cpus N] [--output DIR] [--resume]

Each subcommand lives in its module; the arguments are in :mod:`gym_gridloc_agents.cli_args`; this one parses and dispatches.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from gym_gridloc_agents.cli_args import build_parser
from gym_gridloc_agents.evaluation.bench_command import RESULTS, bench_main, bound_main, fail
from gym_gridloc_agents.files import OutputError


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
    env_kwargs = {"render_shading": args.shading}
    episode_strips(envs, args.seed, args.frames, args.out, env_kwargs=env_kwargs)
    print(f"wrote {args.out}")
    if args.gif:
        frames = [f for f, _ in episode_frames(envs[0], args.seed, 10_000, env_kwargs)]
        write_gif(frames, args.gif)
        print(f"wrote {args.gif} ({len(frames)} frames)")
    return 0


def _plot(args) -> int:
    from gym_gridloc_agents import files
    from gym_gridloc_agents.evaluation.report import env_label, plot, plot_frontier, plot_training, read_rows

    if sum(map(bool, (args.json, args.curves, args.training))) > 1:
        return fail("plot", "give one of a bench JSON, --curves or --training")
    if not (args.json or args.curves or args.training):
        return fail("plot", "name what to draw: a bench JSON (gridloc plot results/bench.json redraws the figures beside "
                            "it), --training MODEL.zip ... --out PATH.png, or --curves RUNS ... --out PATH.png")
    if args.curves:
        return _plot_curves(args)
    args.out = args.out or str(RESULTS / "training.png")
    if args.training:
        try:
            for m in args.training:
                if not Path(m).is_file():
                    raise ValueError(f"--training {m}: no such model file")
            files.check_outputs([(args.out, files.FIGURE, "plot")], inputs=args.training)
            panels = plot_training(args.training, args.out)
        except (ValueError, OutputError) as exc:
            return fail("plot", str(exc))
        print(f"wrote {args.out}" + (f" (one panel per environment: {'; '.join(panels)})" if len(panels) > 1 else ""))
        return 0
    src = Path(args.json)
    if not src.is_file():
        return fail("plot", f"{src} does not exist; run `gridloc bench --all` (or bench --json PATH) first")
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


def _report(args) -> int:
    from gym_gridloc_agents.evaluation.report_command import report_main

    return report_main(args)


def _suite(args) -> int:
    from gym_gridloc_agents.evaluation.suite import suite_main

    return suite_main(args)


def _train(args) -> int:
    from gym_gridloc.core.validation import check_int
    from gym_gridloc_agents.training.config import ConfigError
    from gym_gridloc_agents.training.train import OutputError, TrainingInterrupted, train

    config = args.config
    try:
        if args.timesteps is not None:
            check_int("--timesteps", args.timesteps)
        check_int("--torch-threads", args.torch_threads)
        if args.pretrain_episodes is not None:
            from gym_gridloc_agents.training.config import load_config
            from gym_gridloc_agents.training.pretrain import with_episodes

            config = with_episodes(load_config(args.config), check_int("--pretrain-episodes", args.pretrain_episodes))
    except (ValueError, ConfigError) as exc:
        return fail("train", str(exc))
    try:
        info = train(
            config,
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
        summary = run(spec, address=args.address, cpus=args.cpus, resume=args.resume, verbose=1 if args.verbose else 0)
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
         "bound": ("yaml",), "sweep": (*RL_MODULES, "ray", "optuna"), "report": (),
         "suite": RL_MODULES}
COMMANDS = {"train": "_train", "bench": "bench_main", "render": "_render", "plot": "_plot", "sweep": "_sweep", "bound": "bound_main",
            "report": "_report", "suite": "_suite"}


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
