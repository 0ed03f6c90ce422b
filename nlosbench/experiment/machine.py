"""machine.json: what a run was measured on and what it cost, written by the run itself when it finishes.

The machine (CPU model, cores, memory, GPU if any), the Mitsuba variant and package versions, what decided the
renders' bits (`render`: Dr.Jit's LLVM target, libLLVM, the host's ISA, from the run's fingerprint), the wall time
and renders per study, the command that made the run (its config path relative to the repository when inside it,
every `--set`, `--out`), and the machine's load: the 1-, 5- and 15-minute load averages (runnable processes, so 2.0
fills 2 cores) when the run started and after each study, and their largest 1-minute value, so a time measured on
a shared machine says so. A record that says the wrong thing is re-made by re-running, never edited.
"""
from __future__ import annotations

import os
import platform
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else what `platform` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def memory_gib() -> float | None:
    """Total memory in GiB (Linux /proc/meminfo), None elsewhere."""
    try:
        kb = int(next(x for x in Path("/proc/meminfo").read_text().splitlines() if x.startswith("MemTotal")).split()[1])
        return round(kb / 2 ** 20, 1)
    except (OSError, StopIteration, ValueError):
        return None


def load() -> list[float] | None:
    """The 1-, 5- and 15-minute load averages, rounded to 0.01; None where the system has none."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def command(config: str | Path, overrides=(), out: str | Path | None = None, smoke: bool = False) -> str:
    """The `nlosbench run` line that makes this run: the config relative to the repository when inside it (else as
    given), each override as `--set`, `--smoke`, and `--out`."""
    path = Path(config).resolve()
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else Path(config)
    parts = ["nlosbench", "run", str(shown)] + [a for o in overrides for a in ("--set", o)]
    parts += ["--smoke"] if smoke else []
    parts += ["--out", str(out)] if out is not None else []
    variant = os.environ.get("NLOSBENCH_VARIANT")
    return (f"NLOSBENCH_VARIANT={variant} " if variant else "") + shlex.join(parts)


def render_key(fingerprint: dict) -> dict | None:
    """The render identity a run recorded (its fingerprint's model key, under `render`), or None."""
    key = fingerprint.get("model")
    while isinstance(key, dict) and "render" not in key and "base" in key:  # a restricted or binned model
        key = key["base"]
    return key.get("render") if isinstance(key, dict) else None


def host() -> dict:
    """The machine: CPU model, cores, memory, GPU (None without one), the Mitsuba variant and package versions."""
    import drjit
    import mitsuba
    import numpy
    import torch

    from .. import variant

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "memory_gib": memory_gib(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "variant": mitsuba.variant() or variant.select(),
        "versions": {"python": platform.python_version(), "mitsuba": mitsuba.__version__,
                     "drjit": drjit.__version__, "torch": torch.__version__, "numpy": numpy.__version__},
    }


def describe(results: dict, fingerprint: dict, cmd: str, loads: dict) -> dict:
    """machine.json's content for a finished run (results.json's dict, fingerprint.json's dict, the command, the
    load averages {"start": [...], study id: [...]})."""
    studies = results.get("studies", {})
    ones = [v[0] for v in loads.values() if v]
    return {
        **host(),
        "seconds_total": results.get("seconds_total"),
        "studies": {k: {"seconds": v.get("seconds"), "renders": (v.get("results") or {}).get("renders")}
                    for k, v in studies.items()},
        "load": {"averages": loads, "max_1min": max(ones) if ones else None},
        "render": render_key(fingerprint),
        "command": cmd,
    }
