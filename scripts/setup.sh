#!/usr/bin/env bash
# One-time set-up, idempotent: system libLLVM >= 16 for Dr.Jit's LLVM backend, then .venv with
# torch, Mitsuba 3 and the rest. A second run skips what is already done.
# torch: a torch already in the venv (a CUDA build, say) is kept and pinned while nlosbench installs;
# only a venv without torch gets $NLOSBENCH_TORCH (default torch==2.13.0): a wheel on disk if pip finds one
# there, else PyPI's build where an NVIDIA GPU is present, else the CPU build (PyTorch's CPU index added).
# Sourcing this file (tests do) defines the functions without running anything.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
TORCH=${NLOSBENCH_TORCH:-torch==2.13.0}
TORCH_CPU_INDEX=${NLOSBENCH_TORCH_CPU_INDEX:-https://download.pytorch.org/whl/cpu}

# --- libLLVM: Dr.Jit 1.5 needs >= 15; Debian's 14 and 15 crash it, so we want >= 16 (libllvm19).
newest_llvm() {
    # prints "MAJOR PATH" for the newest libLLVM shared object found, or nothing
    for d in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib64 /usr/lib /usr/local/lib \
             /usr/lib/llvm-*/lib /opt/homebrew/opt/llvm/lib /usr/local/opt/llvm/lib; do
        ls "$d"/libLLVM*.so* "$d"/libLLVM*.dylib 2>/dev/null || true
    done | sed -n 's/.*libLLVM[-.]\{0,1\}\([0-9][0-9]*\).*/\1 &/p' | sort -n -k1,1 | tail -n 1
}

check_llvm() {
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
}

# --- torch: which one the venv has (read from its metadata, without importing torch)
installed_torch() {
    # prints the version of torch installed in the venv $1 (e.g. 2.13.0+cpu, 2.6.0+cu124), or nothing
    "$1/bin/python" -c 'import importlib.metadata as m
try: print(m.version("torch"))
except m.PackageNotFoundError: pass'
}

has_nvidia_gpu() {
    [ -e /dev/nvidia0 ] || { command -v nvidia-smi >/dev/null && nvidia-smi -L >/dev/null 2>&1; }
}

install_torch() {
    local pip=("$VENV/bin/pip" --disable-pip-version-check) probe on_disk=0
    probe=$(mktemp -d)
    # a wheel of $TORCH on this disk (pip's find-links)? `download --no-deps` looks without fetching anything
    if "${pip[@]}" download -q --no-index --no-deps -d "$probe" "$TORCH" >/dev/null 2>&1; then on_disk=1; fi
    rm -rf "$probe"
    if ((on_disk)); then
        echo "setup: $TORCH from a wheel on this disk"
        "${pip[@]}" install -q "$TORCH"        # pip takes the local build (e.g. 2.13.0+cpu sorts above 2.13.0)
    elif has_nvidia_gpu; then
        echo "setup: NVIDIA GPU found: $TORCH from the package index (a CUDA build)"
        "${pip[@]}" install -q "$TORCH"
    else
        echo "setup: no NVIDIA GPU: $TORCH's CPU build from $TORCH_CPU_INDEX"
        "${pip[@]}" install -q --extra-index-url "$TORCH_CPU_INDEX" "$TORCH"   # +cpu sorts above PyPI's build
    fi
}

# --- virtual environment and packages; the stamp holds a hash of pyproject.toml.
install_packages() {
    [ -x "$VENV/bin/python" ] || { echo "setup: creating $VENV"; "$PY" -m venv "$VENV"; }
    local stamp="$VENV/.nlosbench-installed" want have pins="$VENV/.nlosbench-torch-pin.txt"
    want=$(sha256sum pyproject.toml | cut -d' ' -f1)
    if [ "$(cat "$stamp" 2>/dev/null)" = "$want" ]; then
        echo "setup: $VENV up to date"
        return 0
    fi
    have=$(installed_torch "$VENV")
    if [ -n "$have" ]; then
        echo "setup: keeping the torch $have in $VENV"
    else
        # pinned, and from where: a bare 'torch' (or a range), or even the pinned one from PyPI on Linux
        # x86-64, is a CUDA build of several GB. So: a wheel already on disk (pip's find-links) first; then,
        # on a machine with an NVIDIA GPU, PyPI's build; on any other machine the CPU build.
        echo "setup: no torch in $VENV; installing $TORCH"
        install_torch
        have=$(installed_torch "$VENV")
        [ -n "$have" ] || { echo "setup: installing $TORCH left no torch in $VENV" >&2; return 1; }
    fi
    # The installed torch is a constraint: pip may not upgrade or replace it to satisfy pyproject.toml.
    echo "torch==$have" > "$pins"
    if ! "$VENV/bin/pip" install -q --disable-pip-version-check -c "$pins" -e ".[dev,dask,docs,transient,search]"; then
        echo "setup: pip could not install nlosbench next to torch $have (pyproject.toml asks for" \
             "$(sed -n 's/^ *"\(torch[<>=!~][^"]*\)".*/\1/p' pyproject.toml)); upgrade torch yourself (the build you" \
             "want, e.g. from the PyTorch index for your CUDA), then re-run" >&2
        return 1
    fi
    echo "$want" > "$stamp"
    echo "setup: installed packages into $VENV (torch $have)"
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    check_llvm
    install_packages
fi
