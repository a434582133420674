"""The localisation-speed benchmark: every policy on the same episodes, one row per (environment,
policy).

Every policy runs behind :class:`gym_gridloc.HMMBeliefWrapper` on the same episodes: episode ``i``
resets the environment with ``seed_start + i`` and the policy with the same seed (common random
numbers); with ``test_set=True`` it also takes map ``i`` of :func:`gym_gridloc.maps.test_set` and
its start state.  A row holds:

- ``mean_steps``, ``median_steps``, ``mean_steps_ci95`` (mean +- 1.96 sd / sqrt(n)): steps to
  localise, counted from reset, a truncated episode counted at the step limit; with fixed-length
  episodes (``episode_length`` L, the research protocol) the first step at which the referee
  declared the pose localised, L if never;
- ``success_rate`` (ended by localising on the truth), ``truncated_rate``, ``localised_rate``,
  ``localised_correct_rate``, with Wilson 95% intervals for the rates;
- ``accuracy_at``: for budgets k (5, 10, 25, 50), the fraction of episodes whose most probable
  position (pose, where the referee tests poses) is right after k steps (an episode that ended
  earlier keeps its estimate);
- with ``episode_length`` L: ``accuracy_at_L`` (the belief at step L has collapsed onto the true
  pose: largest probability >= the threshold, on the truth) and ``argmax_accuracy_at_L`` (the most
  probable pose is the truth), with Wilson intervals;
- ``ms_per_decision``: the mean time a policy took to choose an action; ``gap_to_best_planner``:
  ``mean_steps`` over the best planner's (``central``, ``expectimax``, ``mcts``, ``pomcp``,
  ``optimal``) on the same environment;
- ``seconds``: wall time of the row; the curves of the fraction localised and of the accuracy.

Several PPO models (one per training seed, e.g. a sweep's ``models/<configuration>/``) give one
``ppo`` row across seeds: every model plays the same episodes; ``mean_steps`` is the mean of the
per-seed mean steps, ``mean_steps_iqm`` their interquartile mean (the mean below 4 seeds) and
``mean_steps_ci95`` a 95% interval resampling the seeds, then the common episodes
(:func:`gym_gridloc_agents.evaluation.stats.hierarchical_ci`; so are ``success_rate_ci95``,
``accuracy_at_ci95`` and ``accuracy_at_L_ci95``), ``mean_steps_seed_range`` the seeds' lowest and
highest; rates, curves and ``median_steps`` pool the episodes of all seeds; ``per_seed`` holds each
model's own numbers.  Every row also keeps its episodes' results (``per_episode``, for paired
comparisons) and its ``normalised_score`` (:mod:`gym_gridloc_agents.evaluation.scores`).  Tables and
figures: :mod:`gym_gridloc_agents.evaluation.report`.
"""

from __future__ import annotations

import hashlib
import math
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc.core.validation import check_int, is_int, unknown_names
from gym_gridloc_agents.envs import make_env, served_env
from gym_gridloc_agents.files import metadata_path, read_metadata
from gym_gridloc_agents.loading import model_method
from gym_gridloc_agents.policies import (DEFAULT_POLICIES, LEARNED_NAMES, PLANNER_POLICIES, POLICIES, POLICY_DIR,
                                         POLICY_NAMES, default_model_path, make_policy)
from gym_gridloc_agents.evaluation.rollout import rollout
from gym_gridloc_agents.evaluation.rows import BUDGETS, Task, add_gaps, seed_aggregate, summarise

#: Decisions of the untimed warm-up episode that precedes every timed run (:func:`simulate`).
WARMUP_DECISIONS = 10
#: The environments of ``gridloc bench --all`` (fixed maps, shipped policies).
BENCH_ENV_IDS = ("ColourGrid-v0", "RingSensor8x8-v0", "WindyMaze-v0")
#: Policies that plan on the exact belief (the "best planner" of ``gap_to_best_planner``), and
#: those that load a model file: :data:`gym_gridloc_agents.policies.POLICIES`' lists.
PLANNERS = PLANNER_POLICIES
LEARNED = LEARNED_NAMES


class BenchmarkInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_benchmark`, or (``lost``: what happened) the cluster of a run with
    ``address`` stopped answering: ``rows`` holds the rows that were finished."""

    def __init__(self, rows: list[dict[str, Any]], total: int, lost: str | None = None) -> None:
        super().__init__(f"{lost + ': ' if lost else ''}interrupted after {len(rows)} of {total} rows")
        self.rows, self.lost = rows, lost

    def __str__(self) -> str:
        return self.args[0]


def episode_specs(env_id: str, env_kwargs: dict, episodes: int, seed_start: int, test_set: bool) -> list[tuple[int, Any]]:
    """``(seed, reset options)`` of the benchmark's episodes: seeds ``seed_start + i``; with
    ``test_set``, the held-out map ``i`` and its start state as reset options (DepthMaze's: the
    set of the maze variant ``env_kwargs`` choose, :func:`gym_gridloc.envs.depth_maze.map_options`)."""
    if not test_set:
        return [(seed_start + i, None) for i in range(episodes)]
    from gym_gridloc import maps

    size = env_kwargs.get("size")
    if size is None:
        raise ValueError(f"--test-set needs --size: the held-out maps of {env_id} are drawn per size")
    side = size if is_int(size) else size[0]
    variant = {}
    if env_id == "DepthMaze-v0":
        from gym_gridloc.envs.depth_maze import map_options

        variant = map_options(env_kwargs)
    return [(seed_start + m.index, {"map": m.grid, "state": m.state}) for m in maps.test_set(env_id, side, episodes, **variant)]


class _Timed:
    """A policy whose decisions are timed (the rest of its interface passes through)."""

    def __init__(self, policy) -> None:
        self.policy, self.seconds, self.decisions = policy, 0.0, 0

    def reset(self, seed=None, model=None) -> None:
        self.policy.reset(seed=seed, model=model)

    @property
    def observation_options(self):
        return getattr(self.policy, "observation_options", None)

    def act(self, observation, belief, **encoded) -> int:
        t = time.perf_counter()
        action = self.policy.act(observation, belief, **encoded)
        self.seconds += time.perf_counter() - t
        self.decisions += 1
        return action


def make_task_policy(task: Task, env):
    """The task's policy for ``env`` (the policies with a ``threshold`` option take the referee's,
    ``optimal`` the episode length)."""
    options = dict(task.options)
    if "threshold" in POLICIES[task.policy].options:
        options.setdefault("threshold", env.unwrapped.localise_threshold)
    return make_policy(task.policy, env.unwrapped.model, env_id=task.env_id, env_kwargs=dict(task.env_kwargs),
                       path=task.model_path, pose=env.unwrapped.referee_pose, **options)


def _learned_name(name: str, path: str | Path | None) -> str:
    """The row name of policy ``name`` with model file ``path``: a ``ppo`` model that was
    distilled from a planner is named ``distilled`` (with a ``FutureWarning``)."""
    if name != "ppo" or path is None or not metadata_path(Path(path)).is_file():
        return name
    try:
        method = model_method(read_metadata(Path(path)))
    except ValueError:
        return name
    if method == "distilled":
        warnings.warn(f"{path} was distilled from a planner: its row is named 'distilled' (pass it as "
                      "--distilled-model; 'ppo' now means PPO from the reward alone)", FutureWarning, stacklevel=3)
        return "distilled"
    return name


def simulate(task: Task, specs: Sequence[tuple[int, Any]], *, budgets: Sequence[int] = BUDGETS,
             progress: bool = True, warmup: bool = True) -> dict[str, Any]:
    """Run one task on the given episodes; returns per-episode arrays.  ``warmup``: first an
    untimed episode of the first spec (at most :data:`WARMUP_DECISIONS` decisions) with the same
    policy and environment, so that compilation and first-call costs stay out of the timed
    decisions and ``seconds``; every episode resets the environment and the policy with its own
    seed, so nothing else changes."""
    from tqdm.auto import tqdm

    env = make_env(task.env_id, task.env_kwargs)
    max_steps = env.spec.max_episode_steps if env.spec is not None else None
    if not max_steps:
        raise ValueError(f"{task.env_id} has no max_episode_steps; the benchmark needs a step limit")
    length = env.unwrapped.episode_length
    limit = min(max_steps, length) if length else max_steps
    policy = _Timed(make_task_policy(task, env))
    env = served_env(env, policy)  # a learned policy's own observation, built by the wrapper
    n = len(specs)
    steps = np.zeros(n, dtype=np.int64)
    localised, success, truncated, collapsed_end = (np.zeros(n, dtype=bool) for _ in range(4))
    correct_at = np.zeros((n, max(limit, max(budgets)) + 1), dtype=bool)
    maps = set()  # the maps the episodes ran on (a digest each): one, or a new one per episode
    if warmup and n:  # compile (numba) and first calls (caches, torch) outside the timed decisions
        seed, options = specs[0]
        rollout(env, policy.policy, int(seed), reset_options=options, max_steps=WARMUP_DECISIONS)
    start = time.perf_counter()
    for i, (seed, options) in enumerate(tqdm(specs, desc=f"{task.env_id} {task.policy}", unit="ep", disable=not progress, leave=False)):
        ep = rollout(env, policy, int(seed), reset_options=options)
        if length:  # fixed length: the first step the referee declared localised
            first = next((k for k, flag in enumerate(ep.localised_at) if flag and k > 0), None)
            localised[i] = first is not None
            steps[i] = first if first is not None else limit
            success[i] = ep.collapsed[-1]
        else:
            localised[i] = ep.terminated
            steps[i] = ep.steps if ep.terminated else max_steps
            success[i] = ep.success
        truncated[i] = ep.truncated and not ep.terminated and not localised[i]
        correct_at[i, : len(ep.correct)] = ep.correct
        correct_at[i, len(ep.correct):] = ep.correct[-1]
        collapsed_end[i] = ep.collapsed[-1]
        maps.add(hashlib.sha1(env.unwrapped.model.grid.labels.tobytes()).hexdigest())
    env.close()
    return {
        "steps": steps, "localised": localised, "success": success, "truncated": truncated, "correct_at": correct_at,
        "collapsed_end": collapsed_end, "maps": maps, "max_steps": int(limit), "episode_length": length,
        "seconds": time.perf_counter() - start, "decision_seconds": policy.seconds, "decisions": policy.decisions,
        "model": _model_name(getattr(policy.policy, "path", None)),
    }


def _model_name(path) -> str | None:
    """How a results file names a model: shipped ones as ``agents/gym_gridloc_agents/models/<file>`` (not this
    machine's install path), a user's as given."""
    if not path:
        return None
    return f"agents/gym_gridloc_agents/models/{Path(path).name}" if Path(path).resolve().parent == POLICY_DIR else str(path)


def run_episodes(env_id: str, policy_name: str, episodes: int, *, seed_start: int = 0, env_kwargs: dict | None = None,
                 model_path: str | Path | None = None, budgets: Sequence[int] = BUDGETS, progress: bool = True,
                 test_set: bool = False, options: dict | None = None) -> dict[str, Any]:
    """Run one policy for ``episodes`` episodes (seeds ``seed_start + i``); returns one row."""
    episodes = check_int("episodes", episodes, whole=True)
    task = Task(env_id, policy_name, dict(env_kwargs or {}), model_path, dict(options or {}))
    specs = episode_specs(env_id, task.env_kwargs, int(episodes), seed_start, test_set)
    return summarise(task, parts=[simulate(task, specs, budgets=budgets, progress=progress)], seed_start=seed_start,
                     budgets=budgets, test_set=test_set)


def _job(args: tuple) -> dict[str, Any]:
    task, specs, budgets, torch_threads = args
    if torch_threads is not None and task.policy in LEARNED:
        import torch

        torch.set_num_threads(torch_threads)
    return simulate(task, specs, budgets=budgets, progress=False)


def applicable(name: str, env_id: str, env_kwargs: dict, options: dict) -> bool:
    """Whether policy ``name`` can run on the environment: ``central`` needs a sensor with a
    "nothing" reading (RingSensor), or a ``nothing`` option naming one; every other policy runs
    everywhere."""
    if name != "central" or options.get("nothing") is not None:
        return True
    env = make_env(env_id, env_kwargs)
    try:
        return getattr(env.unwrapped.model.sensor, "nothing", None) is not None
    finally:
        env.close()


def run_benchmark(
    env_ids: Sequence[str],
    policies: Sequence[str],
    episodes: int,
    *,
    seed_start: int = 0,
    env_kwargs: dict | None = None,
    test_set: bool = False,
    ppo_model: str | Path | Sequence[str | Path] | None = None,
    recurrent_model: str | Path | Sequence[str | Path] | None = None,
    policy_options: dict[str, dict] | None = None,
    progress: bool = True,
    jobs: int = 1,
    distilled_model: str | Path | Sequence[str | Path] | None = None,
    torch_threads: int | None = None,
    address: str | None = None,
) -> list[dict[str, Any]]:
    """Rows for every environment x policy, in that order, on the same episodes.  With
    ``jobs > 1`` the episodes are split into chunks run in parallel processes (the same
    episodes, so the same numbers).  Several ``ppo_model`` (``distilled_model``, ``recurrent_model``)
    files, one per seed, make the ``ppo`` (``distilled``, ``recurrent``) row the aggregate across
    seeds (:func:`seed_aggregate`);
    a ``ppo_model`` that was distilled from a planner is benchmarked as ``distilled``, with a
    ``FutureWarning`` (the name ``ppo`` meant the distilled models before 0.2).  ``policy_options`` maps a policy
    name to its options (e.g. ``{"expectimax": {"depth": 3}}``).  ``torch_threads``: torch's
    threads for the learned policies, in this process and in every job (None: torch's default).
    ``address``: run the same chunks as Ray tasks on the Ray cluster there (``HOST:PORT`` or
    ``auto``; :mod:`gym_gridloc_agents.evaluation.bench_cluster`), the same rows, each with a ``cluster``
    entry saying where its chunks ran."""
    given = {}
    for key, value in (("ppo", ppo_model), ("distilled", distilled_model), ("recurrent", recurrent_model)):
        given[key] = list(value) if isinstance(value, (list, tuple)) else [value]
        if not given[key]:
            raise ValueError(f"{key}_model: an empty list of models")
    for name in policies:
        if name not in POLICY_NAMES:
            raise ValueError(f"unknown policy {unknown_names([name], POLICY_NAMES)}; allowed: {', '.join(POLICY_NAMES)}")
    if len(set(policies)) != len(policies):
        raise ValueError(f"policies must not repeat, got {list(policies)}")
    episodes = check_int("episodes", episodes, whole=True)
    kwargs, options = dict(env_kwargs or {}), dict(policy_options or {})
    groups: list[list[Task]] = []  # one group per row; several tasks = several seeds' models
    for env_id in env_ids:
        for name in policies:
            if not applicable(name, env_id, kwargs, options.get(name, {})):
                warnings.warn(f"policy {name!r} does not apply to {env_id} (its sensor has no 'nothing' reading): "
                              "no row for it", stacklevel=2)
                continue
            paths = given.get(name) or [None]
            groups.append([Task(env_id, _learned_name(name, p), kwargs, p, dict(options.get(name, {}))) for p in paths])
    tasks = [t for group in groups for t in group]
    for task in tasks:  # every policy and option built before the first episode: a late one never fails a long run
        env = make_env(task.env_id, task.env_kwargs)
        try:
            make_task_policy(task, env)
        except TypeError as exc:  # an option the policy's class does not take
            raise ValueError(f"policy {task.policy!r} on {task.env_id}: {exc}") from None
        except ValueError as exc:
            raise ValueError(f"policy {task.policy!r} on {task.env_id}: {exc}") from None
        finally:
            env.close()
    specs = {env_id: episode_specs(env_id, kwargs, int(episodes), seed_start, test_set) for env_id in env_ids}
    if torch_threads is not None and any(t.policy in LEARNED for t in tasks):
        import torch

        torch.set_num_threads(int(torch_threads))
    def finished(parts: list) -> list[dict[str, Any]]:
        """The rows of the groups whose every task is done (``parts[i]``: task ``i``'s parts; a
        task past the list's end, or None, is not done)."""
        rows, i = [], 0
        for group in groups:
            runs = [parts[j] if j < len(parts) else None for j in range(i, i + len(group))]
            if all(r is not None for r in runs):
                row = (seed_aggregate(group[0], runs, seed_start=seed_start, test_set=test_set) if len(group) > 1
                       else summarise(group[0], parts=runs[0], seed_start=seed_start, test_set=test_set))
                if where is not None:  # where the row's chunks ran
                    row["cluster"] = bench_cluster.row_cluster(where, where["tasks"][i: i + len(group)])
                rows.append(row)
            i += len(group)
        return add_gaps(rows)

    where = None
    if address is not None:  # Ray is imported there only (the 'sweep' extra)
        from gym_gridloc_agents.evaluation import bench_cluster

        models = {i: (path, _model_name(path)) for i, t in enumerate(tasks) if (path := _model_file(t)) is not None}
        try:
            work, done, where = bench_cluster.run_chunks(address, lambda cpus: chunk_work(tasks, specs, episodes, cpus, torch_threads),
                                                         len(tasks), models, _job, progress=progress)
        except bench_cluster.ChunksStopped as stop:  # Ctrl-C, or the cluster is gone: the tasks whose every chunk came back
            where = stop.where
            parts = [None if not got or any(stop.done[k] is None for k, (j, _) in enumerate(stop.work) if j == i) else got
                     for i, got in enumerate(gather_chunks(stop.work, stop.done, len(tasks)))]
            raise BenchmarkInterrupted(finished(parts), len(groups), stop.lost) from None
        parts = gather_chunks(work, done, len(tasks))
    elif jobs <= 1:
        parts = []
        try:
            for t in tasks:
                parts.append([simulate(t, specs[t.env_id], progress=progress)])
        except KeyboardInterrupt:
            raise BenchmarkInterrupted(finished(parts), len(groups)) from None
    else:
        import multiprocessing as mp

        from tqdm.auto import tqdm

        work = chunk_work(tasks, specs, episodes, jobs, torch_threads)
        done: list = []
        try:
            with mp.get_context("spawn").Pool(jobs) as pool:
                for part in tqdm(pool.imap(_job, [w for _, w in work]), total=len(work), desc="benchmark chunks",
                                 disable=not progress):
                    done.append(part)
                pool.close()  # let the workers exit on their own (``with`` alone terminates them)
                pool.join()
        except KeyboardInterrupt:  # imap is in order: the tasks whose every chunk came back are finished
            complete = [i for i in range(len(tasks)) if all(k < len(done) for k, (j, _) in enumerate(work) if j == i)]
            parts = [[part for (j, _), part in zip(work, done) if j == i] for i in complete]
            raise BenchmarkInterrupted(finished(parts), len(groups)) from None
        parts = gather_chunks(work, done, len(tasks))
    return finished(parts)


def chunk_work(tasks: Sequence[Task], specs: dict[str, list], episodes: int, workers: int,
               torch_threads: int | None) -> list[tuple[int, tuple]]:
    """The chunks of episodes of ``workers`` parallel workers (``jobs`` processes, a cluster's CPUs):
    about 4 per worker and task, each ``(task index, (task, its episodes, budgets, torch threads))``."""
    chunk = max(1, math.ceil(episodes / (4 * max(1, workers))))
    return [(i, (t, specs[t.env_id][lo: lo + chunk], BUDGETS, torch_threads)) for i, t in enumerate(tasks)
            for lo in range(0, episodes, chunk)]


def _model_file(task: Task) -> Path | None:
    """The model file of a learned task (its ``model_path``, else the shipped one); None for the others."""
    if task.policy not in LEARNED:
        return None
    return Path(task.model_path) if task.model_path else default_model_path(task.env_id, task.policy, task.env_kwargs)


def gather_chunks(work: Sequence[tuple[int, tuple]], done: Sequence[dict[str, Any]], n_tasks: int) -> list[list[dict[str, Any]]]:
    """Every task's :func:`simulate` parts in episode order (``done[k]``: chunk ``work[k]``'s result)."""
    return [[part for (j, _), part in zip(work, done) if j == i] for i in range(n_tasks)]


__all__ = ["BENCH_ENV_IDS", "BUDGETS", "BenchmarkInterrupted", "DEFAULT_POLICIES", "PLANNERS", "Task", "add_gaps", "applicable", "default_model_path",
           "episode_specs", "run_benchmark", "run_episodes", "seed_aggregate", "simulate", "summarise"]
