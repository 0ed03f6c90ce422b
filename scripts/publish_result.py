"""Copy a finished run into results/<name>/ for committing: report.md, results.json, config.yaml, machine.json (which
the run wrote: the machine, its load, the versions, the wall time and renders per study, the command), every CSV and
PNG (no EXR, no render cache, no JSONL logs).

    python scripts/publish_result.py runs/demo quick

The run must be finished (results.json present, every study "done", machine.json written); an existing
results/<name>/ is replaced only after the new copy is complete (written beside it, then renamed). A run made on
another machine is published there (`--into`) and the folder copied back.
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEEP = (".md", ".csv", ".png", ".json", ".yaml")
SKIP_DIRS = {"renders", "images", "views", "cache"}


def publish(run_dir: Path, name: str, dest_root: Path = ROOT / "results") -> Path:
    results = run_dir / "results.json"
    if not results.is_file():
        raise SystemExit(f"{run_dir}: no results.json (is the run finished?)")
    run = json.loads(results.read_text())
    unfinished = [k for k, v in run.get("studies", {}).items() if v.get("status") != "done"]
    if unfinished:
        raise SystemExit(f"{run_dir}: studies not done: {unfinished}")
    if not (run_dir / "machine.json").is_file():
        raise SystemExit(f"{run_dir}: no machine.json (a run writes it when it finishes; re-run to make one)")
    dest_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=dest_root))
    for src in sorted(run_dir.rglob("*")):
        rel = src.relative_to(run_dir)
        if src.is_file() and src.suffix in KEEP and not SKIP_DIRS.intersection(rel.parts[:-1]):
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, tmp / rel)
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
    p.add_argument("run_dir", type=Path, help="a finished run folder (with results.json and machine.json)")
    p.add_argument("name", help="folder name under results/")
    p.add_argument("--into", type=Path, default=ROOT / "results", help="the folder that receives NAME (default: "
                   "results/)")
    a = p.parse_args(argv)
    print(publish(a.run_dir, a.name, a.into))


if __name__ == "__main__":
    main()
