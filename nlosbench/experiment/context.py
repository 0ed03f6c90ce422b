"""RunContext: what a study gets — the run directory, the forward model, noise models, seeds,
an executor, progress bars and small writers for CSV/JSON."""
from __future__ import annotations

import csv
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .. import noise as noise_models
from .. import scenes
from ..forward.model import ForwardModel
from ..io import atomic
from ..seeds import derive


def build_model(spec: dict) -> ForwardModel:
    """The forward model from a picklable spec {name, options, params, fixed, variant, cache}: loaded once
    per process (workers call this in their initialiser), restricted to `params` when given."""
    opts = dict(spec.get("options") or {})
    if spec.get("variant"):
        opts["variant"] = spec["variant"]
    if spec.get("cache"):
        opts["cache"] = spec["cache"]
    model = scenes.get(spec["name"], **opts)
    if spec.get("params"):
        model = model.restrict(spec["params"], spec.get("fixed") or {})
    return model


@dataclass
class RunContext:
    dir: Path
    config: dict
    model_spec: dict
    model: ForwardModel
    noises: list
    seed: int
    resume: bool = False
    executor: object = None
    quiet: bool = False
    started: float = field(default_factory=time.perf_counter)

    @classmethod
    def create(cls, cfg: dict, run_dir: Path, resume: bool = False, quiet: bool = False) -> "RunContext":
        sc = cfg["scene"]
        spec = {"name": sc["name"], "options": sc["options"], "params": sc["params"], "fixed": sc["fixed"],
                "variant": sc["variant"], "cache": cfg["cache"]}
        noises = [noise_models.get(n["model"], **{k: v for k, v in n.items() if k != "model" and v is not None})
                  for n in cfg["noise"]]
        return cls(dir=run_dir, config=cfg, model_spec=spec, model=build_model(spec), noises=noises,
                   seed=cfg["seed"], resume=resume, quiet=quiet)

    def study_dir(self, cfg: dict) -> Path:
        d = self.dir / (cfg.get("id") or cfg["type"])
        d.mkdir(parents=True, exist_ok=True)
        return d

    def seed_for(self, purpose: str, *indices: int) -> int:
        return derive(self.seed, purpose, *indices)

    def progress(self, iterable, total: int | None = None, desc: str = ""):
        """A tqdm progress bar with ETA on stderr (silent when quiet)."""
        from tqdm import tqdm

        return tqdm(iterable, total=total, desc=desc, disable=self.quiet, file=sys.stderr, dynamic_ncols=True)

    def log(self, msg: str) -> None:
        if not self.quiet:
            print(msg, file=sys.stderr, flush=True)


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows of dicts as CSV, written atomically (header from the first row's keys in order, plus any later new keys)."""
    keys: list = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with atomic(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    return path


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_json(path: Path, data) -> Path:
    with atomic(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=_json_default))
    return path


def _json_default(o):
    import numpy as np

    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
