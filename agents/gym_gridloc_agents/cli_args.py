"""The ``gridloc`` command line's arguments: every subcommand's parser (:func:`build_parser`);
:mod:`gym_gridloc_agents.cli` parses with it and dispatches."""

from __future__ import annotations

import argparse

from gym_gridloc_agents.evaluation.bench_command import RESULTS
from gym_gridloc_agents.registry import DEFAULT_POLICIES, names_by_kind, options_text


class _BenchHelp(argparse.HelpFormatter):
    """``gridloc bench --help``: ``{fixed}`` names the environments of ``--all``, read from the
    benchmark's module only when the help is shown (it imports torch)."""

    def _get_help_string(self, action):
        text = super()._get_help_string(action) or ""
        if "{fixed}" in text:
            from gym_gridloc_agents.evaluation.bench import BENCH_ENV_IDS

            text = text.replace("{fixed}", f"{len(BENCH_ENV_IDS)} fixed-map environments, {', '.join(BENCH_ENV_IDS)}")
        return text


def _parser(sub, name: str, text: str, description: str | None = None, **kw) -> argparse.ArgumentParser:
    """A subcommand: ``text`` in ``gridloc --help``, ``description`` (default ``text``) in its own ``--help``."""
    return sub.add_parser(name, help=text, description=description or text[:1].upper() + text[1:] + ".", **kw)


def build_parser() -> argparse.ArgumentParser:
    """The ``gridloc`` command line: its sub-commands and their arguments."""
    import gym_gridloc

    p = argparse.ArgumentParser(prog="gridloc", description="gym_gridloc agents: training and the localisation benchmark")
    p.add_argument("--version", action="version", version=f"gridloc (gym_gridloc {gym_gridloc.__version__})")
    sub = p.add_subparsers(dest="command", required=True)

    t = _parser(sub, "train", "train a policy from a YAML config (see configs/)")
    t.add_argument("config", help="a YAML config, e.g. configs/ppo_windymaze.yml")
    t.add_argument("--force", action="store_true",
                   help="replace an existing model and its metadata (never a file of another kind, an input or a checkpoint)")
    t.add_argument("--resume", metavar="CKPT", help="continue from a checkpoint .zip up to total_timesteps")
    t.add_argument("--output", metavar="PATH", help="model file to write (.zip; overrides the config)")
    t.add_argument("--timesteps", type=int, metavar="N",
                   help="total timesteps of the reinforcement learning (overrides the config; not the warm start: see --pretrain-episodes)")
    t.add_argument("--pretrain-episodes", type=int, metavar="N",
                   help="the warm start's expert episodes (overrides pretrain.episodes; each DAgger round's episodes are scaled "
                        "by the same factor, at least 1): a quick run of a distilled config, e.g. --timesteps 2048 --pretrain-episodes 50")
    t.add_argument("--tensorboard", metavar="DIR", help="log to TensorBoard in DIR")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.add_argument("--torch-threads", type=int, default=1, metavar="N", help="torch threads (default 1: fastest for small MLPs)")

    b = _parser(sub, "bench", "benchmark policies on the same episode seeds", formatter_class=_BenchHelp)
    b.add_argument("--env", metavar="ENV_ID", help=f"environment id, one of {', '.join(gym_gridloc.ENV_IDS)}")
    b.add_argument("--all", action="store_true",
                   help="the {fixed} (the others draw a new map every episode: --env ENV_ID with --size N --test-set), "
                        "the default policies, 1000 episodes; writes results/bench.json and results/bench_<env>.png")
    b.add_argument("--policies", default=None,
                   help=f"comma-separated policy names, of the {names_by_kind()} (default: {','.join(DEFAULT_POLICIES)})")
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
    b.add_argument("--recurrent-model", metavar="PATH", nargs="+",
                   help="benchmark this RecurrentPPO model (policy recurrent) instead of the shipped one; several files, a "
                        "directory or a glob as --ppo-model")
    b.add_argument("--size", type=int, metavar="N", help="map size (the size keyword of the environment, e.g. 7 for DepthMaze 7x7; WindyMaze and "
                   "ColourGrid then run on one map of that size: add --env-kwarg new_map_each_reset=true for a new map "
                   "every episode, or --test-set; every row says how many maps it ran on)")
    b.add_argument("--test-set", action="store_true",
                   help="run on the held-out test maps of gym_gridloc.maps.test_set (episode i: map i and its start pose; needs --size)")
    b.add_argument("--episode-length", type=int, metavar="L",
                   help="fixed-length episodes of L steps (the research protocol): the table adds accuracy at L")
    b.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="another keyword of gym.make (a YAML scalar, e.g. n_colours=4); repeat for several")
    b.add_argument("--option", action="append", default=[], metavar="POLICY.KEY=VALUE",
                   help=f"an option of one policy (a YAML scalar), e.g. expectimax.depth=3 or mcts.simulations=2000; the "
                        f"options: {options_text()} (the others take none)")
    b.add_argument("--frontier", metavar="PATH.png", help="write the speed-quality plot: mean steps against ms per decision")
    b.add_argument("--jobs", type=int, default=1, help="parallel processes, each running chunks of episodes (default 1)")
    b.add_argument("--address", metavar="ADDRESS",
                   help="run the chunks of episodes as Ray tasks on this running Ray cluster (HOST:PORT, or auto; the 'sweep' "
                        "extra): the same rows as a local run, each saying where its chunks ran (docs/cluster.md)")
    b.add_argument("--compare", action="store_true",
                   help="also compare every two policies of a task on their common episodes: the mean difference with a "
                        "paired bootstrap 95%% interval, the probability of improvement and a verdict (better, tie, worse: "
                        "whether the interval excludes 0); kept in the JSON rows as 'pairs'")
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

    d = _parser(sub, "render", "draw one episode per environment as belief heatmaps (and a GIF)",
                "One episode of random (seeded) actions per environment, drawn from its rgb_array frames: a row of "
                "frames per environment in one PNG, each frame pixel for pixel. docs/environments.md ('Reading a "
                "frame') says what a frame shows.")
    d.add_argument("--env", nargs="+", default=None, metavar="ENV_ID",
                   help=f"environment ids (default: all {len(gym_gridloc.ENV_IDS)}, {' '.join(gym_gridloc.ENV_IDS)})")
    d.add_argument("--seed", type=int, default=3, help="episode seed; the random actions are seeded with it too (default 3)")
    d.add_argument("--frames", type=int, default=6, help="frames per environment: the first, the last and evenly spaced ones (default 6)")
    d.add_argument("--shading", choices=("relative", "absolute"), default="relative",
                   help="how the belief is shaded (the environments' render_shading; default relative)")
    d.add_argument("--out", default=str(RESULTS / "episode.png"), help="PNG to write (default results/episode.png)")
    d.add_argument("--gif", default=None, metavar="PATH.gif",
                   help="also write the first environment's whole episode as a GIF (default: none)")

    w = _parser(sub, "sweep", "train seeds and hyperparameter grids of a config on Ray Tune (the 'sweep' extra)")
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
    w.add_argument("--verbose", action="store_true",
                   help="show Ray Tune's trial status tables while it runs (default: only the final table)")

    lb = _parser(sub, "bound", "a lower bound on any policy's mean steps to localise (exhaustive search to depth K)")
    lb.add_argument("env", metavar="ENV_ID", help="environment id, e.g. ColourGrid-v0")
    lb.add_argument("--depth", type=int, default=3, metavar="K", help="search depth (default 3; the cost grows about |A x Z|^K)")
    lb.add_argument("--prune", type=float, default=0.0, metavar="P",
                    help="drop readings below this probability (keeps it a bound, a looser one; default 0)")
    lb.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE", help="a keyword of gym.make (repeatable)")
    lb.add_argument("--json", metavar="PATH", help="also write every number as JSON (the value after each first reading too)")
    lb.add_argument("--force", action="store_true", help="replace an existing bound JSON")

    q = _parser(sub, "plot", "redraw the benchmark figures from a results JSON, or plot training and learning curves",
                "Draw the figures of a bench JSON beside it, or the training curves of models (--training), or learning "
                "curves across seeds (--curves). Name what to draw: without arguments nothing is drawn.")
    q.add_argument("json", nargs="?", default=None,
                   help="a bench JSON, e.g. results/bench.json: its figures are written beside it (bench_<env>.png, "
                        "<name>_frontier.png), replacing those there")
    q.add_argument("--training", nargs="+", metavar="MODEL.zip",
                   help="instead: plot these models' training curves (their held-out evaluations) to --out, one panel per environment")
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

    st = sub.add_parser("suite", help="run every task of the benchmark (fixed maps, random maps, DepthMaze test sets) "
                                      "into one results JSON, resumable")
    st.add_argument("--policies", default=None,
                    help="comma-separated policy names (default per task: random, greedy2, the task's optimum or best "
                         "planner, distilled, ppo)")
    st.add_argument("--tasks", default=None, help="comma-separated suite tasks (default: all; the names are in docs/results.md)")
    st.add_argument("--episodes", type=int, default=1000, help="episodes per task and policy (default 1000)")
    st.add_argument("--seed", type=int, default=0, help="seed of episode 0 (episode i uses seed+i)")
    st.add_argument("--json", default=str(RESULTS / "suite.json"), metavar="PATH",
                    help="the results JSON, merged into after every task (default results/suite.json)")
    st.add_argument("--models", metavar="DIR",
                    help="a folder of models named as the shipped ones (<env_id>[-size<N>]-<method>.zip), or of directories of "
                         "that stem holding one model per seed; the shipped models otherwise")
    st.add_argument("--jobs", type=int, default=1, help="parallel processes, each running chunks of episodes (default 1)")
    st.add_argument("--address", metavar="ADDRESS", help="run the chunks as Ray tasks on this Ray cluster (HOST:PORT or auto)")
    st.add_argument("--torch-threads", type=int, default=1, metavar="N", help="torch threads of the learned policies (default 1)")
    st.add_argument("--no-progress", action="store_true", help="no progress bars")

    rp = sub.add_parser("report", help="write the result tables of markdown files from the results files (between "
                                       "<!-- gridloc-report:NAME --> markers)")
    rp.add_argument("files", nargs="*", metavar="FILE.md", help="markdown files (default: README.md and docs/results.md)")
    rp.add_argument("--results", default=str(RESULTS), metavar="DIR", help="the results files' directory (default results)")
    rp.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file's tables differ from the results files")
    return p
