"""The release: ``python -m build`` makes an sdist and a wheel, and the wheel works on its own.

From a copy of the package's sources (nothing is written into the checkout) the test builds the
sdist and, from it, the wheel (``python -m build``'s default route); makes a fresh virtual
environment; installs ``torch==2.13.0`` first (a local file on the development machines and CI; an
unpinned torch would pull a multi-GB CUDA build), then the wheel with the ``rl`` extra; and, from a
directory outside the checkout: makes every registered environment, runs ``gridloc bench`` with the
shipped PPO policy (so the policies must be inside the wheel) and ``gridloc reproduce --quiet``, and
checks that ``gym_gridloc.__version__`` is the installed distribution's version.

It takes a few minutes (most of it pip installing the rl extra's dependencies), so it is marked
``slow``; CI runs it. ``GYM_GRIDLOC_SKIP_RELEASE=1`` skips it.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tarfile
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TORCH = "torch==2.13.0"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.environ.get("GYM_GRIDLOC_SKIP_RELEASE") == "1", reason="GYM_GRIDLOC_SKIP_RELEASE=1"),
    pytest.mark.skipif(importlib.util.find_spec("build") is None,
                       reason="the 'build' package is not installed (scripts/setup.sh installs it): pip install build"),
]


def run(cmd: list[str], *, cwd: Path, timeout: float, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    result = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert result.returncode == 0, (
        f"{' '.join(map(str, cmd))} exited with {result.returncode}\n--- stdout\n{result.stdout[-4000:]}"
        f"\n--- stderr\n{result.stderr[-4000:]}"
    )
    return result


def clean_env(venv: Path) -> dict[str, str]:
    """The environment of a user of the installed package: no PYTHONPATH, the venv first on PATH."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(venv)
    env["SDL_VIDEODRIVER"] = "dummy"
    env["MPLBACKEND"] = "Agg"
    return env


CHECK_INSTALLED = r"""
import importlib.metadata, pathlib, sys
import gymnasium as gym
import gym_gridloc, gym_gridloc_agents

checkout = pathlib.Path(sys.argv[1]).resolve()
for module in (gym_gridloc, gym_gridloc_agents):
    where = pathlib.Path(module.__file__).resolve()
    assert checkout not in where.parents, f"{module.__name__} imported from the checkout: {where}"
    assert (where.parent / "py.typed").is_file(), f"{module.__name__} has no py.typed"
installed = importlib.metadata.version("gym_gridloc")
assert gym_gridloc.__version__ == installed, (gym_gridloc.__version__, installed)
policies = pathlib.Path(gym_gridloc_agents.__file__).parent / "models"
assert sorted(p.name for p in policies.glob("*.zip")), "no shipped policies in the wheel"
for env_id in gym_gridloc.ENV_IDS:
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
print("ok", installed, ", ".join(gym_gridloc.ENV_IDS))
"""


def test_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    start = time.perf_counter()
    timings: dict[str, float] = {}

    # -- build: sdist, then the wheel from the sdist -----------------------------------------------
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    for name in ("gym_gridloc", "agents"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    dist = tmp_path / "dist"
    run([sys.executable, "-m", "build", "--outdir", str(dist), str(src)], cwd=tmp_path, timeout=600)
    timings["build"] = time.perf_counter() - start
    wheels = list(dist.glob("gym_gridloc-*.whl"))
    sdists = list(dist.glob("gym_gridloc-*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1, sorted(p.name for p in dist.iterdir())
    wheel = wheels[0]
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    assert {"gym_gridloc/py.typed", "gym_gridloc_agents/py.typed"} <= names
    assert any(n.startswith("gym_gridloc_agents/models/") and n.endswith(".zip") for n in names)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    metadata = next(n for n in names if n.endswith(".dist-info/METADATA"))
    with zipfile.ZipFile(wheel) as z:
        meta = z.read(metadata).decode()
    assert "License-Expression: MIT" in meta
    with tarfile.open(sdists[0]) as t:
        assert any(m.name.endswith("/LICENSE") for m in t.getmembers())

    # -- a fresh virtual environment, torch first, then the wheel with the rl extra ----------------
    t0 = time.perf_counter()
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", str(venv)], cwd=tmp_path, timeout=300)
    python = venv / "bin" / "python"
    env = clean_env(venv)
    pip = [str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check"]
    run([*pip, TORCH], cwd=tmp_path, timeout=900, env=env)
    run([*pip, f"{wheel}[rl]"], cwd=tmp_path, timeout=900, env=env)
    timings["install"] = time.perf_counter() - t0

    # -- use it from outside the checkout ----------------------------------------------------------
    t0 = time.perf_counter()
    outside = tmp_path / "user"
    outside.mkdir()
    result = run([str(python), "-c", CHECK_INSTALLED, str(ROOT)], cwd=outside, timeout=300, env=env)
    assert result.stdout.startswith("ok "), result.stdout
    gridloc = str(venv / "bin" / "gridloc")
    bench = run([gridloc, "bench", "--env", "WindyMaze-v0", "--policies", "random,greedy,distilled", "--episodes", "5",
                 "--no-progress"], cwd=outside, timeout=600, env=env)
    for policy in ("random", "greedy", "distilled"):
        assert policy in bench.stdout, bench.stdout
    run([gridloc, "reproduce", "--quiet"], cwd=outside, timeout=300, env=env)
    timings["use"] = time.perf_counter() - t0

    total = time.perf_counter() - start
    print(f"release check: {total:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")")
