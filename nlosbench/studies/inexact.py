"""Study `inexact`: HCR intervals [HCR_Neff, HCR-hat] from Monte Carlo renders at equal render budget.

For every θ* and Δ the scene is rendered at k spp levels (λ̃^(N_i), fitted to λ̂ = the N → ∞ limit)
and once at N_eff (HCR_Neff, the direct bound); each level and the N_eff set are R independent
replicates of N/R spp, which the half-sample bootstrap resamples for confidence intervals. The bound
service (`BoundService.interval`) plans and asks the render bank for these sets: a render at a θ point
serves every θ* that uses it (as θ* or as θ*+Δ), so a grid-aligned Δ set costs about one render set per
grid point. The level renders also feed the 1/N decay check (the paper's appendix), whose measured p the
fit can use (`power: measured`).

Resume: every render is kept in the run's render store (renders/, see `bank`), so a resumed run renders
only what is missing and then repeats the analysis (Gram matrices, fits, bootstrap, decay check: seconds
on small grids; estimated ≈ 3.5 h at paper scale with 6 noise models, recomputed per noise model), so its
numbers equal an uninterrupted run's. Seeds are the bank's (per set, level, replicate and θ point), so
results do not depend on the executor. Disk: 4·(k + 1)·R·H·W·C bytes per point (20 MB at the paper's
160 × 120 RGB, 10 levels, 8 replicates).
"""
from __future__ import annotations

import copy
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bank import check_spp
from ..bounds.decay import decay_check, pixel_variances
from ..bounds.inexact import check_levels, quadratic
from ..bounds.service import SEEDS, interval_points
from ..io import read_csv, write_csv
from ..schema import GRID, ConfigError, Field, grid_spec, grid_values, noise_spec, number_or
from .context import RunContext
from .estimate import Estimate, pixels
from .plots import inexact_plots, slug
from .tables import cell

NAME = "inexact"
BUDGET_TOLERANCE = 0.1  # warn when N_eff and Σ N_i differ by more than this fraction
SCHEMA = {
    "theta": GRID,
    "deltas": Field(grid_spec, help="offsets Δ (parameter units): a list or {start, stop, num}; list ± for both "
                                "sides; Δ = 0 and θ*+Δ outside Θ are skipped"),
    "levels": Field(list, [1024 * i for i in range(2, 12)], "spp levels N_1..N_k of the λ fit (the paper: "
                                                             "2048, 3072, …, 11264)", items=int),
    "n_eff": Field(int, 65536, "spp of the direct render set (equal budget: about the sum of the levels)"),
    "replicates": Field(int, 8, "independent renders per level and for N_eff, N/R spp each (bootstrap units)"),
    "seeds": Field(str, "independent", "render seeds across θ* and θ*+Δ in each replicate and level: independent "
                                       "(the paper) or common (common random numbers: tighter λ at small Δ)",
                   choices=SEEDS),
    "bootstrap": Field(int, 200, "half-sample resamples for the confidence intervals (0: none)"),
    "confidence": Field(float, 0.9, "confidence level of the bootstrap intervals"),
    "noise": Field(noise_spec, None, "index or list of indices into the experiment's noise models (null: all)",
                   nullable=True),
    "power": Field(number_or("measured"), 1.0, "decay rate p in λ̃ = λ + C/N^p: a number, or 'measured' (the "
                                                "decay check)"),
    "decay_weights": Field(int, 10000, "random weightings W ~ U[0, 1] in the decay check (0: skip it)"),
    "p_range": Field(list, [0.5, 1.5, 0.001], "p grid of the decay check: [start, stop, step]", items=float),
    "p_tolerance": Field(float, 0.1, "warn when the measured p is farther than this from 1"),
}


def smoke(block: dict) -> dict:
    """A reduced copy of a validated `inexact` block that runs in seconds through the same code path:
    2 θ* (the grid's ends), the smallest Δ on each side, 2 levels × 2 replicates (2 and 4 spp each),
    N_eff = Σ N_i (equal budget), ≤ 10 bootstrap resamples, ≤ 200 decay weightings."""
    b = copy.deepcopy(block)
    theta = grid_values(b["theta"])
    b["theta"] = [theta[0], theta[-1]] if len(theta) > 1 else theta
    d = np.asarray(grid_values(b["deltas"]), dtype=np.float64)
    neg, pos = d[d < 0], d[d > 0]
    b["deltas"] = ([float(neg.max())] if neg.size else []) + ([float(pos.min())] if pos.size else [])
    b.update(replicates=2, levels=[4, 8], n_eff=12, bootstrap=min(b["bootstrap"], 10),
             decay_weights=min(b["decay_weights"], 200))
    return b


@dataclass(frozen=True)
class Plan:
    """θ* (T,), Δ (D,), spp levels (k,), N_eff, replicates R, the noise models, the decay power (a number or
    'measured'), and the render points (Q,) of θ* and θ* + Δ inside Θ."""

    thetas: np.ndarray
    deltas: np.ndarray
    levels: np.ndarray
    n_eff: int
    replicates: int
    noises: dict
    power: float | str
    points: np.ndarray


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError naming the key for what the schema cannot see."""
    sid = cfg.get("id") or NAME
    params = ctx.model.params
    if params.dim != 1:
        raise ConfigError(
            sid, f"the inexact study needs one parameter; set scene.params to one of {list(params.names)}"
        )
    thetas = np.asarray(grid_values(cfg["theta"]), dtype=np.float64)
    for t in thetas:
        try:
            params.validate([t])
        except ValueError as e:
            raise ConfigError(f"{sid}.theta", str(e)) from None
    deltas = np.asarray(grid_values(cfg["deltas"]), dtype=np.float64)
    R = cfg["replicates"]
    try:
        levels = check_levels(cfg["levels"], R)
    except ValueError as e:
        raise ConfigError(f"{sid}.levels", str(e)) from None
    try:
        n_eff = int(check_spp([cfg["n_eff"]], R)[0])
    except ValueError as e:
        raise ConfigError(f"{sid}.n_eff", str(e)) from None
    try:
        noises = {
            j: quadratic(n)
            for j, n in ctx.select_noises("all" if cfg["noise"] is None else cfg["noise"], f"{sid}.noise").items()
        }
    except TypeError as e:
        raise ConfigError(f"{sid}.noise", str(e)) from None
    power = cfg["power"]
    if not (power == "measured" or (isinstance(power, (int, float)) and not isinstance(power, bool) and power > 0)):
        raise ConfigError(f"{sid}.power", f"expected a number > 0 or 'measured', got {power!r}")
    if cfg["bootstrap"] < 0 or (cfg["bootstrap"] and R < 2):
        raise ConfigError(f"{sid}.bootstrap", "must be >= 0 and needs replicates >= 2")
    if not 0 < cfg["confidence"] < 1:
        raise ConfigError(f"{sid}.confidence", f"must lie in (0, 1), got {cfg['confidence']}")
    if power == "measured" and not (cfg["decay_weights"] > 0 and R >= 2):
        raise ConfigError(f"{sid}.power", "measured needs the decay check (decay_weights > 0 and replicates >= 2)")
    try:
        points, _ = interval_points(thetas, deltas, params.lower[0], params.upper[0])
    except ValueError as e:
        raise ConfigError(f"{sid}.deltas", str(e)) from None
    return Plan(thetas, deltas, levels, n_eff, R, noises, power, points)


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """Every render point × (k levels + N_eff) × R replicates of N/R spp: (Σ N_i + N_eff) spp per point."""
    Q, R = len(p.points), p.replicates
    renders = Q * (len(p.levels) + 1) * R
    return Estimate(renders, Q * (int(sum(p.levels)) + p.n_eff) * pixels(ctx.model))


def run(ctx: RunContext, cfg: dict) -> dict:
    p, out = plan(ctx, cfg), ctx.study_dir(cfg)
    svc, R = ctx.bounds, p.replicates
    before, t0 = ctx.bank.renders, time.perf_counter()
    X = svc.interval_renders(p.thetas, p.deltas, p.levels, R, cfg["seeds"])
    summary: dict = {
        "parameter": ctx.model.params.names[0],
        "units": ctx.model.params.units[0],
        "levels": p.levels.tolist(),
        "n_eff": p.n_eff,
        "replicates": R,
        "seeds": cfg["seeds"],
        "bootstrap": cfg["bootstrap"],
        "confidence": cfg["confidence"],
        "theta_points": len(p.thetas),
        "render_points": len(p.points),
        "renders_planned": len(p.points) * R * (len(p.levels) + 1),
        "samples_levels_per_image": int(p.levels.sum()),
        "samples_eff_per_image": p.n_eff,
        "budget_ratio": p.n_eff / float(p.levels.sum()),
        "warnings": [],
    }
    if abs(summary["budget_ratio"] - 1) > BUDGET_TOLERANCE:
        summary["warnings"].append(
            f"unequal render budget: N_eff = {p.n_eff} vs Σ N_i = {int(p.levels.sum())} spp "
            "per image; the two ends of the interval are not compared at equal cost"
        )
        ctx.log(f"warning: {summary['warnings'][-1]}")
    decay = _decay(ctx, cfg, X, p.levels, out) if cfg["decay_weights"] > 0 and R >= 2 else None
    del X
    if decay is not None:
        summary["decay"] = decay
        if decay["warning"]:
            summary["warnings"].append(decay["warning"])
    power = decay["p"] if p.power == "measured" else float(p.power)
    summary["power"], summary["power_source"] = power, "measured" if p.power == "measured" else "assumed"
    results = svc.interval(
        p.thetas,
        p.deltas,
        p.levels,
        p.n_eff,
        R,
        power,
        cfg["bootstrap"],
        cfg["confidence"],
        ctx.seed_for("inexact-bootstrap"),
        seeds=cfg["seeds"],
        noises=list(p.noises),
    )
    summary.update(renders=ctx.bank.renders - before, render_seconds=time.perf_counter() - t0)
    hcr_rows, lam_rows = _tables(results)
    write_csv(out / "hcr.csv", hcr_rows)
    write_csv(out / "lambda.csv", lam_rows)
    summary["noise"] = _noise_summary(hcr_rows)
    return summary  # plots: report() draws them from the saved CSVs


def _decay(ctx: RunContext, cfg: dict, X, levels: np.ndarray, out: Path) -> dict:
    """The 1/N decay check on the per-pixel variances of every point's replicates (all θ points as
    pixels); writes decay*.csv and returns the summary (warnings are logged, not raised)."""
    R = X.shape[1]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = decay_check(
            pixel_variances(X.reshape(len(levels), R, -1)),
            levels // R,
            cfg["decay_weights"],
            p_grid=tuple(cfg["p_range"]),
            seed=ctx.seed_for("inexact-decay"),
            tolerance=cfg["p_tolerance"],
        )
    for w in caught:
        ctx.log(f"warning: {w.message}")
    write_csv(out / "decay.csv", [{"p": p, "fit_error": e} for p, e in zip(d.p_grid, d.fit_error, strict=True)])
    vals, counts = np.unique(d.p_opt, return_counts=True)
    write_csv(out / "decay_popt.csv", [{"p_opt": v, "count": int(c)} for v, c in zip(vals, counts, strict=True)])
    write_csv(
        out / "decay_gamma.csv",
        [{"spp": int(n), "gamma": g} for n, g in zip(levels // R, d.gamma_example, strict=True)],
    )
    ip = int(np.argmin(np.abs(d.p_grid - 1.0)))
    return {
        "p": d.p,
        "mean": d.mean,
        "std": d.std,
        "mode": d.mode,
        "q05": d.q05,
        "q95": d.q95,
        "at_edge": d.at_edge,
        "n_weights": int(d.p_opt.size),
        "fit_error_at_1": float(d.fit_error[ip]),
        "fit_error_min": float(d.fit_error.min()),
        "c_example": d.c_example,
        "warning": d.warning,
    }


def _tables(results) -> tuple[list[dict], list[dict]]:
    """hcr.csv rows (a row per noise and θ*) and lambda.csv rows (a row per noise, θ* and Δ)."""
    hcr_rows, lam_rows = [], []
    for pt, r in results:
        he, hh = r.hcr_neff, r.hcr_hat
        theta = float(pt.theta[0])
        hcr_rows.append(
            {
                "noise": pt.noise,
                "theta": theta,
                "log10_hcr_neff": he.log10,
                "log10_hcr_hat": hh.log10,
                "width_decades": r.width,
                "inverted": r.inverted,
                "ci_neff_lo": r.ci_neff[0],
                "ci_neff_hi": r.ci_neff[1],
                "ci_hat_lo": r.ci_hat[0],
                "ci_hat_hi": r.ci_hat[1],
                "delta_neff": he.delta,
                "delta_hat": hh.delta,
                "at_edge_neff": he.at_edge or "",
                "at_edge_hat": hh.at_edge or "",
                "unresolved_hat": hh.unresolved,
                "boot_unresolved": r.boot_unresolved,
                "noise_dominated": int(r.fit.noise_dominated.sum()),
                "reason_hat": hh.reason,
            }
        )
        for j, dj in enumerate(r.deltas):
            lam_rows.append(
                {
                    "noise": pt.noise,
                    "theta": theta,
                    "delta": dj,
                    **{f"lam_l{i}": r.lam_levels[i, j] for i in range(len(r.levels))},
                    "lam_neff": r.lam_eff[j],
                    "lam_hat": r.fit.lam[j],
                    "lam_se": r.fit.se[j],
                    "C": r.fit.C[j],
                    "noise_dominated": bool(r.fit.noise_dominated[j]),
                    "log10_f_neff": he.functional[j],
                    "log10_f_hat": hh.functional[j],
                }
            )
    return hcr_rows, lam_rows


def _noise_summary(rows: list[dict]) -> dict:
    """Per noise model: θ* with HCR-hat unresolved, with crossed ends, and the median and largest width."""
    out = {}
    for noise in dict.fromkeys(r["noise"] for r in rows):
        rs = [r for r in rows if r["noise"] == noise]
        widths = [r["width_decades"] for r in rs]
        out[noise] = {
            "unresolved_hat": sum(bool(r["unresolved_hat"]) for r in rs),
            "inverted": sum(bool(r["inverted"]) for r in rs),
            "median_width_decades": float(np.median(widths)),
            "max_width_decades": float(np.max(widths)),
        }
    return out


def report(study_dir: Path, results: dict) -> str:
    inexact_plots(study_dir, results)
    rows = read_csv(study_dir / "hcr.csv")
    lv = results["levels"]
    name = study_dir.name
    lines = [
        f"HCR interval from inexact renders for θ = {results['parameter']} at {results['theta_points']} θ* "
        f"({results['render_points']} distinct render points, {results['renders_planned']} renders planned, "
        f"{results['renders']} made by this run, {results['render_seconds']:.1f} s wall time"
        + f"). λ̂: weighted least squares of λ̃ = λ + C/N^p over "
        f"{len(lv)} levels N = {', '.join(map(str, lv))} (Σ = {results['samples_levels_per_image']} spp per image) "
        f"with p = {results['power']:.3f} ({results['power_source']}); HCR_Neff: one render set at "
        f"N_eff = {results['n_eff']} spp. Each level and N_eff: {results['replicates']} independent replicates, "
        f"{results.get('seeds', 'independent')} seeds across θ* and θ*+Δ.",
        "",
        "HCR_Neff is typically *below* the true HCR (rendering noise inflates λ); HCR-hat is above the HCR over "
        "the tested Δ only *in expectation* — one run can fall on either side, and a sup over more Δ can be "
        "higher. The bracketed ranges are "
        f"{results['confidence']:.0%} half-sample bootstrap intervals over the render replicates "
        f"({results['bootstrap']} resamples): how far another run of the same budget may land. "
        "Values: log10 of the bound on the variance [units²].",
        "",
    ]
    for w in results["warnings"]:
        if w != results.get("decay", {}).get("warning"):
            lines += [f"**Warning:** {w}.", ""]
    dec = results.get("decay")
    if dec:
        lines += [
            f"**Decay check** ({dec['n_weights']} random weightings of per-pixel variances): "
            f"p_opt median {dec['p']:.3f}, mean {dec['mean']:.3f} ± {dec['std']:.3f}, "
            f"90 % within [{dec['q05']:.3f}, {dec['q95']:.3f}]; mean relative fit error "
            f"{dec['fit_error_at_1']:.2e} at p = 1, {dec['fit_error_min']:.2e} at best. "
            + (f"**Warning:** {dec['warning']}." if dec["warning"] else "Consistent with the assumed 1/N rate."),
            "",
            f"![decay check]({name}/decay.png)",
            "",
        ]
    for noise, s in results["noise"].items():
        lines += [
            f"### {noise}",
            "",
            f"![HCR vs θ*]({name}/hcr_vs_theta_{slug(noise)}.png)",
            "",
            f"Median width {s['median_width_decades']:.3g} decades (max {s['max_width_decades']:.3g}); "
            f"HCR-hat unresolved (some λ̂ ≤ 0) at {s['unresolved_hat']} θ*; ends crossed "
            f"(HCR-hat < HCR_Neff) at {s['inverted']} θ*.",
            "",
            "| θ* | log10 HCR_Neff [CI] | log10 HCR-hat [CI] | width (decades) | flags |",
            "|---|---|---|---|---|",
        ]
        for r in (r for r in rows if r["noise"] == noise):
            flags = [
                f
                for f, on in (
                    ("HCR-hat unresolved", r["unresolved_hat"] == "True"),
                    ("ends crossed", r["inverted"] == "True"),
                    (f"sup at {r['at_edge_hat']} Δ", bool(r["at_edge_hat"])),
                    (f"{r['noise_dominated']} Δ noise-dominated", r["noise_dominated"] not in ("0", "")),
                )
                if on
            ]
            lines.append(
                f"| {cell(r['theta']):.4g} | {cell(r['log10_hcr_neff']):.4g} [{cell(r['ci_neff_lo']):.3g}, "
                f"{cell(r['ci_neff_hi']):.3g}] | {cell(r['log10_hcr_hat']):.4g} [{cell(r['ci_hat_lo']):.3g}, "
                f"{cell(r['ci_hat_hi']):.3g}] | {cell(r['width_decades']):.3g} | {'; '.join(flags)} |"
            )
        lines.append("")
    return "\n".join(lines)
