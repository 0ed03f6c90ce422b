"""Study `trials`: Monte Carlo trials of estimators at a list of θ*, MSE against the bounds, speed
against error.

Per θ*: the clean image at N_eff spp (rendered once, saved as EXR, reused by every trial and by the
bounds); per noise model: HCR_Neff from renders at θ* + Δ (Δ over a grid on Θ shared by all θ*, plus
small offsets ±ξ·2^k along each axis), the CRLB from an FD Jacobian at θ* (step ξ, common random
numbers), optionally the Barankin bound (scalar θ) and HCR-hat (bias-corrected λ̂ from several spp
levels, `bounds.inexact`); then n trials per θ* for every estimator setting (`trials.py`), resumable
from trials.jsonl. Outputs: summary.csv, bounds.csv, plots/mse_vs_theta.png, plots/speed_vs_error.png.

An estimator's `gradient: {method: auto}` is resolved once, before any render (`diagnostics.
resolve_gradient`: `choose_backend` from a gradients study's verdicts, `verdicts: PATH`, or the prior:
colour → AD, geometry → FD); workers get the concrete settings, and the choice is in the results and the report.
"""
from __future__ import annotations

import copy
import dataclasses
import itertools
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from .. import estimators, io
from ..bank import JacobianRequest, Request
from ..bounds import barankin, crlb, fisher_matrix, hcr, inexact_hcr
from ..diagnostics import resolve_gradient
from ..diagnostics.images import label as gradient_label
from ..estimators import Budget
from ..forward.gradients import GradientSettings
from ..io import read_csv, write_csv, write_json
from ..montecarlo import LOG_NAME, Setting, make_trials, run_trials, summarize
from ..schema import ConfigError, Field, grid_values, smoke_grid
from .plots import _plt

NAME = "trials"
BOUNDS = ("hcr", "crlb", "barankin", "hcr_hat")
BOUND_NOTES = {
    "hcr": "HCR_Neff: sup_Δ ‖Δ‖²/(exp λ − 1) on the MSE, λ from renders at N_eff (θ* and θ* + Δ: the Θ grid "
           "plus ±ξ·2^k axis offsets); rendering noise inflates λ, so it tends to underestimate the true HCR. "
           "For a vector θ it bounds the MSE through the worst single direction: as Δ → 0 it tends to "
           "1/λ_min(F), up to P times below the CRLB's trace",
    "crlb": "CRLB: trace of F⁻¹, Fisher matrix from a central-FD Jacobian (step ξ, common random numbers) at N_eff",
    "barankin": "Barankin (McAulay–Seidman) on Var of the scalar θ from the same renders as the HCR (≥ HCR)",
    "hcr_hat": "HCR-hat: HCR from the bias-corrected λ̂ (fit of λ̃ = λ + C/N over the spp levels); an upper "
               "bound on the true HCR in expectation, so [HCR_Neff, HCR-hat] brackets it",
}

ESTIMATOR = {
    "name": Field(str, help="registered estimator (nlosbench list estimators)"),
    "options": Field(dict, {}, "keyword options of the estimator"),
    "label": Field(str, None, "name in tables and plots (default: name); unique within the study", nullable=True),
    "gradient": Field(dict, {}, "gradient settings of the problem (forward.GradientSettings): method (fd | ad | "
                                "mixed | auto), step, rounds, crn, spp, ad, ad_params, verdicts; auto picks per "
                                "parameter from `verdicts` (a gradients study's verdicts.json) or the prior"),
}
SCHEMA = {
    "theta": Field("any", help="θ* values: numbers (or {start, stop, num}) for a 1-D θ, else a list of lists"),
    "n": Field(int, 30, "trials per θ* (fresh noise and fresh start each)"),
    "n_eff": Field(int, 4096, "spp of the clean image at θ* and of the bound renders"),
    "estimators": Field(list, help="estimator settings {name, options, label, gradient}", items=ESTIMATOR),
    "noise": Field("any", "all", "index (or list of indices) into the run's noise models, or 'all'"),
    "bounds": Field(list, ["hcr", "crlb"], "bounds compared with the MSE", items=Field(str, choices=BOUNDS)),
    "seeds": Field(str, "independent", "seeds of the clean and HCR renders: independent (the paper) or common "
                   "(common random numbers: less λ inflation by rendering noise)", choices=("independent", "common")),
    "hcr_grid": Field(int, 21, "HCR test points per parameter on a grid over Θ (shared by all θ*)"),
    "hcr_offsets": Field(int, 4, "HCR test offsets ±ξ·2^k, k < hcr_offsets, along each parameter"),
    "fd_step": Field(float, 0.01, "ξ: FD step of the CRLB Jacobian and smallest HCR offset (θ units, every parameter)"),
    "levels": Field(list, [1024, 2048], "spp levels of the λ̂ fit for hcr_hat", items=int),
    "budget": Field({"iterations": Field(int, None, "iterations per fit", nullable=True),
                     "renders": Field(int, None, "renders + AD passes per fit", nullable=True),
                     "seconds": Field(float, None, "wall seconds per fit", nullable=True)}),
    "start_width": Field(float, None, "random starts uniform in θ* ± width·|Θ|/2 (null: uniform in Θ)",
                         nullable=True),
    "far_above": Field(float, 3.0, "flag MSE / bound above this factor"),
    "bootstrap": Field(int, 1000, "bootstrap resamples for standard errors"),
    "traces": Field(bool, False, "store each fit's loss/θ trace in trials.jsonl"),
}


# -- config → objects (all checked before any render) -------------------------------------------
def parse_thetas(spec, params, where: str) -> np.ndarray:
    """θ* values as (T, P) float64, each checked against Θ."""
    if params.dim == 1 and (isinstance(spec, dict) or all(isinstance(v, (int, float)) for v in spec or [])):
        try:
            spec = [[v] for v in grid_values(spec)]
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(where, f"expected a list of numbers or {{start, stop, num}}: {e}") from None
    if not isinstance(spec, list) or not spec:
        raise ConfigError(where, f"expected a non-empty list of θ* values, got {spec!r}")
    out = []
    for i, t in enumerate(spec):
        try:
            out.append(params.validate(t))
        except ValueError as e:
            raise ConfigError(f"{where}[{i}]", str(e)) from None
    return np.array(out)


def check(block: dict, path: str) -> None:
    """Config-time check (before anything is written): every estimator exists and takes its options."""
    check_estimators(block["estimators"], f"{path}.estimators")


def check_estimators(specs: list, where: str) -> None:
    """Build each estimator setting once to check its name and options (ConfigError naming the entry)."""
    if not specs:
        raise ConfigError(where, "expected at least one estimator")
    for k, s in enumerate(specs):
        try:
            estimators.get(s["name"], **s["options"])
        except KeyError as e:
            raise ConfigError(f"{where}[{k}].name", e.args[0]) from None
        except (TypeError, ValueError) as e:
            raise ConfigError(f"{where}[{k}]", str(e)) from None


def parse_settings(specs: list, where: str, model) -> list[Setting]:
    """Estimator settings (checked by `check_estimators`); gradient method `auto` resolved for `model`
    here, once."""
    check_estimators(specs, where)
    out = []
    for k, s in enumerate(specs):
        try:
            grad = resolve_gradient(model, GradientSettings(**s["gradient"]))
        except (TypeError, ValueError, FileNotFoundError) as e:
            raise ConfigError(f"{where}[{k}].gradient", str(e)) from None
        out.append(Setting(s["name"], s["options"], s["label"] or s["name"], grad))
    labels = [s.label for s in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ConfigError(where, f"labels {dup} are used twice; give each setting its own `label`")
    return out


# -- clean images and bounds ---------------------------------------------------------------------
def offsets(params, theta: np.ndarray, count: int, step: float) -> np.ndarray:
    """Axis offsets θ* ± ξ·2^k e_j (k < count) inside Θ, as points (M, P)."""
    pts = []
    for j, k, sgn in itertools.product(range(params.dim), range(count), (-1.0, 1.0)):
        t = theta.copy()
        t[j] += sgn * step * 2.0 ** k
        if params.contains(t):
            pts.append(t)
    return np.array(pts).reshape(-1, params.dim)


def bound_seed(ctx, cfg: dict, purpose: str, *idx: int) -> int:
    """Seed of a clean or bound render: derived per render, or one for all with `seeds: common`
    (common random numbers: L(θ*+Δ) − L(θ*) then carries far less rendering noise)."""
    return ctx.seed_for("bounds-common") if cfg["seeds"] == "common" else ctx.seed_for(purpose, *idx)


def clean_images(ctx, thetas: np.ndarray, cfg: dict, folder: Path) -> tuple[dict[int, torch.Tensor], int]:
    """(θ index → clean image at n_eff, renders done). Each is rendered once and kept as
    images/clean_<i>.exr (a resumed run reads them back: float32 EXR is lossless; files are renamed
    into place once complete)."""
    files = {i: folder / "images" / f"clean_{i:03d}.exr" for i in range(len(thetas))}
    out = {i: torch.from_numpy(io.read_exr(f)) for i, f in files.items() if ctx.resume and f.exists()}
    todo = [i for i in files if i not in out]
    before = ctx.bank.renders
    imgs = ctx.bank.images([Request.of(thetas[i], cfg["n_eff"], bound_seed(ctx, cfg, "clean", i)) for i in todo],
                           "clean images") if todo else []
    for i, img in zip(todo, imgs, strict=True):
        io.write_exr(files[i], img)
        out[i] = img
    return out, ctx.bank.renders - before


def compute_bounds(ctx, thetas, cleans, noises: dict, cfg: dict) -> tuple[list[dict], int]:
    """(one row per (noise j, θ* i) with every requested bound: value, log10 (units²) and diagnostics;
    renders done)."""
    params = ctx.model.params
    want, n_eff, step = cfg["bounds"], cfg["n_eff"], cfg["fd_step"]
    grid = params.grid(cfg["hcr_grid"])
    offs = {i: offsets(params, t, cfg["hcr_offsets"], step) for i, t in enumerate(thetas)}
    before = ctx.bank.renders
    need_alt = bool({"hcr", "barankin", "hcr_hat"} & set(want))
    grid_imgs = ctx.bank.images([Request.of(t, n_eff, bound_seed(ctx, cfg, "hcr-grid", g)) for g, t in enumerate(grid)],
                                "bound renders") if need_alt else None
    off_imgs = {i: ctx.bank.images([Request.of(t, n_eff, bound_seed(ctx, cfg, "hcr-offset", i, q))
                                    for q, t in enumerate(offs[i])], "bound renders")
                for i in offs if len(offs[i])} if need_alt else {}
    jac = ctx.bank.jacobians([JacobianRequest.of(t, n_eff, ctx.seed_for("crlb", i), step) for i, t in enumerate(thetas)],
                             "CRLB Jacobians") if "crlb" in want else None
    rows = {}
    for i, theta in enumerate(thetas):
        # grid points that coincide with θ* (up to rounding) are not test points
        near = np.flatnonzero(np.abs((grid - theta) / (params.upper - params.lower)).max(axis=1) > 1e-9)
        pts = np.concatenate([grid[near], offs[i]])
        alt = torch.cat([grid_imgs[near]] + ([off_imgs[i]] if i in off_imgs else [])) if need_alt else None
        lower, upper = params.lower - theta, params.upper - theta
        deltas = pts - theta if params.dim > 1 else (pts - theta)[:, 0]
        # the spp-level renders do not depend on the noise model: once per θ*
        levels = ctx.bank.replicates(np.concatenate([theta[None], pts]), cfg["levels"], 1, ctx.seed_for("hcr-hat", i),
                                     desc="HCR-hat level points") if "hcr_hat" in want else None
        for j, noise in noises.items():
            row = {"noise": j, "theta_index": i, **{f"theta_{n}": float(v) for n, v in zip(params.names, theta, strict=True)}}
            if "hcr" in want:
                h = hcr(cleans[i], alt, deltas, noise, lower, upper)
                delta = None if h.delta is None else np.atleast_1d(h.delta).tolist()
                row.update(hcr=h.value, hcr_log10=h.log10, hcr_delta=json.dumps(delta), hcr_at_edge=h.at_edge or "",
                           hcr_reason=h.reason)
            if "crlb" in want:
                c = crlb(fisher_matrix(cleans[i], jac[i], noise))
                with np.errstate(divide="ignore"):
                    row.update(crlb=c.trace, crlb_log10=float(np.log10(c.trace)), crlb_reason=c.reason)
            if "barankin" in want:
                b = barankin(cleans[i], alt, deltas, noise, lower=lower, upper=upper)
                row.update(barankin=b.value, barankin_log10=b.log10, barankin_points=len(b.points),
                           barankin_reason=b.reason)
            if "hcr_hat" in want:
                r = inexact_hcr(levels[:, :, 0], levels[:, :, 1:], deltas, cfg["levels"], noise, cleans[i][None],
                                alt[None], n_eff, lower, upper).hcr_hat
                row.update(hcr_hat=r.value, hcr_hat_log10=r.log10, hcr_hat_reason=r.reason)
            rows[j, i] = row
    return [rows[j, i] for j in noises for i in range(len(thetas))], ctx.bank.renders - before


def bounds_map(rows: list[dict], want) -> dict:
    """(noise, θ index) → {bound: {value, log10}} for `trials.summarize`."""
    return {(r["noise"], r["theta_index"]): {b: {"value": float(r[b]), "log10": float(r[f"{b}_log10"])} for b in want}
            for r in rows}


# -- the study ------------------------------------------------------------------------------------
def _plan(ctx, cfg: dict, noises: dict, settings: list[Setting]) -> dict:
    """What fixes the trials and bounds (not the summary's far_above / bootstrap): a resumed run must
    have the same plan, including the gradient settings an `auto` block resolved to."""
    study = {k: v for k, v in cfg.items() if k not in ("far_above", "bootstrap")}
    return json.loads(json.dumps({"study": study, "seed": ctx.seed, "noise": {j: repr(n) for j, n in noises.items()},
                                  "scene": {k: v for k, v in ctx.model_spec.items() if k != "cache"},
                                  "gradients": {s.label: dataclasses.asdict(s.gradient) for s in settings}},
                                 sort_keys=True, default=repr))


def run(ctx, cfg: dict) -> dict:
    """Validate the block, render clean images and bounds, run (or resume) the trials, summarise.
    The result's `renders` counts renders + AD passes in every process: all fits in trials.jsonl, and
    the clean and bound renders this call made (a resumed run reads those back)."""
    t0 = time.perf_counter()
    sid = cfg.get("id") or NAME
    params = ctx.model.params
    thetas = parse_thetas(cfg["theta"], params, f"{sid}.theta")
    if cfg["n"] < 1:
        raise ConfigError(f"{sid}.n", f"expected at least 1 trial per θ*, got {cfg['n']}")
    if cfg["n_eff"] < 1:
        raise ConfigError(f"{sid}.n_eff", f"expected a positive spp, got {cfg['n_eff']}")
    noises = ctx.select_noises(cfg["noise"], f"{sid}.noise")
    settings = parse_settings(cfg["estimators"], f"{sid}.estimators", ctx.model)
    for s in settings:
        if s.gradient.chosen:
            ctx.log(f"[{sid}] {s.label}: gradient auto → {s.gradient.chosen}")
    if "barankin" in cfg["bounds"] and params.dim > 1:
        raise ConfigError(f"{sid}.bounds", f"barankin bounds a scalar θ; this model has {list(params.names)}")
    try:
        budget = Budget(**cfg["budget"])
    except ValueError as e:
        raise ConfigError(f"{sid}.budget", str(e)) from None

    folder = ctx.study_dir(cfg)
    plan = _plan(ctx, cfg, noises, settings)
    plan_file = folder / "plan.json"
    if ctx.resume and plan_file.exists() and json.loads(plan_file.read_text()) != plan:
        raise ConfigError(sid, f"the config differs from the one {folder} was started with; resume with the same "
                               "config or start a new run directory")
    write_json(plan_file, plan)
    cleans, renders = clean_images(ctx, thetas, cfg, folder)
    bounds_file = folder / "bounds.csv"
    if ctx.resume and bounds_file.exists():
        bound_rows = [{k: _num(v) for k, v in r.items()} for r in read_csv(bounds_file)]
    else:
        bound_rows, bound_renders = compute_bounds(ctx, thetas, cleans, noises, cfg)
        renders += bound_renders
        write_csv(bounds_file, bound_rows)

    trials = make_trials(thetas, cfg["n"], settings, noises, cleans, ctx.seed, budget, cfg["start_width"], cfg["traces"])
    records = run_trials(ctx.bank.executor, trials, folder / LOG_NAME, resume=ctx.resume, progress=ctx.progress)
    rows = summarize(records, params.names, bounds_map(bound_rows, cfg["bounds"]), cfg["far_above"], cfg["bootstrap"],
                     ctx.seed_for("summary"), labels=[s.label for s in settings])
    write_csv(folder / "summary.csv", rows)
    plots = [plot_mse(rows, bound_rows, cfg["bounds"], params, {j: repr(n) for j, n in noises.items()},
                      folder / "plots" / "mse_vs_theta.png"),
             plot_speed(rows, mse_units(params.units), folder / "plots" / "speed_vs_error.png")]
    errors = sorted({r["error"] for r in records if r["error"]})
    return {"id": sid, "theta": thetas.tolist(), "params": list(params.names), "units": list(params.units),
            "n": cfg["n"], "n_eff": cfg["n_eff"], "estimators": [s.label for s in settings],
            "gradients": {s.label: gradient_label(s.gradient) + (f" (auto: {s.gradient.chosen})" if s.gradient.chosen
                                                                 else "") for s in settings},
            "noise": {str(j): repr(n) for j, n in noises.items()}, "bounds": cfg["bounds"],
            "bound_notes": {b: BOUND_NOTES[b] for b in cfg["bounds"]}, "fd_step": cfg["fd_step"],
            "far_above": cfg["far_above"], "trials": len(records), "seconds": time.perf_counter() - t0,
            "renders": renders + sum(r["renders"] + r["grad_passes"] for r in records),
            "summary": rows, "bound_rows": bound_rows, "errors": errors[:20],
            "files": [str(p.relative_to(folder)) for p in [folder / LOG_NAME, folder / "summary.csv", bounds_file] + plots]}


#: caps on estimator options in a smoke run (known option names of the built-in estimators; nested
#: `options`, e.g. multi-start's base estimator, are capped the same way)
SMOKE_OPTIONS = {"iterations": 3, "spp": 4, "num": 5, "starts": 2, "refine_evals": 4, "refine_spp": 4}


def _smoke_options(options: dict) -> dict:
    out = {}
    for k, v in options.items():
        if k == "options" and isinstance(v, dict):
            v = _smoke_options(v)
        elif k in SMOKE_OPTIONS and isinstance(v, int) and not isinstance(v, bool):
            v = min(v, SMOKE_OPTIONS[k])
        elif k == "spp" and isinstance(v, list):  # an spp schedule [[fraction, spp], ...]
            v = [[f, min(n, SMOKE_OPTIONS["spp"])] for f, n in v]
        out[k] = v
    return out


def _smoke_gradient(gradient: dict) -> dict:
    g = {**gradient, "rounds": 1}
    if g.get("spp"):
        g["spp"] = min(g["spp"], SMOKE_OPTIONS["spp"])
    return g


def smoke(block: dict) -> dict:
    """A reduced copy of a validated `trials` block that runs in seconds through the same code path:
    2 θ* (the list's ends), 2 trials, N_eff ≤ 32 spp, HCR grid ≤ 5 points per parameter and ≤ 2 offsets,
    spp levels [8, 16], ≤ 20 bootstrap resamples, at most 3 iterations per fit (the budget, which caps
    plug-in estimators too) and the built-in estimators' options capped (`SMOKE_OPTIONS`: spp ≤ 4,
    grid num ≤ 5, starts ≤ 2, ...); gradient renders ≤ 4 spp and 1 FD round."""
    b = copy.deepcopy(block)
    b["theta"] = smoke_grid(b["theta"], 2)
    iters = b["budget"].get("iterations")
    b["budget"] = {**b["budget"], "iterations": min(iters or SMOKE_OPTIONS["iterations"], SMOKE_OPTIONS["iterations"])}
    b["estimators"] = [{**e, "options": _smoke_options(e["options"]), "gradient": _smoke_gradient(e["gradient"])}
                       for e in b["estimators"]]
    b.update(n=min(b["n"], 2), n_eff=min(b["n_eff"], 32), hcr_grid=min(b["hcr_grid"], 5),
             hcr_offsets=min(b["hcr_offsets"], 2), levels=[8, 16], bootstrap=min(b["bootstrap"], 20))
    return b


def _num(v: str):
    """A CSV cell back to a number where it is one."""
    try:
        return int(v)
    except ValueError:
        pass
    try:
        return float(v)
    except ValueError:
        return v


# -- plots ------------------------------------------------------------------------------------------
def mse_units(units) -> str:
    """Units of the MSE of θ: the parameters' unit squared (or a note when they differ)."""
    return f"{units[0]}²" if len(set(units)) == 1 else "mixed units²"


def plot_mse(rows: list[dict], bound_rows: list[dict], bounds, params, noise_names: dict, path: Path) -> Path:
    """MSE (± SE) of every estimator and the bounds against θ*, log scale; one panel per noise model."""
    plt = _plt()
    noises = sorted({r["noise"] for r in rows})
    fig, axes = plt.subplots(1, len(noises), figsize=(6 * len(noises), 4.2), squeeze=False)
    xname = params.names[0] if params.dim == 1 else "θ* index"
    xkey = f"theta_{params.names[0]}" if params.dim == 1 else "theta_index"
    for ax, j in zip(axes[0], noises, strict=True):
        for label in dict.fromkeys(r["estimator"] for r in rows):
            rs = [r for r in rows if r["noise"] == j and r["estimator"] == label and r["mse"] > 0]
            ax.errorbar([r[xkey] for r in rs], [r["mse"] for r in rs], yerr=[r["mse_se"] for r in rs], marker="o",
                        capsize=3, label=f"MSE {label}")
        for b in bounds:
            bs = [r for r in bound_rows if r["noise"] == j and math.isfinite(r[f"{b}_log10"])]
            ax.plot([r[xkey] for r in bs], [10.0 ** r[f"{b}_log10"] for r in bs], "--", marker=".", label=b.upper())
        ax.set_yscale("log")
        ax.set_xlabel(f"θ* ({xname}{', ' + params.units[0] if params.dim == 1 else ''})")
        ax.set_ylabel(f"MSE, bound [{mse_units(params.units)}]")
        ax.set_title(f"noise {j}: {noise_names[j]}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_speed(rows: list[dict], units: str, path: Path) -> Path:
    """Speed against error: per estimator setting (and noise model), mean wall seconds and renders
    (+ AD passes) per trial against the MSE averaged over θ*, log–log."""
    plt = _plt()
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    several = len({r["noise"] for r in rows}) > 1
    xs: list[list[float]] = [[], []]
    for (j, label) in dict.fromkeys((r["noise"], r["estimator"]) for r in rows):
        rs = [r for r in rows if r["noise"] == j and r["estimator"] == label and r["mse"] > 0]
        if not rs:  # every fit failed (or hit θ* exactly): nothing to place on a log axis
            continue
        mse = float(np.mean([r["mse"] for r in rs]))
        secs = float(np.mean([r["mean_seconds"] for r in rs]))
        rend = float(np.mean([r["mean_renders"] + r["mean_grad_passes"] for r in rs]))
        for ax, x, seen in zip(axes, (secs, rend), xs, strict=True):
            seen.append(x)
            ax.scatter([x], [mse], s=40)
            ax.annotate(f"{label} (noise {j})" if several else label, (x, mse), fontsize=8, xytext=(4, 4),
                        textcoords="offset points")
    for ax, xl, seen in zip(axes, ("wall seconds per trial", "renders + AD passes per trial"), xs, strict=True):
        if seen and min(seen) > 0:  # a log axis needs positive data (cached renders count 0)
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlabel(xl)
        ax.set_ylabel(f"MSE averaged over θ* [{units}]")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("speed against error (one point per estimator setting)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# -- report ---------------------------------------------------------------------------------------
def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


BOUND_TITLES = {"hcr": "HCR_Neff", "hcr_hat": "HCR-hat", "crlb": "CRLB", "barankin": "Barankin"}


def paper_table(rows: list[dict], bound_rows: list[dict], bounds, params: list[str], units: list[str],
                noise: int) -> list[str]:
    """The paper's MLE-vs-HCR table for one noise model: θ*, the bounds, then MSE and Var of every
    estimator (units², 4 significant digits; an underflowed bound is written from its log10)."""
    labels = list(dict.fromkeys(r["estimator"] for r in rows))
    head = [f"θ* ({', '.join(units)})"] + [BOUND_TITLES[b] for b in bounds] + [f"{m}({e})" for e in labels for m in ("MSE", "Var")]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for b in (b for b in bound_rows if b["noise"] == noise):
        cells = [", ".join(_fmt(b[f"theta_{n}"], 4) for n in params)]
        cells += [_fmt_log10(float(b[f"{k}_log10"])) for k in bounds]
        for e in labels:
            r = next(r for r in rows if r["noise"] == noise and r["theta_index"] == b["theta_index"] and r["estimator"] == e)
            cells += [_fmt(r["mse"], 4), _fmt(r["var"], 4)]
        out.append("| " + " | ".join(cells) + " |")
    return out


def _fmt_log10(lg: float) -> str:
    """10**lg with 4 significant digits, also beyond float64's range (e.g. 1.3e-400); '–' when the
    bound is unavailable (log10 = ±inf; its reason is in the bounds table)."""
    if not math.isfinite(lg):
        return "–"
    if -300 < lg < 300:
        return f"{10.0 ** lg:.4g}"
    e = math.floor(lg)
    return f"{10.0 ** (lg - e):.4g}e{e:+d}"


def report(study_dir, results: dict) -> str:
    """Markdown: what was run, the paper-style MSE-vs-bounds table and the detailed MSE/bound table per
    noise model, flags, failures and the plots."""
    rows, bounds = results["summary"], results["bounds"]
    failed = sum(r["n_failed"] for r in rows)
    nonconv = sum(r["n_nonconverged"] for r in rows)
    fit_s = sum(r["total_seconds"] for r in rows)
    fit_renders = sum(r["total_renders"] + r["total_grad_passes"] for r in rows)
    lines = [f"Estimators against the bounds: {results['n']} trials per θ* at {len(results['theta'])} θ* of {results['params']} "
             f"({', '.join(results['units'])}), estimators {results['estimators']}, noise "
             f"{', '.join(results['noise'].values())}; clean images at N_eff = {results['n_eff']} spp. "
             f"{results['trials']} fits recorded, {failed} failed, {nonconv} not converged; "
             f"{results['seconds']:.1f} s in all, of which the fits took {fit_s:.1f} s and {fit_renders} renders "
             "(+ AD passes).", ""]
    lines += [f"- gradient of **{label}**: {g}" for label, g in results.get("gradients", {}).items()]
    lines += ["", "MSE = mean ‖θ̂ − θ*‖² over the fits that did not fail, standard errors by bootstrap over trials; "
              + ("each ratio is MSE / that bound. Bounds:" if bounds else "no bounds were computed."), ""]
    lines += [f"- **{b}**: {results['bound_notes'][b]}" for b in bounds]
    for j in sorted({r["noise"] for r in rows}):
        lines += ["", f"### MSE against the bounds, the paper's format (noise {j}: {results['noise'][str(j)]}; "
                      f"{mse_units(results['units'])})", ""]
        lines += paper_table(rows, results["bound_rows"], bounds, results["params"], results["units"], j)
    head = ["θ*", "estimator", "n", "failed", "not conv.", "MSE ± SE", "Var", "‖bias‖"] + \
           [f"MSE/{b}" for b in bounds] + ["s / trial", "renders / trial", "flag"]
    for j in sorted({r["noise"] for r in rows}):
        lines += ["", f"### Details, noise {j}: {results['noise'][str(j)]}", "", "| " + " | ".join(head) + " |",
                  "|" + "---|" * len(head)]
        for r in (r for r in rows if r["noise"] == j):
            theta = ", ".join(_fmt(r[f"theta_{n}"], 4) for n in results["params"])
            flag = "; ".join(filter(None, [f"far above {r['far_above']}" if r["far_above"] else "",
                                           f"below {r['below']}" if r["below"] else ""]))
            cells = [theta, r["estimator"], r["n"], r["n_failed"], r["n_nonconverged"],
                     f"{_fmt(r['mse'])} ± {_fmt(r['mse_se'], 2)}", _fmt(r["var"]), _fmt(r["bias"])] + \
                    [_fmt(r.get(f"mse_over_{b}")) for b in bounds] + \
                    [_fmt(r["mean_seconds"]), _fmt(r["mean_renders"] + r["mean_grad_passes"]), flag or "ok"]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    far = [r for r in rows if r["far_above"]]
    below = [r for r in rows if r["below"]]
    lines += ["", f"**Far above the bound** (MSE > {results['far_above']:g} × bound): "
              + ("; ".join(f"{r['estimator']} at θ* #{r['theta_index']} (noise {r['noise']}; {r['far_above']})"
                           for r in far) or "none.")]
    lines += ["**Below the bound** (MSE + 2 SE < bound: biased, too few trials, or the bound is off): "
              + ("; ".join(f"{r['estimator']} at θ* #{r['theta_index']} (noise {r['noise']}; {r['below']})"
                           for r in below) or "none.")]
    if results["errors"]:
        lines += ["", "Failed fits (distinct errors):", ""] + [f"- `{e}`" for e in results["errors"]]
    bhead = ["noise", "θ*"] + [f"log10 {b}" for b in bounds] + (["HCR Δ at sup"] if "hcr" in bounds else []) + ["notes"]
    if bounds:
        lines += ["", "Bounds at θ* (log10 of units²; a bound may underflow to 0, its log10 is exact):", "",
                  "| " + " | ".join(bhead) + " |", "|" + "---|" * len(bhead)]
    for r in results["bound_rows"] if bounds else []:
        notes = "; ".join(filter(None, (str(r.get(f"{b}_reason") or "") for b in bounds)))
        cells = [r["noise"], ", ".join(_fmt(r[f"theta_{n}"], 4) for n in results["params"])] + \
                [_fmt(float(r[f"{b}_log10"]), 4) for b in bounds] + ([r["hcr_delta"]] if "hcr" in bounds else []) + \
                [notes or "–"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    rel = Path(study_dir).name
    lines += ["", f"![MSE and bounds against θ*]({rel}/plots/mse_vs_theta.png)",
              f"![speed against error]({rel}/plots/speed_vs_error.png)", ""]
    return "\n".join(lines)
