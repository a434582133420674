#!/usr/bin/env bash
# Set up .venv with the package and every extra (RL, rendering, sweeps on Ray, RLlib's imports, pomdp_py
# planning, numba kernels), the test tools and the documentation tools.
# torch is installed first and pinned: an unpinned torch resolves to a multi-GB CUDA build.
# About 5 minutes and 2.2 GB on a fresh clone (most of it torch, Ray and their dependencies); pip
# runs quietly, so each stage prints one line.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
stage() { printf '%s %s\n' "$1" "$2"; }
if [ -x .venv/bin/python ]; then
    stage "[1/4]" "using the existing .venv"
else
    stage "[1/4]" "creating .venv with $("$PY" --version 2>&1)"
    "$PY" -m venv .venv
fi
stage "[2/4]" "installing torch==2.13.0 (the CPU build, about 750 MB installed)"
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "torch==2.13.0"
stage "[3/4]" "installing gym_gridloc (editable) with every extra: rl, render, dev, fast, docs, sweep, rllib, planning"
.venv/bin/python -m pip install -q -e ".[rl,render,dev,fast,docs,sweep,rllib,planning]"
# tests/test_release.py builds the wheel and sdist with `python -m build`.
stage "[4/4]" "installing build (the release test's wheel builder)"
.venv/bin/python -m pip install -q build
echo "done: .venv is ready; 'source .venv/bin/activate' puts gridloc on your PATH (or call .venv/bin/gridloc)"
