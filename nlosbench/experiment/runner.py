"""Run an experiment: validate the config, make the run directory, run each study, write
config.yaml (resolved), results.json (after every study) and report.md. A resumed run skips
finished studies (and studies resume their own partial work, e.g. trials.jsonl)."""
from __future__ import annotations

import json
import time
from pathlib import Path

import yaml

from .. import studies
from ..io import write_json
from ..studies.context import RunContext
from . import config as config_mod
from .report import make_report


def run(config_path: str | Path, overrides: list[str] = (), out: str | Path | None = None,
        resume: bool = False, quiet: bool = False, smoke: bool = False) -> Path:
    """Run every study of a config (shrunk to seconds with `smoke`); returns the run directory."""
    cfg = config_mod.load(config_path, overrides, smoke=smoke)
    run_dir = Path(out) if out else Path(cfg["output"]) / cfg["name"]
    results_path = run_dir / "results.json"
    if results_path.exists() and not resume:
        raise FileExistsError(f"{run_dir} already holds a run; pass --resume to continue it or --out for a new one")
    ctx = RunContext.create(cfg, run_dir, resume=resume, quiet=quiet)  # loads the scene before anything is written
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    results = json.loads(results_path.read_text()) if resume and results_path.exists() else {"studies": {}}
    ctx.start()
    try:
        for i, study in enumerate(cfg["studies"]):
            study["id"] = study.get("id") or f"{i:02d}-{study['type']}"
            if results["studies"].get(study["id"], {}).get("status") == "done":
                ctx.log(f"[{study['id']}] done already, skipped")
                continue
            ctx.log(f"[{study['id']}] running")
            before, t0 = ctx.model.stats.snapshot(), time.perf_counter()
            try:
                summary = studies.get(study["type"]).run(ctx, study)
            except (ValueError, KeyError) as e:  # bad input found by the study: name the study, keep the kind
                msg = f"study {study['id']}: {e.args[0] if isinstance(e, KeyError) and e.args else e}"
                raise (KeyError if isinstance(e, KeyError) else ValueError)(msg) from e
            spent = ctx.model.stats.since(before)
            results["studies"][study["id"]] = {"type": study["type"], "status": "done", "results": summary,
                                               "seconds": time.perf_counter() - t0, "renders_in_process": spent.renders,
                                               "render_seconds_in_process": spent.seconds}
            write_json(results_path, results)
    finally:
        ctx.close()
    results["seconds_total"] = sum(s.get("seconds", 0) for s in results["studies"].values())
    write_json(results_path, results)
    make_report(run_dir)
    return run_dir
