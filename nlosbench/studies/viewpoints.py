"""Study `viewpoints`: average per-pixel Fisher information over a grid of camera positions (the paper's
plenoptic information localisation: 31 × 31 offsets at 2.54 cm in the x–z plane).

At each viewpoint the camera is moved by an offset (two world axes, `num` points each, the standard view
in the centre) and re-aimed at a fixed `target`; the image L_θ and its FD Jacobian (central, common random
numbers) give per-pixel Fisher maps for every parameter and noise model, whose spatial mean is one cell of
the heat map; the view's Fisher matrix F̂ (P × P) and its A-optimal score tr F̂⁻¹ with one-sided limits (the bound
service's CRLB of θ, `camera.view_scores`; limits need fd_rounds >= 3) are in every row too (the score and F̂'s
upper triangle repeat across a view's parameter rows). Views are compared at one FD step ξ, so the score is that of
the model smoothed by ξ (flag "fd-smoothed": its ends are confidence limits of that, not of the CRLB of L(θ)). With a
`precision` target p, fresh FD rounds are added at each view only until its score's interval is within ±p for every
noise model (the stopping rule of bounds.precision, within `precision_budget` pixel-samples per view): the score,
F̂ and the maps are then the reported look's, at its level, and each row says whether the view met the target, or,
once the whole map is known, whether its information is negligible (`resolution`: each parameter's upper limit
≤ 1 % of the map's largest) or left open.
Beside the unbiased mean FI, `plugin_mean_fisher` is what the
paper's method gives: one FD Jacobian's Ĵᵀ W Ĵ per pixel (averaged over the rounds, each one such estimate), whose
expectation exceeds the information by the Jacobian's rendering noise Σ w Var(Ĵ): small where the object is seen,
dominant where it is hidden. Output: viewpoints.csv, heat map PNGs per noise model of log10 of the mean FI, unbiased
(heatmap_noise{k}.png) and plug-in (heatmap_plugin_noise{k}.png), the profile along the first axis (profiles.png; the
report lists its largest steps, `transitions`), and the render and FD-FI maps at the centre and two opposite corners.
Viewpoints are independent tasks for the run's executor (each worker poses its own copy of the scene); finished ones
are appended to viewpoints.jsonl (a `records.RecordLog`), so a resumed run skips them.

The camera is posed by `camera.CameraRig` (outside θ, no reload); a pose's information comes from the bound
service (`camera.viewpoint_information`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bounds import fisher_maps, save_fisher_maps
from ..bounds.precision import CEILING, check_precision
from ..forward.model import ForwardModel
from ..io import read_csv, write_csv, write_exr, write_png
from ..records import RecordLog
from ..schema import ConfigError, Field, integer_in
from .camera import VIEW_KEYS, CameraRig, score_cells, unit_axes, view_scores, viewpoint_information
from .context import RunContext, theta_at
from .estimate import Estimate, pixels
from .plots import heat_maps, profile_plot
from .plotstyle import noise_text

NAME = "viewpoints"
SCHEMA = {
    "at": Field(list, None, "θ (one value per studied parameter) at which information is computed "
                "(default: the parameters' defaults)", items=float, nullable=True),
    "num": Field(int, 3, "viewpoints per axis; odd, so the standard view is the centre (paper: 31)"),
    "step": Field(float, 0.0254, "offset between neighbouring viewpoints [m] (paper: 2.54 cm)"),
    **VIEW_KEYS,
    "fd_rounds": Field(int, 2, "independent FD rounds of the unbiased Fisher information (>= 2; >= 3 for limits and "
                       "for a precision target)"),
    "precision": Field(float, None, "target relative half-width p of each view's A-optimal score tr F̂⁻¹ (of the "
                       "FD-smoothed model): fresh FD rounds at a view only until its interval is within ±p for every "
                       "noise model; null: the fd_rounds given", nullable=True),
    "precision_budget": Field(int, None, "cap on the pixel-samples one view may spend on its target (needs "
                              "`precision`); null: the default ceiling, 16 × its pilot", nullable=True),
    "looks": Field(integer_in(1, 64), 2, "with `precision`: the pilot and at most looks − 1 fresh looks per view "
                   "(1: the pilot alone at the full level, each view classified against ±p with the predicted cost "
                   "of meeting it)"),
    "reduce": Field(str, "mean", "combine the RGB channels' information by (paper: mean)", choices=("sum", "mean")),
}


def offset_grid(num: int, step: float, axes) -> tuple[np.ndarray, np.ndarray]:
    """Offsets along each axis (num,) [m], centred on 0, and the world offsets (num, num, 3): [i, j] is
    u_i·axes[0] + u_j·axes[1] with unit axes."""
    if num < 1 or num % 2 == 0:
        raise ValueError(f"num must be a positive odd number (the standard view in the centre), got {num}")
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    a = unit_axes(axes)
    u = (np.arange(num) - (num - 1) / 2) * step
    return u, u[:, None, None] * a[0] + u[None, :, None] * a[1]


def _saved_views(num: int) -> dict[tuple[int, int], str]:
    """Viewpoints whose images are kept: the centre and the (−, +) and (+, −) corners (paper's figure)."""
    c = (num - 1) // 2
    return {(0, num - 1): "corner_minus_plus", (num - 1, 0): "corner_plus_minus", (c, c): "center"}


def _viewpoint_task(model: ForwardModel, item: dict) -> tuple:
    """Render-bank task (module level, picklable): one viewpoint → ((i, j), its record, renders made);
    the record holds the render and the Fisher maps under "images" when item["keep"]."""
    before = model.stats.snapshot()
    rig = CameraRig(model, item["target"])
    with rig.at(item["offset"]):
        fp = viewpoint_information(model, item["theta"], item["spp"], item["seed"], item["fd_step"],
                                   item["fd_rounds"], item["noises"], item["reduce"], smoothed=True,
                                   precision=item["precision"], budget=item["precision_budget"],
                                   looks=item["looks"])
    maps = [fp.maps[k] for k in range(len(item["noises"]))]
    renders = model.stats.since(before).renders
    plugin = [np.mean([fisher_maps(fp.L, J, noise, item["reduce"]) for J in fp.rounds], axis=0)
              for noise in item["noises"]]  # (P, H, W) per noise: the mean over rounds of one round's Ĵᵀ W Ĵ
    rec = {"i": item["i"], "j": item["j"], "offset": item["offset"],
           "mean_fisher": [[float(np.mean(mp)) for mp in nm] for nm in maps],
           "plugin_mean_fisher": [[float(np.mean(mp)) for mp in nm] for nm in plugin],
           "infinite_pixels": [[int(np.isinf(mp).sum()) for mp in nm] for nm in maps],
           # per noise and parameter: log10 of F̂_jj and of its upper limit (NaN where that end is not a limit)
           "information": [[(-b.point, math.nan if b.lower_note else -b.lower) for b in fp.crlb[k]]
                           for k in range(len(item["noises"]))],
           "scores": _scores(fp, item["noises"], model.channels), "renders": renders}
    if item["keep"]:
        rec["images"] = (fp.L.numpy(), maps)
    return (item["i"], item["j"]), rec, renders


def _scores(fp, noises, group: int) -> list[dict]:
    """`view_scores` of one view (the FD-smoothed model's); with a precision target each noise model's score ends
    are the reported look's (at its level, `precise`), and "met", "reached", "rounds" say what the target got."""
    scores = view_scores([fp], noises, group, smoothed=True)
    for k, s in enumerate(scores):
        pt = fp.precise.get(k)
        if pt is not None:
            b, pr = pt.bounds["crlb"], pt.precision
            s.update(log10=b.point, lower=b.lower, upper=b.upper, lower_note=b.lower_note, met=pr.met,
                     reached=pr.reached.get("crlb", float("inf")), rounds=int(fp.rounds.shape[0]),
                     extra=pr.extra_pixel_samples)
    return scores


@dataclass(frozen=True)
class Plan:
    """θ (P,), the offsets along each axis (num,), the world offsets (num, num, 3) and the camera's target."""

    theta: np.ndarray
    u: np.ndarray
    offsets: np.ndarray
    target: np.ndarray


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError naming the key for what the schema cannot see
    (θ inside Θ, an odd grid, positive step/spp/FD step, ≥ 2 FD rounds, axes and target, a Mitsuba camera).
    Casts one ray (the default target), renders nothing."""
    sid = cfg.get("id") or NAME
    m = ctx.model
    theta = theta_at(ctx, cfg, sid)
    if cfg["spp"] < 1:
        raise ConfigError(f"{sid}.spp", f"expected a positive integer, got {cfg['spp']}")
    if cfg["fd_rounds"] < 2:
        raise ConfigError(f"{sid}.fd_rounds", f"the unbiased Fisher information needs >= 2 rounds, got "
                                              f"{cfg['fd_rounds']}")
    if not cfg["fd_step"] > 0:
        raise ConfigError(f"{sid}.fd_step", f"expected a step > 0, got {cfg['fd_step']}")
    try:
        check_precision(cfg["precision"], cfg["precision_budget"], cfg["looks"], ("crlb",), cfg["fd_rounds"])
    except ValueError as e:
        raise ConfigError(sid, str(e)) from None
    for key, call in (("num", lambda: offset_grid(cfg["num"], 1.0, [[1, 0, 0], [0, 0, 1]])),
                      ("step", lambda: offset_grid(1, cfg["step"], [[1, 0, 0], [0, 0, 1]])),
                      ("axes", lambda: offset_grid(1, 1.0, cfg["axes"]))):
        try:
            call()
        except ValueError as e:
            raise ConfigError(f"{sid}.{key}", str(e)) from None
    u, offsets = offset_grid(cfg["num"], cfg["step"], cfg["axes"])
    try:
        target = CameraRig(m, cfg["target"]).target
    except ValueError as e:
        raise ConfigError(f"{sid}.target" if cfg["target"] is not None or "hits nothing" in str(e) else sid,
                          str(e)) from None
    return Plan(theta, u, offsets, target)


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """num² viewpoints × (a render + `fd_rounds` central-FD Jacobians) at `spp`; with a precision target, the most
    each view may spend (its `precision_budget`, else CEILING × its pilot), renders in proportion."""
    views, px = cfg["num"] ** 2, cfg["spp"] * pixels(ctx.model)
    per_view = 1 + 2 * ctx.model.params.dim * cfg["fd_rounds"]
    if cfg["precision"] is None:
        return Estimate(views * per_view, views * per_view * px)
    if cfg["looks"] == 1:  # the pilot alone: no fresh round is ever rendered
        return Estimate(views * per_view, views * per_view * px, note="the pilot alone (looks: 1)")
    most = cfg["precision_budget"] or CEILING * per_view * px
    return Estimate(views * max(per_view, round(most / px)), views * max(most, per_view * px),
                    note=f"with the precision target: at most {most:.3g} pixel-samples per view",
                    least=views * per_view * px)


def run(ctx: RunContext, cfg: dict) -> dict:
    p = plan(ctx, cfg)
    out = ctx.study_dir(cfg)
    m = ctx.model
    theta, u, offsets, target = p.theta, p.u, p.offsets, p.target
    log = RecordLog(out / "viewpoints.jsonl")
    if not ctx.resume:
        log.reset()
    done = {(rec["i"], rec["j"]): rec for rec in log.read()}
    saved = _saved_views(cfg["num"])
    items = [
        {
            "i": i,
            "j": j,
            "offset": offsets[i, j].tolist(),
            "target": target.tolist(),
            "theta": theta.tolist(),
            "spp": cfg["spp"],
            "seed": ctx.seed_for("viewpoint", i, j),
            "fd_step": cfg["fd_step"],
            "fd_rounds": cfg["fd_rounds"],
            "precision": cfg["precision"],
            "precision_budget": cfg["precision_budget"],
            "looks": cfg["looks"],
            "noises": ctx.noises,
            "reduce": cfg["reduce"],
            "keep": (i, j) in saved,
        }
        for i in range(cfg["num"])
        for j in range(cfg["num"])
        if (i, j) not in done
    ]
    with log:
        for _, rec in ctx.bank.map(_viewpoint_task, items, "viewpoints"):
            images = rec.pop("images", None)
            if images is not None:
                _save_view(out, saved[(rec["i"], rec["j"])], *images, list(m.params.names))
            log.append(rec)
            done[(rec["i"], rec["j"])] = rec
    rows = []
    for (i, j), rec in sorted(done.items()):
        for k, noise in enumerate(ctx.noises):
            for p, name in enumerate(m.params.names):
                rows.append(
                    {
                        "i": i,
                        "j": j,
                        "offset_0": u[i],
                        "offset_1": u[j],
                        "noise": str(noise),
                        "param": name,
                        "mean_fisher": rec["mean_fisher"][k][p],
                        "plugin_mean_fisher": rec["plugin_mean_fisher"][k][p],
                        "infinite_pixels": rec["infinite_pixels"][k][p],
                        "log10_information": rec["information"][k][p][0],
                        "information_upper": rec["information"][k][p][1],
                        **score_cells(rec["scores"][k], list(m.params.names)),
                        **({"score_met": rec["scores"][k]["met"], "score_reached": rec["scores"][k]["reached"],
                            "fd_rounds": rec["scores"][k]["rounds"],
                            "score_extra_pixel_samples": rec["scores"][k]["extra"]}
                           if "met" in rec["scores"][k] else {}),
                    }
                )
    if cfg["precision"] is not None:  # met / negligible / open, once the whole map is known
        for noise in map(str, ctx.noises):
            state = resolution([r for r in rows if r["noise"] == noise])
            for r in rows:
                if r["noise"] == noise:
                    r["score_resolution"] = state[r["i"], r["j"]]
    write_csv(out / "viewpoints.csv", rows)
    summary = {
        "num": cfg["num"],
        "step": cfg["step"],
        "axes": cfg["axes"],
        "target": target.tolist(),
        "theta": theta.tolist(),
        "params": list(m.params.names),
        "units": list(m.params.units),
        "noises": [str(n) for n in ctx.noises],
        "spp": cfg["spp"],
        "fd_step": cfg["fd_step"],
        "precision": cfg["precision"],
        "renders": sum(rec["renders"] for rec in done.values()),  # every invocation's, from the records
        "infinite_cells": sum(r["infinite_pixels"] > 0 for r in rows),
    }
    return summary  # the heat maps: report() draws them from viewpoints.csv


#: a view not met is resolved as negligible where the upper limit of each parameter's information F̂_jj is at most
#: this share of the map's largest F̂_jj (point) for that parameter
NEGLIGIBLE = 0.01


def resolution(rows: list[dict]) -> dict[tuple, str]:
    """Per view (i, j) of one noise model's map (its parameter rows, with score_met, log10_information and
    information_upper in log10 of 1/units², NaN where that end is not a limit): "met" (its A-optimal score within
    ±p); "negligible" (not met, but every parameter's information has an upper limit at most NEGLIGIBLE × the map's
    largest point for that parameter: the view is known to carry under 1 % of the best view's information about each,
    and tr F⁻¹ ≥ Σ_j 1/F_jj, so its score is at least 100× the best view's Σ_j 1/F_jj); else "open"."""
    best: dict[str, float] = {}
    views: dict[tuple, list[dict]] = {}
    for r in rows:
        views.setdefault((r["i"], r["j"]), []).append(r)
        v = float(r["log10_information"])
        if math.isfinite(v):
            best[r["param"]] = max(best.get(r["param"], -math.inf), v)
    cut = math.log10(NEGLIGIBLE)
    out = {}
    for key, vrows in views.items():
        if vrows[0]["score_met"] in (True, "True"):
            out[key] = "met"
        elif all(float(r["information_upper"]) <= best.get(r["param"], math.nan) + cut for r in vrows):
            out[key] = "negligible"  # a NaN (not a limit, or no finite point in the map) never compares true
        else:
            out[key] = "open"
    return out


def profile(rows: list[dict], noise: str, param: str, column: str = "mean_fisher") -> tuple[np.ndarray, np.ndarray]:
    """The map along its first axis: offsets u0 (n0,) [m] and the 10 %, 50 % and 90 % quantiles over the second axis
    of log10 `column` (3, n0) (non-finite or non-positive cells left out; NaN where a column has none)."""
    sel = [r for r in rows if r["noise"] == noise and r["param"] == param]
    u0 = np.unique([float(r["offset_0"]) for r in sel])
    cols: list[list[float]] = [[] for _ in u0]
    for r in sel:
        v = float(r[column])
        if math.isfinite(v) and v > 0:
            cols[int(np.searchsorted(u0, float(r["offset_0"])))].append(math.log10(v))
    q = np.array([np.quantile(c, (0.1, 0.5, 0.9)) if c else np.full(3, np.nan) for c in cols]).reshape(-1, 3).T
    return u0, q


def transitions(u0: np.ndarray, median: np.ndarray, top: int = 3) -> list[tuple[float, float]]:
    """The `top` largest changes of a profile between neighbouring offsets, in order along the axis: (midpoint [m],
    change in decades, signed: negative where the information falls as the offset grows)."""
    d = np.diff(median)
    ok = np.flatnonzero(np.isfinite(d))
    best = ok[np.argsort(-np.abs(d[ok]), kind="stable")[:top]]
    return [(float((u0[k] + u0[k + 1]) / 2), float(d[k])) for k in sorted(best)]


def transition_table(curves: dict) -> list[dict]:
    """Per noise model and parameter, the map's largest steps along its first axis (`transitions` of the median of
    its `profile`, curves[(noise, param)] = (u0, q)), in order along it: rows {noise, param, order (1, 2, …), offset
    (m, midway between the neighbouring offsets), decades (signed change of log10 mean FI)}."""
    return [{"noise": noise, "param": name, "order": k, "offset": x, "decades": d}
            for (noise, name), (u0, q) in curves.items() for k, (x, d) in enumerate(transitions(u0, q[1]), 1)]


def _transition_lines(table: list[dict], results: dict) -> list[str]:
    """The `transition_table` as the report's table."""
    out = ["", f"**Transitions** along {results['axes'][0]} (the median over the other axis of log10 mean FI; the "
               "three largest changes between neighbouring offsets, cm: decades):", "",
           "| noise | parameter | transitions |", "|---|---|---|"]
    for noise in results["noises"]:
        for name in results["params"]:
            steps = ", ".join(f"{r['offset'] * 100:+.3g} cm: {r['decades']:+.2f}" for r in table
                              if r["noise"] == noise and r["param"] == name)
            out.append(f"| {noise_text(noise)} | {name} | {steps or 'none'} |")
    return out


def resolution_table(rows: list[dict], results: dict) -> list[dict]:
    """With a precision target, per noise model: rows {noise, views, met, negligible, open (`resolution`),
    rounds_min, rounds_max (FD rounds per view), open_pixel_samples (the open views' predicted cost to meet the
    target, summed; inf where one is predicted never to)}; [] without a target."""
    if not results.get("precision") or not rows or "score_resolution" not in rows[0]:
        return []
    views = {(r["noise"], r["i"], r["j"]): r for r in rows}  # one score per view and noise (parameter rows repeat it)
    out = []
    for noise in results["noises"]:
        sel = [r for (n, _, _), r in views.items() if n == noise]
        rounds = [int(r["fd_rounds"]) for r in sel]
        counts = [r["score_resolution"] for r in sel]  # `resolution`, as the run wrote it
        out.append({"noise": noise, "views": len(sel), "met": counts.count("met"),
                    "negligible": counts.count("negligible"), "open": counts.count("open"),
                    "rounds_min": min(rounds), "rounds_max": max(rounds),
                    "open_pixel_samples": sum(float(r["score_extra_pixel_samples"]) for r in sel
                                              if r["score_resolution"] == "open")})
    return out


def _precision_lines(rows: list[dict], table: list[dict], results: dict) -> list[str]:
    """The `resolution_table` as the report's table, with the views left open (at most 20 named, with what each
    reached)."""
    if not table:
        return []
    out = ["", f"**Precision.** Target: each view's A-optimal score (of the FD-smoothed model, ξ = "
               f"{results['fd_step']:g}) within ±{results['precision'] * 100:.3g} %, or the upper limit of "
               f"each parameter's information at most {NEGLIGIBLE * 100:g} % of the map's largest for it "
               "(negligible). The open views' cost to meet the target is each one's predicted fresh look, summed "
               "(∞ where no number of rounds is predicted to).", "",
           "| noise | views met | negligible | FD rounds (min–max) | open: cost to meet | open (offset cm: reached) |",
           "|---|---|---|---|---|---|"]
    u = float(results["step"]) * 100
    c = (int(results["num"]) - 1) / 2
    views = {(r["noise"], r["i"], r["j"]): r for r in rows}
    for t in table:
        missed = sorted((r for (n, _, _), r in views.items() if n == t["noise"] and r["score_resolution"] == "open"),
                        key=lambda r: -float(r["score_reached"]))
        named = ", ".join(f"({(int(r['i']) - c) * u:.3g}, {(int(r['j']) - c) * u:.3g}): "
                          f"±{float(r['score_reached']) * 100:.3g} %" for r in missed[:20])
        more = f" and {len(missed) - 20} more" if len(missed) > 20 else ""
        extra = t["open_pixel_samples"]
        cost = "–" if not missed else "∞" if extra == math.inf else f"{extra:.3g} pixel-samples"
        out.append(f"| {noise_text(t['noise'])} | {t['met']} of {t['views']} | {t['negligible']} | "
                   f"{t['rounds_min']}–{t['rounds_max']} | {cost} | {named + more or 'none'} |")
    return out


def _save_view(out: Path, label: str, L, maps, names: list[str]) -> None:
    write_exr(out / "views" / f"{label}_rgb.exr", L)
    write_png(out / "views" / f"{label}_rgb.png", L, title=label)
    for k, mp in enumerate(maps):
        save_fisher_maps(mp, names, out / "views", prefix=f"{label}_noise{k}_fisher")


def smoke(block: dict) -> dict:
    return {**block, "num": min(block["num"], 3), "spp": min(block["spp"], 16), "fd_rounds": min(block["fd_rounds"], 3)}


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "viewpoints.csv")
    paths = heat_maps(rows, study_dir, results)
    plugin = heat_maps(rows, study_dir, results, "plugin_mean_fisher") if rows and "plugin_mean_fisher" in rows[0] \
        else []
    n, s = results["num"], results["step"]
    lines = [
        f"Average per-pixel Fisher information over a {n} × {n} grid of camera offsets "
        f"({s * 100:.3g} cm steps, ±{(n - 1) / 2 * s * 100:.3g} cm along {results['axes']}), camera aimed at "
        f"{[round(v, 3) for v in results['target']]}, θ = {results['theta']}, {results['spp']} spp, "
        f"{results['renders']} renders (image + central FD with common random numbers per viewpoint).",
        "",
    ]
    lines += [
        f"![viewpoints {noise}]({study_dir.name}/{p.name})" for noise, p in zip(results["noises"], paths, strict=True)
    ]
    if plugin:
        lines += ["", "The same with the paper's plug-in estimate (one FD Jacobian's Ĵᵀ W Ĵ per pixel): biased upward "
                  "by the Jacobian's rendering noise, most where the object is hidden and the information small.", ""]
        lines += [f"![plug-in {noise}]({study_dir.name}/{p.name})"
                  for noise, p in zip(results["noises"], plugin, strict=True)]
    lines += [
        "",
        "| noise | parameter | min mean FI | centre | max mean FI | argmax offset [cm] | plug-in / unbiased, median |",
        "|---|---|---|---|---|---|---|",
    ]
    c = str((n - 1) // 2)
    for noise in results["noises"]:
        for name in results["params"]:
            sel = [r for r in rows if r["noise"] == noise and r["param"] == name]
            vals = np.array([float(r["mean_fisher"]) for r in sel])
            if not len(vals):
                continue
            best = sel[int(np.nanargmax(vals))]
            centre = [float(r["mean_fisher"]) for r in sel if r["i"] == c and r["j"] == c]
            ratio = [float(r["plugin_mean_fisher"]) / float(r["mean_fisher"]) for r in sel
                     if "plugin_mean_fisher" in r and float(r["mean_fisher"]) > 0]
            lines.append(
                f"| {noise} | {name} | {np.nanmin(vals):.4g} | {centre[0] if centre else float('nan'):.4g} | "
                f"{np.nanmax(vals):.4g} | ({float(best['offset_0']) * 100:.3g}, {float(best['offset_1']) * 100:.3g}) | "
                f"{np.median(ratio) if ratio else float('nan'):.3g} |"
            )
    if rows and len({r["i"] for r in rows}) > 1:
        curves = {(noise, name): profile(rows, noise, name) for noise in results["noises"]
                  for name in results["params"]}
        steps = transition_table(curves)
        write_csv(study_dir / "transitions.csv", steps)
        lines += _transition_lines(steps, results)
        write_csv(study_dir / "profiles.csv", [  # the data of profiles.png (log10 mean FI, 1/units²)
            {"noise": noise, "param": name, "offset": float(x), "q10": float(q[0, k]), "median": float(q[1, k]),
             "q90": float(q[2, k])} for (noise, name), (u0, q) in curves.items() for k, x in enumerate(u0)])
        prof = profile_plot(curves, study_dir, results)
        lines += ["", f"![profiles]({study_dir.name}/{prof.name})"]
    table = resolution_table(rows, results)
    if table:
        write_csv(study_dir / "resolution.csv", table)
    lines += _precision_lines(rows, table, results)
    if results.get("infinite_cells"):
        lines.append(
            f"\n{results['infinite_cells']} cell(s) have infinite Fisher information (a Poisson pixel rendered "
            "as exactly 0 that changes with θ): render with more spp."
        )
    return "\n".join(lines)
