"""Study `fidelity`: the cheapest scene model whose bound matches the highest-fidelity one.

For a 1-D θ grid, every noise model and one knob at a time around a reference (the highest-fidelity
point: the largest spp, no binning, the deepest path, FD gradients), the HCR curve (G renders,
the bound service's `curve`) and the CRLB (image Jacobian at each grid point) are computed,
with the point's wall time, renders and pixel-samples. Knobs:
  spp        samples per sensor pixel of every render;
  bin        b×b binning at a fixed photon budget (`nlosbench.binning`): rendered at full resolution with
             spp/b² samples per pixel (the samples of a b× coarser sensor at `spp`), the renders and
             Jacobians binned to their block means, the noise model `noise.binned(b)` (AWGN σ/b, Poisson
             counts summed);
  max_depth  the integrator's path depth (scene reloaded with `defines: {max_depth: d}`; 1 = emitters
             seen directly, 2 = direct lighting, 3 = one indirect bounce, ...);
  gradient   the CRLB's Jacobian by central FD with common random numbers (reference) or Mitsuba AD.
Error of a point: |b/b_ref − 1| of its bounds' point estimates against the reference's, aggregated
(`aggregate`: max or median) over θ, noise models and bound kinds (HCR, CRLB). The point estimates come
from unbiased estimates of λ (HCR) and of the Fisher information (CRLB), U-statistics over `replicates`
independent render sets, so they carry no 1/spp bias (the plug-in λ̂'s, which made a 512-spp reference
look unconverged), only Monte Carlo noise. Each error has joint confidence limits at `level`
(`nlosbench.tradeoff.error_limits`): a delete-one jackknife of the log ratio over the replicate sets,
paired by index (set k of a setting and of the reference share their seeds where the spp does, so a
change of depth, pruning or gradient is compared on the same samples and their common noise cancels),
Bonferroni over every value in the aggregate. A value is within tolerance when its upper limit is
(resolved), outside when its lower limit exceeds it. The reference's own noise, the Monte Carlo noise of its
point estimates (`nlosbench.tradeoff.jackknife_noise`: one-sided t limits of a jackknife over the sets), says
how well the reference itself is known: converged when ≤ tolerance / 2; the report says when it is not and how
many replicates would make it so. Its bounds' confidence intervals can be wider: a CRLB end spans the FD
variants too (central, forward and backward differences at the step), which an edge crossing a pixel within
the step parts, and replicates do not shrink that spread; every setting's point is the central difference,
so the spread does not enter the errors, and the report says so when it is the wider.
Recommendation per knob: the cheapest value resolved within `tolerance` (`nlosbench.tradeoff.recommend`);
overall: the per-knob choices together, without every element whose removal is within tolerance, computed
once more (`verify`) for their actual error and speed-up. Depth sufficiency: the max_depth points over the
NLOS grid points (θ > `los_until`) and the depth from which the bound stops changing (upper limits within
tolerance). Pruning: the reference with each element of `prune` removed from the scene (one at a time)
against the full scene.

Every point is computed from scratch by the bound service (`curve`) on its own render bank of the
model (or of its b×b-binned sensor, `forward.Binned`), serially in this process and without the render
cache, so its cost is measured; the bank's seeds (common random numbers across settings of equal spp)
make the comparison paired; scene loads and one warm-up render per model (kernel compilation) are not
counted. Files: fidelity.csv (a row per knob value, noise model and
θ: bounds, errors, cost), fidelity.png (error against cost, a panel per knob), depth.png (bound against
depth); the recommendations are in results.json.
"""
from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..bank import RenderBank
from ..binning import check_bin
from ..bounds import BoundService
from ..forward.gradients import GradientSettings, jacobian
from ..forward.mitsuba_model import MitsubaModel, pruned_xml
from ..forward.model import Binned, RenderStats
from ..io import write_csv
from ..scenes import build
from ..schema import GRID, ConfigError, Field, grid_values, smoke_grid
from ..tradeoff import (
    AGGREGATES,
    Point,
    aggregate,
    check_tolerance,
    decisive,
    error_limits,
    jackknife_noise,
    recommend,
    relative_error,
    settled,
)
from .context import RunContext
from .estimate import AD_PASS_RENDERS, Estimate, image_hw
from .plots import fidelity_plots

NAME = "fidelity"
KNOBS = ("spp", "bin", "max_depth", "gradient")
GRADIENTS = ("fd", "ad")
SCHEMA = {
    "grid": GRID,
    "spp": Field(list, [256, 1024, 4096], "samples per sensor pixel; the largest is the reference", items=int),
    "bins": Field(list, [1], "binning factors b (b×b pixels → one, photon budget fixed); 1 is the reference",
                  items=int),
    "max_depth": Field(list, [], "integrator path depths (scene reloaded); the largest is the reference; "
                                 "[]: the scene's own depth, not swept", items=int),
    "gradient": Field(list, ["fd"], "Jacobian methods for the CRLB; fd (central, common random numbers) is "
                                    "the reference", items=Field(str, choices=GRADIENTS)),
    "fd_step": Field(float, None, "FD step ξ of the CRLB term (parameter units; null: the grid neighbours)",
                     nullable=True),
    "replicates": Field(int, 3, "independent replicate render sets per setting (unbiased U-statistics need 2, "
                                "their confidence limits 3)"),
    "level": Field(float, 0.95, "confidence level: one-sided for each bound's limits (its noise), joint for the "
                                "limits of a setting's errors"),
    "ad": Field(dict, {}, "AD integrator options, e.g. {sppc: 4, sppp: 4, sppi: 0} for prb_projective on CPU"),
    "seeds": Field(str, "independent", "render seeds across the θ grid: independent or common (as in `bounds`)",
                   choices=("independent", "common")),
    "tolerance": Field(float, 0.05, "largest relative bound error |b/b_ref − 1| a recommendation may have"),
    "aggregate": Field(str, "max", "how a point's errors over θ, noise models and bounds combine",
                       choices=AGGREGATES),
    "cost": Field(str, "seconds", "cost measure: wall seconds, or pixel-samples (an AD pass counts as one "
                                  "render's samples)", choices=("seconds", "samples")),
    "los_until": Field(float, None, "θ where the object leaves the line of sight: depth sufficiency uses "
                                    "θ > los_until (null: every grid point)", nullable=True),
    "prune": Field(list, [], "scene element ids: the reference bound without each of them", items=str),
    "verify": Field(bool, True, "compute the combined recommended setting for its actual error and speed-up"),
}


@dataclass(frozen=True)
class Setting:
    """One point: samples per sensor pixel, binning b, path depth (None: the scene's own), Jacobian
    method and the removed scene elements (none: the full scene)."""

    spp: int
    bin: int
    max_depth: int | None
    gradient: str
    prune: tuple[str, ...] = ()

    @property
    def render_spp(self) -> int:
        """Samples per full-resolution pixel (spp of the coarse sensor spread over its b² pixels)."""
        return self.spp // self.bin ** 2


@dataclass
class _Bounds:
    """One noise model's bounds at one setting over the θ grid: log10 point estimates of the HCR and CRLB
    (G,), the same without each replicate set (G, R; R = 0 below 3 replicates), the points' Monte Carlo noise
    (`jackknife_noise`, (G,)) and their intervals' relative half-widths (`bound_noise`, (G,); both NaN where
    fewer than 3 replicates give no interval), CRLB flags, and how many HCR sups sit at the smallest grid Δ
    (grid-limited)."""

    hcr: np.ndarray
    crlb: np.ndarray
    hcr_loo: np.ndarray
    crlb_loo: np.ndarray
    hcr_noise: np.ndarray
    crlb_noise: np.ndarray
    hcr_width: np.ndarray
    crlb_width: np.ndarray
    flags: list[str]
    sup_at_smallest: int


def bound_noise(b) -> float:
    """Relative half-width of a Bound's confidence interval about its point estimate: the larger of
    10^(upper − point) − 1 and 1 − 10^(lower − point); 0 for an exact bound, ∞ for an open end or no
    finite point, NaN for a point estimate without limits (fewer than 3 replicates)."""
    if b.point is None or "estimate-only" in b.flags:
        return math.nan
    if not math.isfinite(b.point) or b.upper is None or not math.isfinite(b.upper):
        return math.inf
    lo = 0.0 if b.lower is None or b.lower == -math.inf else 10.0 ** (b.lower - b.point)
    return max(10.0 ** (b.upper - b.point) - 1.0, 1.0 - lo)


def _integrator_depth(model) -> int | None:
    """The loaded integrator's max_depth (None for a model without a Mitsuba scene)."""
    scene = getattr(getattr(model, "base", model), "scene", None)
    found = re.search(r"max_depth = (-?\d+)", str(scene.integrator())) if scene is not None else None
    return int(found.group(1)) if found else None


class _Sweep:
    """Models per (depth, removed element), loaded once; per setting a fresh render bank of the model (or
    of its b×b-binned sensor) and the bound service's curve over it, timed (serial, in this process)."""

    def __init__(self, ctx: RunContext, cfg: dict, thetas: list[float], pixels: int):
        self.ctx, self.cfg, self.thetas, self.pixels = ctx, cfg, thetas, pixels
        self.models: dict = {}
        self.warm: set = set()
        self.done: dict[Setting, tuple[dict, RenderStats]] = {}

    def model(self, depth: int | None, prune: tuple[str, ...]):
        key = (depth, prune)
        if key not in self.models:
            ctx = self.ctx
            same_depth = depth is None or _integrator_depth(ctx.model) == depth
            if same_depth and not prune and not ctx.model_spec.get("cache"):
                self.models[key] = ctx.model
            else:
                opts = dict(ctx.model_spec.get("options") or {})
                if depth is not None:
                    opts["defines"] = {**(opts.get("defines") or {}), "max_depth": depth}
                if prune:
                    opts["remove"] = [*(opts.get("remove") or []), *prune]
                m = build({**ctx.model_spec, "options": opts, "cache": None})
                if depth is not None and _integrator_depth(m) != depth:
                    raise ValueError(f"max_depth: scene {m.name!r} does not take its integrator's max_depth from "
                                     f"the define $max_depth (asked {depth}, loaded {_integrator_depth(m)})")
                self.models[key] = m
        return self.models[key]

    def _warm_up(self, model, method: str) -> None:
        """One untimed render (and AD pass) per model: kernel compilation is not the setting's cost."""
        if (id(model), method) in self.warm:
            return
        seed = self.ctx.seed_for("fidelity-warmup")
        model.render([self.thetas[0]], 1, seed)
        if method == "ad":
            jacobian(model, [self.thetas[0]], 1, seed, GradientSettings("ad", ad=dict(self.cfg["ad"])))
        self.warm.add((id(model), method))

    def bounds_of(self, s: Setting) -> tuple[dict[str, _Bounds], RenderStats]:
        """Bounds per noise model (by its unbinned name) of one setting, and their cost."""
        base = self.model(s.max_depth, s.prune)
        self._warm_up(base, s.gradient)
        model = base if s.bin == 1 else Binned(base, s.bin)
        noises = [n.binned(s.bin) if s.bin > 1 else n for n in self.ctx.noises]
        svc = BoundService(RenderBank(model, progress=self.ctx.progress, seed=self.ctx.seed), noises,
                           level=self.cfg["level"])
        before, t0 = base.stats.snapshot(), time.perf_counter()
        curve = svc.curve(self.thetas, s.spp, self.cfg["seeds"], self.cfg["replicates"], crlb=True, zzb=False,
                          fd_step=self.cfg["fd_step"], gradient=s.gradient, ad=dict(self.cfg["ad"]), check_step=False)
        points = curve.points
        spent, seconds = base.stats.since(before), time.perf_counter() - t0
        cost = RenderStats(spent.renders, spent.grad_passes,
                           spent.samples + spent.grad_passes * s.render_spp * self.pixels, seconds)
        out = {}
        for j, noise in enumerate(self.ctx.noises):
            pts = [pt for pt in points if pt.noise_index == j]
            hcr, crlb = [pt.bounds["hcr"] for pt in pts], [pt.bounds["crlb"] for pt in pts]
            kinds = (hcr, crlb)
            pts_ = [np.array([b.point for b in bs]) for bs in kinds]
            loos = [np.stack([b.loo for b in bs]) for bs in kinds]
            noise_ = [jackknife_noise(p_, lo, self.cfg["level"]) for p_, lo in zip(pts_, loos, strict=True)]
            out[str(noise)] = _Bounds(*pts_, *loos, *noise_, *(np.array([bound_noise(b) for b in bs]) for bs in kinds),
                                      [b.reason for b in crlb],
                                      sum("sup-at-smallest-delta" in pt.bounds["hcr"].flags for pt in pts))
        return out, cost

    def evaluate(self, settings: list[Setting]) -> None:
        """Bounds and cost of every setting not done yet (each from its own render sets)."""
        for s in dict.fromkeys(settings):
            if s not in self.done:
                self.done[s] = self.bounds_of(s)
                if s.prune and all(t.prune != s.prune for t in settings if t not in self.done):
                    self.models.pop((s.max_depth, s.prune), None)  # used up: free its scene


@dataclass(frozen=True)
class Plan:
    """The θ grid, the reference setting, pixels per full-resolution image (H·W) and the knob settings."""

    thetas: list
    reference: Setting
    pixels: int
    knobs: dict


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError naming the key for what the schema cannot see.
    Renders nothing: the image size comes from the scene's film (`estimate.image_hw`)."""
    sid = cfg.get("id") or NAME
    p = ctx.model.params
    if p.dim != 1:
        raise ConfigError(sid, f"the fidelity study needs one parameter; set scene.params to one of {list(p.names)}")
    thetas = grid_values(cfg["grid"])
    if len(thetas) < 3 or len(set(thetas)) != len(thetas):
        raise ConfigError(f"{sid}.grid", f"the HCR curve needs at least 3 distinct points, got {thetas}")
    for t in (min(thetas), max(thetas)):
        try:
            p.validate([t])
        except ValueError as e:
            raise ConfigError(f"{sid}.grid", str(e)) from None
    try:
        check_tolerance(cfg["tolerance"])
    except ValueError as e:
        raise ConfigError(f"{sid}.tolerance", str(e)) from None
    if not cfg["spp"] or min(cfg["spp"]) < 1:
        raise ConfigError(f"{sid}.spp", f"expected at least one value, all >= 1, got {cfg['spp']}")
    if cfg["replicates"] < 2:
        raise ConfigError(f"{sid}.replicates", f"expected >= 2 (unbiased U-statistics), got {cfg['replicates']}")
    if cfg["fd_step"] is not None and not cfg["fd_step"] > 0:
        raise ConfigError(f"{sid}.fd_step", f"expected a step > 0 or null, got {cfg['fd_step']}")
    spp_ref = max(cfg["spp"])
    h, w = image_hw(ctx.model)
    for b in cfg["bins"]:
        try:
            check_bin(b)
        except ValueError as e:
            raise ConfigError(f"{sid}.bins", str(e)) from None
        if spp_ref % (b * b):
            raise ConfigError(f"{sid}.bins", f"b = {b} renders spp/b² samples per pixel; the reference spp {spp_ref} "
                                             f"is not a multiple of b² = {b * b}")
        if h % b or w % b:
            raise ConfigError(f"{sid}.bins", f"b = {b} does not divide the {h}×{w} image")
    base = getattr(ctx.model, "base", ctx.model)
    if (cfg["max_depth"] or cfg["prune"]) and not isinstance(base, MitsubaModel):
        raise ConfigError(f"{sid}.max_depth" if cfg["max_depth"] else f"{sid}.prune",
                          f"max_depth and prune need a Mitsuba scene; {ctx.model.name!r} is not one")
    if any(d < 1 for d in cfg["max_depth"]):
        raise ConfigError(f"{sid}.max_depth", f"path depths must be >= 1, got {cfg['max_depth']}")
    if cfg["prune"]:
        if len(set(cfg["prune"])) != len(cfg["prune"]):
            raise ConfigError(f"{sid}.prune", f"repeated element ids in {cfg['prune']}")
        try:
            pruned_xml(base.scene_file, cfg["prune"])  # ValueError naming unknown ids
        except ValueError as e:
            raise ConfigError(f"{sid}.prune", str(e)) from None
        bound = {b.object or b.key.split(".")[0]: b.param.name for b in base.binder.bindings}
        for e in cfg["prune"]:
            if e in bound:
                raise ConfigError(f"{sid}.prune", f"element {e!r} carries θ ({bound[e]}); removing it leaves nothing "
                                                  "to estimate")
    ref = Setting(spp_ref, 1, max(cfg["max_depth"]) if cfg["max_depth"] else None, "fd")
    return Plan(thetas, ref, h * w, _knob_settings(cfg, ref))


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """Per setting (the reference, every knob value, the pruned scenes and the verified combination, counted
    as one more reference): R·G grid renders, plus 2R·G FD stencil renders with an `fd_step`, or R·G AD
    passes (counted as AD_PASS_RENDERS renders each) for the AD gradient; at the setting's spp per fine pixel."""
    settings = list(dict.fromkeys([p.reference] + [s for pts in p.knobs.values() for _, s in pts]))
    settings += [p.reference] if cfg["verify"] else []
    R, G = cfg["replicates"], len(p.thetas)
    renders = samples = 0
    for s in settings:
        n = R * G * (1 + (2 if cfg["fd_step"] is not None else 0) + (AD_PASS_RENDERS if s.gradient == "ad" else 0))
        renders += n
        samples += n * s.render_spp * p.pixels
    return Estimate(renders, samples, "the verified combination counted at the reference's cost")


def _knob_settings(cfg: dict, ref: Setting) -> dict[str, list[tuple[object, Setting]]]:
    """(value, setting) per swept knob, reference included; knobs with one value only are left out."""
    values = {"spp": sorted(set(cfg["spp"])), "bin": sorted(set(cfg["bins"]) | {1}),
              "max_depth": sorted(set(cfg["max_depth"])),
              "gradient": [m for m in GRADIENTS if m in set(cfg["gradient"]) | {"fd"}]}
    out = {k: [(v, replace(ref, **{k: v})) for v in vals] for k, vals in values.items() if len(vals) > 1}
    if cfg["prune"]:
        out["prune"] = [("none", ref)] + [(e, replace(ref, prune=(e,))) for e in cfg["prune"]]
    return out


def _errors(res: dict, ref: dict, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Relative errors against the reference: {"hcr": (N·G',), "crlb": (N·G',)} over noise models and θ (masked)."""
    m = slice(None) if mask is None else mask
    return {kind: np.concatenate([relative_error(getattr(res[n], kind)[m], getattr(ref[n], kind)[m]) for n in ref])
            for kind in ("hcr", "crlb")}


def _limits(res: dict, ref: dict, cfg: dict, mask: np.ndarray | None = None) -> tuple[float, float]:
    """Aggregated joint confidence limits (lower, upper) of the errors against the reference over noise
    models, θ (masked) and both bound kinds (`error_limits`, one Bonferroni family; an aggregate of values
    that all lie in their intervals lies in the aggregate of the limits); NaN below 3 replicates."""
    m = slice(None) if mask is None else mask
    if cfg["replicates"] < 3:
        return math.nan, math.nan
    cols = [(getattr(res[n], k)[m], getattr(ref[n], k)[m], getattr(res[n], f"{k}_loo")[m],
             getattr(ref[n], f"{k}_loo")[m]) for n in ref for k in ("hcr", "crlb")]
    lo, hi = error_limits(*(np.concatenate(c) for c in zip(*cols, strict=True)), level=cfg["level"])
    return aggregate(lo, cfg["aggregate"]), aggregate(hi, cfg["aggregate"])


def _reference_noise(ref: dict, how: str, what: str = "noise") -> float:
    """The reference's own noise, aggregated over noise models, θ and both kinds: `what` "noise", the Monte
    Carlo noise of its point estimates; "width", its bounds' intervals' relative half-widths (which span the FD
    variants too); NaN without intervals (fewer than 3 replicates)."""
    noise = np.concatenate([getattr(ref[n], f"{k}_{what}") for n in ref for k in ("hcr", "crlb")])
    return math.nan if np.isnan(noise).any() else aggregate(noise, how)


def _point(value, setting: Setting, res: dict, cost: RenderStats, ref: dict, cfg: dict) -> dict:
    e = _errors(res, ref)
    how = cfg["aggregate"]
    lower, upper = _limits(res, ref, cfg)
    return {
        "value": value,
        "setting": vars(setting).copy(),
        "cost": cost.seconds if cfg["cost"] == "seconds" else cost.samples,
        "seconds": cost.seconds,
        "samples": cost.samples,
        "renders": cost.renders,
        "grad_passes": cost.grad_passes,
        "error": aggregate(np.concatenate([e["hcr"], e["crlb"]]), how),
        "error_hcr": aggregate(e["hcr"], how),
        "error_crlb": aggregate(e["crlb"], how),
        "lower": lower,
        "upper": upper,
    }


def run(ctx: RunContext, cfg: dict) -> dict:
    p = plan(ctx, cfg)
    out = ctx.study_dir(cfg)
    thetas, ref, knobs = p.thetas, p.reference, p.knobs
    tol, how = cfg["tolerance"], cfg["aggregate"]
    sweep = _Sweep(ctx, cfg, thetas, p.pixels)
    sweep.evaluate([ref] + [s for pts in knobs.values() for _, s in pts])
    ref_res = sweep.done[ref][0]

    rows, summary = [], {}
    for knob, pts in knobs.items():
        points = [_point(v, s, *sweep.done[s], ref_res, cfg) for v, s in pts]
        ref_value = next(v for v, s in pts if s == ref)
        summary[knob] = {"reference": ref_value, "points": points}
        if knob != "prune":
            rec = recommend(knob, [Point(p["value"], p["cost"], p["error"], p["upper"]) for p in points], ref_value,
                            tol)
            summary[knob]["recommendation"] = {
                "value": rec.value,
                "error": rec.error,
                "upper": rec.upper,
                "cost": rec.cost,
                "speedup": rec.speedup,
            }
        for (v, s), p in zip(pts, points, strict=True):
            res = sweep.done[s][0]
            for noise, r in res.items():
                e_h, e_c = relative_error(r.hcr, ref_res[noise].hcr), relative_error(r.crlb, ref_res[noise].crlb)
                for g, t in enumerate(thetas):
                    rows.append(
                        {
                            "knob": knob,
                            "value": v,
                            "reference": s == ref,
                            **vars(s),
                            "cost": p["cost"],
                            "seconds": p["seconds"],
                            "renders": p["renders"],
                            "noise": noise,
                            "theta": t,
                            "log10_hcr": r.hcr[g],
                            "log10_crlb": r.crlb[g],
                            "err_hcr": e_h[g],
                            "err_crlb": e_c[g],
                            "crlb_flag": r.flags[g],
                        }
                    )
    write_csv(out / "fidelity.csv", rows)

    overall = _overall(sweep, summary, ref, cfg)
    depth = _depth_sufficiency(sweep, summary, ref, thetas, cfg) if "max_depth" in summary else None
    ref_cost = sweep.done[ref][1]
    ref_noise = _reference_noise(ref_res, how)
    results = {
        "parameter": ctx.model.params.names[0],
        "units": ctx.model.params.units[0],
        "grid_points": len(thetas),
        "noises": [str(n) for n in ctx.noises],
        "reference": vars(ref).copy(),
        "reference_cost": {"seconds": ref_cost.seconds, "renders": ref_cost.renders},
        # every setting's renders, each model's own (the run's count sees only the scene it loaded); warm-ups excluded
        "renders": sum(c.renders for _, c in sweep.done.values()),
        "reference_sup_at_smallest_delta": sum(r.sup_at_smallest for r in ref_res.values()),
        # the reference's own Monte Carlo noise (its points' relative one-sided limits, aggregated): converged
        # when an error at the tolerance is resolved; its intervals' half-widths (FD variants' spread included)
        "reference_noise": ref_noise,
        "reference_interval": _reference_noise(ref_res, how, "width"),
        "reference_converged": bool(ref_noise <= tol / 2),
        "replicates": cfg["replicates"],
        "level": cfg["level"],
        "tolerance": tol,
        "aggregate": how,
        "cost": cfg["cost"],
        "seeds": cfg["seeds"],
        "los_until": cfg["los_until"],
        "knobs": summary,
        "overall": overall,
        "depth": depth,
    }
    return results  # plots: report() draws them from the saved files


def _overall(sweep: _Sweep, summary: dict, ref: Setting, cfg: dict) -> dict:
    """The per-knob recommendations together, without every element whose removal is resolved within
    tolerance; with `verify`, computed for their actual error and speed-up."""
    chosen = {k: summary[k]["recommendation"]["value"] for k in KNOBS if k in summary}
    pts = summary.get("prune", {}).get("points", [])
    full = next((p for p in pts if p["value"] == "none"), None)
    removable = [p for p in pts if p["value"] != "none" and decisive(p["error"], p["upper"]) <= cfg["tolerance"]]
    combo = replace(ref, **chosen, prune=tuple(p["value"] for p in removable))
    predicted = math.prod(summary[k]["recommendation"]["speedup"] for k in chosen)
    predicted *= math.prod(full["cost"] / p["cost"] for p in removable)
    out = {"setting": vars(combo).copy(), "predicted_speedup": predicted, "verified": False, "reason": ""}
    if not cfg["verify"] or combo == ref:
        out["reason"] = "not requested" if not cfg["verify"] else "the reference itself"
        return out
    if combo.spp % combo.bin**2:
        out["reason"] = f"spp {combo.spp} is not a multiple of b² = {combo.bin**2}: not computed"
        return out
    sweep.evaluate([combo])
    p, r = (
        _point(name, s, *sweep.done[s], sweep.done[ref][0], cfg)
        for name, s in (("combined", combo), ("reference", ref))
    )
    out.update(
        verified=True,
        error=p["error"],
        lower=p["lower"],
        upper=p["upper"],
        cost=p["cost"],
        speedup=r["cost"] / p["cost"],
        within=decisive(p["error"], p["upper"]) <= cfg["tolerance"],
    )
    return out


def _depth_sufficiency(sweep: _Sweep, summary: dict, ref: Setting, thetas: list[float], cfg: dict) -> dict:
    """Bound change against the deepest path over the NLOS grid points (all when none is NLOS), with its
    limits, and the depth from which it stays within tolerance (upper limits, where there are any)."""
    lu = cfg["los_until"]
    mask = np.array([lu is None or t > lu for t in thetas])
    if not mask.any():
        mask[:] = True
    ref_res = sweep.done[ref][0]
    rows = []
    for p in summary["max_depth"]["points"]:
        res = sweep.done[replace(ref, max_depth=p["value"])][0]
        e = _errors(res, ref_res, mask)
        error = aggregate(np.concatenate([e["hcr"], e["crlb"]]), cfg["aggregate"])
        lower, upper = _limits(res, ref_res, cfg, mask)
        rows.append(
            {
                "max_depth": p["value"],
                "error": error,
                "lower": lower,
                "upper": upper,
                "median_log10_hcr": {n: float(np.median(res[n].hcr[mask])) for n in res},
                "median_log10_crlb": {n: float(np.median(res[n].crlb[mask])) for n in res},
            }
        )
    return {
        "nlos_points": int(mask.sum()),
        "all_points": bool(mask.all()),
        "rows": rows,
        "settled": settled([r["max_depth"] for r in rows],
                           [decisive(r["error"], r["upper"]) for r in rows], cfg["tolerance"]),
    }


def smoke(block: dict) -> dict:
    """A seconds-long copy: 3 grid points, spp [4, 16], bins [1, 2], two depths, one pruned element."""
    two = lambda xs: sorted(set(xs))[:1] + sorted(set(xs))[-1:] if len(set(xs)) > 1 else list(xs)  # noqa: E731
    return {
        **block,
        "grid": smoke_grid(block["grid"], 3),
        "spp": [4, 16] if len(set(block["spp"])) > 1 else [16],
        "bins": [1, 2] if any(b > 1 for b in block["bins"]) else [1],
        "max_depth": two(block["max_depth"]),
        "prune": block["prune"][:1],
    }


def _pct(e: float) -> str:
    return "∞" if math.isinf(e) else f"{100 * e:.3g} %"


def _limits_cell(p: dict) -> str:
    return "n/a" if math.isnan(p["upper"]) else f"[{_pct(p['lower'])}, {_pct(p['upper'])}]"


def _verdict(p: dict, tol: float) -> str:
    """Is the error within tolerance? yes (upper limit within it) / no (lower limit beyond it) / not
    resolved; without limits (fewer than 3 replicates) the point error decides."""
    if math.isnan(p["upper"]):
        return "yes" if p["error"] <= tol else "no"
    return "yes" if p["upper"] <= tol else "no" if p["lower"] > tol else "not resolved"


def _marked(verdict: str, p: dict) -> str:
    """A verdict cell, marked "(no limits)" where the point error alone decided it."""
    return verdict + (" (no limits)" if math.isnan(p["upper"]) else "")


def _convergence(results: dict) -> str:
    """One sentence on the reference's own noise and whether it resolves the tolerance."""
    tol, noise, R = results["tolerance"], results["reference_noise"], results["replicates"]
    head = (f"The bounds compared are point estimates from unbiased λ and Fisher information (U-statistics over {R} "
            "independent render sets), so the reference has no spp bias to converge away; its Monte Carlo noise ")
    if math.isnan(noise):
        return head + ("is unknown: confidence limits need replicates >= 3. **Caution:** errors below may be noise.")
    level = f"{results['level']:.0%} one-sided limits"
    if results["reference_converged"]:
        return head + f"is ±{_pct(noise)} ({level}): converged (≤ tolerance / 2 = {_pct(tol / 2)})." + _spread(results)
    need = math.ceil(R * (noise / (tol / 2)) ** 2) if math.isfinite(noise) else None
    more = f"about {need} replicates (or {need / R:.3g}× the spp)" if need else "resolved bounds (an open end)"
    return head + (f"is ±{_pct(noise)} ({level}), more than tolerance / 2 = {_pct(tol / 2)}. **Caution:** the "
                   "reference is not converged: the errors' limits below still compare each setting with the "
                   f"reference on the same render sets, but the reference bound itself is that uncertain; {more} "
                   "would converge it." + _spread(results))


def _spread(results: dict) -> str:
    """A sentence when the reference's intervals are wider than its points' noise (the FD variants' spread):
    what that spread is and that more replicates would not remove it; "" otherwise (or for an older run)."""
    width, noise, tol = results.get("reference_interval", math.nan), results["reference_noise"], results["tolerance"]
    if not (width > max(noise, tol / 2)):  # NaN-safe: no sentence without both
        return ""
    return (f" Its bounds' confidence intervals are wider, ±{_pct(width)}: a CRLB end also spans the FD variants "
            "(central, forward and backward differences at the step), whose spread is not Monte Carlo noise but how "
            "far those derivatives differ (an edge that crosses a pixel within the step parts them); more replicates "
            "do not shrink it, and the errors compare central differences only, so it does not enter them.")


def report(study_dir: Path, results: dict) -> str:
    fidelity_plots(study_dir, results)
    ref, tol = results["reference"], results["tolerance"]
    unit = "s" if results["cost"] == "seconds" else "pixel-samples"
    rc = results["reference_cost"]
    lines = [
        f"Bound error against cost, one knob at a time around the reference (spp {ref['spp']} per sensor pixel, "
        f"no binning, max_depth {ref['max_depth'] or 'of the scene'}, FD Jacobians): {results['grid_points']}-point "
        f"grid of {results['parameter']}, {results['seeds']} seeds, noise {', '.join(results['noises'])}. Error = "
        f"{results['aggregate']} over θ, noise models and bounds (HCR, CRLB) of |b/b_ref − 1|; cost in {unit} "
        f"(renders and Jacobians; scene loads and warm-up excluded). Reference: {rc['seconds']:.3g} s, "
        f"{rc['renders']} renders. Tolerance {_pct(tol)}."
        + (
            f" In {results['reference_sup_at_smallest_delta']} (θ, noise) pairs the reference HCR's sup sits at the "
            "smallest grid Δ: a finer grid may raise those bounds, whose errors then compare grid-limited values."
            if results["reference_sup_at_smallest_delta"]
            else ""
        ),
        "",
        "",
        _convergence(results),
        "",
        f"Limits: joint {results['level']:.0%} confidence limits of the error (paired jackknife over the "
        f"{results['replicates']} replicate sets, Bonferroni over the distinct comparisons of θ, noise models and "
        "bounds); within: yes when the upper limit is within tolerance, no when the lower limit is beyond it.",
    ]
    swept = {k: s for k, s in results["knobs"].items() if k != "prune"}
    if swept:
        lines += ["", f"| knob | value | cost [{unit}] | renders | error HCR | error CRLB | error | limits | within |",
                  "|---|---|---|---|---|---|---|---|---|"]
    for knob, s in swept.items():
        for p in s["points"]:
            mark = " (ref)" if p["value"] == s["reference"] else ""
            work = f"{p['renders']}" + (f" + {p['grad_passes']} AD passes" if p["grad_passes"] else "")
            lines.append(
                f"| {knob} | {p['value']}{mark} | {p['cost']:.4g} | {work} | {_pct(p['error_hcr'])} | "
                f"{_pct(p['error_crlb'])} | {_pct(p['error'])} | {_limits_cell(p)} | {_marked(_verdict(p, tol), p)} |"
            )
    if swept:
        lines += ["", "| knob | recommended | reference | error | limits | speed-up |", "|---|---|---|---|---|---|"]
    for knob, s in swept.items():
        if "recommendation" in s:
            r = s["recommendation"]
            chosen = next(p for p in s["points"] if p["value"] == r["value"])
            lines.append(f"| {knob} | {r['value']} | {s['reference']} | {_pct(r['error'])} | {_limits_cell(chosen)} | "
                         f"{r['speedup']:.3g}× |")
    o = results["overall"]
    combo = ", ".join(
        f"{k} {o['setting'][k]}" for k in ("spp", "bin", "max_depth", "gradient") if o["setting"][k] is not None
    ) + (f", without {', '.join(o['setting']['prune'])}" if o["setting"]["prune"] else "")
    lines += [
        "",
        f"**Overall:** {combo}; predicted speed-up {o['predicted_speedup']:.3g}× (product of the knobs' and "
        "removals'). "
        + (
            f"Computed: error {_pct(o['error'])}, limits {_limits_cell(o)} "
            f"({'within' if o['within'] else 'NOT within'} tolerance: "
            + ("the errors do not compound here" if o["within"]
               else "the errors compound: keep one knob at its reference")
            + f"), speed-up {o['speedup']:.3g}×."
            if o["verified"]
            else f"Not computed ({o['reason']})."
        ),
    ]
    lines += ["", f"![bound error against cost]({study_dir.name}/fidelity.png)"]
    d = results["depth"]
    if d is not None:
        where = (
            "all grid points"
            if d["all_points"]
            else f"the {d['nlos_points']} NLOS grid points (θ > {results['los_until']})"
        )
        lines += [
            "",
            f"**Depth sufficiency** over {where}: "
            + (f"the bound stops changing (within {_pct(tol)}) from max_depth {d['settled']} on."
               if d["settled"] != d["rows"][-1]["max_depth"] else
               f"the bound still changes up to the deepest path tried (max_depth {d['settled']}): no shorter "
               f"path is within {_pct(tol)} of it, and deeper paths may still move it."),
            "",
            "| max_depth | change vs deepest | limits | "
            + " | ".join(f"median log10 HCR, {n}" for n in results["noises"])
            + " |",
            "|---|---|---|" + "---|" * len(results["noises"]),
        ]
        for r in d["rows"]:
            lines.append(
                f"| {r['max_depth']} | {_pct(r['error'])} | {_limits_cell(r)} | "
                + " | ".join(f"{r['median_log10_hcr'][n]:.4g}" for n in results["noises"])
                + " |"
            )
        lines += [
            "",
            "(±inf: no usable Δ or no information at that depth, e.g. the object does not show in the image; "
            "the plot leaves such values out.)",
            "",
            f"![depth]({study_dir.name}/depth.png)",
        ]
    if "prune" in results["knobs"]:
        s = results["knobs"]["prune"]
        base = next(p for p in s["points"] if p["value"] == "none")
        lines += [
            "",
            "**Scene pruning:** the reference bound with one element removed.",
            "",
            "| element removed | error HCR | error CRLB | limits | bound depends on it | cost vs full scene |",
            "|---|---|---|---|---|---|",
        ]
        depends = {"yes": "no", "no": "yes", "not resolved": "not resolved"}  # depends = not within
        for p in s["points"]:
            if p["value"] != "none":
                lines.append(
                    f"| {p['value']} | {_pct(p['error_hcr'])} | {_pct(p['error_crlb'])} | {_limits_cell(p)} | "
                    f"{_marked(depends[_verdict(p, tol)], p)} | {p['cost'] / base['cost']:.3g}× |"
                )
    return "\n".join(lines)
