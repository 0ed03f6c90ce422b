"""Study `fisher-maps`: per-pixel Fisher information images (FD-FI) at chosen θ, beside the RGB image:
where in the picture the information about each parameter lives."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import bounds
from ..bank import JacobianRequest, Request
from ..io import read_csv, read_exr, write_csv, write_exr
from ..schema import Field
from .context import RunContext
from .plots import _plt

NAME = "fisher-maps"
SCHEMA = {
    "at": Field(list, help="θ values (a number per point for 1-D θ, else a list)"),
    "labels": Field(list, None, "a label per θ (e.g. LOS, NLOS)", items=str, nullable=True),
    "spp": Field(int, 1024, "samples per pixel of the renders"),
    "fd_step": Field(float, 0.01, "FD step ξ (parameter units)"),
    "fd_rounds": Field(int, 1, "FD rounds averaged (independent seeds)"),
    "reduce": Field(str, "sum", "combine channels by", choices=("sum", "mean")),
}


def run(ctx: RunContext, cfg: dict) -> dict:
    out = ctx.study_dir(cfg)
    m = ctx.model
    labels = cfg["labels"] or [f"p{i}" for i in range(len(cfg["at"]))]
    if len(labels) != len(cfg["at"]):
        raise ValueError(f"fisher-maps: {len(cfg['at'])} points but {len(labels)} labels")
    ts = [m.params.validate(np.atleast_1d(theta)) for theta in cfg["at"]]
    Ls = ctx.bank.images([Request.of(t, cfg["spp"], ctx.seed_for("fisher-render", i)) for i, t in enumerate(ts)],
                         "Fisher-map renders")
    Js = ctx.bank.jacobians([JacobianRequest.of(t, cfg["spp"], ctx.seed_for("fisher-fd", i), cfg["fd_step"],
                                                cfg["fd_rounds"]) for i, t in enumerate(ts)], "Fisher-map FD Jacobians")
    rows = []
    for t, label, L, J in zip(ts, labels, Ls, Js, strict=True):
        write_exr(out / f"{label}_rgb.exr", L)
        for j, name in enumerate(m.params.names):
            write_exr(out / f"{label}_dL_d{name}.exr", J[j])
        for k, noise in enumerate(ctx.noises):
            maps = bounds.fisher_maps(L, J, noise, cfg["reduce"])
            bounds.save_fisher_maps(maps, list(m.params.names), out, prefix=f"{label}_noise{k}_fisher")
            log10_crlb, flag = bounds.crlb_log10(L, J, noise)
            for j, name in enumerate(m.params.names):
                rows.append({"label": label, "theta": t.tolist(), "noise": str(noise), "param": name,
                             "fisher_total": float(maps[j].sum()), "log10_crlb": float(log10_crlb[j]), "flag": flag})
    write_csv(out / "fisher.csv", rows)  # the figure: report() draws it from the saved EXRs
    return {"points": labels, "params": list(m.params.names), "noises": [str(n) for n in ctx.noises],
            "renders": len(labels) * (1 + 2 * m.params.dim * cfg["fd_rounds"]), "spp": cfg["spp"]}


def _figure(out: Path, labels: list[str], names: list[str]) -> Path:
    """One row per point: the RGB render, then the log-scale FI map of each parameter (first noise)."""
    plt = _plt()
    cols = 1 + len(names)
    fig, axes = plt.subplots(len(labels), cols, figsize=(3.2 * cols, 3 * len(labels)), squeeze=False)
    for r, label in enumerate(labels):
        rgb = read_exr(out / f"{label}_rgb.exr")
        axes[r, 0].imshow(np.clip(rgb / max(np.percentile(rgb, 99), 1e-12), 0, 1) ** (1 / 2.2))
        axes[r, 0].set_title(f"{label}: render")
        for c, name in enumerate(names, start=1):
            fi = read_exr(out / f"{label}_noise0_fisher_{name}.exr")[..., 0].astype(np.float64)
            pos = fi[fi > 0]
            im = axes[r, c].imshow(np.log10(np.where(fi > 0, fi, np.nan)), cmap="inferno",
                                   vmin=np.log10(pos.min()) if pos.size else None, vmax=np.log10(pos.max()) if pos.size else None)
            axes[r, c].set_title(f"log10 FI, {name}")
            fig.colorbar(im, ax=axes[r, c], fraction=0.046, pad=0.04)
    for a in axes.ravel():
        a.set_axis_off()
    fig.tight_layout()
    fig.savefig(out / "fisher_maps.png", dpi=110)
    plt.close(fig)
    return out / "fisher_maps.png"


def smoke(block: dict) -> dict:
    keep = block["at"][:2]
    return {**block, "at": keep, "labels": block["labels"] and block["labels"][:2], "spp": min(block["spp"], 16),
            "fd_rounds": 1}


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "fisher.csv")
    _figure(study_dir, results["points"], results["params"])
    lines = [f"Per-pixel Fisher information from central FD (common random numbers) at {results['spp']} spp; "
             f"{results['renders']} renders.", "", f"![Fisher maps]({study_dir.name}/fisher_maps.png)", "",
             "| point | θ | noise | parameter | total FI | log10 CRLB | flag |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['label']} | {r['theta']} | {r['noise']} | {r['param']} | {float(r['fisher_total']):.4g} "
                     f"| {float(r['log10_crlb']):.4g} | {r['flag']} |")
    return "\n".join(lines)
