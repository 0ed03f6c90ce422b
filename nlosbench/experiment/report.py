"""report.md for a run directory, made only from saved files (config.yaml, results.json, study CSVs)."""
from __future__ import annotations

import platform
from pathlib import Path

import yaml

from .. import studies
from ..io import write_text
from ..studies.context import noise_options
from . import outputs
from .rundir import RunFolderError


def make_report(run_dir: str | Path) -> Path:
    """Write report.md; RunFolderError (one line naming the file) when results.json is damaged or a study's
    table or record log holds less than results.json says (cut short: `--resume` rebuilds it)."""
    run_dir = Path(run_dir)
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    results = outputs.load_results(run_dir / "results.json")
    for sid, s in results["studies"].items():
        for path, what in outputs.problems(run_dir / sid, s.get("outputs", {}), (".csv", ".json", ".jsonl"))[:1]:
            raise RunFolderError(str(path), f"{what}: a report from it would be wrong; resume the run (nlosbench run "
                                            f"<its config> --out {run_dir} --resume) to rebuild it")
    sc = cfg["scene"]
    noises = ", ".join(f"{n['model']} ({', '.join(f'{k} = {v}' for k, v in noise_options(n).items())})".replace(
        "sigma =", "σ =") for n in cfg["noise"])
    total = sum(s.get("seconds", 0) for s in results["studies"].values())
    renders = sum(
        max(int(s["results"].get("renders") or 0), s.get("renders_in_process", 0)) for s in results["studies"].values()
    )
    lines = [
        f"# nlosbench run: {cfg['name']}",
        "",
        "**Question.** How well can the scene parameter(s) "
        f"{', '.join(sc['params'] or ['(all)'])} of scene `{sc['name']}` be estimated from noisy images "
        "(information bounds), and how close do estimators get?",
        "",
        f"**Setup.** scene `{sc['name']}` (options {sc['options'] or '{}'}), fixed {sc['fixed'] or '{}'}; "
        f"noise: {noises}; seed {cfg['seed']}; executor {cfg['executor']['type']}; "
        f"machine: {platform.machine()}, {platform.system()}, Python {platform.python_version()}.",
        "",
        f"**Cost.** {total:.1f} s wall time in total; {renders} renders (each study's own count, worker "
        "processes included, where it keeps one; else those of the main process).",
        "",
    ]
    for r in results.get("resumed_anyway", []):
        files = ", ".join(r["changed"]) or "the rendering code"
        lines += [f"**Resumed across a code change** (`--resume-anyway`, {r['at']}): nlosbench {r['from']} → "
                  f"{r['to']}, changed: {files}. Work finished before and after it is mixed in these results.", ""]
    for sid, s in results["studies"].items():
        mod = studies.get(s["type"])
        lines += [
            f"## {sid}: {s['type']} ({s.get('seconds', 0):.1f} s)",
            "",
            mod.report(run_dir / sid, s["results"]),
            "",
        ]
    return write_text(run_dir / "report.md", "\n".join(lines))
