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
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import estimators, io
from ..bank import TRUTH
from ..diagnostics import resolve_gradient
from ..diagnostics.images import label as gradient_label
from ..estimators import Budget
from ..forward.gradients import GradientSettings
from ..io import write_csv, write_json
from ..montecarlo import LOG_NAME, Setting, make_trials, run_trials, summarize
from ..schema import ConfigError, Field, grid_values, smoke_grid
from .plots import plot_mse, plot_speed
from .tables import fmt, mse_units, paper_table

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


# -- plan ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Plan:
    """What the study computes: θ* (T, P), trials per θ*, N_eff, the noise models (index → model), the
    estimator settings (gradients resolved), the budget per fit, and what fixes the results (`fingerprint`)."""

    thetas: np.ndarray
    n: int
    n_eff: int
    noises: dict
    settings: list
    budget: Budget
    fingerprint: dict


def plan(ctx, cfg: dict) -> Plan:
    """The study's plan from its validated block (ConfigError naming the key for what the schema cannot
    see); gradient method `auto` resolved for the run's model here, once."""
    sid = cfg.get("id") or NAME
    params = ctx.model.params
    thetas = parse_thetas(cfg["theta"], params, f"{sid}.theta")
    for k in ("n", "n_eff", "hcr_grid"):
        if cfg[k] < 1:
            raise ConfigError(f"{sid}.{k}", f"expected a positive integer, got {cfg[k]}")
    noises = ctx.select_noises(cfg["noise"], f"{sid}.noise")
    settings = parse_settings(cfg["estimators"], f"{sid}.estimators", ctx.model)
    if "barankin" in cfg["bounds"] and params.dim > 1:
        raise ConfigError(f"{sid}.bounds", f"barankin bounds a scalar θ; this model has {list(params.names)}")
    try:
        budget = Budget(**cfg["budget"])
    except ValueError as e:
        raise ConfigError(f"{sid}.budget", str(e)) from None
    study = {k: v for k, v in cfg.items() if k not in ("far_above", "bootstrap")}
    fingerprint = json.loads(json.dumps({
        "study": study, "seed": ctx.seed, "noise": {j: repr(n) for j, n in noises.items()},
        "scene": {k: v for k, v in ctx.model_spec.items() if k != "cache"},
        "gradients": {s.label: dataclasses.asdict(s.gradient) for s in settings}}, sort_keys=True, default=repr))
    return Plan(thetas, cfg["n"], cfg["n_eff"], noises, settings, budget, fingerprint)


def bounds_map(rows: list[dict], want) -> dict:
    """(noise, θ index) → {bound: {value, log10}} for `montecarlo.summarize`."""
    return {(r["noise_index"], r["theta_index"]): {b: {"value": 10.0 ** min(float(r[f"log10_{b}"]), 308),
                                                       "log10": float(r[f"log10_{b}"])} for b in want} for r in rows}


# -- the study ------------------------------------------------------------------------------------
def run(ctx, cfg: dict) -> dict:
    """Plan, render the truth images (the bank's TRUTH set: the observation's mean, never seen by an
    estimator), ask the bound service for every bound at θ*, run (or resume) the trials, summarise.
    The result's `renders` counts renders + AD passes in every process: all fits in trials.jsonl, and the
    truth and bound renders this call made (a resumed run reads those from the run's render store)."""
    t0 = time.perf_counter()
    sid = cfg.get("id") or NAME
    p = plan(ctx, cfg)
    for s in p.settings:
        if s.gradient.chosen:
            ctx.log(f"[{sid}] {s.label}: gradient auto → {s.gradient.chosen}")
    folder = ctx.study_dir(cfg)
    plan_file = folder / "plan.json"
    if ctx.resume and plan_file.exists() and json.loads(plan_file.read_text()) != p.fingerprint:
        raise ConfigError(sid, f"the config differs from the one {folder} was started with; resume with the same "
                               "config or start a new run directory")
    write_json(plan_file, p.fingerprint)
    before = ctx.bank.renders
    truth = ctx.bank.at(p.thetas, p.n_eff, TRUTH, desc="truth images")
    for i, img in enumerate(truth):
        io.write_exr(folder / "images" / f"clean_{i:03d}.exr", img)
    points = ctx.bounds.at(p.thetas, p.n_eff, cfg["bounds"], cfg["seeds"], cfg["hcr_grid"], cfg["hcr_offsets"],
                           cfg["fd_step"], cfg["levels"], noises=list(p.noises)) if cfg["bounds"] else []
    bound_rows = [{"theta_index": i % len(p.thetas), **pt.row(ctx.model.params.names)} for i, pt in enumerate(points)]
    write_csv(folder / "bounds.csv", bound_rows)
    renders = ctx.bank.renders - before

    trials = make_trials(p.thetas, p.n, p.settings, p.noises, dict(enumerate(truth)), ctx.seed, p.budget,
                         cfg["start_width"], cfg["traces"])
    records = run_trials(ctx.bank.executor, trials, folder / LOG_NAME, resume=ctx.resume, progress=ctx.progress)
    rows = summarize(records, ctx.model.params.names, bounds_map(bound_rows, cfg["bounds"]), cfg["far_above"],
                     cfg["bootstrap"], ctx.seed_for("summary"), labels=[s.label for s in p.settings])
    write_csv(folder / "summary.csv", rows)
    errors = sorted({r["error"] for r in records if r["error"]})
    params = ctx.model.params
    return {"id": sid, "theta": p.thetas.tolist(), "params": list(params.names), "units": list(params.units),
            "n": p.n, "n_eff": p.n_eff, "estimators": [s.label for s in p.settings],
            "gradients": {s.label: gradient_label(s.gradient) + (f" (auto: {s.gradient.chosen})" if s.gradient.chosen
                                                                 else "") for s in p.settings},
            "noise": {str(j): repr(n) for j, n in p.noises.items()}, "bounds": cfg["bounds"],
            "bound_notes": {b: BOUND_NOTES[b] for b in cfg["bounds"]}, "fd_step": cfg["fd_step"],
            "far_above": cfg["far_above"], "trials": len(records), "seconds": time.perf_counter() - t0,
            "renders": renders + sum(r["renders"] + r["grad_passes"] for r in records),
            "summary": rows, "bound_rows": bound_rows, "errors": errors[:20],
            "files": [LOG_NAME, "summary.csv", "bounds.csv", "plots/mse_vs_theta.png", "plots/speed_vs_error.png"]}


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


def report(study_dir, results: dict) -> str:
    """Markdown: what was run, the paper-style MSE-vs-bounds table and the detailed MSE/bound table per
    noise model, flags, failures and the plots (drawn here from results.json)."""
    rows, bounds = results["summary"], results["bounds"]
    study_dir = Path(study_dir)
    noise_names = {int(j): n for j, n in results["noise"].items()}
    plot_mse(rows, results["bound_rows"], bounds, results["params"], results["units"], noise_names,
             study_dir / "plots" / "mse_vs_theta.png")
    plot_speed(rows, mse_units(results["units"]), study_dir / "plots" / "speed_vs_error.png")
    failed = sum(r["n_failed"] for r in rows)
    nonconv = sum(r["n_nonconverged"] for r in rows)
    fit_s = sum(r["total_seconds"] for r in rows)
    fit_renders = sum(r["total_renders"] + r["total_grad_passes"] for r in rows)
    lines = [
        f"Estimators against the bounds: {results['n']} trials per θ* at {len(results['theta'])} θ* of "
        f"{results['params']} "
        f"({', '.join(results['units'])}), estimators {results['estimators']}, noise "
        f"{', '.join(results['noise'].values())}; clean images at N_eff = {results['n_eff']} spp. "
        f"{results['trials']} fits recorded, {failed} failed, {nonconv} not converged; "
        f"{results['seconds']:.1f} s in all, of which the fits took {fit_s:.1f} s and {fit_renders} renders "
        "(+ AD passes).",
        "",
    ]
    lines += [f"- gradient of **{label}**: {g}" for label, g in results.get("gradients", {}).items()]
    lines += [
        "",
        "MSE = mean ‖θ̂ − θ*‖² over the fits that did not fail, standard errors by bootstrap over trials; "
        + ("each ratio is MSE / that bound. Bounds:" if bounds else "no bounds were computed."),
        "",
    ]
    lines += [f"- **{b}**: {results['bound_notes'][b]}" for b in bounds]
    for j in sorted({r["noise"] for r in rows}):
        lines += [
            "",
            f"### MSE against the bounds, the paper's format (noise {j}: {results['noise'][str(j)]}; "
            f"{mse_units(results['units'])})",
            "",
        ]
        lines += paper_table(rows, results["bound_rows"], bounds, results["params"], results["units"], j)
    head = (
        ["θ*", "estimator", "n", "failed", "not conv.", "MSE ± SE", "Var", "‖bias‖"]
        + [f"MSE/{b}" for b in bounds]
        + ["s / trial", "renders / trial", "flag"]
    )
    for j in sorted({r["noise"] for r in rows}):
        lines += [
            "",
            f"### Details, noise {j}: {results['noise'][str(j)]}",
            "",
            "| " + " | ".join(head) + " |",
            "|" + "---|" * len(head),
        ]
        for r in (r for r in rows if r["noise"] == j):
            theta = ", ".join(fmt(r[f"theta_{n}"], 4) for n in results["params"])
            flag = "; ".join(
                filter(
                    None,
                    [
                        f"far above {r['far_above']}" if r["far_above"] else "",
                        f"below {r['below']}" if r["below"] else "",
                    ],
                )
            )
            cells = (
                [
                    theta,
                    r["estimator"],
                    r["n"],
                    r["n_failed"],
                    r["n_nonconverged"],
                    f"{fmt(r['mse'])} ± {fmt(r['mse_se'], 2)}",
                    fmt(r["var"]),
                    fmt(r["bias"]),
                ]
                + [fmt(r.get(f"mse_over_{b}")) for b in bounds]
                + [fmt(r["mean_seconds"]), fmt(r["mean_renders"] + r["mean_grad_passes"]), flag or "ok"]
            )
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    far = [r for r in rows if r["far_above"]]
    below = [r for r in rows if r["below"]]
    lines += [
        "",
        f"**Far above the bound** (MSE > {results['far_above']:g} × bound): "
        + (
            "; ".join(f"{r['estimator']} at θ* #{r['theta_index']} (noise {r['noise']}; {r['far_above']})" for r in far)
            or "none."
        ),
    ]
    lines += [
        "**Below the bound** (MSE + 2 SE < bound: biased, too few trials, or the bound is off): "
        + (
            "; ".join(f"{r['estimator']} at θ* #{r['theta_index']} (noise {r['noise']}; {r['below']})" for r in below)
            or "none."
        )
    ]
    if results["errors"]:
        lines += ["", "Failed fits (distinct errors):", ""] + [f"- `{e}`" for e in results["errors"]]
    bhead = ["noise", "θ*"] + [f"log10 {b}" for b in bounds] + (["HCR Δ at sup"] if "hcr" in bounds else []) + ["notes"]
    if bounds:
        lines += [
            "",
            "Bounds at θ* (log10 of units²; a bound may underflow to 0, its log10 is exact):",
            "",
            "| " + " | ".join(bhead) + " |",
            "|" + "---|" * len(bhead),
        ]
    for r in results["bound_rows"] if bounds else []:
        notes = "; ".join(filter(None, (str(r.get(f"{b}_reason") or "") for b in bounds)))
        cells = (
            [r["noise_index"], ", ".join(fmt(r[f"theta_{n}"], 4) for n in results["params"])]
            + [fmt(float(r[f"log10_{b}"]), 4) for b in bounds]
            + ([r["hcr_delta"]] if "hcr" in bounds else [])
            + [notes or "–"]
        )
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    rel = Path(study_dir).name
    lines += [
        "",
        f"![MSE and bounds against θ*]({rel}/plots/mse_vs_theta.png)",
        f"![speed against error]({rel}/plots/speed_vs_error.png)",
        "",
    ]
    return "\n".join(lines)
