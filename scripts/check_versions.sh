#!/usr/bin/env bash
# The declared dependency ranges, tested: for the oldest gymnasium we claim (1.1.x), RLlib's pin
# (1.2.2) and the newest, each with numpy 1.26 and numpy 2.x, make a throwaway virtual environment,
# install the core package (no extras, no torch) with those versions plus the test tools, and run the
# core tests from the checkout. Prints one line per combination (pass/FAIL, versions, seconds) and
# exits non-zero if any combination fails.
#
#   bash scripts/check_versions.sh              # every combination
#   bash scripts/check_versions.sh 1.1.1:1.26.4 # only these (gymnasium:numpy[:scipy[:numba[:rl]]]), space-separated
#
# A combination with a numba version also installs numba (the `fast` extra's compiled kernels) and
# runs the tests that hold the compiled numbers to numpy's as well. One whose fifth field is `rl`
# installs the `rl` extra at the oldest versions it declares (torch: the 2.13.0 CPU build, the only
# one these machines have) and runs the agents' tests too (without Ray and pomdp_py: they skip).
#
# Environment: PYTHON (the interpreter for the venvs; default .venv/bin/python, else python3),
# KEEP=1 keeps the temporary directory, JOBS (pytest-xdist workers per run; default 2).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)

if [ -n "${PYTHON:-}" ]; then PY=$PYTHON
elif [ -x .venv/bin/python ]; then PY=.venv/bin/python
else PY=python3
fi
JOBS=${JOBS:-2}
PER_RUN_TIMEOUT=${PER_RUN_TIMEOUT:-420}

# gymnasium:numpy. 1.1.1 is the newest 1.1.x (the oldest series pyproject claims); 1.2.2 is the
# version RLlib pins; the newest is whatever pip resolves for "gymnasium>=1.1,<2" (empty = unpinned).
# The last is the oldest of every declared range (gymnasium 1.1, numpy 1.24, scipy 1.10) with the
# oldest numba the `fast` extra claims (0.60): numpy before 2.4 reduces a long row buffer by
# buffer, and the compiled kernels' numbers must match it too.
# The `rl` one: the agents' oldest declared dependencies, on numpy 2.0 (the extra needs numpy 2).
COMBOS=("1.1.1:1.26.4" "1.1.1:2" "1.2.2:1.26.4" "1.2.2:2" ":1.26.4" ":2" "1.1.1:1.24.4:1.10.1:0.60.0"
        "1.1.1:2.0.2:::rl")
if [ "$#" -gt 0 ]; then COMBOS=("$@"); fi

TESTS=(tests/core tests/test_engine.py tests/test_filter.py tests/envs)
# What these tests need beyond the core install:
# - pygame-ce: gymnasium's check_env (tests/envs/test_registry.py) renders every declared render mode,
#   `human` included, on every gymnasium version from 1.1 to the newest; without pygame the env's
#   human mode raises an ImportError that names the render extra.
# - tqdm: tests/test_filter.py imports scripts/long_run.py, which imports tqdm.
TEST_TOOLS=(pytest pytest-xdist hypothesis pygame-ce tqdm)
# With numba: the compiled kernels' tests against numpy and the vector env's.
NUMBA_TESTS=(tests/test_kernels.py tests/test_readout.py tests/test_vector.py tests/test_generators.py)
# With `rl`: the extra's oldest declared versions (pyproject.toml), torch first (an unpinned torch
# resolves to a CUDA build), and the agents' tests.
RL_TORCH="torch==2.13.0"
RL_OLDEST=("stable-baselines3==2.9.0" "sb3-contrib==2.9.0" "tqdm==4.60.0" "rich==13.0.0" "pyyaml==6.0"
           "matplotlib==3.8.4" "tensorboard==2.14.0")
RL_TESTS=(tests/agents)

TMP=$(mktemp -d "${TMPDIR:-/tmp}/gridloc-versions.XXXXXX")
if [ "${KEEP:-0}" != 1 ]; then trap 'rm -rf "$TMP"' EXIT; fi

# The package is built once, as a wheel, from a copy of its sources (nothing is written into the
# checkout); every venv installs that wheel, so pip checks our declared ranges against each pin.
mkdir -p "$TMP/src" "$TMP/dist"
cp -r pyproject.toml README.md LICENSE gym_gridloc agents "$TMP/src/"
find "$TMP/src" -name __pycache__ -prune -exec rm -rf {} +
"$PY" -m pip wheel -q --no-deps -w "$TMP/dist" "$TMP/src" >"$TMP/wheel.log" 2>&1 || { cat "$TMP/wheel.log"; exit 1; }
WHEEL=$(ls "$TMP"/dist/gym_gridloc-*.whl)

failed=0
total_start=$(date +%s)
printf '%-10s %-8s %-40s %s\n' "result" "seconds" "gymnasium / numpy / scipy" "log"
for combo in "${COMBOS[@]}"; do
    IFS=: read -r gym_v np_v scipy_v numba_v rl <<<"$combo"
    name="gym${gym_v:-newest}-np${np_v}${scipy_v:+-scipy$scipy_v}${numba_v:+-numba$numba_v}${rl:+-$rl}"
    venv="$TMP/$name"
    log="$TMP/$name.log"
    start=$(date +%s)
    gym_req="gymnasium>=1.1,<2"; [ -n "$gym_v" ] && gym_req="gymnasium==$gym_v"
    case "$np_v" in
        2) np_req="numpy>=2,<3" ;;
        *) np_req="numpy==$np_v" ;;
    esac
    scipy_req="scipy"; [ -n "${scipy_v:-}" ] && scipy_req="scipy==$scipy_v"
    extra=(); tests=("${TESTS[@]}")
    if [ -n "${numba_v:-}" ]; then extra=("numba==$numba_v"); tests+=("${NUMBA_TESTS[@]}"); fi
    pkg="$WHEEL"
    if [ "${rl:-}" = rl ]; then pkg="$WHEEL[rl]"; extra+=("${RL_OLDEST[@]}"); tests+=("${RL_TESTS[@]}"); fi
    ok=1
    {
        "$PY" -m venv --without-pip "$venv"
        if [ "${rl:-}" = rl ]; then "$PY" -m pip --python "$venv/bin/python" install -q "$RL_TORCH" "$np_req"; fi
        # the outer pip installs into the venv (fast: no pip inside each venv)
        "$PY" -m pip --python "$venv/bin/python" install -q "$pkg" "$gym_req" "$np_req" \
            "$scipy_req" "${extra[@]}" "${TEST_TOOLS[@]}"
        "$venv/bin/python" -c 'import gymnasium, numpy, scipy; print("versions", gymnasium.__version__, numpy.__version__, scipy.__version__)'
    } >"$log" 2>&1 || ok=0
    if [ "$ok" = 1 ]; then
        xdist=(); [ "$JOBS" -gt 1 ] && xdist=(-n "$JOBS")
        # from the checkout, with the venv's python: the tests import the checkout's gym_gridloc,
        # which is the same code as the installed wheel; the dependencies are the venv's
        timeout "$PER_RUN_TIMEOUT" "$venv/bin/python" -m pytest -q -p no:cacheprovider "${xdist[@]}" \
            "${tests[@]}" >>"$log" 2>&1 || ok=0
    fi
    seconds=$(( $(date +%s) - start ))
    versions=$(grep -m1 '^versions ' "$log" | cut -d' ' -f2- | sed 's/ / \/ /g' || true)
    [ -n "${numba_v:-}" ] && versions="${versions:-?} + numba $numba_v"
    [ "${rl:-}" = rl ] && versions="${versions:-?} + oldest rl"
    summary=$(grep -E '(passed|failed|error)' "$log" | tail -1 || true)
    if [ "$ok" = 1 ]; then
        printf '%-10s %-8s %-40s %s\n' "pass" "$seconds" "${versions:-?}" "$summary"
    else
        failed=1
        printf '%-10s %-8s %-40s %s\n' "FAIL" "$seconds" "${versions:-$combo}" "${summary:-install failed}"
        echo "---- $name: the last 40 lines of its log ----"
        tail -40 "$log"
        echo "----"
    fi
done
echo "check_versions: ${#COMBOS[@]} combinations in $(( $(date +%s) - total_start )) s"
exit "$failed"
