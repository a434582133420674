"""``gridloc bench`` and ``gridloc bound``: their arguments checked before any long run, the run,
and the outputs (a failing write puts computed rows elsewhere and says where).  The parser is
:mod:`gym_gridloc_agents.cli`'s; the benchmark itself is :mod:`gym_gridloc_agents.evaluation.bench`."""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path

RESULTS = Path("results")
#: The most episodes per policy ``gridloc bench`` runs (its per-episode arrays must fit in memory).
MAX_EPISODES = 10**7
#: Environment keywords the held-out test maps replace (``--test-set`` refuses them: the row would
#: report keywords its maps ignored).
MAP_KWARGS = ("layout", "map_seed", "obstacle_density", "new_map_each_reset", "n_colours")


def fail(command: str, message: str) -> int:
    """Print ``gridloc COMMAND: error: MESSAGE`` to stderr; the exit status of a usage error (2).
    Every ``gridloc`` subcommand reports its errors through it."""
    print(f"gridloc {command}: error: {message}", file=sys.stderr)
    return 2


def _key_values(items: list[str], what: str) -> dict:
    """``KEY=VALUE`` strings as a dict (:func:`gym_gridloc_agents.values.key_values`)."""
    from gym_gridloc_agents.values import key_values

    return key_values(items, what)


def _bench_env_kwargs(args) -> dict:
    from gym_gridloc.core.validation import check_int

    kwargs = _key_values(args.env_kwarg, "--env-kwarg")
    for key, value in (("size", args.size), ("episode_length", args.episode_length)):
        if value is not None:
            kwargs[key] = check_int(f"--{key.replace('_', '-')}", value)
    return kwargs


def _policy_options(items: list[str], policies: list[str]) -> dict[str, dict]:
    from gym_gridloc.core.validation import unknown_names
    from gym_gridloc_agents.registry import policy_spec

    options: dict[str, dict] = {}
    for key, value in _key_values(items, "--option").items():
        policy, dot, name = key.partition(".")
        if not dot or not name:
            raise ValueError(f"--option {key}: expected POLICY.KEY=VALUE, e.g. expectimax.depth=3")
        if policy not in policies:
            raise ValueError(f"--option {key}: {unknown_names([policy], policies)} is not among the benchmarked policies "
                             f"({', '.join(policies)})")
        try:
            policy_spec(policy).check_options({name: value})  # the table's options: refused here, before any run
        except ValueError as exc:
            raise ValueError(f"--option {key}: {exc}") from None
        options.setdefault(policy, {})[name] = value
    return options


def _available_defaults(envs: list[str], policies: list[str], env_kwargs: dict, args) -> list[str]:
    """The default policies without the learned ones (``ppo``, ``distilled``, ``recurrent``) that
    have no model for these environments and keywords and no ``--<name>-model``; says which rows
    it leaves out on stderr."""
    from gym_gridloc_agents.policies import LEARNED_NAMES, default_model_path

    def shipped(env_id: str, method: str) -> bool:
        try:
            return default_model_path(env_id, method, env_kwargs).is_file()
        except FileNotFoundError:
            return False

    given = {name: getattr(args, f"{name}_model") for name in LEARNED_NAMES}  # (--<name>-model)
    keep = []
    for name in policies:
        missing = [] if name not in given or given[name] else [e for e in envs if not shipped(e, name)]
        if missing:
            print(f"gridloc bench: no shipped {name} model for {', '.join(missing)}"
                  f"{' with ' + str(env_kwargs) if env_kwargs else ''}: its row is left out "
                  f"(train one and pass --{name}-model PATH)", file=sys.stderr)
        else:
            keep.append(name)
    return keep


def bench_main(args) -> int:
    """``gridloc bench``: every argument checked before the first episode, then the run and its outputs."""
    from gym_gridloc.core.validation import check_int, is_int
    from gym_gridloc_agents.evaluation.bench import BENCH_ENV_IDS, DEFAULT_POLICIES, BenchmarkInterrupted, add_gaps, run_benchmark
    from gym_gridloc_agents.evaluation.bench_cluster import ClusterError  # (Ray itself only once a run on a cluster starts)
    from gym_gridloc_agents.envs import check_environment
    from gym_gridloc_agents import files
    from gym_gridloc_agents.files import OutputError
    from gym_gridloc_agents.loading import expand_models
    from gym_gridloc_agents.policies import LEARNED_NAMES, POLICY_NAMES
    from gym_gridloc_agents.evaluation.report import merge_rows, read_rows

    if args.all == bool(args.env):
        return fail("bench", "give exactly one of --env ENV_ID or --all")
    envs = list(BENCH_ENV_IDS) if args.all else [args.env]
    policies = [p.strip() for p in (args.policies or ",".join(DEFAULT_POLICIES)).split(",") if p.strip()]
    episodes = args.episodes if args.episodes is not None else (1000 if args.all else 200)
    json_path = args.json or (str(RESULTS / "bench.json") if args.all else None)
    # --all: the figures and the table go beside its JSON (results/ by default), as `gridloc plot` draws them
    here = Path(json_path).parent if json_path else RESULTS
    stem = Path(json_path).stem if json_path else "bench"
    frontier = args.frontier or (str(here / f"{stem}_frontier.png") if args.all else None)
    table = here / f"{stem}_table.json" if args.all else None
    # Everything is checked before the first episode: a long run never ends in a traceback.
    try:
        env_kwargs = _bench_env_kwargs(args)
        if args.all and env_kwargs:
            raise ValueError("--all runs the default environments; give --env ENV_ID with --size, --episode-length or --env-kwarg")
        for e in envs:
            check_environment(e, env_kwargs, what=f"--env {e}", error=ValueError)
        if not policies:
            raise ValueError(f"--policies names no policy (got {args.policies!r}); allowed: {', '.join(POLICY_NAMES)}")
        if args.policies is None:  # the defaults: learned rows only where a model exists for them
            policies = _available_defaults(envs, policies, env_kwargs, args)
        options = _policy_options(args.option, policies)
        if args.test_set and "size" not in env_kwargs:
            raise ValueError("--test-set needs --size N: the held-out maps are drawn per size")
        check_int("--episodes", episodes)
        if episodes > MAX_EPISODES:  # the per-episode arrays must fit in memory
            raise ValueError(f"--episodes must be at most {MAX_EPISODES:_} (per policy), got {episodes}")
        if args.test_set and (given := [k for k in env_kwargs if k in MAP_KWARGS]):
            raise ValueError(f"--test-set runs on the stored test maps, which replace {', '.join(given)}: leave "
                             f"{'it' if len(given) == 1 else 'them'} out (the row would report keywords its maps ignored)")
        if args.test_set and not is_int(env_kwargs["size"]):
            raise ValueError(f"--test-set: the test maps are square; give --size N, not size={env_kwargs['size']!r}")
        if args.test_set and envs == ["DepthMaze-v0"]:  # the rows name the maze variant their test set is drawn as
            from gym_gridloc.envs.depth_maze import map_options

            env_kwargs = {**env_kwargs, **map_options(env_kwargs)}
        for name in LEARNED_NAMES:
            flag = f"--{name}-model"
            if getattr(args, f"{name}_model") and name not in policies:
                raise ValueError(f"{flag} is given but {name!r} is not among the benchmarked policies "
                                 f"({', '.join(policies)}): add it to --policies or leave {flag} out")
        if args.seed < 0 or args.seed + episodes > 2**32:
            raise ValueError(f"--seed must be in 0..{2**32 - episodes} (episode i uses seed+i), got {args.seed}")
        for flag, value in (("--jobs", args.jobs), ("--torch-threads", args.torch_threads)):
            check_int(flag, value)
        address = getattr(args, "address", None)
        if address is not None:
            from gym_gridloc_agents.cluster import check_address

            check_address(address)  # (host, port 1..65535, no spaces: before Ray is called)
            if args.jobs > 1:
                raise ValueError("--jobs sets the processes of a run on this machine; with --address the cluster's CPUs run the chunks")
            import importlib.util

            if importlib.util.find_spec("ray") is None:
                raise ValueError("--address runs on Ray: install the 'sweep' extra (pip install 'gym_gridloc[rl,sweep]')")
        if args.plot and len(envs) > 1:
            raise ValueError("--plot takes one environment; --all writes results/bench_<env>.png")
        if args.update and not json_path:
            raise ValueError("--update needs --json PATH (or --all)")
        seeds_models = {}
        for name in LEARNED_NAMES:
            given = getattr(args, f"{name}_model")
            found = expand_models(given, flag=f"--{name}-model") if given else None
            if found is not None and len(found) > 1 and len(envs) > 1:
                raise ValueError(f"several --{name}-model files (one per seed) are models of one environment: give --env ENV_ID, not --all")
            seeds_models[name] = found
        outputs = [(json_path, files.BENCH_RESULTS, "results JSON"), (args.markdown, files.MARKDOWN, "markdown table"),
                   (args.plot, files.FIGURE, "plot"), (frontier, files.FIGURE, "frontier plot"), (table, files.TABLE, "table JSON")]
        outputs += [(here / f"bench_{e}.png", files.FIGURE, f"plot of {e}") for e in envs if args.all]
        inputs = [m for found in seeds_models.values() for m in found or []]
        files.check_outputs(outputs, inputs=inputs, replace=args.update or args.force, flag="--update or --force")
        old_rows = read_rows(json_path) if args.update and Path(json_path).exists() else []
        for name, found in seeds_models.items():
            if found is not None and len(found) == 1:
                seeds_models[name] = found[0]
    except (ValueError, OutputError) as exc:
        return fail("bench", str(exc))
    interrupted = None
    try:
        with warnings.catch_warnings(record=True) as notes:
            warnings.simplefilter("always", UserWarning)
            rows = run_benchmark(
                envs, policies, episodes, seed_start=args.seed, env_kwargs=env_kwargs, test_set=args.test_set,
                ppo_model=seeds_models["ppo"], distilled_model=seeds_models["distilled"],
                recurrent_model=seeds_models["recurrent"], policy_options=options,
                progress=not args.no_progress, jobs=args.jobs, torch_threads=args.torch_threads, address=address,
            )
    except BenchmarkInterrupted as exc:  # Ctrl-C: the finished rows are written, then exit 130
        rows, interrupted = exc.rows, exc
    except (ValueError, TypeError, FileNotFoundError, ClusterError) as exc:  # ClusterError: --address could not run
        return fail("bench", " ".join(str(exc).split()))
    # Ctrl-C: exit status 130; a cluster that stopped answering: 1 (the finished rows are written either way)
    stopped, said = (130, "gridloc bench:") if interrupted is None or interrupted.lost is None else (1, "gridloc bench: error:")
    for note in notes:  # e.g. a policy that does not apply to an environment: one line each
        print(f"gridloc bench: {note.message}", file=sys.stderr)
    if interrupted is not None and not rows:
        print(f"{said} {interrupted}; no row was finished, nothing written", file=sys.stderr)
        return stopped
    from gym_gridloc_agents.evaluation.report import env_label

    labels = {env_label(r) for r in rows}  # what this run measured (merged rows of other keywords are not plotted with it)
    lock = files.locked(json_path, what="results JSON") if json_path else contextlib.nullcontext()
    with lock:  # two --update runs at once: each merges into what the other wrote
        if args.update:  # re-read under the lock; the gaps are recomputed over the merged rows
            try:
                old_rows = read_rows(json_path) if Path(json_path).exists() else []
            except ValueError as exc:  # the computed rows are never discarded: written beside it
                try:
                    files.rescue_write(lambda p: files.atomic_write_json(p, rows, files.BENCH_RESULTS), Path(json_path),
                                       "results JSON", places=(Path(json_path).parent,), problem=f"{exc} (it changed during the run)")
                except OutputError as rescued:
                    return fail("bench", " ".join(str(rescued).split()))
            rows = add_gaps(merge_rows(old_rows, rows))
        code = _write_bench(args, rows, labels, json_path, frontier, table, here)
    if interrupted is not None and code == 0:
        print(f"{said} {interrupted}; the {len(rows)} finished row(s) are kept"
              + (f" in {json_path} (run the others with --update)" if json_path else " (printed above)"), file=sys.stderr)
        return stopped
    return code


def _write_bench(args, rows, labels, json_path, frontier, table, here) -> int:
    from gym_gridloc_agents.files import BENCH_RESULTS, MARKDOWN, TABLE, OutputError, atomic_write_json, atomic_write_text, rescue_write
    from gym_gridloc_agents.evaluation.report import env_label, markdown_table, plot, plot_frontier, public_row, terminal_table

    mine = [r for r in rows if env_label(r) in labels]

    print(terminal_table(rows))  # fits 100 columns; the full table: --markdown, every number: --json
    if getattr(args, "compare", False):  # every pair of rows of a task, on their common episodes
        from gym_gridloc_agents.evaluation.paired import attach_pairs, pairs_table

        found = attach_pairs(rows)
        print("\n" + pairs_table(found) if found else "(no pairs: no two rows of one task keep their episodes' results)")
    if not (args.markdown or json_path):
        print("(a short table; every column: --markdown PATH, every number: --json PATH)", file=sys.stderr)
    # (path or None, write, what, text before "wrote"); --all: a plot per environment
    writes = [(json_path, lambda p: atomic_write_json(p, rows, BENCH_RESULTS), "results JSON", "\n"),
              (args.markdown, lambda p: atomic_write_text(p, markdown_table(rows) + "\n", MARKDOWN), "markdown table", ""),
              (args.plot if mine else None, lambda p: plot(mine, p), "plot", ""),
              (frontier, lambda p: plot_frontier(rows, p), "frontier plot", "")]
    writes += [(here / f"bench_{e}.png", lambda p, e=e: plot([r for r in mine if r["env"] == e], p), "plot", "")
               for e in sorted({r["env"] for r in mine}) if args.all]
    try:  # the rows are computed: a failing write puts them elsewhere and says where
        for path, write, what, before in writes:
            if path:
                rescue_write(write, Path(path), what, places=(Path(path).parent,))
                print(f"{before}wrote {path}", file=sys.stderr)
        if args.all:
            rescue_write(lambda p: atomic_write_json(p, [public_row(r) for r in rows], TABLE), table, "table JSON")
    except OutputError as exc:
        return fail("bench", str(exc))
    return 0


def bound_main(args) -> int:
    """``gridloc bound``: the depth-K lower bound of one environment."""
    from gym_gridloc_agents.envs import check_environment, make_env
    from gym_gridloc_agents import files
    from gym_gridloc_agents.files import BOUND, OutputError, atomic_write_json, rescue_write
    from gym_gridloc_agents.planners import lower_bound
    from gym_gridloc_agents.planners.expectimax import MAX_BOUND_DEPTH

    try:
        kwargs = _key_values(args.env_kwarg, "--env-kwarg")
        check_environment(args.env, kwargs, what=f"--env {args.env}", error=ValueError)
        if not 1 <= args.depth <= MAX_BOUND_DEPTH:
            raise ValueError(f"--depth must be in 1..{MAX_BOUND_DEPTH} (the search grows about |A x Z|^K), got {args.depth}")
        if not 0.0 <= args.prune < 1.0:
            raise ValueError(f"--prune must be in [0, 1), got {args.prune}")
        files.check_outputs([(args.json, files.BOUND, "bound JSON")], replace=args.force)
    except (ValueError, OutputError) as exc:
        return fail("bound", str(exc))
    env = make_env(args.env, kwargs)
    u = env.unwrapped
    if getattr(u, "episode_length", None):
        env.close()
        return fail("bound", "the bound is on steps to localise; fixed-length episodes (episode_length) have no such count")
    if getattr(u, "map_factory", None) is not None:  # the first map's bound is no bound of the environment
        env.close()
        return fail("bound", f"{args.env} draws a new map at every reset (new_map_each_reset): the bound is of one map; "
                              "give a fixed map (--env-kwarg map_seed=N or layout=PATH)")
    print(f"gridloc bound: {args.env}, depth {args.depth}: exhaustive search over actions and readings ...", file=sys.stderr)
    result = lower_bound(u.model, args.depth, threshold=u.localise_threshold, pose=u.referee_pose, prune=args.prune,
                         progress=True)
    env.close()
    result = {"env": args.env, "env_kwargs": kwargs, **result}
    print(f"no policy localises {args.env}{' (its pose: the referee tests poses)' if result['pose'] else ''} in fewer "
          f"than {result['bound']:.4f} mean steps "
          f"(depth {args.depth}, {result['seconds']:.0f} s)")
    if args.json:  # every number, the value after each first reading too, only when asked for
        try:
            rescue_write(lambda p: atomic_write_json(p, result, BOUND), Path(args.json), "bound JSON")
        except OutputError as exc:
            return fail("bound", str(exc))
        print(f"wrote {args.json}", file=sys.stderr)
    return 0
