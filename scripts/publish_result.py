"""Copy a finished run into results/<name>/ for committing: report.md, results.json, config.yaml, every CSV
and PNG (no EXR, no render cache, no JSONL logs), plus machine.json (CPU, cores, memory, GPU if any, the
Mitsuba variant, package versions, what decided the renders' bits as the run recorded it in its fingerprint
(`render`: Dr.Jit's LLVM target, libLLVM, the host's ISA), the run's wall time and renders per study, the
command that made it).

    python scripts/publish_result.py runs/demo quick --config configs/quick.yaml
    python scripts/publish_result.py runs/x x --config configs/x.yaml --command "nlosbench run … --set seed=1 …"

The run must be finished (results.json present, every study "done"); an existing results/<name>/ is
replaced only after the new copy is complete (written beside it, then renamed).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEEP = (".md", ".csv", ".png", ".json", ".yaml")
SKIP_DIRS = {"renders", "images", "views", "cache"}


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gib() -> float | None:
    try:
        kb = int(next(x for x in Path("/proc/meminfo").read_text().splitlines() if x.startswith("MemTotal")).split()[1])
        return round(kb / 2 ** 20, 1)
    except (OSError, StopIteration, ValueError):
        return None


def render_identity(run_dir: Path) -> dict | None:
    """The render identity the run recorded (its fingerprint's model key, under `render`), or None."""
    try:
        key = json.loads((run_dir / "fingerprint.json").read_text())["model"]
    except (OSError, ValueError, KeyError):
        return None
    while isinstance(key, dict) and "render" not in key and "base" in key:  # a restricted or binned model
        key = key["base"]
    return key.get("render") if isinstance(key, dict) else None


def machine(run: dict) -> dict:
    """What the run was measured on and what it cost."""
    import drjit
    import mitsuba
    import numpy
    import torch

    import nlosbench

    studies = run.get("studies", {})
    return {
        "cpu": _cpu(),
        "cores": os.cpu_count(),
        "memory_gib": _memory_gib(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "variant": mitsuba.variant() or nlosbench.variant.select(),
        "versions": {"python": platform.python_version(), "mitsuba": mitsuba.__version__,
                     "drjit": drjit.__version__, "torch": torch.__version__, "numpy": numpy.__version__},
        "seconds_total": run.get("seconds_total"),
        "studies": {k: {"seconds": v.get("seconds"), "renders": (v.get("results") or {}).get("renders")}
                    for k, v in studies.items()},
    }


def publish(run_dir: Path, name: str, config: str | None, dest_root: Path = ROOT / "results",
            command: str | None = None) -> Path:
    results = run_dir / "results.json"
    if not results.is_file():
        raise SystemExit(f"{run_dir}: no results.json (is the run finished?)")
    run = json.loads(results.read_text())
    unfinished = [k for k, v in run.get("studies", {}).items() if v.get("status") != "done"]
    if unfinished:
        raise SystemExit(f"{run_dir}: studies not done: {unfinished}")
    dest_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=dest_root))
    for src in sorted(run_dir.rglob("*")):
        rel = src.relative_to(run_dir)
        if src.is_file() and src.suffix in KEEP and not SKIP_DIRS.intersection(rel.parts[:-1]):
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, tmp / rel)
    info = machine(run) | {"render": render_identity(run_dir),
                           "command": command or (f"nlosbench run {config} --out runs/{Path(config).stem}"
                                                  if config else None)}
    (tmp / "machine.json").write_text(json.dumps(info, indent=2) + "\n")
    dest = dest_root / name
    if dest.exists():
        old = dest.with_name(f".{name}-old")
        shutil.rmtree(old, ignore_errors=True)
        dest.rename(old)
        tmp.rename(dest)
        shutil.rmtree(old)
    else:
        tmp.rename(dest)
    return dest


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", type=Path, help="a finished run folder (with results.json)")
    p.add_argument("name", help="folder name under results/")
    p.add_argument("--config", default=None, help="the config the run came from (recorded in machine.json)")
    p.add_argument("--command", default=None, help="the command that made the run, as recorded in machine.json "
                   "(default: `nlosbench run CONFIG --out runs/STEM`)")
    p.add_argument("--into", type=Path, default=ROOT / "results", help="the folder that receives NAME (default: "
                   "results/; a run made on another machine is published there and copied back)")
    a = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    print(publish(a.run_dir, a.name, a.config, a.into, a.command))


if __name__ == "__main__":
    main()
