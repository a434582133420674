"""``gridloc suite``: every task of the benchmark in one command, into one results JSON that
``gridloc report`` reads.

The tasks (:data:`SUITE`): the fixed maps (WindyMaze-v0, ColourGrid-v0, RingSensor8x8-v0), the
random 9x9 WindyMaze maps on their held-out test set, and DepthMaze 7x7 (L = 15 and 30), 15x15
(L = 20 and 40) and 21x21 (L = 30 and 60) under the research protocol on the held-out test sets of
both maze generators (Kruskal's and Eller's), rotation-symmetric mazes rejected.  Every task runs
the given policies on the same episodes (:func:`gym_gridloc_agents.evaluation.bench.run_benchmark`,
with ``jobs`` processes or on a Ray cluster at ``address``, the chunks of ``--jobs``); a policy that
does not apply to a task (``optimal`` on a noisy model, ``central`` without a "nothing" reading) or
a learned one without a model for it is left out of that task, with a note.

Learned policies use the shipped models, or those of a models folder: for the task's shipped
model name ``<env_id>[-size<N>]-<method>.zip``, the folder's file of that name, or its directory of
that stem holding one model per training seed (the row is then across seeds).

Resumable: the JSON is rewritten after every task (each row tagged ``suite_task``), and a task
whose rows are all there (same policies, episodes and first seed) is not run again.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from gym_gridloc_agents.registry import LEARNED_NAMES

#: The learned policies (a model per task).
LEARNED = LEARNED_NAMES


@dataclass(frozen=True)
class SuiteTask:
    """One task of the suite: its name, environment, keywords and whether it runs on the held-out test set."""

    name: str
    env_id: str
    env_kwargs: dict = field(default_factory=dict)
    test_set: bool = False
    #: The planner the default policies include: the task's optimum or its best planner (the normalised score's 1).
    planner: str = "expectimax"


def _depth_tasks() -> list[SuiteTask]:
    tasks = []
    for size, lengths in ((7, (15, 30)), (15, (20, 40)), (21, (30, 60))):
        for length in lengths:
            for generator in ("kruskal", "eller"):
                kwargs = {"size": size, "episode_length": length, "generator": generator, "reject_symmetric": True}
                tasks.append(SuiteTask(f"depthmaze{size}-L{length}-{generator}", "DepthMaze-v0", kwargs, True, "optimal"))
    return tasks


#: Every task of the suite, in order.
SUITE: tuple[SuiteTask, ...] = (
    SuiteTask("windymaze", "WindyMaze-v0"),
    SuiteTask("colourgrid", "ColourGrid-v0"),
    SuiteTask("ringsensor", "RingSensor8x8-v0", planner="central"),
    SuiteTask("windymaze9-random", "WindyMaze-v0", {"size": 9}, True),
    *_depth_tasks(),
)
TASK_NAMES = tuple(t.name for t in SUITE)
#: The default policies of every task, with the task's own planner after greedy2.
DEFAULT_POLICIES = ("random", "greedy2", "<planner>", "distilled", "ppo")


def default_policies(task: SuiteTask) -> list[str]:
    return [task.planner if p == "<planner>" else p for p in DEFAULT_POLICIES]


def select(names: Sequence[str] | None) -> list[SuiteTask]:
    """The suite's tasks named (all for None); ``ValueError`` naming an unknown one."""
    if not names:
        return list(SUITE)
    unknown = [n for n in names if n not in TASK_NAMES]
    if unknown:
        raise ValueError(f"unknown suite task(s) {', '.join(unknown)}; the tasks: {', '.join(TASK_NAMES)}")
    return [t for t in SUITE if t.name in names]


def task_models(task: SuiteTask, policy: str, models: str | Path | None) -> list[Path] | None:
    """The model files of a learned ``policy`` on ``task`` (from ``models``, else the shipped one);
    None when there is none."""
    from gym_gridloc_agents.loading import expand_models
    from gym_gridloc_agents.policies import default_model_path

    try:
        shipped = default_model_path(task.env_id, policy, task.env_kwargs)
    except FileNotFoundError:
        shipped = None
    if models is not None:
        name = shipped.name if shipped is not None else f"{task.env_id}-size{task.env_kwargs.get('size')}-{policy}.zip"
        folder = Path(models)
        if (folder / name).is_file():
            return [folder / name]
        if (folder / Path(name).stem).is_dir():
            return expand_models([folder / Path(name).stem], flag="--models")
    return [shipped] if shipped is not None and shipped.is_file() else None


def runnable(task: SuiteTask, policy: str) -> str | None:
    """Why ``policy`` cannot run on ``task`` (None if it can)."""
    from gym_gridloc_agents.envs import make_env
    from gym_gridloc_agents.evaluation.bench import applicable, make_task_policy
    from gym_gridloc_agents.evaluation.rows import Task

    if not applicable(policy, task.env_id, task.env_kwargs, {}):
        return "its sensor has no 'nothing' reading"
    env = make_env(task.env_id, task.env_kwargs)
    try:
        make_task_policy(Task(task.env_id, policy, dict(task.env_kwargs)), env)
    except (ValueError, TypeError) as exc:
        return " ".join(str(exc).split())[:200]
    finally:
        env.close()
    return None


def finished(rows: Sequence[dict[str, Any]], task: SuiteTask, policies: Sequence[str], episodes: int, seed_start: int) -> bool:
    """Whether ``rows`` already hold ``task``'s rows of every one of ``policies`` on these episodes."""
    have = {r["policy"] for r in rows if r.get("suite_task") == task.name and r["episodes"] == episodes
            and r.get("seed_start") == seed_start}
    return set(policies) <= have


def run_suite(policies: Sequence[str] | None, episodes: int, out: str | Path, *, tasks: Sequence[str] | None = None,
              seed_start: int = 0, jobs: int = 1, address: str | None = None, models: str | Path | None = None,
              torch_threads: int | None = 1, progress: bool = True) -> list[dict[str, Any]]:
    """Run the suite's ``tasks`` (all by default) with ``policies`` (None: each task's
    :func:`default_policies`), rewriting ``out`` after each
    task; the rows of ``out`` at the end.  A Ctrl-C keeps the tasks finished so far in ``out``
    (``BenchmarkInterrupted``: the interrupted task's finished rows are kept too)."""
    from gym_gridloc_agents.evaluation.bench import BenchmarkInterrupted, run_benchmark
    from gym_gridloc_agents.evaluation.report import merge_rows, read_rows
    from gym_gridloc_agents.evaluation.rows import add_gaps
    from gym_gridloc_agents.files import atomic_write_json, locked

    out = Path(out)
    chosen = select(tasks)
    rows = read_rows(out) if out.is_file() else []

    def save(new: list[dict[str, Any]], task: SuiteTask) -> None:
        nonlocal rows
        for r in new:
            r["suite_task"] = task.name
        with locked(out, what="suite results JSON"):
            current = read_rows(out) if out.is_file() else []
            rows = add_gaps(merge_rows(current, new))
            atomic_write_json(out, rows)

    for task in chosen:
        run, given = [], {}
        for name in (policies or default_policies(task)):
            if name in LEARNED:
                found = task_models(task, name, models)
                if found is None:
                    print(f"gridloc suite: {task.name}: no {name} model, its row is left out", file=sys.stderr)
                    continue
                given[name] = found
            elif (why := runnable(task, name)) is not None:
                print(f"gridloc suite: {task.name}: {name} does not apply ({why}), its row is left out", file=sys.stderr)
                continue
            run.append(name)
        if not run or finished(rows, task, run, episodes, seed_start):
            print(f"gridloc suite: {task.name}: {'done already' if run else 'no policy applies'}", file=sys.stderr)
            continue
        print(f"gridloc suite: {task.name}: {', '.join(run)} x {episodes} episodes", file=sys.stderr)
        try:
            new = run_benchmark([task.env_id], run, episodes, seed_start=seed_start, env_kwargs=dict(task.env_kwargs),
                                test_set=task.test_set, ppo_model=given.get("ppo"), distilled_model=given.get("distilled"),
                                recurrent_model=given.get("recurrent"), progress=progress, jobs=jobs,
                                torch_threads=torch_threads, address=address)
        except BenchmarkInterrupted as exc:
            if exc.rows:
                save(exc.rows, task)
            raise
        save(new, task)
    return rows


def suite_main(args) -> int:
    """``gridloc suite``: arguments checked before the first episode, then :func:`run_suite`."""
    from gym_gridloc.core.validation import check_int
    from gym_gridloc_agents import files
    from gym_gridloc_agents.evaluation.bench import BenchmarkInterrupted
    from gym_gridloc_agents.evaluation.bench_command import fail
    from gym_gridloc_agents.evaluation.bench_cluster import ClusterError
    from gym_gridloc_agents.policies import POLICY_NAMES

    policies = [p.strip() for p in args.policies.split(",") if p.strip()] if args.policies else None
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()] if args.tasks else None
    try:
        for name in policies or []:
            if name not in POLICY_NAMES:
                raise ValueError(f"--policies: unknown policy {name!r}; allowed: {', '.join(POLICY_NAMES)}")
        select(tasks)
        for flag, value in (("--episodes", args.episodes), ("--jobs", args.jobs), ("--torch-threads", args.torch_threads)):
            check_int(flag, value)
        if args.seed < 0 or args.seed + args.episodes > 2**32:
            raise ValueError(f"--seed must be in 0..{2**32 - args.episodes} (episode i uses seed+i), got {args.seed}")
        if args.address is not None and args.jobs > 1:
            raise ValueError("--jobs sets the processes of a run on this machine; with --address the cluster's CPUs run the chunks")
        if args.models is not None and not Path(args.models).is_dir():
            raise ValueError(f"--models {args.models}: no such directory")
        # the JSON is merged into, never lost: only a file of another kind is refused
        files.check_outputs([(args.json, files.BENCH_RESULTS, "suite results JSON")], replace=True)
    except (ValueError, files.OutputError) as exc:
        return fail("suite", str(exc))
    try:
        rows = run_suite(policies, args.episodes, args.json, tasks=tasks, seed_start=args.seed, jobs=args.jobs,
                         address=args.address, models=args.models, torch_threads=args.torch_threads,
                         progress=not args.no_progress)
    except BenchmarkInterrupted as exc:
        print(f"gridloc suite: {exc}; the finished tasks are kept in {args.json}: run the same command again to go on",
              file=sys.stderr)
        return 130
    except (ValueError, TypeError, FileNotFoundError, ClusterError, files.OutputError) as exc:
        return fail("suite", " ".join(str(exc).split()))
    from gym_gridloc_agents.evaluation.report import terminal_table

    print(terminal_table(rows))
    print(f"wrote {args.json} ({len(rows)} rows); gridloc report reads it (tables named KIND:{Path(args.json).stem})",
          file=sys.stderr)
    return 0


__all__ = ["DEFAULT_POLICIES", "SUITE", "TASK_NAMES", "SuiteTask", "finished", "default_policies", "run_suite", "runnable", "select",
           "suite_main", "task_models"]
