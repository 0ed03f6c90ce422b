#!/usr/bin/env bash
# One-time set-up, idempotent: system libLLVM >= 16 for Dr.Jit's LLVM backend, then .venv with
# torch 2.13.0 (CPU build), Mitsuba 3 and the rest. A second run skips what is already done.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}

# --- libLLVM: Dr.Jit 1.5 needs >= 15; Debian's 14 and 15 crash it, so we want >= 16 (libllvm19).
newest_llvm() {
    # prints "MAJOR PATH" for the newest libLLVM shared object found, or nothing
    for d in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib64 /usr/lib /usr/local/lib \
             /usr/lib/llvm-*/lib /opt/homebrew/opt/llvm/lib /usr/local/opt/llvm/lib; do
        ls "$d"/libLLVM*.so* "$d"/libLLVM*.dylib 2>/dev/null || true
    done | sed -n 's/.*libLLVM[-.]\{0,1\}\([0-9][0-9]*\).*/\1 &/p' | sort -n -k1,1 | tail -n 1
}
found=$(newest_llvm)
major=${found%% *}
if [ -z "$found" ] || [ "$major" -lt 16 ]; then
    echo "setup: no usable system libLLVM (newest: ${found:-none}); Dr.Jit's llvm_ad_rgb needs libLLVM >= 16 here"
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing libllvm19 with apt-get"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
        found=$(newest_llvm)
    else
        cat >&2 <<MSG
setup: cannot install libLLVM here (needs root and apt-get). Install it yourself, then re-run:
    Debian/Ubuntu: sudo apt-get install libllvm19      Fedora: sudo dnf install llvm-libs
    macOS: brew install llvm
or point DRJIT_LIBLLVM_PATH at a libLLVM.so of version >= 16. A CUDA GPU (cuda_ad_rgb) needs no libLLVM.
MSG
        [ -n "${DRJIT_LIBLLVM_PATH:-}" ] || exit 1
    fi
fi
echo "setup: libLLVM ${found:-from DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-}}"

# --- virtual environment and packages; the stamp holds a hash of pyproject.toml.
[ -x "$VENV/bin/python" ] || { echo "setup: creating $VENV"; "$PY" -m venv "$VENV"; }
stamp="$VENV/.nlosbench-installed"
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    # torch first and pinned: a bare 'torch' would pull GBs of CUDA wheels.
    "$VENV/bin/pip" install -q --disable-pip-version-check torch==2.13.0
    "$VENV/bin/pip" install -q --disable-pip-version-check -e ".[dev,dask]"
    echo "$want" > "$stamp"
    echo "setup: installed packages into $VENV"
else
    echo "setup: $VENV up to date"
fi
