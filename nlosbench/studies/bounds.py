"""Study `bounds`: the HCR curve (and CRLB, optionally Barankin) over a 1-D grid of θ from G renders.

Every grid render serves as θ* and as a test point θ*+Δ for all others (G renders, not G²). The CRLB
at each θ* comes from an FD Jacobian with common random numbers (2 more renders per point).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import bounds
from ..bank import JacobianRequest, Request
from ..io import read_csv, write_csv, write_exr
from ..schema import GRID, Field, grid_values, smoke_grid
from .context import RunContext
from .plots import bound_curves_plot

NAME = "bounds"
SCHEMA = {
    "grid": GRID,
    "spp": Field(int, 1024, "samples per pixel of each grid render"),
    "seeds": Field(str, "independent", "render seeds across the grid: independent (the paper) or common "
                   "(common random numbers: less λ inflation by rendering noise)", choices=("independent", "common")),
    "crlb": Field(bool, True, "also compute the CRLB from an FD Jacobian at each grid point"),
    "fd_step": Field(float, 0.01, "FD step ξ for the CRLB (parameter units)"),
    "barankin": Field(bool, False, "also compute the multi-point Barankin bound at each grid point"),
    "los_until": Field(float, None, "θ where the object leaves the line of sight (marked on plots)", nullable=True),
    "save_images": Field(bool, True, "keep every grid render as EXR"),
}


def grid_renders(ctx: RunContext, thetas: list[float], spp: int, purpose: str, seeds: str = "independent",
                 fd_step: float | None = None) -> tuple[np.ndarray, list | None]:
    """Renders (G, H, W, C) float32 at each θ and, with `fd_step`, their FD Jacobians (CRN), from the
    run's render bank. seeds: "independent" (a derived seed per point, as in the paper) or "common" (one
    seed for every point: common random numbers across θ, so differences L(θ+Δ) − L(θ) carry far less
    rendering noise and λ is inflated less, at the price of correlated errors along the curve)."""
    idx = (lambda g: 0) if seeds == "common" else (lambda g: g)
    renders = ctx.bank.images([Request.of([t], spp, ctx.seed_for(purpose, idx(g))) for g, t in enumerate(thetas)],
                              f"{purpose} renders").numpy()
    if fd_step is None:
        return renders, None
    jac = ctx.bank.jacobians([JacobianRequest.of([t], spp, ctx.seed_for(purpose + "-fd", idx(g)), fd_step)
                              for g, t in enumerate(thetas)], "FD Jacobians")
    return renders, list(jac)


def run(ctx: RunContext, cfg: dict) -> dict:
    if ctx.model.params.dim != 1:
        raise ValueError(f"the bounds study needs one parameter; set scene.params to one of {list(ctx.model.params.names)}")
    out = ctx.study_dir(cfg)
    thetas = grid_values(cfg["grid"])
    for t in (min(thetas), max(thetas)):
        ctx.model.params.validate([t])
    lo, hi = ctx.model.params.lower[0], ctx.model.params.upper[0]
    renders, jac = grid_renders(ctx, thetas, cfg["spp"], "bounds-grid", cfg["seeds"],
                                cfg["fd_step"] if cfg["crlb"] else None)
    np.save(out / "renders.npy", renders)
    if cfg["save_images"]:
        for g, img in enumerate(renders):
            write_exr(out / "images" / f"grid_{g:04d}.exr", img)
    rows, per_noise, T = [], {}, np.array(thetas)
    for noise in ctx.noises:
        curve = bounds.hcr_curve(renders, T, noise, lo, hi)
        for g, t in enumerate(thetas):
            row = {"noise": str(noise), "theta": t, "log10_hcr": curve.log10[g], "delta": curve.delta[g],
                   "at_edge": curve.at_edge[g] or "", "unresolved": bool(curve.unresolved[g]), "reason": curve.reason[g]}
            if jac is not None:
                log10_crlb, row["crlb_flag"] = bounds.crlb_log10(renders[g], jac[g], noise)
                row["log10_crlb"] = float(log10_crlb[0])
            if cfg["barankin"]:
                others = [j for j in range(len(thetas)) if j != g]
                b = bounds.barankin(renders[g], renders[others], T[others] - t, noise, lower=lo - t, upper=hi - t)
                row["log10_barankin"] = b.log10
            rows.append(row)
        per_noise[str(noise)] = {"max_log10_hcr": float(np.nanmax(curve.log10)),
                                 "min_log10_hcr": float(np.nanmin(curve.log10)),
                                 "at_edge": int(sum(bool(e) for e in curve.at_edge))}
    write_csv(out / "bounds.csv", rows)
    summary = {"grid_points": len(thetas), "renders": len(thetas) * (3 if cfg["crlb"] else 1), "spp": cfg["spp"],
               "seeds": cfg["seeds"], "los_until": cfg["los_until"], "parameter": ctx.model.params.names[0],
               "units": ctx.model.params.units[0], "noise": per_noise}
    return summary  # the plot: report() draws it from bounds.csv


def _plot(rows: list[dict], study_dir: Path, results: dict) -> Path:
    """bounds.png: log10 HCR (and CRLB, Barankin) against θ per noise model."""
    units = results.get("units", "units")
    return bound_curves_plot(rows, study_dir / "bounds.png", los_until=results.get("los_until"), units=units,
                             xlabel=f"θ = {results.get('parameter', 'θ')} [{units}]")


def smoke(block: dict) -> dict:
    return {**block, "grid": smoke_grid(block["grid"], 4), "spp": min(block["spp"], 16)}


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "bounds.csv")
    _plot(rows, study_dir, results)
    lines = [f"HCR over a {results['grid_points']}-point grid at {results['spp']} spp, "
             f"{results.get('seeds', 'independent')} seeds ({results['renders']} renders). Bounds on the variance "
             f"of an unbiased estimator, log10 of {results.get('units', 'units')}².", "",
             f"![bounds]({study_dir.name}/bounds.png)", "",
             "| noise | min log10 HCR | max log10 HCR | sup at Δ-grid edge |", "|---|---|---|---|"]
    for noise, s in results["noise"].items():
        lines.append(f"| {noise} | {s['min_log10_hcr']:.3g} | {s['max_log10_hcr']:.3g} | {s['at_edge']} points |")
    return "\n".join(lines)
