"""Study `bounds`: the HCR interval with its Δ → 0 term, the CRLB from an unbiased Fisher information,
the paper's HCR_Neff (and optionally Barankin) over a 1-D grid of θ, and the Ziv–Zakai bound over Θ.

Plan: the grid, spp, seeds and replicates from the block. Work: one call to the bound service's `curve`
(R·G renders from the render bank: every grid render serves as θ* and as a test point for all others,
the grid neighbours as FD stencils). Tables: bounds.csv (a row per noise and θ), zzb.csv (a row per noise).
With a `precision` target, the same `curve` call also quotes the bounds at the θ the study names (`precision_at`,
on or off the grid; every grid θ when it is empty): after the curve, the service's `at` there with the curve's sets
as pilot (its test grid the curve's own when the grid is `params.grid(G)`), which adds fresh replicate sets where an
interval is wider than asked (`bounds.precision`): precise.csv (a row per noise and quoted θ, with the precision_*
columns), a report table "Precision at the quoted θ" and those points on the plot.
With `precision_predict`, the curve predicts from its own sets what meeting that target at each grid θ would cost in
fresh replicate sets of the whole grid (nothing is rendered for it; results.json `predicted`), and the report says
what the points it did not resolve would cost.
Report: from those and results.json only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bounds import BoundService
from ..bounds.service import quote_test_grid
from ..io import read_csv, write_csv, write_exr
from ..schema import GRID, MAX_HALVINGS, STEP_TOL, ConfigError, Field, grid_values, positive_number, smoke_grid
from . import precise
from .context import RunContext
from .estimate import Estimate, describe, pixels
from .plots import bound_curves_plot
from .plotstyle import noise_text, note, resolved
from .tables import fmt, fmt_end, fmt_log10

NAME = "bounds"
SCHEMA = {
    "grid": GRID,
    "spp": Field(int, 1024, "samples per pixel of each grid render"),
    "seeds": Field(str, "common", "render seeds across the grid in each replicate: common (common random "
                   "numbers: far less rendering noise in L(θ+Δ) − L(θ)) or independent (the paper)",
                   choices=("independent", "common")),
    "replicates": Field(int, 3, "independent replicate render sets (U-statistics; >= 3 for confidence limits)"),
    "level": Field(float, 0.95, "one-sided confidence level of every interval end"),
    "crlb": Field(bool, True, "also report the CRLB (its Δ → 0 term enters the HCR either way)"),
    "fd_step": Field(float, None, "FD step ξ of the Δ → 0 term and the CRLB (parameter units); null: the grid "
                                  "neighbours (no extra render)", nullable=True),
    "step_tol": STEP_TOL,
    "max_halvings": Field(MAX_HALVINGS.type, MAX_HALVINGS.default, MAX_HALVINGS.help + " (at the `precision_at` θ "
                          "only: a curve does not halve its step)"),
    "precision_at": Field(list, [], "θ the study quotes (on or off the grid): after the curve, the bounds there to "
                                    "the `precision` target (needs `precision`); empty with a `precision`: every "
                                    "grid θ", items=float),
    **precise.KEYS,
    "precision_predict": Field(positive_number, None, "a target p for the curve's own points: from its sets, the fresh "
                               "replicate sets of the whole grid each θ would need for ±p (nothing is rendered for "
                               "it; one set serves every θ), so the report says what the curve would cost at p",
                               nullable=True),
    "precision_beyond": Field(list, [], "[θ₀, p₀]: beyond θ₀ the target of the quoted bounds and of the curve's "
                              "prediction is p₀ instead of `precision` / `precision_predict` (where the information "
                              "is small a looser target decides as much; needs one of them)", items=float),
    "precision_step_tol_beyond": Field(positive_number, None, "beyond `precision_beyond`'s θ₀, the quoted bounds' "
                                       "step tolerance instead of `step_tol` (F(ξ/2)/F(ξ) shown ≤ 1 + it): a looser "
                                       "target may take a check as much looser, which costs fewer sets where F has "
                                       "settled; needs `precision` and `precision_beyond`", nullable=True),
    "precision_fd_step": Field(float, None, "the quoted bounds' first FD step ξ, halved per θ until F settles (at most "
                               "`max_halvings` times): large where L(θ) is smooth, the halvings reach an edge's step; "
                               "null: `fd_step`, else the grid spacing", nullable=True),
    "precision_fd_step_until": Field(list, [], "[[θ₁, ξ₁], [θ₂, ξ₂], …] (θ increasing): up to θ₁ the quoted bounds' "
                                     "first FD step is ξ₁, from there up to θ₂ ξ₂ …, beyond the last "
                                     "`precision_fd_step` (in line of sight an edge at pixel scale wants a small "
                                     "start, beyond the corner a smooth L(θ) a large one; one pair may be given "
                                     "flat, [θ₀, ξ₀]; needs `precision`)"),
    "hcr_offsets": Field(int, 4, "the quoted bounds' extra HCR test points ±ξ·2^k (k < hcr_offsets) around each θ, "
                         "besides the grid's Δ and Δ → 0; 0: none"),
    "barankin": Field(bool, False, "also compute the multi-point Barankin bound at each grid point (plug-in)"),
    "zzb": Field(bool, True, "the Ziv–Zakai bound on the Bayesian MSE over a uniform prior on the grid's range "
                             "(needs a uniform grid)"),
    "los_until": Field(float, None, "θ where the object leaves the line of sight (marked on plots)", nullable=True),
    "save_images": Field(bool, True, "keep every grid render as EXR"),
}


@dataclass(frozen=True)
class Plan:
    """What the study computes: the θ grid (G,), spp, seeds, replicates, level and which bounds; the quoted θ
    (precision_at, (Q,)), the test grid the service gives their bounds (`quote_test_grid`), for the cost, their
    first FD step (`quote_step`: one for all, one per quoted θ (Q,), or None: the service's default) and step
    tolerance (`quote_step_tol`: one per quoted θ (Q,), or None: `step_tol`)."""

    thetas: np.ndarray
    spp: int
    seeds: str
    replicates: int
    level: float
    crlb: bool
    barankin: bool
    zzb: bool
    fd_step: float | None
    step_tol: float
    precision_at: np.ndarray
    test_grid: int
    quote_step: float | np.ndarray | None = None
    quote_step_tol: float | np.ndarray | None = None


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError for what the schema cannot see."""
    sid = cfg.get("id") or NAME
    params = ctx.model.params
    if params.dim != 1:
        raise ConfigError(f"{sid}", f"the bounds study needs one parameter; set scene.params to one of "
                                    f"{list(params.names)}")
    thetas = np.asarray(grid_values(cfg["grid"]), dtype=np.float64)
    for t in (thetas.min(), thetas.max()):
        try:
            params.validate([t])
        except ValueError as e:
            raise ConfigError(f"{sid}.grid", str(e)) from None
    if len(thetas) < 3 or np.any(np.diff(thetas) <= 0):
        raise ConfigError(f"{sid}.grid", f"expected at least 3 distinct θ, got {len(set(thetas.tolist()))}")
    if cfg["spp"] < 1:
        raise ConfigError(f"{sid}.spp", f"expected a positive number of samples per pixel, got {cfg['spp']}")
    if cfg["replicates"] < 2:
        raise ConfigError(f"{sid}.replicates", f"expected >= 2 (>= 3 for confidence limits), got {cfg['replicates']}")
    if cfg["fd_step"] is not None and not cfg["fd_step"] > 0:
        raise ConfigError(f"{sid}.fd_step", f"expected a step > 0 or null, got {cfg['fd_step']}")
    if not 0 < cfg["level"] < 1:
        raise ConfigError(f"{sid}.level", f"expected a confidence level in (0, 1), got {cfg['level']}")
    if cfg["precision_at"] and cfg["precision"] is None:
        raise ConfigError(f"{sid}.precision_at", "quoting bounds at θ needs a `precision` target")
    if cfg["precision_predict"] is not None:  # the same needs as a target the study spends
        precise.check({**cfg, "precision": cfg["precision_predict"], "precision_budget": None}, sid,
                      ("hcr", "crlb") if cfg["crlb"] else ("hcr",))
    if cfg["precision_beyond"] and cfg["precision"] is None and cfg["precision_predict"] is None:
        raise ConfigError(f"{sid}.precision_beyond", "needs a `precision` or `precision_predict` target")
    for key in ("precision_fd_step", "precision_fd_step_until"):
        if cfg[key] not in (None, []) and cfg["precision"] is None:
            raise ConfigError(f"{sid}.{key}", "needs a `precision` target")
    if cfg["precision_beyond"] and (len(cfg["precision_beyond"]) != 2 or not cfg["precision_beyond"][1] > 0):
        raise ConfigError(f"{sid}.precision_beyond", f"expected [θ₀, p₀] with p₀ > 0, got {cfg['precision_beyond']}")
    if cfg["precision_step_tol_beyond"] is not None and (cfg["precision"] is None or not cfg["precision_beyond"]):
        raise ConfigError(f"{sid}.precision_step_tol_beyond", "needs a `precision` target and `precision_beyond`")
    if cfg["precision_fd_step"] is not None and not cfg["precision_fd_step"] > 0:
        raise ConfigError(f"{sid}.precision_fd_step", f"expected a step > 0 or null, got {cfg['precision_fd_step']}")
    ranges = step_ranges(cfg["precision_fd_step_until"], f"{sid}.precision_fd_step_until")
    if cfg["hcr_offsets"] < 0:
        raise ConfigError(f"{sid}.hcr_offsets", f"expected an integer >= 0, got {cfg['hcr_offsets']}")
    precise.check(cfg, sid, ("hcr", "crlb") if cfg["crlb"] else ("hcr",))
    for i, t in enumerate(cfg["precision_at"]):
        try:
            params.validate([t])
        except ValueError as e:
            raise ConfigError(f"{sid}.precision_at[{i}]", str(e)) from None
    grid = np.unique(thetas)
    # a target without `precision_at` quotes every grid θ: the curve's sets are the pilot, fresh sets go only where
    # an interval is wider than asked
    quoted = np.asarray(cfg["precision_at"] or (grid.tolist() if cfg["precision"] is not None else []),
                        dtype=np.float64)
    step = cfg["precision_fd_step"]
    if ranges:  # a first FD step per quoted θ
        step = first_steps(quoted, ranges, step or cfg["fd_step"] or float(np.diff(grid).min()))
    tol = None if cfg["precision_step_tol_beyond"] is None else np.where(
        quoted > cfg["precision_beyond"][0], cfg["precision_step_tol_beyond"], cfg["step_tol"])
    return Plan(grid, cfg["spp"], cfg["seeds"], cfg["replicates"], cfg["level"], cfg["crlb"],
                cfg["barankin"], cfg["zzb"], cfg["fd_step"], cfg["step_tol"], quoted,
                quote_test_grid(params, grid), step, tol)


def step_ranges(value: list, path: str) -> list[list[float]]:
    """`precision_fd_step_until` as pairs [[θ₁, ξ₁], …] (a flat [θ₀, ξ₀] is one pair): θ finite and increasing,
    ξ > 0 (parameter units); ConfigError otherwise."""
    pairs = [value] if value and not any(isinstance(v, list) for v in value) else value
    out = []
    for pair in pairs:
        ok = (isinstance(pair, list) and len(pair) == 2 and
              all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pair))
        if not ok or not pair[1] > 0:
            raise ConfigError(path, f"expected [θ₀, ξ₀] pairs with ξ₀ > 0, got {value}")
        if out and not pair[0] > out[-1][0]:
            raise ConfigError(path, f"expected the pairs' θ increasing, got {value}")
        out.append([float(pair[0]), float(pair[1])])
    return out


def first_steps(thetas: np.ndarray, ranges: list[list[float]], beyond: float) -> np.ndarray:
    """The first FD step of each quoted θ (T,): ξ_k of the first range [θ_k, ξ_k] with θ ≤ θ_k, else `beyond`."""
    out = np.full(len(thetas), float(beyond))
    for edge, xi in reversed(ranges):
        out[np.asarray(thetas) <= edge] = xi
    return out


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """R·G grid renders; with an `fd_step`, 4R·G FD stencil renders more (at ξ and at ξ/2, the step check);
    with a noise model whose weight is signal-dependent (Poisson), G weight renders more; with a `precision` target,
    the pilot at the quoted θ (per set θ*, its 2·`hcr_offsets` axis offsets, 2 FD stencils per step, every halving
    counted, and the test grid, which is the curve's own renders when it is the curve's grid: charged to the pilot,
    not rendered again) and what its fresh looks may spend (`precise.estimate`)."""
    weight = any(n.signal_dependent for n in ctx.noises)
    px = pixels(ctx.model)
    renders = p.replicates * len(p.thetas) * (1 + (4 if p.fd_step is not None else 0)) + weight * len(p.thetas)
    samples, pilot = renders * p.spp * px, 0
    if len(p.precision_at):
        Q = len(p.precision_at)
        own = p.replicates * Q * (1 + 2 * cfg["hcr_offsets"] + 2 * (cfg["max_halvings"] + 1)) + weight * Q
        renders += own + (0 if p.test_grid == len(p.thetas) else p.replicates * p.test_grid)
        samples = renders * p.spp * px
        pilot = (own + p.replicates * p.test_grid) * p.spp * px
    return precise.estimate(renders, samples, cfg, p.spp, px, pilot)


def run(ctx: RunContext, cfg: dict) -> dict:
    p, out = plan(ctx, cfg), ctx.study_dir(cfg)
    before = ctx.bank.renders
    svc = BoundService(ctx.bank, ctx.noises, p.level)
    # with a target, the quoted θ (None: every grid θ) to it, the curve's sets their pilot
    kw = precise.at_kwargs(cfg)
    predict = cfg["precision_predict"]
    if cfg["precision_beyond"]:  # a target per quoted θ, and per grid θ for the curve's prediction
        edge, looser = cfg["precision_beyond"]
        if kw["precision"] is not None:
            kw["precision"] = np.where(p.precision_at > edge, looser, kw["precision"])
        if predict is not None:
            predict = np.where(p.thetas > edge, looser, predict)
    curve = svc.curve(p.thetas, p.spp, p.seeds, p.replicates, crlb=p.crlb, barankin=p.barankin, zzb=p.zzb,
                      fd_step=p.fd_step, step_tol=p.step_tol, quote=cfg["precision_at"] or None,
                      max_halvings=cfg["max_halvings"], offsets=cfg["hcr_offsets"], quote_step=p.quote_step,
                      quote_step_tol=p.quote_step_tol, predict=predict, **kw)
    names = ctx.model.params.names
    write_csv(out / "bounds.csv", [pt.row(names) for pt in curve.points])
    precision = []
    if curve.precise:
        Q = len(p.precision_at)
        write_csv(out / "precise.csv", [{"theta_index": n % Q, **pt.row(names)} for n, pt in enumerate(curve.precise)])
        precision = precise.records(curve.precise, Q, names)
    zrows = [{"noise_index": j, "noise": str(ctx.noises[j]), **b.columns(), **b.extra}
             for j, b in curve.zzb.items() if b is not None]
    if zrows:
        write_csv(out / "zzb.csv", zrows)
    if cfg["save_images"]:  # the first replicate's grid renders, from the bank's memory
        for g, img in enumerate(svc.replicates(p.thetas, p.spp, p.seeds, 1)[0]):
            write_exr(out / "images" / f"grid_{g:04d}.exr", img)
    return {"grid_points": len(p.thetas), "renders": ctx.bank.renders - before, "spp": p.spp, "seeds": p.seeds,
            "replicates": p.replicates, "level": p.level, "step_tol": p.step_tol, "los_until": cfg["los_until"],
            "parameter": names[0],
            "units": ctx.model.params.units[0], "zzb_reason": curve.zzb_reason,
            "noise": summarize(read_csv(out / "bounds.csv"), zrows, precision),
            **({"precision": precision} if precision else {}),
            **({"step_tol_beyond": [cfg["precision_beyond"][0], cfg["precision_step_tol_beyond"]]}
               if p.quote_step_tol is not None else {}),
            **({"predicted": precise.records(curve.points, len(p.thetas), names)} if predict is not None else {}),
            **({"seconds_per_sample": ctx.rate} if precision or predict is not None else {})}


def summarize(rows: list[dict], zrows: list[dict], records: list[dict] = ()) -> dict:
    """Per noise model: the range of the HCR's lower end, where the Δ → 0 term sets it, θ with an open upper
    end, θ whose Δ → 0 lower end is not a confidence limit (FD step not converged), θ resolved (`plotstyle.resolved`:
    both ends of the HCR and the CRLB confidence limits), the ZZB with its ends, and with precision `records`
    (`precise.records`) how many θ were quoted and how many met their target there (`quoted`, `met`)."""
    out = {}
    for noise in dict.fromkeys(r["noise"] for r in rows):
        rs = [r for r in rows if r["noise"] == noise]
        low = np.array([float(r["log10_hcr"]) for r in rs])
        fin = low[np.isfinite(low)]
        z = next((z for z in zrows if z["noise"] == noise), None)
        out[noise] = {"max_log10_hcr": float(fin.max()) if fin.size else float("nan"),
                      "min_log10_hcr": float(fin.min()) if fin.size else float("nan"),
                      "set_by_limit": sum("lower: Δ → 0" in r["hcr_terms"] for r in rs),
                      "upper_unbounded": sum("upper-unbounded" in r["hcr_flags"] for r in rs),
                      "step_not_converged": sum("fd-step-not-converged" in r["hcr_flags"] for r in rs),
                      "not_limits": sum(bool(r.get("hcr_lower_note")) for r in rs),
                      "resolved": sum(resolved(r) for r in rs),
                      "zzb": None if z is None else {k: float(z[k]) for k in ("log10_zzb", "zzb_upper", "zzb_point",
                                                                               "prior_variance", "halved")} |
                      {"flags": z["zzb_flags"]}}
        mine = [r for r in records if r["noise"] == noise]
        if mine:
            out[noise] |= {"quoted": len(mine), "met": sum(r["met"] for r in mine)}
    return out


def resolution(rows: list[dict], parameter: str, records: list[dict], seconds_per_sample: float | None,
               level: float, los_until: float | None = None, predicted: list[dict] = ()) -> list[str]:
    """The caption's lines under the curve: per noise model how many θ of `rows` (bounds.csv) are resolved
    (`plotstyle.resolved`; with `los_until`, also in line of sight, θ < los_until, and beyond), then what the
    precision `records` (`precise.records`, at the quoted θ; [] without a target) say of every quoted θ, resolved on
    the curve or not (`_quoted_cost`, its time at `seconds_per_sample`, the run's measured rate; None: no time); without
    them, for the θ not resolved, what the curve's own prediction (`predicted`, its records per grid θ:
    `BoundService.curve(predict=...)`) says: the fresh sets of the whole grid that would meet the target there (one
    set serves every θ: the largest count is the cost), or none at the curve's FD step; else how to have the cost
    predicted. Each end is a pointwise one-sided limit at `level`."""
    lines = [f"Resolved: both ends of the HCR and of the CRLB are one-sided {level:.0%} confidence limits (no open "
             f"end, none labelled not a confidence limit); each end holds pointwise, so about {1 - level:.0%} of the "
             "ends may miss.", ""]
    for noise in dict.fromkeys(r["noise"] for r in rows):
        rs = [r for r in rows if r["noise"] == noise]
        rest = [float(r[f"theta_{parameter}"]) for r in rs if not resolved(r)]
        text = f"- {noise_text(noise)}: {len(rs) - len(rest)} of {len(rs)} points resolved"
        if los_until is not None:
            thetas = [float(r[f"theta_{parameter}"]) for r in rs]
            los = sum(t < los_until for t in thetas)
            text += (f" (line of sight {los - sum(t < los_until for t in rest)} of {los}, beyond the corner "
                     f"{len(rs) - los - sum(t >= los_until for t in rest)} of {len(rs) - los})")
        mine = [r for r in records if r["noise"] == noise]
        own = [r for r in predicted if r["noise"] == noise and not r["met"]]
        if mine:
            lines.append(text + "; " + _quoted_cost(mine, rest, seconds_per_sample))
        elif not rest:
            lines.append(text + ".")
        elif own:
            lines.append(text + "; " + _curve_cost(own, len(rs), seconds_per_sample))
        else:
            lines.append(text + f"; the other {len(rest)}: no cost predicted without a precision target (set "
                         "`precision`, e.g. 0.25, and the bound service predicts at each θ what more replicate sets "
                         "would cost; `precision_budget: 1` keeps it to the pilot and the prediction).")
    return lines


def _quoted_cost(mine: list[dict], rest: list[float], seconds_per_sample: float | None) -> str:
    """What the precision records at the quoted θ (`mine`, one noise model) say, whether or not the curve resolved
    their grid point: how many met their target, the extra pixel-samples of the others summed over θ with their time
    at `seconds_per_sample` (None: no time), how many no number of sets is predicted to meet, and how many of the
    curve's unresolved θ (`rest`) were not quoted."""
    met = sum(r["met"] for r in mine)
    extra = [r["extra_pixel_samples"] for r in mine if not r["met"]]
    finite = [x for x in extra if math.isfinite(x)]
    goals = " / ".join(f"±{fmt(100 * g, 3)} %" for g in sorted({r["target"] for r in mine}))
    parts = [f"{met} met {goals}"]
    if finite:
        total = sum(finite)
        when = (f", ≈ {describe(total * seconds_per_sample)} on this machine at its measured "
                f"{seconds_per_sample * 1e9:.3g} ns per pixel-sample" if seconds_per_sample else "")
        parts.append(f"{len(finite)} would need ≈ {total:.3g} more pixel-samples (each θ's prediction, summed{when})")
    if len(extra) > len(finite):
        parts.append(f"{len(extra) - len(finite)} are predicted to need more than any number of replicate sets at this "
                     "spp (more spp, a settled FD step or a wider target)")
    quoted = [next(iter(r["theta"].values())) for r in mine]
    unquoted = sum(not any(math.isclose(q, t, rel_tol=1e-9, abs_tol=1e-12) for q in quoted) for t in rest)
    tail = f"; {unquoted} unresolved θ not quoted (no prediction)" if unquoted else ""
    return f"at the {len(mine)} quoted θ, " + ", ".join(parts) + tail + "."


def _curve_cost(own: list[dict], G: int, seconds_per_sample: float | None) -> str:
    """What the curve's own prediction says of the θ that did not meet its target (`own`, records of one noise
    model; G grid θ in all): how many fresh sets of the whole grid meet it where a count is predicted, the
    largest count's pixel-samples and time (one set serves every θ), and how many no number of sets at the curve's
    FD step would."""
    targets = " / ".join(f"±{fmt(100 * g, 3)} %" for g in sorted({r["target"] for r in own}))
    finite = [r for r in own if math.isfinite(r["extra_sets"])]
    parts = []
    if finite:
        counts = sorted(r["extra_sets"] for r in finite)
        per_set = finite[0]["extra_pixel_samples"] / finite[0]["extra_sets"]  # a set of the whole grid

        def cost(sets: float) -> str:
            px = sets * per_set
            return (f"{fmt(sets, 3)} sets, {px:.3g} pixel-samples" +
                    (f", ≈ {describe(px * seconds_per_sample)}" if seconds_per_sample else ""))

        half = counts[(len(counts) - 1) // 2]
        parts.append(f"{len(finite)} would meet it with fresh replicate sets of the whole grid, one set serving every "
                     f"θ (from {fmt(counts[0], 3)} sets): half of them with {cost(half)}, all {len(finite)} with "
                     f"{cost(counts[-1])}" + (f" on this machine at its measured {seconds_per_sample * 1e9:.3g} ns per "
                                              "pixel-sample" if seconds_per_sample else ""))
    rising = sum(r["finer_step"] for r in own)
    if rising:
        parts.append(f"{rising} need a finer FD step than the grid's (F still rises at it: an edge), which a "
                     "`precision` target quotes through the bound service's `at`")
    if len(own) - len(finite) - rising:
        parts.append(f"{len(own) - len(finite) - rising} are predicted to need more than any number of sets at "
                     "this spp")
    return (f"what {targets} would cost, predicted from the curve's own sets (nothing rendered for it): {len(own)} of "
            f"the {G} θ miss it; " + "; ".join(parts) + ".")


def smoke(block: dict) -> dict:
    """The grid shrunk to about 4 points, ≤ 16 spp; a precision target keeps its quoted θ with a budget of 1
    pixel-sample (`precise.smoke`: the pilot and the plan, no fresh look)."""
    return precise.smoke({**block, "grid": smoke_grid(block["grid"], 4), "spp": min(block["spp"], 16)})


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "bounds.csv")
    units = results.get("units", "units")
    zzb = {n: s["zzb"]["log10_zzb"] for n, s in results["noise"].items() if s.get("zzb")}
    zrows = read_csv(study_dir / "zzb.csv") if (study_dir / "zzb.csv").exists() else []
    quoted = read_csv(study_dir / "precise.csv") if (study_dir / "precise.csv").exists() else []
    bound_curves_plot(rows, study_dir / "bounds.png", los_until=results.get("los_until"), units=units,
                      parameter=results.get("parameter", "θ"), zzb=zzb,
                      zzb_notes={z["noise"]: note(z, "zzb", "lower") for z in zrows}, quoted=quoted)
    lvl = f"{results['level']:.0%}"
    lines = [f"Bounds over a {results['grid_points']}-point grid at {results['spp']} spp × {results['replicates']} "
             f"replicate sets, {results['seeds']} seeds ({results['renders']} renders). log10 of {units}².", "",
             f"- **HCR** (variance of an unbiased estimator): each θ's HCR is a sup over every Δ ≠ 0, including Δ → 0, "
             f"whose limit is the CRLB term; λ(Δ) and the Fisher information are U-statistics over the replicates "
             f"(unbiased: rendering noise does not inflate them). On the plot its point (○, solid line) with a bar "
             f"from the lower end, a one-sided {lvl} confidence limit (jointly over the tested Δ and Δ → 0 that could "
             f"reach the sup) — the bound to quote — to the upper end, a one-sided {lvl} limit on the HCR over the "
             f"tested Δ and Δ → 0 (no Bonferroni share: one fixed term sets it; open where any tested Δ or F is not "
             f"resolved: an arrow to the top of the frame on the plot, ∞ in tables).",
             f"- **CRLB**: 1/F̂ from the unbiased Fisher information of the FD-smoothed derivative, with its {lvl} "
             f"ends over the FD steps tried (□, dashed line, its own bar beside the HCR's). An FD step that is too "
             f"wide makes F too small (an edge crossing a pixel inside θ ± ξ), so the step is checked: where the "
             f"paired upper limit of F at the finer step over F at the coarser exceeds "
             f"1 + {results.get('step_tol', 0.1):g}, the Δ → 0 lower ends are *not confidence limits* (labelled in "
             f"bounds.csv: hcr_lower_note, crlb_lower_note; the point drawn hollow on the plot). A curve does not "
             f"refine its step; the bounds a trials or fisher-maps study quotes at its θ* do.",
             "- **HCR_Neff (paper)**: the paper's direct bound from the replicate means, sup over the grid's Δ "
             "only: without its Δ → 0 term it can sit decades below the CRLB (the paper's 80 cm row is this).",
             "- **ZZB**: the Ziv–Zakai bound on the Bayesian MSE over a uniform prior on the grid's range: it holds "
             "for every estimator, biased or not (one number per noise model).", "",
             f"![bounds]({study_dir.name}/bounds.png)", "",
             *resolution(rows, results.get("parameter", "θ"), results.get("precision", []),
                         results.get("seconds_per_sample"), results["level"], results.get("los_until"),
                         results.get("predicted", [])), "",
             "| noise | log10 HCR lower end, min – max | θ where Δ → 0 sets it | θ with open upper end | "
             f"θ whose lower end is not a confidence limit | ZZB point [{lvl} ends] |", "|---|---|---|---|---|---|"]
    for noise, s in results["noise"].items():
        z = s.get("zzb")
        zz = "–"
        if z is not None:
            zz = f"{fmt_log10(z['zzb_point'])} [{fmt_end(z['log10_zzb'])}, {fmt_end(z['zzb_upper'])}]"
            if z["flags"]:
                zz += f" ({z['flags']}; grid halving: {z['halved']:+.2g} decades)"
        lines.append(f"| {noise} | {s['min_log10_hcr']:.3g} – {s['max_log10_hcr']:.3g} | {s['set_by_limit']} of "
                     f"{results['grid_points']} | {s['upper_unbounded']} | {s.get('not_limits', '–')} | {zz} |")
    if results.get("zzb_reason"):
        lines += ["", f"No ZZB: {results['zzb_reason']}."]
    if results.get("precision"):
        tol = f"1 + {results.get('step_tol', 0.1):g}"
        if results.get("step_tol_beyond"):
            edge, looser = results["step_tol_beyond"]
            tol += f" (1 + {looser:g} beyond {edge:g}, where the target is looser)"
        lines += ["", f"### Precision at the quoted θ ({units}²)", "",
                  "The bounds at `precision_at` from the bound service's `at` (the Δ → 0 term and the CRLB with their "
                  f"FD step halved until F(ξ/2)/F(ξ) is shown ≤ {tol}; ◆ HCR, ■ CRLB with their ends on the plot).",
                  ""]
        lines += precise.table(results["precision"], f"{units}²", results.get("seconds_per_sample"))
    return "\n".join(lines)
