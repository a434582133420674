"""Nothing lost on a Ray cluster: every ``--address`` is checked before Ray is called and a head
must answer within a deadline (one line, exit status 2, in seconds: never Ray's retries for
minutes), and a run on a cluster keeps the rows whose chunks all came back, on Ctrl-C (exit status
130) and when the cluster's head dies (one line naming the address, exit status 1).

The cluster is one head node on this machine (``ray start --block --node-ip-address 127.0.0.1``,
its own temp dir, token authentication), started in a session of its own and ended by killing that
session -- never with ``ray stop``, which stops every Ray process on the machine."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import pytest

from gym_gridloc_agents.cli import main
from tests.agents.test_cluster import RAY, _free_port, _node_ports, _stop
from tests.helpers import kill_session

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ray") is None or importlib.util.find_spec("optuna") is None,
                                reason="needs the sweep extra (ray[tune], optuna)")


@contextlib.contextmanager
def _listener(reply: bytes | None):
    """A TCP server on a free port that answers every connection with ``reply`` (None: reads and
    never answers): something that is not a Ray head."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    stop = threading.Event()
    held = []

    def serve() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            with contextlib.suppress(OSError):
                conn, _ = server.accept()
                held.append(conn)
                if reply is not None:
                    conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        server.close()


def _sweep_config(tmp_path: Path) -> Path:
    path = tmp_path / "cfg.yml"
    path.write_text("algo: ppo\nenv_id: ColourGrid-v0\nn_envs: 2\ntotal_timesteps: 256\n"
                    "hyperparams: {n_steps: 64, batch_size: 64, n_epochs: 1}\noutput: m.zip\n")
    return path


@pytest.mark.parametrize("address, says", [
    ("127.0.0.1:-1", "is not an address"), ("127.0.0.1:1 ", "holds a space"), (" 127.0.0.1:1", "holds a space"),
    ("127.0.0.1:0", "is not an address"), ("127.0.0.1:65536", "is not an address"), ("127.0.0.1", "is not an address"),
    (":6379", "is not an address"), ("my host:6379", "holds a space"), ("127.0.0.1:1", "nothing answers there"),
    ("http", "something answers there, but not a Ray head"), ("silent", "nothing answers there (timed out)"),
])
@pytest.mark.parametrize("command", ["bench", "sweep"])
def test_an_address_is_checked_and_joined_within_a_deadline(tmp_path, capsys, command, address, says):
    argv = {"bench": ["bench", "--env", "ColourGrid-v0", "--policies", "random", "--episodes", "2", "--no-progress"],
            "sweep": ["sweep", str(_sweep_config(tmp_path)), "--seeds", "1", "--output", str(tmp_path / "out")]}[command]
    reply = {"http": b"HTTP/1.0 400 Bad Request\r\n\r\n", "silent": None}
    with _listener(reply.get(address)) if address in reply else contextlib.nullcontext(address) as where:
        start = time.monotonic()
        assert main([*argv, "--address", where]) == 2
        took = time.monotonic() - start
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith(f"gridloc {command}: error:") and says in err, err
    assert took < 12, f"{took:.1f} s"  # about 10 s at most: the checks, then the deadline (5 s)
    assert not (tmp_path / "out" / "sweep.json").exists()


# -- on a running cluster ------------------------------------------------------------------------------
@contextlib.contextmanager
def _head(logs: Path):
    """One head node, 1 CPU, on this machine; yields ``(address, env, process)``."""
    temp = Path(tempfile.mkdtemp(prefix="glc-", dir="/tmp"))  # short: Ray's socket paths have a length limit
    port = _free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": uuid.uuid4().hex}
    env.pop("RAY_ADDRESS", None)
    with open(logs / "head.log", "w") as log:
        head = subprocess.Popen([str(RAY), "start", "--head", "--port", str(port), "--include-dashboard=false", "--block",
                                 "--num-cpus", "1", "--node-ip-address", "127.0.0.1", "--temp-dir", str(temp),
                                 "--disable-usage-stats", *_node_ports()], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True, env=env)
    try:
        deadline = time.monotonic() + 90
        while not (temp / "ray_current_cluster").exists():
            assert head.poll() is None and time.monotonic() < deadline, (logs / "head.log").read_text()[-2000:]
            time.sleep(0.2)
        yield f"127.0.0.1:{port}", env, head
    finally:
        _stop(head)
        shutil.rmtree(temp, ignore_errors=True)


#: A fast row (random) then a slow one (mcts, 1.5 s a decision): 4 chunks each on 1 CPU, in this order.
SLOW = ["bench", "--env", "WindyMaze-v0", "--policies", "random,mcts", "--option", "mcts.time_ms=1500", "--episodes", "8"]


def _run_until_the_first_row(address: str, env: dict, tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    """Start the slow benchmark on the cluster; return once the first row's 4 chunks came back
    (its progress bar at 4 of 8 chunks)."""
    err = tmp_path / f"{name}.err"
    with open(err, "w") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "gym_gridloc_agents.cli", *SLOW, "--address", address,
                                 "--json", str(tmp_path / f"{name}.json")], stdout=subprocess.DEVNULL, stderr=fh,
                                env=env, cwd=tmp_path, start_new_session=True)
    deadline = time.monotonic() + 240
    while not re.search(r"\b[4-7]/8\b", err.read_text()):
        assert proc.poll() is None and time.monotonic() < deadline, err.read_text()[-3000:]
        time.sleep(0.1)
    return proc, err


def _gridloc_lines(err: Path) -> list[str]:
    return [line for line in re.split(r"[\r\n]", err.read_text()) if line.startswith("gridloc bench")]


@pytest.mark.cluster
def test_a_cluster_run_keeps_its_finished_rows_on_ctrl_c_and_when_the_head_dies(tmp_path):
    with _head(tmp_path) as (address, env, head):
        proc, err = _run_until_the_first_row(address, env, tmp_path, "ctrl_c")
        try:
            proc.send_signal(signal.SIGINT)  # Ctrl-C while the mcts row runs
            assert proc.wait(60) == 130, err.read_text()[-3000:]
        finally:
            kill_session(proc.pid)
        assert "Traceback" not in err.read_text(), err.read_text()[-3000:]
        assert any("interrupted after 1 of 2 rows; the 1 finished row(s) are kept" in line for line in _gridloc_lines(err))
        rows = json.loads((tmp_path / "ctrl_c.json").read_text())
        assert [r["policy"] for r in rows] == ["random"] and rows[0]["episodes"] == 8 and rows[0]["cluster"]["chunks"] == 4

        proc, err = _run_until_the_first_row(address, env, tmp_path, "lost")
        try:
            killed = time.monotonic()
            kill_session(head.pid)  # the head dies while the mcts row runs
            assert proc.wait(60) == 1, err.read_text()[-3000:]
            took = time.monotonic() - killed
        finally:
            kill_session(proc.pid)
        text = err.read_text()
        assert "Traceback" not in text and "Failed to connect to GCS within" not in text, text[-3000:]
        lines = [line for line in _gridloc_lines(err) if "error:" in line]
        assert len(lines) == 1 and f"the Ray cluster at {address} stopped answering" in lines[0], text[-3000:]
        assert "the 1 finished row(s) are kept" in lines[0] and "--update" in lines[0]
        rows = json.loads((tmp_path / "lost.json").read_text())
        assert [r["policy"] for r in rows] == ["random"] and rows[0]["episodes"] == 8
        print(f"\n[head killed: the run ended {took:.1f} s later]")
