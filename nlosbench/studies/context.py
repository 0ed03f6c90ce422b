"""RunContext: what a study gets — the run directory, the forward model, noise models, seeds, the
executor, the render bank and the bound service (`start`), progress bars and a log."""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import executors, scenes
from .. import noise as noise_models
from ..bank import RenderBank
from ..bounds import BoundService
from ..forward import llvm_target
from ..forward.cache import RenderCache
from ..forward.model import ForwardModel
from ..schema import ConfigError
from ..seeds import derive
from .progress import Progress


def load_model(spec: dict) -> ForwardModel:
    """The run's model from its spec; a scene that cannot be found or loaded (unknown name, missing file,
    invalid XML, bad options) is a ConfigError naming `scene`."""
    try:
        return scenes.build(spec)
    except ConfigError as e:  # a SpecError: names the spec file and what is wrong in it
        raise ConfigError("scene", str(e)) from None
    except KeyError as e:
        raise ConfigError("scene.name", e.args[0] if e.args else str(e)) from None
    except FileNotFoundError as e:
        raise ConfigError("scene.name", str(e) if e.errno is None else f"{e.strerror}: {e.filename}") from None
    except (TypeError, ValueError, yaml.YAMLError) as e:
        raise ConfigError("scene", str(e).replace("\n", " ")) from None


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
    bank: RenderBank | None = None
    bounds: BoundService | None = None
    quiet: bool = False
    #: seconds per pixel-sample of this run's model on this machine (`estimate.rate`, set by the runner); None
    #: outside a prepared run (no time is predicted from it then)
    rate: float | None = None
    started: float = field(default_factory=time.perf_counter)
    bars: Progress = field(init=False, repr=False)

    def __post_init__(self):
        self.bars = Progress(self.quiet)
        if self.bank is None:  # until `start`: renders run serially in this process
            self.bank = RenderBank(self.model, self.executor, self.progress, seed=self.seed)
        self.bounds = BoundService(self.bank, self.noises)

    @classmethod
    def create(cls, cfg: dict, run_dir: Path, resume: bool = False, quiet: bool = False) -> RunContext:
        sc = cfg["scene"]
        try:  # resolved here, so workers elsewhere (Dask) render with this process's choice, not their environment
            target = llvm_target.requested(sc["llvm_target"])
        except ValueError as e:
            raise ConfigError("scene.llvm_target", str(e)) from None
        spec = {"name": sc["name"], "options": sc["options"], "params": sc["params"], "fixed": sc["fixed"],
                "variant": sc["variant"], "llvm_target": target, "cache": cfg["cache"]}
        noises = []
        for i, n in enumerate(cfg["noise"]):
            try:
                noises.append(noise_models.get(n["model"], **noise_options(n)))
            except (KeyError, TypeError, ValueError) as e:
                raise ConfigError(f"noise[{i}]", e.args[0] if isinstance(e, KeyError) and e.args else str(e)) from None
        model = base = load_model(spec)
        while hasattr(base, "base"):  # a model with fixed parameters wraps the scene's
            base = base.base
        if any(isinstance(n, noise_models.Poisson) for n in noises) and getattr(base, "render_noise", 0) > 0 \
                and not base.render_noise_clip:
            raise ConfigError("scene.options.render_noise_clip", "Poisson noise needs renders >= 0, and the analytic "
                              "scene's render_noise can make a pixel negative: set render_noise_clip: true (renders "
                              "clipped at 0), render_noise: 0, or use awgn noise")
        return cls(dir=run_dir, config=cfg, model_spec=spec, model=model, noises=noises,
                   seed=cfg["seed"], resume=resume, quiet=quiet)

    def start(self) -> None:
        """Start the run's executor (the config's `executor` block), its render bank (renders kept in
        the run directory's renders/ when the config's `keep_renders` is on) and its bound service."""
        self.executor = executors.create(self.config["executor"], self.model_spec, self.model,
                                         log=self.dir / "dask.log")  # Dask's own log lines: a file, not stderr
        self.executor.start()  # Dask: connect now (ConnectionError naming the address), not at the first task
        store = RenderCache(self.dir / "renders") if self.config.get("keep_renders", True) else None
        self.bank = RenderBank(self.model, self.executor, self.progress, seed=self.seed, store=store)
        self.bounds = BoundService(self.bank, self.noises)

    def close(self) -> None:
        """Close the progress bar and release the executor's workers."""
        self.bars.close()
        if self.executor is not None:
            self.executor.close()

    def abort(self) -> None:
        """Stop the executor's workers at once (after Ctrl-C or an error)."""
        if self.executor is not None:
            self.executor.abort()

    def study_dir(self, cfg: dict) -> Path:
        d = self.dir / (cfg.get("id") or cfg["type"])
        d.mkdir(parents=True, exist_ok=True)
        return d

    def select_noises(self, spec, where: str) -> dict:
        """index → noise model for `spec` = 'all', an index or a list of indices into the run's noise models
        (ConfigError naming `where` otherwise)."""
        idx = range(len(self.noises)) if spec == "all" else [spec] if isinstance(spec, int) else spec
        if not isinstance(idx, (list, range)) or not idx or not all(
                isinstance(j, int) and not isinstance(j, bool) and 0 <= j < len(self.noises) for j in idx):
            raise ConfigError(
                where, f"expected 'all' or indices into the {len(self.noises)} noise model(s), got {spec!r}"
            )
        return {j: self.noises[j] for j in idx}

    def seed_for(self, purpose: str, *indices: int) -> int:
        return derive(self.seed, purpose, *indices)

    def progress(self, iterable, total: int | None = None, desc: str = ""):
        """`iterable` counted on its stage's progress bar with ETA on stderr (none when quiet or empty: `Progress`)."""
        return self.bars(iterable, total, desc)

    def log(self, msg: str) -> None:
        """A line on stderr (after closing the open progress bar; silent when quiet)."""
        self.bars.close()
        if not self.quiet:
            print(msg, file=sys.stderr, flush=True)


def noise_options(block: dict) -> dict:
    """A config's `noise:` entry as the parameters of `noise.get`: sigma / scale where given, and `options`."""
    return {**{k: v for k, v in block.items() if k not in ("model", "options") and v is not None},
            **(block.get("options") or {})}


def theta_at(ctx: RunContext, cfg: dict, sid: str) -> np.ndarray:
    """θ (P,) of a study block's `at` (None: the parameters' defaults), inside Θ; ConfigError naming `<sid>.at`."""
    params = ctx.model.params
    try:
        return params.validate(params.default if cfg["at"] is None else cfg["at"])
    except ValueError as e:
        raise ConfigError(f"{sid}.at", str(e)) from None
