"""The code-generation target of Dr.Jit's LLVM backend (the CPU variants): read it, or pin a portable one.

Dr.Jit compiles its kernels for the host, like `-march=native`: LLVM's name for the host CPU (e.g.
`znver5`), its feature list, and a vector width of 16 with AVX-512 (8 with AVX, 4 with SSE 4.2). The
target changes a render's last bits, and through them Monte Carlo paths (pi_hallway 40×30, 96 spp on an
AMD EPYC, znver5 at width 16 against the portable target: 2890 of 3600 values differ, by up to 3.7e-3):

- at width 16 on an AVX-512 host, 1/√x is `vrsqrt14ps` plus a Newton step; at width 8 on an AVX host,
  `vrsqrtps` plus a Newton step (an approximation whose bits the CPU vendor decides); at any other
  width, an exact `sqrt(1/x)`;
- vector sums are emitted with `reassoc`, so LLVM orders them for the target's registers.

`pin("portable")` sets x86-64-v3 (AVX2 and FMA: every x86-64 CPU since Intel Haswell and AMD Zen 1)
at width 4 (`PORTABLE`): no approximate instruction, no AVX-512, the same kernels on every such CPU for a
given libLLVM. Width 4, not 8, because width 8 brings back `vrsqrtps` (and costs about the same: ×1.73
against ×1.81 CPU time per render over the native AVX-512 target, measured side by side). Width 16 with
an AVX2 CPU is no option: Dr.Jit still emits the AVX-512 intrinsic on an AVX-512 host and LLVM aborts.
Dr.Jit 1.5 has no Python call for this; libdrjit-core exports `jit_llvm_set_target(cpu, features, width)`
(C++ linkage), called here through ctypes. It takes effect for kernels compiled afterwards, so it is
applied once per process, before the first scene is loaded (`MitsubaModel` does it); asking for another
target later in the same process is an error.

Not pinned by this: Embree, Mitsuba's ray–triangle intersector on the CPU (meshes: `cube`, `ply`, `obj`;
`rectangle`, `sphere` and `disk` are Mitsuba's own code), picks its kernels by the host's ISA (SSE 4.2,
AVX, AVX2, AVX-512) at run time, and its triangle tests scale t, u, v by an approximate reciprocal
(`rcp`); Mitsuba passes Embree no option to fix the ISA.
`identity.render_identity` therefore keeps the host's ISA level and CPU vendor in every key.

Choose with the `scene.llvm_target` config key or the environment variable NLOSBENCH_LLVM_TARGET
(`native`, the default, or `portable`).
"""
from __future__ import annotations

import ctypes
import os
import platform
from dataclasses import asdict, dataclass
from functools import cache

from .. import variant as _variant

ENV = "NLOSBENCH_LLVM_TARGET"
CHOICES = ("native", "portable")


@dataclass(frozen=True)
class Target:
    """An LLVM code-generation target: CPU name, feature list ('' = the CPU's own), vector width (lanes)."""

    cpu: str
    features: str
    width: int

    def as_dict(self) -> dict:
        return asdict(self)


#: the portable target (see the module docstring for why width 4)
PORTABLE = Target("x86-64-v3", "", 4)


class TargetError(ValueError):
    """The LLVM target cannot be set as asked (a bad `llvm_target` for this CPU or process); one line."""


@cache
def _core() -> ctypes.CDLL:
    """libdrjit-core with the target functions typed (Dr.Jit imported first, its libLLVM configured)."""
    _variant.configure_libllvm()
    import drjit

    lib = ctypes.CDLL(os.path.join(os.path.dirname(drjit.__file__), "libdrjit-core.so"))
    try:
        lib.set_target = lib._Z19jit_llvm_set_targetPKcS0_j
        lib.cpu = lib._Z19jit_llvm_target_cpuv
        lib.features = lib._Z24jit_llvm_target_featuresv
        lib.width = lib._Z21jit_llvm_vector_widthv
        lib.version = lib._Z16jit_llvm_versionPiS_S_
    except AttributeError as e:
        raise TargetError(f"this Dr.Jit build ({drjit.__version__}) does not export the LLVM target functions "
                          f"({e}); the LLVM target cannot be read or pinned") from None
    lib.set_target.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    lib.cpu.restype = lib.features.restype = ctypes.c_char_p
    lib.width.restype = ctypes.c_uint32
    return lib


def current() -> Target | None:
    """The target Dr.Jit compiles LLVM kernels for now, or None when the LLVM backend is not loaded."""
    lib = _core()
    width = int(lib.width())
    if width == 0:
        return None
    return Target((lib.cpu() or b"").decode(), (lib.features() or b"").decode(), width)


def llvm_version() -> str | None:
    """The libLLVM version Dr.Jit loaded ('19.1.7'), or None when the LLVM backend is not loaded."""
    lib = _core()
    v = [ctypes.c_int(-1) for _ in range(3)]
    lib.version(*(ctypes.byref(x) for x in v))
    return None if v[0].value < 0 else ".".join(str(x.value) for x in v)


_fixed: str | None = None  # the target this process was pinned to (first `pin` call)


def requested(name: str | None = None) -> str:
    """The target asked for: `name`, else $NLOSBENCH_LLVM_TARGET, else 'native'; ValueError if unknown."""
    name = name or os.environ.get(ENV) or "native"
    if name not in CHOICES:
        src = "llvm_target" if name != os.environ.get(ENV) else ENV
        raise ValueError(f"{src} is {name!r}; expected one of {', '.join(CHOICES)}")
    return name


def pin(name: str | None = None) -> str:
    """Fix this process's LLVM target (`requested(name)`) before any kernel; return its name.

    Calling it again with the same target, or with None once a target is fixed, is free; another target
    raises TargetError (kernels already compiled for the first would mix with the second). 'portable' on a
    CPU that is not x86-64 with AVX2 and FMA raises TargetError."""
    global _fixed
    if name is None and _fixed is not None:
        return _fixed
    name = requested(name)
    if _fixed is not None:
        if name != _fixed:
            raise TargetError(f"the LLVM target of this process is already {_fixed!r}; {name!r} needs a new "
                              f"process (set {ENV}={name} before starting it)")
        return name
    if name == "portable":
        if platform.machine().lower() not in ("x86_64", "amd64") or not {"avx2", "fma"} <= _cpu_flags():
            raise TargetError(f"the portable LLVM target ({PORTABLE.cpu}: AVX2 and FMA) needs an x86-64 CPU "
                              f"with AVX2 and FMA; this is {platform.machine()}: use llvm_target native")
        lib = _core()
        if current() is None:
            raise TargetError("Dr.Jit's LLVM backend is not loaded, so its target cannot be pinned")
        lib.set_target(PORTABLE.cpu.encode(), PORTABLE.features.encode() or None, PORTABLE.width)
        got = current()
        if (got.cpu, got.width) != (PORTABLE.cpu, PORTABLE.width):
            raise TargetError(f"Dr.Jit did not take the LLVM target {PORTABLE.cpu}/{PORTABLE.width} "
                              f"(it reports {got.cpu}/{got.width})")
    _fixed = name
    return name


def pinned() -> str | None:
    """The name this process was pinned to, or None before the first `pin`."""
    return _fixed


@cache
def _cpu_flags() -> frozenset[str]:
    """The host CPU's flags from /proc/cpuinfo (Linux; empty elsewhere)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


@cache
def host_isa() -> dict:
    """The host's vector ISA level as Embree dispatches on it, and the CPU vendor: {'isa', 'vendor'}."""
    flags = _cpu_flags()
    levels = [("avx512", {"avx512f", "avx512dq", "avx512cd", "avx512bw", "avx512vl"}), ("avx2", {"avx2", "fma"}),
              ("avx", {"avx"}), ("sse4.2", {"sse4_2"})]
    isa = next((name for name, need in levels if need <= flags), platform.machine())
    vendor = ""
    try:
        with open("/proc/cpuinfo") as f:
            vendor = next((x.split(":", 1)[1].strip() for x in f if x.startswith(("vendor_id", "CPU implementer"))),
                          "")
    except OSError:
        pass
    return {"isa": isa, "vendor": vendor}
