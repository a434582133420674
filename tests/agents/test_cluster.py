"""``gridloc bench --address`` and ``gridloc sweep --address`` on a real two-node Ray cluster on
this machine: a head node and a second node, each started with ``ray start --block`` in a process
group of its own (its own temp dir, token authentication with a token made for these tests), and
stopped at the end by ending those process groups -- never with ``ray stop``, which stops every
Ray process on the machine, other people's included.

The rows and summaries on the cluster equal those of local runs (all but the timing columns and
where things ran).  The checks on the cluster are one test (``pytest -n 2`` would start a cluster
per xdist worker otherwise), marked ``cluster``: ``-m 'not cluster'`` leaves it out; CI runs it.
"""

from __future__ import annotations

import contextlib
import io
import importlib.util
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from gym_gridloc_agents.cli import main
from tests.helpers import kill_session, session_processes

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ray") is None or importlib.util.find_spec("optuna") is None,
                                reason="needs the sweep extra (ray[tune], optuna)")

RAY = Path(sys.executable).parent / "ray"
#: Columns that measure time (or say where a row ran): they differ between two runs of the same rows.
TIMING = {"seconds", "ms_per_decision", "cluster"}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _node_ports() -> list[str]:
    """Ports a node would otherwise take at fixed defaults (two nodes on one machine must differ)."""
    return ["--dashboard-agent-listen-port", str(_free_port()), "--dashboard-agent-grpc-port", str(_free_port()),
            "--metrics-export-port", str(_free_port()), "--runtime-env-agent-port", str(_free_port())]


def _stop(proc: subprocess.Popen) -> None:
    """End a ``ray start --block`` and its node's processes: SIGTERM to it (it stops its node in
    about 2 s; SIGTERM to the whole group at once takes Ray 30 s), then SIGKILL to whatever is left
    of its process group and session."""
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(30)
    kill_session(proc.pid)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(10)


def _alive_nodes(address: str, env: dict, want: int, timeout: float) -> int:
    """Wait (one Ray client, polling) until ``want`` nodes are alive; the number alive at the end."""
    code = ("import sys, time, ray; ray.init(address=sys.argv[1], logging_level='ERROR'); end = time.monotonic() + float(sys.argv[3])\n"
            "while True:\n"
            "    n = sum(1 for x in ray.nodes() if x['Alive'])\n"
            "    if n == int(sys.argv[2]) or time.monotonic() > end: break\n"
            "    time.sleep(0.2)\n"
            "print(n)")
    run = subprocess.run([sys.executable, "-c", code, address, str(want), str(timeout)], capture_output=True, text=True,
                         env=env, timeout=timeout + 60)
    assert run.returncode == 0, run.stderr[-2000:]
    return int(run.stdout.split()[-1])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A head node and a second node on this machine, 1 CPU each."""
    logs = tmp_path_factory.mktemp("cluster")
    temp = Path(tempfile.mkdtemp(prefix="glc-", dir="/tmp"))  # short: Ray's socket paths have a length limit
    port = _free_port()
    address = f"127.0.0.1:{port}"
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": uuid.uuid4().hex}
    env.pop("RAY_ADDRESS", None)
    # A lost node is declared dead after ~2 s instead of Ray's ~15-30 s (the rerun test's wait).
    nodes_env = {**env, "RAY_health_check_period_ms": "500", "RAY_health_check_timeout_ms": "1000",
                 "RAY_health_check_failure_threshold": "3"}
    common = ["--block", "--num-cpus", "1", "--node-ip-address", "127.0.0.1", "--temp-dir", str(temp), "--disable-usage-stats"]
    procs: list[subprocess.Popen] = []
    start = time.monotonic()

    def launch(name: str, args: list[str]) -> subprocess.Popen:
        with open(logs / f"{name}.log", "w") as log:
            proc = subprocess.Popen([str(RAY), "start", *args, *common, *_node_ports()], stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, env=nodes_env)
        procs.append(proc)
        return proc

    try:
        head = launch("head", ["--head", "--port", str(port), "--include-dashboard=false"])
        deadline = time.monotonic() + 60
        while not (temp / "ray_current_cluster").exists():
            assert head.poll() is None and time.monotonic() < deadline, (logs / "head.log").read_text()[-2000:]
            time.sleep(0.2)
        second = launch("second", ["--address", address])
        assert _alive_nodes(address, env, 2, 60) == 2, (logs / "second.log").read_text()[-2000:]
        up = time.monotonic() - start
        print(f"\n[two-node cluster: up in {up:.1f} s]")
        yield SimpleNamespace(address=address, env=env, head=head, second=second, logs=logs, up=up)
    finally:
        stopping = time.monotonic()
        for proc in reversed(procs):
            _stop(proc)
        shutil.rmtree(temp, ignore_errors=True)
        print(f"\n[two-node cluster: stopped in {time.monotonic() - stopping:.1f} s]")


def _gridloc(*args: str, env: dict, cwd: Path, timeout: float = 180, status: int = 0) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, "-m", "gym_gridloc_agents.cli", *args], capture_output=True, text=True,
                         env=env, cwd=cwd, timeout=timeout)
    assert run.returncode == status, run.stderr[-3000:]
    return run


# -- without a cluster ----------------------------------------------------------------------------------
@pytest.mark.parametrize("args, says", [
    (["--address", "127.0.0.1:1"], "nothing answers there"),
    (["--address", "127.0.0.1:1", "--jobs", "2"], "--jobs"),
    (["--address", " "], "HOST:PORT"),
])
def test_address_errors_are_one_line(capsys, args, says):
    start = time.monotonic()
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "greedy", "--episodes", "2", "--no-progress", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("gridloc bench: error:") and says in err, err
    assert time.monotonic() - start < 30  # not Ray's endless retries on an address where nothing listens


def test_a_ray_that_raises_a_bare_exception_is_one_line(capsys, monkeypatch):
    ray = pytest.importorskip("ray")

    def broken(*args, **kwargs):
        raise Exception("The current node timed out during startup.")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", broken)
    assert main(["bench", "--env", "WindyMaze-v0", "--policies", "greedy", "--episodes", "2", "--no-progress",
                 "--address", "auto"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot join the Ray cluster at auto: The current node timed out" in err, err


def test_chunks_in_any_number_give_the_serial_parts():
    """The chunking that --jobs and --address share: whatever the number of workers, the parts put
    back together are the serial run's episodes in order."""
    from gym_gridloc_agents.evaluation.bench import Task, chunk_work, episode_specs, gather_chunks

    tasks = [Task("ColourGrid-v0", "random"), Task("ColourGrid-v0", "greedy")]
    specs = {"ColourGrid-v0": episode_specs("ColourGrid-v0", {}, 10, 5, False)}
    for workers in (1, 2, 3, 16):
        work = chunk_work(tasks, specs, 10, workers, None)
        parts = gather_chunks(work, [{"task": i, "seeds": [seed for seed, _ in args[1]]} for i, args in work], len(tasks))
        assert [[s for p in ps for s in p["seeds"]] for ps in parts] == [list(range(5, 15))] * 2
        assert all(p["task"] == i for i, ps in enumerate(parts) for p in ps)
        assert len(work) == 2 * -(-10 // max(1, -(-10 // (4 * workers))))


def _timeless(row: dict) -> dict:
    out = {k: v for k, v in row.items() if k not in TIMING}
    if "per_seed" in out:
        out["per_seed"] = [{k: v for k, v in r.items() if k not in TIMING} for r in out["per_seed"]]
    return out


#: The issue's command: greedy2 and the shipped PPO on WindyMaze-v0, 200 episodes.
WINDY = ["bench", "--env", "WindyMaze-v0", "--policies", "greedy2,ppo", "--episodes", "200"]


def windy_local(tmp_path: Path) -> tuple[list[dict], float]:
    """The rows of :data:`WINDY` run here (one process), and how long they took."""
    path = tmp_path / "local.json"
    start = time.monotonic()
    assert main([*WINDY, "--no-progress", "--json", str(path)]) == 0
    return json.loads(path.read_text()), time.monotonic() - start


def bench_on_two_nodes_gives_the_local_rows(cluster, windy_local, tmp_path):
    """The rows of :data:`WINDY` on the cluster equal the local run's, and each says where its
    chunks ran (both nodes)."""
    local, local_s = windy_local
    start = time.monotonic()
    run = _gridloc(*WINDY, "--no-progress", "--address", cluster.address, "--json", str(tmp_path / "cluster.json"),
                   env=cluster.env, cwd=tmp_path)
    cluster_s = time.monotonic() - start
    remote = json.loads((tmp_path / "cluster.json").read_text())
    assert [_timeless(r) for r in remote] == [_timeless(r) for r in local]
    assert remote[1]["model"] == local[1]["model"] == "agents/gym_gridloc_agents/models/WindyMaze-v0-ppo.zip"  # the name, not a worker's copy
    nodes = set()
    for row in remote:
        c = row["cluster"]
        assert c["address"].endswith(f":{cluster.address.rsplit(':', 1)[1]}") and c["nodes"] == 2 and c["cpus"] == 2
        assert c["chunk_episodes"] == 25 and c["chunks"] == 8 == sum(c["chunks_per_node"].values()) and c["reruns"] == 0
        nodes |= set(c["chunks_per_node"])
    assert len(nodes) == 2, nodes  # both nodes ran chunks
    assert "WindyMaze-v0 | greedy2" in run.stdout
    print(f"\n[bench 2 x 200 episodes: local {local_s:.1f} s, on the cluster {cluster_s:.1f} s (cluster up in {cluster.up:.1f} s)]")


def maps_and_a_users_model_travel(cluster, tmp_path):
    """Held-out maps (in the chunks' episodes) and a model file of the user's (its bytes, written
    on the node that runs the chunk, the row naming the user's path) give the local rows too."""
    from gym_gridloc_agents.policies import default_model_path

    shipped = default_model_path("DepthMaze-v0", "ppo", {"size": 7, "episode_length": 15})
    mine = tmp_path / "models" / "mine.zip"
    mine.parent.mkdir()
    shutil.copy(shipped, mine)
    shutil.copy(shipped.with_suffix(".json"), mine.with_suffix(".json"))
    args = ["bench", "--env", "DepthMaze-v0", "--size", "7", "--test-set", "--episode-length", "15", "--policies", "greedy,ppo",
            "--episodes", "12", "--ppo-model", "models/mine.zip", "--no-progress"]
    cwd = Path.cwd()
    try:
        os.chdir(tmp_path)
        assert main([*args, "--json", "local.json"]) == 0
    finally:
        os.chdir(cwd)
    _gridloc(*args, "--address", cluster.address, "--json", "cluster.json", env=cluster.env, cwd=tmp_path)
    local, remote = (json.loads((tmp_path / f"{name}.json").read_text()) for name in ("local", "cluster"))
    assert [_timeless(r) for r in remote] == [_timeless(r) for r in local]
    assert remote[1]["model"] == "models/mine.zip" and remote[0]["test_set"] is True


def a_chunks_own_error_stops_the_run_as_locally(cluster, tmp_path):
    """A policy's bad option (a planner's depth) stops the run with the same one-line error as a
    local run: every policy is built and checked before the first chunk is sent, and nothing is
    rerun."""
    args = ["bench", "--env", "WindyMaze-v0", "--policies", "expectimax", "--option", "expectimax.depth=0", "--episodes", "4",
            "--no-progress"]
    local = io.StringIO()
    with contextlib.redirect_stderr(local):
        assert main(args) == 2
    remote = _gridloc(*args, "--address", cluster.address, env=cluster.env, cwd=tmp_path, status=2)
    assert remote.stderr.strip().splitlines()[-1] == local.getvalue().strip() == ("gridloc bench: error: policy 'expectimax' on WindyMaze-v0: "
                                                                                  "depth must be at least 1, got 0")


def _summary(out: Path) -> dict:
    """A sweep's summary without what names where it ran (the command, trial ids, paths under --output)."""
    text = (out / "summary.json").read_text().replace(str(out), "OUT")
    s = json.loads(text)
    s.pop("command", None)
    for c in s["configurations"]:
        for r in c["seeds"]:
            r.pop("trial_id", None)
    s.get("best", {}).pop("trial_id", None)
    return s


def start_local_sweep(tmp_path: Path) -> subprocess.Popen:
    """The tiny sweep on a Ray of its own on this machine (``--cpus 2``), started in the background
    while the benchmark's checks run; its output in ``tmp_path/local``."""
    from tests.agents.test_sweep import tiny_config

    cfg = tiny_config(tmp_path, total_timesteps=1024, eval_freq=512)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    with open(tmp_path / "local.log", "w") as log:
        return subprocess.Popen([sys.executable, "-m", "gym_gridloc_agents.cli", "sweep", str(cfg), "--seeds", "2", "--cpus", "2",
                                 "--output", str(tmp_path / "local")], stdout=log, stderr=subprocess.STDOUT, env=env,
                                cwd=tmp_path, start_new_session=True)


def sweep_on_two_nodes_gives_the_local_summary(cluster, local_sweep, tmp_path):
    """The same tiny sweep on the cluster: the same summary (scores, aggregates, best
    configuration and median seed) and the same best model's weights as the local sweep."""
    start = time.monotonic()
    assert local_sweep.wait(300) == 0, (tmp_path / "local.log").read_text()[-3000:]
    local_s = time.monotonic() - start
    args = ["sweep", str(tmp_path / "tiny.yml"), "--seeds", "2"]
    run = _gridloc(*args, "--address", cluster.address, "--output", str(tmp_path / "cluster"), env=cluster.env, cwd=tmp_path)
    cluster_s = time.monotonic() - start - local_s
    local, remote = _summary(tmp_path / "local"), _summary(tmp_path / "cluster")
    assert remote["statuses"] == {"done": 2} and "Best configuration: base" in run.stdout
    assert remote == local
    weights = [{n: z.read(n) for n in ("policy.pth", "policy.optimizer.pth")}  # (its "data" holds times)
               for z in (zipfile.ZipFile(tmp_path / where / "best.zip") for where in ("local", "cluster"))]
    assert weights[0] == weights[1]
    print(f"\n[sweep 2 seeds x 1024 steps: the local sweep (started first, in the background) waited for "
          f"{local_s:.1f} s more, on the cluster {cluster_s:.1f} s]")


def chunks_lost_with_a_node_are_rerun(cluster, windy_local, tmp_path):
    """The second node is killed (SIGKILL to all its processes) as soon as it runs a chunk of the
    benchmark: the lost chunks run again on the head, the rows are still the local run's and say
    how many chunks were rerun.  (Last in this module: it ends the second node.)"""
    local, _ = windy_local
    with open(tmp_path / "err.log", "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "gym_gridloc_agents.cli", *WINDY, "--no-progress", "--address",
                                 cluster.address, "--json", str(tmp_path / "cluster.json")], stdout=subprocess.DEVNULL,
                                stderr=err, env=cluster.env, cwd=tmp_path, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not any(c.startswith(b"ray::run_chunk") for c in session_processes(cluster.second.pid).values()):
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "err.log").read_text()[-3000:]
            time.sleep(0.02)
        killed = time.monotonic()
        kill_session(cluster.second.pid)  # the node and its workers, at once
        assert proc.wait(150) == 0, (tmp_path / "err.log").read_text()[-3000:]
        print(f"\n[second node killed while running a chunk; the run ended {time.monotonic() - killed:.1f} s later]")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    remote = json.loads((tmp_path / "cluster.json").read_text())
    assert [_timeless(r) for r in remote] == [_timeless(r) for r in local]
    reruns = sum(r["cluster"]["reruns"] for r in remote)
    assert reruns >= 1 and all(r["cluster"]["chunks"] == 8 for r in remote)
    print(f"[{reruns} chunk(s) rerun]")


@pytest.mark.cluster
def test_on_a_two_node_cluster(cluster, tmp_path):
    """The checks above, in this order (the last ends the second node), on one cluster: as one
    test, so that ``pytest -n 2`` never starts a cluster per xdist worker."""
    (tmp_path / "sweep").mkdir()
    local_sweep = start_local_sweep(tmp_path / "sweep")  # beside the benchmark's checks
    local = windy_local(tmp_path)
    steps = [
        (bench_on_two_nodes_gives_the_local_rows, (local,)),
        (maps_and_a_users_model_travel, ()),
        (a_chunks_own_error_stops_the_run_as_locally, ()),
        (sweep_on_two_nodes_gives_the_local_summary, (local_sweep,)),
        (chunks_lost_with_a_node_are_rerun, (local,)),
    ]
    try:
        for check, extra in steps:
            folder = tmp_path / ("sweep" if check is sweep_on_two_nodes_gives_the_local_summary else check.__name__)
            folder.mkdir(exist_ok=True)
            start = time.monotonic()
            check(cluster, *extra, folder)
            print(f"[{check.__name__}: {time.monotonic() - start:.1f} s]")
    finally:
        if local_sweep.poll() is None:
            kill_session(local_sweep.pid)
            local_sweep.wait(30)


def test_ctrl_c_while_waiting_for_chunks_is_noted_not_raised_inside_ray():
    """The first Ctrl-C is noted for the driver's loop (never raised inside one of Ray's calls,
    which could take it for a lost chunk); a second raises at once; the handler is put back."""
    from gym_gridloc_agents.evaluation.bench_cluster import _ctrl_c_noted

    before = signal.getsignal(signal.SIGINT)
    with _ctrl_c_noted() as pressed:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        assert pressed == [signal.SIGINT]
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
    assert signal.getsignal(signal.SIGINT) is before
