"""``gridloc bench --address``: the benchmark's chunks of episodes as Ray tasks on a Ray cluster.

The chunks are those of ``--jobs`` (:func:`gym_gridloc_agents.evaluation.bench.chunk_work`, about 4 per CPU
of the cluster and row) and each runs :func:`gym_gridloc_agents.evaluation.bench.simulate` on its episodes,
with the seeds of a local run: the rows are a local run's (common random numbers), except the
timing columns (``seconds``, ``ms_per_decision``) and the ``cluster`` entry saying where the
chunks ran.

What travels to the workers: each chunk's task and episodes (seeds, and with ``--test-set`` the
held-out maps and start states), and the bytes of every model file (``.zip`` and its metadata
``.json``), put once in Ray's object store and written to a temporary directory on the node that
runs a chunk; the code itself is not sent (every node needs the same install).

A chunk whose worker or node is lost is run again (up to :data:`RERUNS` times; the episodes are
seeded, so the rerun gives the same numbers), and counted in the row's ``cluster.reruns``.  An
error of the chunk itself (a bad option, say) is not retried: it stops the run, as locally.
Ctrl-C, or a head that stops answering (:func:`gym_gridloc_agents.cluster.answers`), stops the run
with the chunks that came back (:class:`ChunksStopped`): the caller writes the rows they finish.

This module, :mod:`gym_gridloc_agents.cluster` (joining: the address and its deadline) and
:mod:`gym_gridloc_agents.sweeps.sweep` are the only ones importing Ray (the ``sweep`` extra), and
only when a run on a cluster starts.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import signal
import sys
import tempfile
import threading
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Sequence

from gym_gridloc_agents.cluster import ClusterError, answers

#: How many times one chunk is run again after its worker or node was lost.
RERUNS = 3


#: Seconds between two checks, while no chunk comes back, that the cluster's head still answers.
HEARTBEAT = 1.0
#: Checks in a row without an answer after which the cluster counts as lost.
SILENT_CHECKS = 3


class ChunksStopped(Exception):
    """The run on the cluster stopped before every chunk came back: Ctrl-C (``lost`` None) or a
    cluster that stopped answering (``lost``: what happened).  ``work``, ``done`` (None for a chunk
    that did not come back) and ``where`` as :func:`run_chunks` returns them, for the chunks that did."""

    def __init__(self, work: list, done: list, where: dict[str, Any] | None, lost: str | None = None) -> None:
        super().__init__(lost or "interrupted")
        self.work, self.done, self.where, self.lost = work, done, where, lost


def connect(address: str) -> bool:
    """Join the Ray cluster at ``address`` (:func:`gym_gridloc_agents.cluster.join`: the address
    checked, a deadline on finding its head)."""
    from gym_gridloc_agents.cluster import join

    return join(address)


def model_blob(path: Path) -> dict[str, Any]:
    """A model file's bytes and those of its metadata beside it (what travels to the workers)."""
    meta = path.with_suffix(".json")
    return {"name": path.name, "zip": path.read_bytes(), "json": meta.read_bytes() if meta.is_file() else None}


def materialise(blob: dict[str, Any]) -> Path:
    """The model of ``blob`` as files on this node (a temporary directory named by the bytes'
    hash, written once per node and atomically: chunks running at once share it)."""
    digest = hashlib.sha256(blob["zip"] + (blob["json"] or b"")).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "gridloc-models" / digest
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / blob["name"]
    for target, data in ((path.with_suffix(".json"), blob["json"]), (path, blob["zip"])):
        if data is not None and not (target.is_file() and target.stat().st_size == len(data)):
            tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, target)
    return path


def run_chunk(job: Callable[[tuple], dict[str, Any]], args: tuple, blob: dict[str, Any] | None, name: str | None) -> dict[str, Any]:
    """One chunk on a worker: ``job(args)`` (:func:`gym_gridloc_agents.evaluation.bench._job`) with the
    task's model written on this node; the part names the model as a local run does and says
    where it ran."""
    import ray

    if blob is not None:
        args = (dataclasses.replace(args[0], model_path=materialise(blob)), *args[1:])
    part = job(args)
    if blob is not None:
        part["model"] = name
    part["node"] = f"{ray.util.get_node_ip_address()}/{ray.get_runtime_context().get_node_id()[:8]}"
    return part


def run_chunks(address: str, chunks: Callable[[int], list[tuple[int, tuple]]], n_tasks: int,
               models: dict[int, tuple[Path, str]], job: Callable[[tuple], dict[str, Any]], *,
               progress: bool = True) -> tuple[list[tuple[int, tuple]], list[dict[str, Any]], dict[str, Any]]:
    """Run ``job`` on every chunk as a Ray task on the cluster at ``address``.

    ``chunks(cpus)``: the chunks ``(task index, job arguments)`` for the cluster's CPUs
    (:func:`gym_gridloc_agents.evaluation.bench.chunk_work`); ``models``: task index -> (its model file, the
    name rows give it).  Returns the chunks, their results (the same order) and where they ran:
    ``{"address", "nodes", "cpus", "chunk_episodes", "tasks": [per task: {"chunks_per_node":
    {node: n}, "reruns": n}]}``.  Ctrl-C, or a head that stops answering (checked every
    :data:`HEARTBEAT` seconds while no chunk comes back), raises :class:`ChunksStopped` with the
    chunks that came back."""
    import ray
    from ray.exceptions import RayTaskError
    from tqdm.auto import tqdm

    started = False
    work: list[tuple[int, tuple]] = []
    done: list[dict[str, Any] | None] = []
    reruns: list[int] = []
    nodes, cpus = [], 0

    def where() -> dict[str, Any]:
        """Where the chunks that came back ran, per task (their results lose the ``node`` they name)."""
        per_task = [{"chunks_per_node": Counter(), "reruns": 0} for _ in range(n_tasks)]
        for k, ((i, _), part) in enumerate(zip(work, done)):
            if part is not None:
                per_task[i]["chunks_per_node"][part.pop("node")] += 1
                per_task[i]["reruns"] += reruns[k]
        return {"address": gcs, "nodes": len(nodes), "cpus": cpus, "chunk_episodes": len(work[0][1][1]) if work else 0,
                "tasks": [{"chunks_per_node": dict(sorted(t["chunks_per_node"].items())), "reruns": t["reruns"]} for t in per_task]}

    gcs, lost = address, None
    try:
        started = connect(address)
        gcs = ray.get_runtime_context().gcs_address
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if cpus < 1:
            raise ClusterError(f"the Ray cluster at {address} has no CPU to run the benchmark's chunks")
        work = chunks(cpus)
        done, reruns = [None] * len(work), [0] * len(work)
        # task index -> (the model's bytes, once in the object store, and its name in the rows)
        blobs = {i: (ray.put(model_blob(path)), name) for i, (path, name) in models.items()}
        # Retries are the driver's (not Ray's max_retries), so that each rerun is counted in the row.
        remote = ray.remote(run_chunk).options(num_cpus=1, max_retries=0, scheduling_strategy="SPREAD")

        def submit(k: int):
            i, args = work[k]
            blob, name = blobs.get(i, (None, None))
            return remote.remote(job, args, blob, name)

        def head_gone() -> str | None:
            """Why the cluster's head no longer answers, after :data:`SILENT_CHECKS` checks in a row (None: it answers)."""
            for _ in range(SILENT_CHECKS):
                if (why := answers(gcs, timeout=HEARTBEAT)) is None:
                    return None
            return f"the Ray cluster at {address} stopped answering during the run (its head {gcs}: {why})"

        pending = {submit(k): k for k in range(len(work))}
        with tqdm(total=len(work), desc=f"benchmark chunks on {len(nodes)} node(s), {cpus} CPU(s)", disable=not progress) as bar, \
                _ctrl_c_noted() as pressed:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=HEARTBEAT)
                if pressed:
                    raise KeyboardInterrupt
                if not ready:  # nothing came back: is the cluster still there? (Ray would wait for it for minutes)
                    if (lost := head_gone()) is not None:
                        raise ChunksStopped(work, done, where(), lost)
                    continue
                k = pending.pop(ready[0])
                try:
                    done[k] = ray.get(ready[0])
                except RayTaskError as exc:  # the chunk's own error: as a local run would raise it
                    raise (exc.cause if isinstance(exc.cause, Exception) else exc.as_instanceof_cause()) from None
                except ray.exceptions.RayError as exc:  # its worker or node was lost: run it again
                    if (lost := head_gone()) is not None:
                        raise ChunksStopped(work, done, where(), lost) from None
                    if reruns[k] >= RERUNS:
                        raise ClusterError(f"a chunk of {work[k][1][0].env_id} {work[k][1][0].policy} was lost "
                                           f"{reruns[k] + 1} times ({type(exc).__name__}); last: {' '.join(str(exc).split())[:300]}") from None
                    reruns[k] += 1
                    print(f"gridloc bench: a chunk of {work[k][1][0].env_id} {work[k][1][0].policy} was lost with its worker "
                          f"or node ({type(exc).__name__}): running it again", file=sys.stderr)
                    pending[submit(k)] = k
                    continue
                bar.update(1)
        return work, done, where()
    except KeyboardInterrupt:  # the chunks that came back are kept (their rows written by the caller)
        raise ChunksStopped(work, done, where()) from None
    finally:
        if started and lost is None:
            ray.shutdown()
        elif started:  # the head is gone: Ray's shutdown would wait for it; the driver's own processes end with it
            _shutdown_quietly(ray)


@contextlib.contextmanager
def _ctrl_c_noted():
    """While the driver waits for chunks, Ctrl-C (SIGINT) is noted in the list yielded, which the
    loop reads after every wait: a KeyboardInterrupt raised inside Ray's own calls could be taken
    for a lost chunk there.  A second Ctrl-C raises at once.  Outside the main thread: no change."""
    pressed: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield pressed
        return

    def note(signum, frame):
        if pressed:
            raise KeyboardInterrupt
        pressed.append(signum)

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield pressed
    finally:
        signal.signal(signal.SIGINT, previous)


def _shutdown_quietly(ray) -> None:
    """``ray.shutdown()`` of a driver whose cluster is gone, in a daemon thread given a few seconds."""
    thread = threading.Thread(target=ray.shutdown, daemon=True)
    thread.start()
    thread.join(10)


def row_cluster(where: dict[str, Any], tasks: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A row's ``cluster`` entry: the cluster, and where the chunks of its tasks (several with
    one model per seed) ran."""
    per_node: Counter = Counter()
    for t in tasks:
        per_node.update(t["chunks_per_node"])
    return {"address": where["address"], "nodes": where["nodes"], "cpus": where["cpus"],
            "chunk_episodes": where["chunk_episodes"], "chunks": sum(per_node.values()),
            "chunks_per_node": dict(sorted(per_node.items())), "reruns": sum(t["reruns"] for t in tasks)}


__all__ = ["HEARTBEAT", "RERUNS", "SILENT_CHECKS", "ChunksStopped", "ClusterError", "connect", "materialise", "model_blob", "row_cluster", "run_chunk", "run_chunks"]
