"""Study `bounds`: the HCR curve (and CRLB, optionally Barankin) over a 1-D grid of θ.

Plan: the grid, spp and seeds from the block. Work: one call to the bound service's `curve` (G renders
and G FD Jacobians from the render bank: every grid render serves as θ* and as a test point for all
others). Table: bounds.csv, a row per (noise, θ). Report: from bounds.csv and results.json only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import read_csv, write_csv, write_exr
from ..schema import GRID, ConfigError, Field, grid_values, smoke_grid
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


@dataclass(frozen=True)
class Plan:
    """What the study computes: the θ grid (G,), spp, seeds, which bounds and the FD step."""

    thetas: np.ndarray
    spp: int
    seeds: str
    crlb: bool
    barankin: bool
    fd_step: float


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
    if cfg["spp"] < 1:
        raise ConfigError(f"{sid}.spp", f"expected a positive number of samples per pixel, got {cfg['spp']}")
    return Plan(thetas, cfg["spp"], cfg["seeds"], cfg["crlb"], cfg["barankin"], cfg["fd_step"])


def run(ctx: RunContext, cfg: dict) -> dict:
    p, out = plan(ctx, cfg), ctx.study_dir(cfg)
    before = ctx.bank.renders
    points = ctx.bounds.curve(p.thetas, p.spp, p.seeds, p.crlb, p.barankin, p.fd_step)
    names = ctx.model.params.names
    write_csv(out / "bounds.csv", [pt.row(names) for pt in points])
    if cfg["save_images"]:  # the grid renders, from the bank's memory
        for g, img in enumerate(ctx.bank.at(p.thetas, p.spp, "bounds", p.seeds == "common")):
            write_exr(out / "images" / f"grid_{g:04d}.exr", img)
    return {"grid_points": len(p.thetas), "renders": ctx.bank.renders - before, "spp": p.spp, "seeds": p.seeds,
            "los_until": cfg["los_until"], "parameter": names[0], "units": ctx.model.params.units[0],
            "noise": summarize(read_csv(out / "bounds.csv"))}


def summarize(rows: list[dict]) -> dict:
    """Per noise model: the smallest and largest log10 HCR and how many sups sit at the grid's edge."""
    out = {}
    for noise in dict.fromkeys(r["noise"] for r in rows):
        hcr = np.array([float(r["log10_hcr"]) for r in rows if r["noise"] == noise])
        flags = [r["hcr_flags"] for r in rows if r["noise"] == noise]
        out[noise] = {"max_log10_hcr": float(np.nanmax(hcr)), "min_log10_hcr": float(np.nanmin(hcr)),
                      "at_edge": sum("sup-at" in f for f in flags)}
    return out


def smoke(block: dict) -> dict:
    return {**block, "grid": smoke_grid(block["grid"], 4), "spp": min(block["spp"], 16)}


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "bounds.csv")
    units = results.get("units", "units")
    bound_curves_plot(rows, study_dir / "bounds.png", los_until=results.get("los_until"), units=units,
                      parameter=results.get("parameter", "θ"))
    lines = [f"HCR over a {results['grid_points']}-point grid at {results['spp']} spp, "
             f"{results.get('seeds', 'independent')} seeds ({results['renders']} renders). Bounds on the variance "
             f"of an unbiased estimator, log10 of {units}².", "",
             f"![bounds]({study_dir.name}/bounds.png)", "",
             "| noise | min log10 HCR | max log10 HCR | sup at Δ-grid edge |", "|---|---|---|---|"]
    for noise, s in results["noise"].items():
        lines.append(f"| {noise} | {s['min_log10_hcr']:.3g} | {s['max_log10_hcr']:.3g} | {s['at_edge']} points |")
    return "\n".join(lines)
