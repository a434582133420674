#!/usr/bin/env bash
# Set up .venv with the package and every extra (RL, rendering, sweeps on Ray, pomdp_py planning,
# numba kernels), the test tools and the documentation tools.
# torch is installed first and pinned: an unpinned torch resolves to a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "torch==2.13.0"
.venv/bin/python -m pip install -q -e ".[rl,render,dev,fast,docs,sweep,planning]"
# tests/test_release.py builds the wheel and sdist with `python -m build`.
.venv/bin/python -m pip install -q build
