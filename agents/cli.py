"""``gridloc``: train agents, run the localisation-speed benchmark, reproduce the seeds, draw.

    gridloc train configs/ppo_windymaze.yml [--force] [--resume CKPT] [--tensorboard DIR]
    gridloc bench --env WindyMaze-v0 --policies random,greedy,greedy2,ppo --episodes 200 \\
                  --json out.json --plot out.png
    gridloc bench --all            # the README's table: 3 environments x 5 policies x 1000 episodes
    gridloc reproduce [--quiet]    # the seed documents' numbers (needs only the core install)
    gridloc render [--env ...] [--out results/episode.png] [--gif EP.gif]
    gridloc plot [results/bench.json]
    gridloc view WindyMaze-v0 --policy ppo       # step through an episode (the render extra: pygame-ce)
    gridloc play DepthMaze-v0                    # drive the robot with the arrow keys
    gridloc sweep configs/ppo_colourgrid.yml --seeds 5 --grid hyperparams.learning_rate=1e-4,3e-4 \
                  [--search optuna --trials N] [--address HEAD:PORT] [--cpus N] [--output DIR] [--resume]

Each subcommand lives in its module; this one parses and dispatches.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

RESULTS = Path("results")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gridloc", description="gym_gridloc agents: training and the localisation benchmark")
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train a policy from a YAML config (see configs/)")
    t.add_argument("config", help="a YAML config, e.g. configs/ppo_windymaze.yml")
    t.add_argument("--force", action="store_true", help="overwrite an existing model file")
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
    b.add_argument("--policies", default=None, help="comma-separated policy names (default: random,greedy,greedy2,ppo,recurrent)")
    b.add_argument("--episodes", type=int, default=None, help="episodes per policy (default 200; 1000 with --all)")
    b.add_argument("--seed", type=int, default=0, help="seed of episode 0 (episode i uses seed+i)")
    b.add_argument("--json", metavar="PATH", help="write the rows as JSON")
    b.add_argument("--plot", metavar="PATH.png", help="write the plot (one environment)")
    b.add_argument("--ppo-model", metavar="PATH", nargs="+",
                   help="benchmark this PPO model instead of the shipped one; several files, a directory (its *.zip) or a "
                        "glob: one model per seed, the ppo row is then the aggregate across seeds (e.g. a sweep's "
                        "models/<configuration>)")
    b.add_argument("--recurrent-model", metavar="PATH", help="benchmark this RecurrentPPO model instead of the shipped one")
    b.add_argument("--jobs", type=int, default=1, help="parallel processes, each running chunks of episodes (default 1)")
    b.add_argument("--update", action="store_true",
                   help="merge the new rows into the existing JSON file (same env and policy: replaced) and plot the merged rows")
    b.add_argument("--no-progress", action="store_true", help="no progress bars")

    # Their options are their modules' own (main() hands them over unparsed).
    sub.add_parser("reproduce", help="reproduce the seed documents' numbers (PASS/FAIL per check; --help for options)")
    sub.add_parser("view", help="step through an episode under a policy in a window, with the model inspector (--help)")
    sub.add_parser("play", help="drive the robot with the arrow keys in a window (--help)")

    d = sub.add_parser("render", help="draw one episode per environment as belief heatmaps (and a GIF)")
    d.add_argument("--env", nargs="+", default=None, help="environment ids (default: the three registered ones)")
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

    q = sub.add_parser("plot", help="redraw the benchmark figures from a results JSON")
    q.add_argument("json", nargs="?", default=str(RESULTS / "bench.json"), help="a bench JSON (default results/bench.json)")
    return p


def _render(args) -> int:
    import gym_gridloc
    from gym_gridloc_agents.figures import episode_frames, episode_strips, write_gif

    envs = args.env or list(gym_gridloc.ENV_IDS)
    if args.frames < 1:
        print(f"gridloc render: error: --frames must be at least 1, got {args.frames}", file=sys.stderr)
        return 2
    episode_strips(envs, args.seed, args.frames, args.out)
    print(f"wrote {args.out}")
    if args.gif:
        frames = [f for f, _ in episode_frames(envs[0], args.seed, 10_000)]
        write_gif(frames, args.gif)
        print(f"wrote {args.gif} ({len(frames)} frames)")
    return 0


def _plot(args) -> int:
    from gym_gridloc_agents.bench import plot, read_rows

    src = Path(args.json)
    if not src.is_file():
        return _fail("plot", f"{src} does not exist; run `gridloc bench --all` first")
    try:
        rows = read_rows(src)
    except ValueError as exc:
        return _fail("plot", str(exc))
    for env in sorted({r["env"] for r in rows}):
        out = src.parent / f"bench_{env}.png"
        plot([r for r in rows if r["env"] == env], out)
        print(f"wrote {out}")
    return 0


def _train(args) -> int:
    from gym_gridloc_agents.config import ConfigError
    from gym_gridloc_agents.train import OutputError, TrainingInterrupted, train

    if args.timesteps is not None and args.timesteps < 1:
        print(f"gridloc train: error: --timesteps must be at least 1, got {args.timesteps}", file=sys.stderr)
        return 2
    if args.torch_threads < 1:
        print(f"gridloc train: error: --torch-threads must be at least 1, got {args.torch_threads}", file=sys.stderr)
        return 2
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
        print(f"gridloc train: error: {exc}", file=sys.stderr)
        return 2
    out = info["config"]["output"]
    print(f"saved {out} ({info['num_timesteps']} steps, {info['wall_time_seconds']:.0f} s) and {Path(out).with_suffix('.json')}")
    return 0


def _sweep(args) -> int:
    from gym_gridloc_agents.config import ConfigError
    from gym_gridloc_agents.sweep import SweepError, prepare, run

    try:
        spec = prepare(args.config, seeds=args.seeds, grid=args.grid, search=args.search, trials=args.trials,
                       output=args.output, address=args.address, cpus=args.cpus)
        summary = run(spec, address=args.address, cpus=args.cpus, resume=args.resume)
    except (SweepError, ConfigError) as exc:
        return _fail("sweep", " ".join(str(exc).split()))
    from gym_gridloc_agents.sweep import summary_table

    print(summary_table(summary))
    print(f"\nwrote {summary['output']}/summary.md, summary.json and results/", file=sys.stderr)
    failed = summary["statuses"].get("error", 0)
    if summary["pending"] or failed:
        print(f"gridloc sweep: {summary['pending']} trial(s) unfinished, {failed} failed; continue with: "
              f"{spec['command']} --resume", file=sys.stderr)
        return 1
    return 0 if summary["best"] else 1


def _fail(command: str, message: str) -> int:
    print(f"gridloc {command}: error: {message}", file=sys.stderr)
    return 2


def _bench(args) -> int:
    from gym_gridloc_agents.bench import BENCH_ENV_IDS, DEFAULT_POLICIES, markdown_table, plot, public_row, read_rows, run_benchmark
    from gym_gridloc_agents.bench import expand_models
    from gym_gridloc_agents.envs import check_environment
    from gym_gridloc_agents.files import OutputError, atomic_write_json, rescue_write, writable_file
    from gym_gridloc_agents.policies import POLICY_NAMES

    if args.all == bool(args.env):
        return _fail("bench", "give exactly one of --env ENV_ID or --all")
    envs = list(BENCH_ENV_IDS) if args.all else [args.env]
    policies = [p.strip() for p in (args.policies or ",".join(DEFAULT_POLICIES)).split(",") if p.strip()]
    episodes = args.episodes if args.episodes is not None else (1000 if args.all else 200)
    json_path = args.json or (str(RESULTS / "bench.json") if args.all else None)
    # Everything is checked before the first episode: a long run never ends in a traceback.
    try:
        for e in envs:
            check_environment(e, {}, what=f"--env {e}", error=ValueError)
        if not policies:
            raise ValueError(f"--policies names no policy (got {args.policies!r}); allowed: {', '.join(POLICY_NAMES)}")
        if episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {episodes}")
        if args.seed < 0 or args.seed + episodes > 2**32:
            raise ValueError(f"--seed must be in 0..{2**32 - episodes} (episode i uses seed+i), got {args.seed}")
        if args.jobs < 1:
            raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
        if args.plot and len(envs) > 1:
            raise ValueError("--plot takes one environment; --all writes results/bench_<env>.png")
        if args.update and not json_path:
            raise ValueError("--update needs --json PATH (or --all)")
        outputs = [(json_path, "results JSON")] if json_path else []
        outputs += [(args.plot, "plot")] if args.plot else []
        outputs += [(RESULTS / f"bench_{e}.png", "plot") for e in envs] if args.all else []
        for path, what in outputs:
            writable_file(path, what)
        old_rows = read_rows(json_path) if args.update and Path(json_path).exists() else []
    except (ValueError, OutputError) as exc:
        return _fail("bench", str(exc))
    try:
        ppo_model = expand_models(args.ppo_model) if args.ppo_model else None
        if ppo_model is not None and len(ppo_model) > 1 and len(envs) > 1:
            raise ValueError("several --ppo-model files (one per seed) are models of one environment: give --env ENV_ID, not --all")
        if ppo_model is not None and len(ppo_model) == 1:
            ppo_model = ppo_model[0]
    except ValueError as exc:
        return _fail("bench", str(exc))
    try:
        rows = run_benchmark(
            envs, policies, episodes, seed_start=args.seed, ppo_model=ppo_model,
            recurrent_model=args.recurrent_model, progress=not args.no_progress, jobs=args.jobs,
        )
    except (ValueError, FileNotFoundError) as exc:
        return _fail("bench", str(exc))
    if args.update:
        rows = merge_rows(old_rows, rows)
    print(markdown_table(rows))
    try:  # the rows are computed: a failing write puts them elsewhere and says where
        if json_path:
            rescue_write(lambda p: atomic_write_json(p, rows), Path(json_path), "results JSON")
            print(f"\nwrote {json_path}", file=sys.stderr)
        if args.plot:
            rescue_write(lambda p: plot([r for r in rows if r["env"] == envs[0]], p), Path(args.plot), "plot")
            print(f"wrote {args.plot}", file=sys.stderr)
        if args.all:
            for e in sorted({r["env"] for r in rows}):
                path = RESULTS / f"bench_{e}.png"
                rescue_write(lambda p, e=e: plot([r for r in rows if r["env"] == e], p), path, "plot")
                print(f"wrote {path}", file=sys.stderr)
            rescue_write(lambda p: atomic_write_json(p, [public_row(r) for r in rows]), RESULTS / "bench_table.json", "table JSON")
    except OutputError as exc:
        return _fail("bench", str(exc))
    return 0


def merge_rows(old: list[dict], new: list[dict]) -> list[dict]:
    """``old`` rows with ``new`` merged in (same env and policy: replaced), in the order
    environment, then policy as in POLICY_NAMES."""
    import gym_gridloc
    from gym_gridloc_agents.policies import POLICY_NAMES

    keyed = {(r["env"], r["policy"]): r for r in old}
    keyed.update({(r["env"], r["policy"]): r for r in new})
    envs = list(gym_gridloc.ENV_IDS)

    def order(key):
        env, pol = key
        return (envs.index(env) if env in envs else len(envs), env,
                POLICY_NAMES.index(pol) if pol in POLICY_NAMES else len(POLICY_NAMES))

    return [keyed[k] for k in sorted(keyed, key=order)]


#: What ``gridloc`` needs beyond the core install (the ``rl`` extra), by import name.
RL_MODULES = ("tqdm", "yaml", "matplotlib", "torch", "stable_baselines3", "sb3_contrib")
#: The modules each subcommand needs beyond the core install.
NEEDS = {"train": RL_MODULES, "bench": RL_MODULES, "render": ("matplotlib",), "plot": ("matplotlib",), "reproduce": ()}
NEEDS["sweep"] = (*RL_MODULES, "ray", "optuna")
COMMANDS = {"train": "_train", "bench": "_bench", "render": "_render", "plot": "_plot"}
COMMANDS["sweep"] = "_sweep"


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
    args = _parser().parse_args(argv)
    missing = missing_modules(args.command)
    if missing and args.command == "sweep":
        print(
            f"gridloc sweep needs the 'rl' and 'sweep' extras (missing: {', '.join(missing)}). Install them with\n"
            "  pip install torch==2.13.0 && pip install 'gym_gridloc[rl,sweep]'",
            file=sys.stderr,
        )
        return 2
    if missing:
        print(
            f"gridloc {args.command} needs the 'rl' extra (missing: {', '.join(missing)}). Install it with\n"
            "  pip install torch==2.13.0 && pip install 'gym_gridloc[rl]'\n"
            "(torch first and pinned: an unpinned torch resolves to a multi-GB CUDA build).",
            file=sys.stderr,
        )
        return 2
    return globals()[COMMANDS[args.command]](args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
