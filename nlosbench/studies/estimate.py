"""What a study will cost, said before any render: planned renders and pixel-samples, and a time from a
rate measured on this machine.

Each study module has `cost(ctx, cfg, plan) -> Estimate`: the renders its plan asks for and their
pixel-samples (renders × spp × pixels; an FD Jacobian counts its 2 renders per parameter and round, an AD
pass counts as `AD_PASS_RENDERS` renders). It is an upper bound where work may be skipped (a resumed run,
a render shared between sets, an estimator that converges early) and an estimate where the work depends on
the data (a trial's fit: the estimator's iterations × spp). The time is samples × a rate in seconds per
pixel-sample plus renders × the cost every render has beside its samples (the bank's task and its store's
checksummed, fsynced write: what makes a lattice of 10⁵ cheap renders take minutes), for this scene, variant
and versions (the model's content key), measured once on this machine with tiny timed renders (after untimed
ones that compile the kernels) and kept in `rates_path()` (~/.cache/nlosbench/rates.json, or
$XDG_CACHE_HOME/nlosbench/rates.json) with the load per core it was measured at: one measured under load is
measured again once the machine is at most half as loaded (a rate kept from a busy moment made every later
estimate too long).
"""
from __future__ import annotations

import datetime
import hashlib
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..bank import RenderBank
from ..forward.cache import RenderCache
from ..forward.model import ForwardModel
from ..io import write_json

#: render-equivalents of one AD gradient pass in an estimate (measured 3–12× a forward render: README)
AD_PASS_RENDERS = 4
#: pixel-samples of the timed render that measures a rate
RATE_SAMPLES = 1 << 18
#: 1-spp renders timed through a bank with a store to measure a render's cost beside its samples
OVERHEAD_RENDERS = 4
#: a kept rate measured at a 1-minute load average above this per core (or at an unknown load) is measured again
#: when the machine is at most half as loaded: other work slowed the first measurement down
LOADED = 0.5


@dataclass(frozen=True)
class Estimate:
    """Planned renders and pixel-samples of a study; `note` says what is estimated rather than counted; `least`,
    where `samples` is a maximum that depends on the data (a precision target's fresh looks, capped by their
    budget), the pixel-samples spent in any case (the pilot meeting the target); None: `samples`."""

    renders: int
    samples: int
    note: str = ""
    least: int | None = None

    @property
    def floor(self) -> int:
        """The pixel-samples spent in any case."""
        return self.samples if self.least is None else self.least

    def __add__(self, o: Estimate) -> Estimate:
        least = None if self.least is None and o.least is None else self.floor + o.floor
        return Estimate(self.renders + o.renders, self.samples + o.samples,
                        "; ".join(n for n in (self.note, o.note) if n), least)


@dataclass(frozen=True)
class Rate:
    """Seconds per pixel-sample of a model on this machine, seconds per render beside its samples (the bank's
    task and store write), and where the numbers come from."""

    seconds_per_sample: float
    source: str
    seconds_per_render: float = 0.0

    def seconds(self, est: Estimate) -> float:
        """Seconds of an Estimate: its pixel-samples and its renders, each at its rate."""
        return est.samples * self.seconds_per_sample + est.renders * self.seconds_per_render


def _base(model: ForwardModel) -> ForwardModel:
    while hasattr(model, "base"):
        model = model.base
    return model


def image_hw(model: ForwardModel) -> tuple[int, int]:
    """(H, W) of the model's images without rendering where the model knows its film (a Mitsuba scene);
    otherwise (the analytic toys, cheap) from one 1-spp render."""
    size = getattr(_base(model), "size", None)
    if isinstance(size, tuple) and len(size) == 2:
        return int(size[1]), int(size[0])
    shape = model.render(model.params.default, 1, 0).shape
    return int(shape[0]), int(shape[1])


def pixels(model: ForwardModel) -> int:
    """Pixels per image (H·W)."""
    h, w = image_hw(model)
    return h * w


def rates_path() -> Path:
    """Where measured rates are kept: $XDG_CACHE_HOME/nlosbench/rates.json (default ~/.cache/...)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "nlosbench" / "rates.json"


def _key(model: ForwardModel) -> str:
    blob = json.dumps(model.content_key(), sort_keys=True, default=repr).encode()
    return hashlib.sha256(blob).hexdigest()[:24]


def load_per_core() -> float:
    """The 1-minute load average per CPU core (NaN where the system does not say)."""
    try:
        return os.getloadavg()[0] / (os.cpu_count() or 1)
    except (OSError, AttributeError):
        return math.nan


def rate(model: ForwardModel) -> Rate:
    """This machine's seconds per pixel-sample and per render for `model` (cached in `rates_path()` with the load per
    core it was measured at; measured on a miss, and again when it was measured under load (`LOADED`, or at an
    unknown load) and the machine is now at most half as loaded)."""
    path, key = rates_path(), _key(model)
    try:
        known = json.loads(path.read_text())
    except (OSError, ValueError):
        known = {}
    hit = known.get(key) if isinstance(known, dict) else None
    now = load_per_core()
    if isinstance(hit, dict) and _usable(hit.get("seconds_per_sample")) and _usable(hit.get("seconds_per_render"),
                                                                                    zero=True):
        then = hit.get("load_per_core")
        then = float(then) if _usable(then, zero=True) else math.inf  # unknown: as if loaded
        if not (then > LOADED and now <= min(then, 2 * LOADED) / 2):  # NaN now: kept
            return Rate(float(hit["seconds_per_sample"]), f"measured {hit.get('when', '')} ({path})",
                        float(hit["seconds_per_render"]))  # else (NaN, 0, < 0, text, missing) measured again
    r = measure(model)
    o = measure_overhead(model, r)
    try:
        write_json(path, {**(known if isinstance(known, dict) else {}),
                          key: {"seconds_per_sample": r, "seconds_per_render": o, "scene": model.name,
                                "variant": getattr(_base(model), "variant", type(_base(model)).__name__),
                                "when": datetime.date.today().isoformat(),
                                "load_per_core": None if math.isnan(now) else round(now, 3)}})
    except OSError:  # a read-only home: the estimate still stands, it is just measured again next time
        pass
    return Rate(r, "measured now", o)


def _usable(value, zero: bool = False) -> bool:
    """A kept rate is a finite number > 0 (≥ 0 with `zero`): NaN, infinity, zero or a negative rate (a hand-edited
    or damaged rates.json) would make every estimate NaN, infinite or 0 and switch off the one-hour `--yes` guard."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and (value >= 0 if zero else value > 0))


def measure(model: ForwardModel) -> float:
    """Seconds per pixel-sample from a timed render of about RATE_SAMPLES pixel-samples at the default θ
    (after an untimed one of the same size: kernel compilation is not the rate); the model's render cache
    is bypassed."""
    base = _base(model)
    spp = 1 << max(0, int(math.log2(max(1, RATE_SAMPLES // pixels(model)))))
    cache, base.cache = base.cache, None
    try:
        theta = model.params.default
        model.render(theta, spp, 1)
        t0 = time.perf_counter()
        model.render(theta, spp, 2)
        seconds = time.perf_counter() - t0
    finally:
        base.cache = cache
    return max(seconds, 1e-9) / (spp * pixels(model))


def measure_overhead(model: ForwardModel, seconds_per_sample: float) -> float:
    """Seconds per render beside its pixel-samples (≥ 0): OVERHEAD_RENDERS 1-spp renders through a RenderBank with
    a store (the task, the checksummed entry and its fsynced write) in a temporary folder beside rates.json (the
    system's temporary folder where that cannot be made), less their samples' time at `seconds_per_sample`, after
    an untimed one; the model's render cache is bypassed."""
    base = _base(model)
    cache, base.cache = base.cache, None
    try:
        where = rates_path().parent
        where.mkdir(parents=True, exist_ok=True)
    except OSError:
        where = None
    try:
        with tempfile.TemporaryDirectory(dir=where) as tmp:
            bank = RenderBank(model, store=RenderCache(tmp))
            theta = [model.params.default]
            bank.at(theta, 1, "rate")
            t0 = time.perf_counter()
            for r in range(1, OVERHEAD_RENDERS + 1):
                bank.at(theta, 1, "rate", replicate=r)
            seconds = (time.perf_counter() - t0) / OVERHEAD_RENDERS
    finally:
        base.cache = cache
    return max(seconds - pixels(model) * seconds_per_sample, 0.0)


def describe(seconds: float) -> str:
    """A duration for people: '42 s', '3.5 min', '2.1 h', '4.0 days'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"
