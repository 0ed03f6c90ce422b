#!/usr/bin/env bash
# Run the test suite against one end of the supported Mitsuba / Dr.Jit range, in a fresh venv.
#
#   scripts/check_versions.sh lowest             # mitsuba / drjit at the minimum in pyproject.toml
#   scripts/check_versions.sh highest            # the newest release the range in pyproject.toml admits
#   scripts/check_versions.sh 3.8.0 1.3.1        # any other pair (mitsuba pins its own drjit exactly)
#   scripts/check_versions.sh lowest -- -k bounds   # arguments after -- go to pytest (default: -q -x)
#
# Environment: CHECK_VENV (default /tmp/nlosbench-check-LABEL, recreated each run), PYTHON (python3),
# NLOSBENCH_TORCH (default torch==2.13.0: the CPU wheel; give your own spec, e.g. a CUDA build, to test with it).
# torch, mitsuba and drjit are installed first and then pinned by a constraints file, so installing
# nlosbench itself cannot move them. The last line printed is a row for docs/versions.md.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)

usage() { sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; }
[ $# -ge 1 ] || usage
which=$1; shift
drjit_arg=""
if [ $# -ge 1 ] && [ "$1" != "--" ]; then drjit_arg=$1; shift; fi
[ "${1:-}" = "--" ] && shift
pytest_args=("$@")
[ ${#pytest_args[@]} -gt 0 ] || pytest_args=(-q -x)

# the requirement strings of pyproject.toml's [project] dependencies, e.g. mitsuba>=3.7.0,<3.10
requirement() { sed -n "s/^ *\"\($1[<>=!~][^\"]*\)\",.*/\1/p" pyproject.toml | head -n 1; }
minimum() { requirement "$1" | sed -n 's/.*>=\([0-9][0-9.]*\).*/\1/p'; }

case "$which" in
    lowest)  label=lowest;  want=("mitsuba==$(minimum mitsuba)" "drjit==$(minimum drjit)") ;;
    highest) label=highest; want=("$(requirement mitsuba)" "$(requirement drjit)") ;;
    [0-9]*)  label="mitsuba-$which"; want=("mitsuba==$which"); [ -z "$drjit_arg" ] || want+=("drjit==$drjit_arg") ;;
    *) usage ;;
esac
for w in "${want[@]}"; do
    case "$w" in mitsuba==|drjit==|"") echo "check_versions: cannot read the range from pyproject.toml" >&2; exit 2 ;; esac
done

VENV=${CHECK_VENV:-/tmp/nlosbench-check-$label}
PY=${PYTHON:-python3}
TORCH=${NLOSBENCH_TORCH:-torch==2.13.0}
pip() { "$VENV/bin/python" -m pip --disable-pip-version-check "$@"; }

echo "check_versions: fresh venv $VENV; installing $TORCH, then ${want[*]}"
rm -rf "$VENV"
"$PY" -m venv "$VENV"
pip install -q "$TORCH"
pip install -q "${want[@]}"
pip freeze | grep -iE '^(torch|mitsuba|drjit)==' > "$VENV/constraints.txt"
pip install -q -c "$VENV/constraints.txt" -e ".[dev,dask]"

versions=$("$VENV/bin/python" - <<'EOF'
import platform, drjit, mitsuba, torch
print(f"python {platform.python_version()} | torch {torch.__version__} | mitsuba {mitsuba.__version__} | drjit {drjit.__version__}")
EOF
)
echo "check_versions: $versions"

log="$VENV/pytest.log"
set +e
(cd "$ROOT" && "$VENV/bin/python" -m pytest "${pytest_args[@]}" -p no:cacheprovider) 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
set -e
summary=$(grep -E '^=* ?[0-9]+ (passed|failed|error)|^=+ .*(passed|failed|error).* =+$|^[0-9]+ (passed|failed)' "$log" | tail -n 1 \
          | sed 's/^=* *//; s/ *=*$//')
cpu=$(sed -n 's/^model name\s*: //p' /proc/cpuinfo 2>/dev/null | head -n 1)
machine="$(uname -s) $(uname -m), $(nproc) cores${cpu:+ ($cpu)}, $(command -v nvidia-smi >/dev/null && nvidia-smi -L 2>/dev/null | head -n 1 || echo 'no GPU')"
echo
echo "check_versions: exit $rc; log $log"
echo "| $label | $(date -u +%Y-%m-%d) | $versions | ${summary:-no summary (exit $rc)} | $machine |"
exit "$rc"
