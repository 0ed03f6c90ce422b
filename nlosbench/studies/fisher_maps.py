"""Study `fisher-maps`: per-pixel Fisher information images (FD-FI) at chosen θ, beside the RGB image:
where in the picture the information about each parameter lives. With `pool` (the default from 4 FD rounds)
also a pooled map: pixels pooled into quadtree cells chosen on half of the rounds, each cell's information
estimated on the other half with limits Bonferroni over the cells (`bounds.pooling`); cells not resolved on
the selection half are masked. With a `precision` target the bound service adds fresh FD rounds at the θ whose
CRLB interval is wider than asked (`BoundService.fisher`; the stopping rule of `bounds.precision`): the maps, the
pooled cells and the CRLBs are then the reported look's, and the report says the precision each θ reached. With
`gradient: {method: ad, ...}` the rounds are independent Mitsuba AD passes instead (no FD step): the same maps and
CRLB limits of AD's derivative, to hold against an FD reference where AD may be biased."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import diagnostics
from ..bounds import save_fisher_maps
from ..bounds.pooling import PooledFisherMap, pool_fisher_map, pooled_summary
from ..io import read_csv, write_csv, write_exr
from ..schema import MAX_HALVINGS, STEP_TOL, ConfigError, Field, folder_name, point_spec
from . import precise
from .context import RunContext
from .estimate import AD_PASS_RENDERS, Estimate, pixels
from .plots import fisher_figure
from .plotstyle import theta_text
from .tables import fmt_end

NAME = "fisher-maps"
SCHEMA = {
    "at": Field(list, help="θ values (a number per point for 1-D θ, else a list)", items=point_spec),
    "labels": Field(list, None, "a label per θ (e.g. LOS, NLOS); it names files in the study's folder, so one name "
                                "each (no '/' or '..')", items=folder_name, nullable=True),
    "spp": Field(int, 1024, "samples per pixel of the renders"),
    "fd_step": Field(float, 0.01, "FD step ξ (parameter units)"),
    "fd_rounds": Field(int, 3, "independent FD rounds: the unbiased Fisher information is a U-statistic over them "
                               "(>= 2; >= 3 for the CRLB's interval)"),
    "reduce": Field(str, "sum", "combine channels by", choices=("sum", "mean")),
    "pool": Field(bool, None, "also draw a pooled map: quadtree cells chosen on half of the FD rounds, estimated on "
                              "the other half, Bonferroni over the cells; unresolved cells masked (needs fd_rounds "
                              ">= 4; null: on from 4 rounds)", nullable=True),
    "pool_precision": Field(float, None, "a relative precision p a pooled cell must also meet to count as resolved "
                                         "(its limits within a factor 1 + p of its estimate; null: its lower "
                                         "limit > 0)", nullable=True),
    "step_tol": STEP_TOL,
    "max_halvings": MAX_HALVINGS,
    "gradient": Field(dict, {"method": "fd"}, "the Jacobians: {method: fd}, central FD rounds at `fd_step` halved by "
                      "the step rule; {method: ad, integrator: prb_projective, guiding: none, ...}: `fd_rounds` "
                      "independent Mitsuba forward-mode AD passes with those integrator options (no FD step: "
                      "fd_step, step_tol and max_halvings unused; no precision target)"),
    **precise.KEYS,
}


@dataclass(frozen=True)
class Plan:
    """θ points (T, P) with their labels, spp, FD step and rounds, channel reduction."""

    thetas: np.ndarray
    labels: list
    spp: int
    fd_step: float
    fd_rounds: int
    reduce: str
    step_tol: float
    max_halvings: int
    pool: bool = False
    pool_precision: float | None = None
    precision: dict = field(default_factory=dict)
    ad: dict | None = None  # AD integrator options where the Jacobians are AD passes


def plan(ctx: RunContext, cfg: dict) -> Plan:
    sid = cfg.get("id") or NAME
    labels = cfg["labels"] or [f"p{i}" for i in range(len(cfg["at"]))]
    if len(labels) != len(cfg["at"]):
        raise ConfigError(f"{sid}.labels", f"{len(cfg['at'])} points but {len(labels)} labels")
    thetas = []
    for i, theta in enumerate(cfg["at"]):
        try:
            thetas.append(ctx.model.params.validate(np.atleast_1d(theta)))
        except (TypeError, ValueError) as e:
            raise ConfigError(f"{sid}.at[{i}]", str(e)) from None
    if cfg["spp"] < 1:
        raise ConfigError(f"{sid}.spp", f"expected a positive integer, got {cfg['spp']}")
    if not cfg["fd_step"] > 0:
        raise ConfigError(f"{sid}.fd_step", f"expected a step > 0, got {cfg['fd_step']}")
    if cfg["fd_rounds"] < 2:
        raise ConfigError(f"{sid}.fd_rounds", f"the unbiased Fisher information needs >= 2 rounds, got "
                                              f"{cfg['fd_rounds']}")
    pool = cfg.get("pool")
    pool = cfg["fd_rounds"] >= 4 if pool is None else pool
    if pool and cfg["fd_rounds"] < 4:
        raise ConfigError(f"{sid}.pool", f"a pooled map chooses its cells on half of the FD rounds and estimates "
                                         f"them on the other half: it needs fd_rounds >= 4, got {cfg['fd_rounds']}")
    prec = cfg.get("pool_precision")
    if prec is not None and not prec > 0:
        raise ConfigError(f"{sid}.pool_precision", f"expected a precision > 0, got {prec}")
    precise.check(cfg, sid, ("crlb",), sets="fd_rounds")
    try:
        grad = diagnostics.backend(cfg["gradient"])
    except ValueError as e:
        raise ConfigError(f"{sid}.gradient", str(e)) from None
    if grad.method == "fd" and set(cfg["gradient"]) != {"method"}:
        raise ConfigError(f"{sid}.gradient", f"FD Jacobians take `fd_step`, `fd_rounds`, `step_tol` and "
                                             f"`max_halvings` from the study, got {cfg['gradient']}")
    if grad.method == "ad" and cfg.get("precision") is not None:
        raise ConfigError(f"{sid}.precision", "a precision target plans fresh FD rounds and their step; with AD "
                                              "Jacobians give the number of passes as `fd_rounds`")
    return Plan(np.array(thetas), labels, cfg["spp"], cfg["fd_step"], cfg["fd_rounds"], cfg["reduce"],
                cfg["step_tol"], cfg["max_halvings"], bool(pool), prec, precise.at_kwargs(cfg),
                grad.ad if grad.method == "ad" else None)


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """Per θ: a render and `fd_rounds` central-FD Jacobians (2 renders per parameter and round) at ξ and ξ/2, with
    θ rendered under each round's seed (the step check's one-sided differences); at most `max_halvings` − 1 more
    halvings where the step has not converged (counted: the most it can cost); with a `precision` target, these are
    its pilot and the fresh rounds spend at most its `precision_budget` or the default ceiling (`precise.estimate`).
    AD: one pass per parameter and round, `AD_PASS_RENDERS` renders each."""
    per_round = (AD_PASS_RENDERS * ctx.model.params.dim if p.ad is not None else
                 2 * ctx.model.params.dim * (1 + max(p.max_halvings, 0)) + (p.max_halvings > 0))
    renders = len(p.thetas) * (1 + p.fd_rounds * per_round)
    samples = renders * p.spp * pixels(ctx.model)
    return precise.estimate(renders, samples, cfg, p.spp, pixels(ctx.model), pilot=samples)


def pooled_rows(label: str, noise: str, name: str, m: PooledFisherMap) -> list[dict]:
    """pooled_cells.csv rows: one per cell of a pooled map."""
    return [{"label": label, "noise": noise, "param": name, "cell": c, "pixels": int(m.pixels[c]),
             "fisher": float(m.est[c]), "se": float(m.se[c]), "df": float(m.df[c]), "lower": float(m.lower[c]),
             "upper": float(m.upper[c]), "chosen": bool(m.chosen[c]), "resolved": bool(m.resolved[c]),
             "level": m.level, "tests": m.tests} for c in range(m.cells)]


def run(ctx: RunContext, cfg: dict) -> dict:
    p, out, m = plan(ctx, cfg), ctx.study_dir(cfg), ctx.model
    before = ctx.bank.renders
    rows, cells = [], []
    names, units = list(m.params.names), list(m.params.units)
    where, pooled = {}, []
    points = ctx.bounds.fisher(p.thetas, p.spp, p.fd_step, p.fd_rounds, p.reduce, step_tol=p.step_tol,
                               max_halvings=p.max_halvings, **p.precision,
                               **({"gradient": "ad", "ad": p.ad} if p.ad is not None else {}))
    T = len(points)
    precision = precise.records([fp.precise[k] for k in range(len(ctx.noises)) for fp in points if fp.precise], T,
                                names)
    for label, fp in zip(p.labels, points, strict=True):
        where[label] = theta_text(names, fp.theta, units)
        write_exr(out / f"{label}_rgb.exr", fp.L)
        for j, name in enumerate(m.params.names):
            write_exr(out / f"{label}_dL_d{name}.exr", fp.J[j])
        for k, noise in enumerate(ctx.noises):
            save_fisher_maps(fp.maps[k], names, out, prefix=f"{label}_noise{k}_fisher", units=units,
                             where=f"{label}, {where[label]}, {noise}")
            for j, name in enumerate(m.params.names):
                b = fp.crlb[k][j]
                rows.append({"label": label, "theta": fp.theta.tolist(), "noise": str(noise), "param": name,
                             "fd_rounds": int(fp.rounds.shape[0]), "fd_step": fp.step,
                             "fisher_total": float(fp.maps[k][j].sum()), "log10_crlb": b.log10,
                             "crlb_lower": b.lower, "crlb_upper": b.upper, "crlb_lower_note": b.lower_note,
                             "flag": b.reason})
                if not p.pool:
                    continue
                if fp.rounds.shape[0] < 4:  # a precision look that met the target with 3 fresh rounds
                    pooled.append({"label": label, "noise": str(noise), "param": name, "step": fp.step,
                                   "summary": f"not drawn: the reported look has {fp.rounds.shape[0]} FD rounds (a "
                                              "pooled map needs >= 4)"})
                    continue
                pm = pool_fisher_map(fp.rounds[:, j].numpy(), fp.weights[k].numpy(), ctx.bounds.level, p.reduce,
                                     p.pool_precision)
                write_exr(out / f"{label}_noise{k}_pooled_{name}.exr", pm.density("chosen"))
                write_exr(out / f"{label}_noise{k}_cells_{name}.exr", pm.labels.astype(np.float32))
                cells += pooled_rows(label, str(noise), name, pm)
                pooled.append({"label": label, "noise": str(noise), "param": name, "step": fp.step,
                               "summary": pooled_summary(pm)})
    write_csv(out / "fisher.csv", rows)  # the figure: report() draws it from the saved EXRs
    if p.pool:
        write_csv(out / "pooled_cells.csv", cells)
    return {"points": p.labels, "params": names, "units": units, "where": where,
            "noises": [str(n) for n in ctx.noises], "renders": ctx.bank.renders - before, "spp": p.spp,
            "pooled": pooled, "fd_rounds": p.fd_rounds, "level": ctx.bounds.level,
            "gradient": "fd" if p.ad is None else diagnostics.label(diagnostics.backend(cfg["gradient"])),
            **({"precision": precision, "seconds_per_sample": ctx.rate} if precision else {})}


def smoke(block: dict) -> dict:
    """The first two θ, ≤ 16 spp, 2 FD rounds (4 with `pool`, 3 with a `precision`, whose budget becomes 1
    pixel-sample: `precise.smoke`, the pilot and the plan, no fresh look)."""
    keep = block["at"][:2]
    rounds = 4 if block.get("pool") else 3 if block.get("precision") is not None else 2
    return precise.smoke({**block, "at": keep, "labels": block["labels"] and block["labels"][:2],
                          "spp": min(block["spp"], 16), "fd_rounds": rounds})


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "fisher.csv")
    pooled = results.get("pooled") or {}
    fisher_figure(study_dir, results["points"], results["params"], results.get("where"), results["noises"][0],
                  results.get("units"), pooled=bool(pooled))
    grad = results.get("gradient", "fd")
    how = ("central FD (common random numbers)" if grad == "fd" else
           f"{results['fd_rounds']} independent AD passes (`{grad}`, forward mode; no FD step: the information of "
           "AD's derivative, which an FD reference at a converged step says whether to trust)")
    lines = [f"Per-pixel Fisher information from {how} at {results['spp']} spp; "
             f"{results['renders']} renders.", "", f"![Fisher maps]({study_dir.name}/fisher_maps.png)", "",
             "| point | θ | noise | parameter | total FI | log10 CRLB [95 % ends] | how |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        ends = (f" [{fmt_end(r['crlb_lower'])}{'†' if r.get('crlb_lower_note') else ''}, "
                f"{fmt_end(r['crlb_upper'])}]" if "crlb_lower" in r else "")
        lines.append(f"| {r['label']} | {r['theta']} | {r['noise']} | {r['param']} | {float(r['fisher_total']):.4g} "
                     f"| {float(r['log10_crlb']):.4g}{ends} | {r['flag']} |")
    if results.get("precision"):
        lines += ["", "## Precision of the CRLB of θ", "",
                  "The bound service added fresh FD rounds only at the θ whose CRLB interval was wider than asked; "
                  "the maps, pooled cells and CRLBs above are those of the reported look (`fd_rounds` in "
                  "fisher.csv).", ""]
        lines += precise.table(results["precision"], f"{results['units'][0]}²" if len(results["params"]) == 1
                               else "parameter units²", results.get("seconds_per_sample"))
    unchecked = {"not checked" in r["crlb_lower_note"] for r in rows if r.get("crlb_lower_note")}  # `crlb_term`'s notes
    why = {frozenset({True}): "the FD step was not checked (one step: the CRLB of the derivative smoothed over ±ξ)",
           frozenset({False}): "the FD step did not converge (the note in fisher.csv says which step or spp would "
                               "settle it)",
           frozenset({True, False}): "the FD step was not checked or did not converge (fisher.csv's note says which)"}
    if unchecked:
        lines += ["", f"† not a confidence limit: {why[frozenset(unchecked)]}."]
    if pooled:
        lines += ["", f"Pooled maps (right-hand panels, first noise model): pixels pooled into quadtree cells chosen "
                      f"on half of the {results['fd_rounds']} {'FD rounds' if grad == 'fd' else 'AD passes'} "
                      f"(a cell is split while its parts stay "
                      f"resolved there), each cell's information estimated on the other half with one-sided limits "
                      f"at {results['level']:.0%} jointly over all cells (Bonferroni over 2 limits per cell). Drawn: "
                      f"the cells resolved on the selection half, valued by the estimation half (unbiased whatever "
                      f"the cells); hatched: drawn cells whose limits on the estimation half include 0; blank: "
                      f"masked. Per cell in pooled_cells.csv.", ""]
        lines += [f"- {v['label']}, {v['noise']}, {v['param']}"
                  + (f" (FD step ξ = {v['step']:.3g})" if math.isfinite(v['step']) else "") + f": {v['summary']}"
                  for v in pooled]
    return "\n".join(lines)
