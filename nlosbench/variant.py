"""Mitsuba variant selection: `cuda_ad_rgb` when a CUDA GPU works, `llvm_ad_rgb` otherwise.

Override with the environment variable NLOSBENCH_VARIANT or `select(variant)` (configs pass theirs).
Dr.Jit's LLVM backend needs a system libLLVM; Debian's 14 and 15 crash Dr.Jit 1.5, so before Mitsuba
is imported we point DRJIT_LIBLLVM_PATH at the newest libLLVM found (unless the user already set it).
"""
from __future__ import annotations

import glob
import os
import re

from . import interrupts

MIN_LLVM = 16
_SEARCH = ["/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
           "/usr/local/lib", "/usr/lib/llvm-*/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib"]
_FIX = ("install a newer libLLVM (Debian/Ubuntu: `apt-get install libllvm19`; macOS: `brew install llvm`) "
        f"or set DRJIT_LIBLLVM_PATH to a libLLVM of version >= {MIN_LLVM}; `make setup` does this when run as root")


class VariantError(RuntimeError):
    """No usable Mitsuba variant; the message names the fix."""


def newest_libllvm() -> tuple[int, str] | None:
    """(major version, path) of the newest libLLVM shared library on this system, or None."""
    found = []
    for d in _SEARCH:
        for p in glob.glob(os.path.join(d, "libLLVM*.so*")) + glob.glob(os.path.join(d, "libLLVM*.dylib")):
            m = re.search(r"libLLVM[-.]?(\d+)", os.path.basename(p))
            if m:
                found.append((int(m.group(1)), p))
    return max(found) if found else None


def configure_libllvm() -> str | None:
    """Set DRJIT_LIBLLVM_PATH to the newest libLLVM unless already set; return the path used."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    best = newest_libllvm()
    if best is None:
        return None
    os.environ["DRJIT_LIBLLVM_PATH"] = best[1]
    return best[1]


def _llvm_problem() -> str | None:
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        m = re.search(r"libLLVM[-.]?(\d+)", os.path.basename(path))
        if m and int(m.group(1)) < MIN_LLVM:
            return f"DRJIT_LIBLLVM_PATH points at libLLVM {m.group(1)} ({path}), which crashes Dr.Jit 1.5"
        return None
    return "no libLLVM found on this system"


_selected: str | None = None


def select(variant: str | None = None) -> str:
    """Activate and return a Mitsuba variant. Order: argument, $NLOSBENCH_VARIANT, cuda_ad_rgb, llvm_ad_rgb.

    Calling it again with the same (or no) variant is free; a different variant switches Mitsuba over.
    Every model load calls it; call it yourself before using Mitsuba directly.

    Parameters
    ----------
    variant : str, optional
        A Mitsuba variant name (``"llvm_ad_rgb"``); default: $NLOSBENCH_VARIANT, else the first of
        cuda_ad_rgb and llvm_ad_rgb that loads.

    Returns
    -------
    str
        The active variant.

    Examples
    --------
    >>> nb.variant.select() in ("cuda_ad_rgb", "llvm_ad_rgb")
    True
    """
    want = variant or os.environ.get("NLOSBENCH_VARIANT")
    if _selected is not None and want in (None, _selected):
        return _selected
    with interrupts.deferred():  # a Ctrl-C in the middle of a native import is held until it ends
        return _activate(want)


def _activate(want: str | None) -> str:
    """`select`'s work: import Mitsuba and activate the first usable candidate; an interrupt is re-raised as such."""
    global _selected
    configure_libllvm()
    import mitsuba as mi

    candidates = [want] if want else ["cuda_ad_rgb", "llvm_ad_rgb"]
    errors = []
    for v in candidates:
        if v not in mi.variants():
            errors.append(f"{v}: not in this Mitsuba build (has {', '.join(mi.variants())})")
            continue
        if v.startswith("llvm"):
            problem = _llvm_problem()
            if problem:
                errors.append(f"{v}: {problem}; {_FIX}")
                continue
        try:
            mi.set_variant(v)
            import drjit as dr

            if v.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
                raise RuntimeError("no usable CUDA device")
            if v.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
                raise RuntimeError(f"Dr.Jit could not load libLLVM; {_FIX}")
        except Exception as e:  # noqa: BLE001 - every failure is reported with its fix below (an interrupt is not one)
            stop = interrupts.interrupt_in(e)
            if stop is not None:  # a Ctrl-C wrapped by the binding: the user's, not a reason the variant is unusable
                raise stop from None
            errors.append(f"{v}: {e}")
            continue
        _selected = v
        return v
    raise VariantError("no usable Mitsuba variant:\n  " + "\n  ".join(errors))
