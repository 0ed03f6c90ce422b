"""Study `trials`: Monte Carlo trials of estimators against the bounds that apply to them, speed against error.

Two protocols (`mode`):
* local (the paper's table): at each θ*, n trials from fresh noise on the clean image. An estimator that
  starts near θ*, is confined to Θ or uses a prior is biased there, so its MSE is set beside the HCR
  interval and the CRLB *with its measured bias* (a bias test whose standard error includes the clean
  image's own Monte Carlo error: the clean image is `truth_replicates` independent renders, trial k uses
  replicate k mod C); a row "below" the interval (a one-sided test at `level`, `nlosbench.verdicts`) is
  explained by that bias, or flagged as unexplained.
* bayesian: every trial draws its own θ* from the prior (uniform over Θ) and starts uniformly over Θ (the
  paper's protocol); the Bayesian MSE with its one-sided limits is held against the Ziv–Zakai bound, which
  holds for every estimator, biased or not.

Per θ* the bound service gives the HCR interval (with its Δ → 0 term), the CRLB from an unbiased Fisher
information, and the paper's HCR_Neff / HCR-hat; in bayesian mode its curve over a uniform `hcr_grid` on
Θ gives the ZZB. In local mode every row also gets its estimator's predicted variance
(`Estimator.predicted_variance`, from its linearised update at θ*: `predict`), tested against the measured one
(`montecarlo.variance_verdict`). Estimators get the bound sets' grid renders as `Problem.bank` (a profile-likelihood
start costs no render: estimator option `start: profile`); those sets never share a seed with the
observation's mean (the bank's TRUTH set). An estimator that renders a grid before its fits (grid-search:
`Estimator.grid_wanted`) gets it from the bank as replicate 0 (or the first `sets` replicates) of the bound
service's render sets at its spp (`Problem.grids`; with common seeds across the grid where the estimator needs them,
`Estimator.grid_seeds`, whatever the study's `seeds`): rendered once per run, counted with the bank's renders,
and the bound grid's own renders when its θ and spp are the bound grid's. With a `precision` target (local mode)
the service adds fresh replicate sets at the θ* whose HCR / CRLB interval is wider than asked, within
`precision_budget` pixel-samples and `looks` looks (`bounds.precision`); bounds.csv gets its precision_* columns
and the report a table of what was reached, spent and (where unmet) still needed. Trials resume from trials.jsonl.
Outputs: summary.csv, bounds.csv (zzb.csv), plots/mse_vs_theta.png, plots/speed_vs_error.png.

An estimator's `gradient: {method: auto}` is resolved once, before any render (`diagnostics.
resolve_gradient`: `choose_backend` from a gradients study's verdicts, `verdicts: PATH`, or the prior:
colour → AD, geometry → FD); workers get the concrete settings, and the choice is in the results and the report.
"""
from __future__ import annotations

import copy
import dataclasses
import inspect
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import estimators, io
from ..bank import TRUTH
from ..bounds import BoundService
from ..bounds.service.renders import per_theta
from ..diagnostics import resolve_gradient
from ..diagnostics.images import label as gradient_label
from ..estimators import BankGrid, Budget, Estimator, Problem
from ..estimators.predict import (
    Linearisation,
    choose_response,
    jacobian_covariance,
    render_covariance,
    variance,
    weight,
)
from ..forward.gradients import GradientSettings, jacobian
from ..io import write_csv
from ..montecarlo import (
    LOG_NAME,
    Setting,
    bound_entry,
    make_bayes_trials,
    make_trials,
    read_log,
    run_trials,
    summarize,
    summarize_bayes,
)
from ..schema import (
    MAX_HALVINGS,
    STEP_TOL,
    ConfigError,
    Field,
    grid_values,
    noise_spec,
    points_spec,
    positive_number,
    smoke_grid,
)
from . import precise
from .estimate import AD_PASS_RENDERS, Estimate, pixels
from .plots import plot_mse, plot_speed
from .tables import fmt, fmt_end, fmt_log10, mse_units, paper_table

NAME = "trials"
BOUNDS = ("hcr", "crlb", "hcr_neff", "hcr_hat", "barankin")
BOUND_NOTES = {
    "hcr": "HCR interval on the MSE of an unbiased estimator, with its Δ → 0 (CRLB) term: λ(Δ) and the Fisher "
           "information are U-statistics over independent replicate render sets (unbiased: rendering noise does "
           "not inflate them); the value shown is the lower end, a one-sided confidence limit (Bonferroni over "
           "the tested Δ and Δ → 0); the upper end bounds the HCR over the tested Δ and Δ → 0 (open when any "
           "tested Δ is unresolved)",
    "crlb": "CRLB (trace of F̂⁻¹) from an unbiased Fisher information (U-statistic over independent FD rounds: the "
            "FI of the FD-smoothed derivative, its step ξ halved until F is shown to have stopped rising), with "
            "its one-sided ends; a lower end whose step did not converge is marked as not a confidence limit",
    "hcr_neff": "HCR_Neff (the paper's direct bound): plug-in λ̃ of the replicate means, sup over the tested Δ "
                "only; no Δ → 0 term, so it can fall decades below the CRLB (the paper's 80 cm row)",
    "hcr_hat": "HCR-hat (the paper's): HCR from the bias-corrected λ̂ (fit of λ̃ = λ + C/N over the spp levels), "
               "a point estimate, an upper bound in expectation on the HCR over the tested Δ only",
    "barankin": "Barankin (McAulay–Seidman) on Var of the scalar θ, plug-in from the replicate means",
}

ESTIMATOR = {
    "name": Field(str, help="registered estimator (nlosbench list estimators)"),
    "options": Field(dict, {}, "keyword options of the estimator"),
    "label": Field(str, None, "name in tables and plots (default: name); unique within the study", nullable=True),
    "gradient": Field(dict, {}, "gradient settings of the problem (forward.GradientSettings): method (fd | ad | "
                                "mixed | auto), step, rounds, crn, spp, ad, ad_params, verdicts; auto picks per "
                                "parameter from `verdicts` (a gradients study's verdicts.json) or the prior"),
}


def positive_steps(value, path: str):
    """A Field type: one FD step > 0, or a non-empty list of them (one per θ*; its length is checked by `plan`)."""
    if isinstance(value, list):
        if not value:
            raise ConfigError(path, "expected a step > 0 or a list of one per θ*, got []")
        return [positive_number(v, f"{path}[{k}]") for k, v in enumerate(value)]
    return positive_number(value, path)


SCHEMA = {
    "mode": Field(str, "local", "local: fixed θ*, the HCR interval and CRLB with a bias test; bayesian: θ* drawn "
                                "from the prior per trial, the Bayesian MSE against the Ziv–Zakai bound",
                  choices=("local", "bayesian")),
    "theta": Field(points_spec, None, "θ* values (local mode): numbers (or {start, stop, num}) for a 1-D θ, "
                                      "else a list of lists", nullable=True),
    "prior": Field(str, "uniform", "prior of θ* in bayesian mode (and of the ZZB)", choices=("uniform",)),
    "n": Field(int, 30, "trials per θ* (local) or in all (bayesian), each with fresh noise and a fresh start"),
    "n_eff": Field(int, 4096, "spp of the clean image (the observation's mean) per θ*; local: split over "
                              "`truth_replicates` independent renders, so each trial's observation has the mean "
                              "of n_eff / truth_replicates spp"),
    "truth_replicates": Field(int, 4, "local mode: independent renders making the clean image (trial k uses render "
                                      "k mod truth_replicates), whose spread enters the bias test's SE and the "
                                      "MSE's limits (n_eff divisible by it); = n makes the trials independent, "
                                      "which gives the sharpest verdicts"),
    "estimators": Field(list, help="estimator settings {name, options, label, gradient}", items=ESTIMATOR),
    "noise": Field(noise_spec, "all", "index (or list of indices) into the run's noise models, or 'all'"),
    "bounds": Field(list, ["hcr", "crlb", "hcr_neff"], "bounds at each θ* (local mode)",
                    items=Field(str, choices=BOUNDS)),
    "bound_spp": Field(int, None, "spp of each bound render (default: n_eff)", nullable=True),
    "replicates": Field(int, 3, "independent replicate render sets of the bounds (>= 3 for confidence limits)"),
    "seeds": Field(str, "common", "seeds across θ within a bound replicate: common (common random numbers) or "
                                  "independent", choices=("independent", "common")),
    "level": Field(float, 0.95, "one-sided confidence level of every bound's ends, and of the verdicts of a "
                                "table (Bonferroni over its tests)"),
    "hcr_grid": Field(int, 21, "HCR test points (and the bank grid, and the ZZB grid) per parameter over Θ"),
    "hcr_offsets": Field(int, 4, "HCR test offsets ±ξ·2^k, k < hcr_offsets, along each parameter"),
    "fd_step": Field(positive_steps, 0.01, "ξ: first FD step of the Δ → 0 term and the CRLB, and the smallest HCR "
                     "offset; one for every θ*, or a list of one per θ* (small where an edge crosses pixels, large "
                     "where L(θ) is smooth)"),
    "step_tol": STEP_TOL,
    "max_halvings": MAX_HALVINGS,
    **precise.KEYS,
    "levels": Field(list, [1024, 2048], "spp levels of the λ̂ fit for hcr_hat", items=int),
    "budget": Field({"iterations": Field(int, None, "iterations per fit", nullable=True),
                     "renders": Field(int, None, "renders + AD passes per fit", nullable=True),
                     "seconds": Field(float, None, "wall seconds per fit", nullable=True)}),
    "start_width": Field(float, None, "local mode: starts uniform in θ* ± width·|Θ|/2 (null: uniform in Θ, the "
                                      "paper's protocol)", nullable=True),
    "far_above": Field(float, 3.0, "flag MSE / bound above this factor"),
    "bootstrap": Field(int, 1000, "bootstrap resamples for the variance's standard error"),
    "traces": Field(bool, False, "store each fit's loss/θ trace in trials.jsonl"),
    "predict_jacobians": Field(int, 8, "local mode: independent gradient Jacobians per θ* and estimator setting (at "
                                       "its spp, with its gradient settings) that measure its Jacobian noise for the "
                                       "predicted variance; 0: no prediction"),
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
    """What the study computes: mode, θ* (T, P) (local) or the drawn θ* (n, P) (bayesian), trials, N_eff and its
    replicates, bound renders (spp, replicates, seeds), the noise models, the estimator settings (gradients
    resolved), the budget per fit, what fixes the results besides the config (`fingerprint`: the resolved
    gradients; the run folder's fingerprint holds it, so a resume after the verdicts changed is refused), and
    the grids the settings' estimators want (label → [(θ grid, spp, sets, seeds), …]: `Estimator.grid_wanted`)."""

    mode: str
    thetas: np.ndarray
    n: int
    n_eff: int
    clusters: int
    bound_spp: int
    replicates: int
    noises: dict
    settings: list
    budget: Budget
    fingerprint: dict
    grids: dict = dataclasses.field(default_factory=dict)


def plan(ctx, cfg: dict) -> Plan:
    """The study's plan from its validated block (ConfigError naming the key for what the schema cannot
    see); gradient method `auto` resolved for the run's model here, once; in bayesian mode θ* are drawn."""
    sid = cfg.get("id") or NAME
    params = ctx.model.params
    for k in ("n", "n_eff", "hcr_grid", "truth_replicates"):
        if cfg[k] < 1:
            raise ConfigError(f"{sid}.{k}", f"expected a positive integer, got {cfg[k]}")
    if cfg["replicates"] < 2:
        raise ConfigError(f"{sid}.replicates", f"expected >= 2 (>= 3 for confidence limits), got {cfg['replicates']}")
    if cfg["bound_spp"] is not None and cfg["bound_spp"] < 1:
        raise ConfigError(f"{sid}.bound_spp", f"expected a positive integer, got {cfg['bound_spp']}")
    if not 0 < cfg["level"] < 1:
        raise ConfigError(f"{sid}.level", f"expected a confidence level in (0, 1), got {cfg['level']}")
    bayes = cfg["mode"] == "bayesian"
    if bayes:
        if cfg["theta"] is not None:
            raise ConfigError(f"{sid}.theta", "bayesian mode draws θ* from the prior; remove `theta`")
        if params.dim != 1:
            raise ConfigError(sid, f"bayesian mode (the ZZB) needs one parameter; the model has {list(params.names)}")
        if cfg["hcr_grid"] < 5:
            raise ConfigError(f"{sid}.hcr_grid", f"the ZZB grid needs >= 5 points, got {cfg['hcr_grid']}")
        rng = np.random.default_rng(ctx.seed_for("bayes-theta", 0))
        thetas = np.stack([params.sample_uniform(rng) for _ in range(cfg["n"])])
        clusters = 1
    else:
        if cfg["theta"] is None:
            raise ConfigError(f"{sid}.theta", "local mode needs θ* values")
        thetas = parse_thetas(cfg["theta"], params, f"{sid}.theta")
        clusters = 1 if ctx.model.exact else cfg["truth_replicates"]  # an exact image has no error to sample
        if cfg["n_eff"] % clusters:
            raise ConfigError(f"{sid}.n_eff", f"{cfg['n_eff']} spp do not split over truth_replicates = {clusters}")
    if bayes and cfg["precision"] is not None:
        raise ConfigError(f"{sid}.precision", "a precision target applies to the bounds at θ* (local mode); "
                                              "bayesian mode has none")
    if isinstance(cfg["fd_step"], list) and len(cfg["fd_step"]) != len(thetas):
        raise ConfigError(f"{sid}.fd_step", f"one step, or one per θ* ({len(thetas)}), got {len(cfg['fd_step'])}")
    precise.check(cfg, sid, cfg["bounds"])
    noises = ctx.select_noises(cfg["noise"], f"{sid}.noise")
    settings = parse_settings(cfg["estimators"], f"{sid}.estimators", ctx.model)
    if "barankin" in cfg["bounds"] and params.dim > 1:
        raise ConfigError(f"{sid}.bounds", f"barankin bounds a scalar θ; this model has {list(params.names)}")
    try:
        budget = Budget(**cfg["budget"])
    except ValueError as e:
        raise ConfigError(f"{sid}.budget", str(e)) from None
    # what fixes the numbers besides the config (which the run's fingerprint holds): `auto` gradients as resolved
    fingerprint = json.loads(json.dumps({"gradients": {s.label: dataclasses.asdict(s.gradient) for s in settings}},
                                        sort_keys=True, default=repr))
    return Plan(cfg["mode"], thetas, cfg["n"], cfg["n_eff"], clusters, cfg["bound_spp"] or cfg["n_eff"],
                cfg["replicates"], noises, settings, budget, fingerprint,
                wanted_grids(settings, params, f"{sid}.estimators", cfg["seeds"]))


def wanted_grids(settings: list[Setting], params, where: str, seeds: str) -> dict:
    """label → [(θ grid (G, P), spp, independent render sets, seeds), …] of each setting whose estimator renders
    grids before its fits (`Estimator.grid_wanted`: one grid, or several at their own spp; sets 1 where it names
    none; seeds the estimator's `grid_seeds`, else the study's `seeds`); ConfigError naming the setting for a grid
    it refuses (e.g. above max_grid)."""
    out = {}
    for k, s in enumerate(settings):
        try:
            est = estimators.get(s.name, **s.options)
            want = est.grid_wanted(params)
        except ValueError as e:
            raise ConfigError(f"{where}[{k}]", str(e)) from None
        if want is not None:
            out[s.label] = [(*w[:2], w[2] if len(w) > 2 else 1, est.grid_seeds or seeds)
                            for w in (want if isinstance(want, list) else [want])]
    return out


def cost(ctx, cfg: dict, p: Plan) -> Estimate:
    """Renders and pixel-samples: counted for the clean images and the bound renders (the bank grid, θ*, FD
    stencils at ξ and ξ/2 — further halvings, up to max_halvings, where the step has not converged, are not
    counted —, the axis offsets, the spp levels of hcr_hat, Poisson weight renders, and with a precision target
    the most its fresh looks may spend, within its `precision_budget` or the default ceiling (`precise.estimate`);
    for a predicted variance the settings' Jacobians and the response's FD stages down to ξ/2^max_halvings, all
    counted though the bound may have made some), estimated for the fits (`_fit_cost`: each setting's planned
    iterations × spp)."""
    P, R, bspp, px = ctx.model.params.dim, p.replicates, p.bound_spp, pixels(ctx.model)
    G, T = cfg["hcr_grid"] ** P, len(p.thetas)
    renders, samples = R * G, R * G * bspp  # the bank grid (the bayesian ZZB curve uses the same renders)
    pilot = 0
    if p.mode == "bayesian":
        renders, samples = renders + p.n, samples + p.n * p.n_eff
        fits = len(p.noises) * p.n
    else:
        renders, samples = renders + T * p.clusters, samples + T * p.n_eff
        want = set(cfg["bounds"])
        if want:
            extra = T * R * (1 + (4 * P if want & {"hcr", "crlb"} else 0)
                             + (2 * P * cfg["hcr_offsets"] if want - {"crlb"} else 0))
            renders, samples = renders + extra, samples + extra * bspp
            pilot = (R * G + extra) * bspp * px  # a precision target's pilot: the bound renders, the grid's too
        if "hcr_hat" in want:
            pts = T * (G + 2 * P * cfg["hcr_offsets"])
            renders, samples = renders + pts * len(cfg["levels"]), samples + pts * sum(cfg["levels"])
        fits = len(p.noises) * T * p.n
        if cfg["predict_jacobians"] > 0:  # the predicted variance: K gradients per setting (J: the bound's FD rounds)
            for s in (s for s in p.settings if _predicts(s.name)):
                r, spp = _fit_cost(s.name, {**s.options, "iterations": 1}, s.gradient, P, Budget())
                k = T * cfg["predict_jacobians"]
                renders, samples = renders + k * max(r - 1, 0), samples + k * spp
            if any(_predicts(s.name) for s in p.settings) and getattr(ctx.model, "noise_variance", None) is None:
                # the response's FD stages at ξ/2 … ξ/2^max_halvings (the bound's own where it made them; ξ/2 counted)
                k = T * R * 2 * P * max(cfg["max_halvings"] - (1 if want & {"hcr", "crlb"} else 0), 0)
                renders, samples = renders + k, samples + k * bspp
    # made once by the bank; the bound grid's when they are the same
    for thetas, spp, sets, seeds in (g for gs in p.grids.values() for g in gs):
        if not (spp == bspp and len(thetas) == G and sets <= R and seeds == cfg["seeds"]):
            renders, samples = renders + sets * len(thetas), samples + sets * len(thetas) * spp
    for s in p.settings:
        r, spp = _fit_cost(s.name, s.options, s.gradient, P, p.budget)
        renders, samples = renders + round(fits * r), samples + round(fits * spp)
    note = ("fits estimated from each estimator's planned iterations × spp (its cap, an upper bound where fits stop "
            "early; mle-adam with lr auto: what its stopping rule typically takes)")
    return precise.estimate(renders, samples * px, cfg, bspp, px, pilot, note)


def _predicts(est) -> bool:
    """Whether an estimator (an instance, or the name it is registered under) offers a predicted variance: its
    class overrides `Estimator.fit_cov`."""
    try:
        cls = estimators.factory(est) if isinstance(est, str) else type(est)
    except (KeyError, ImportError):
        return False
    return getattr(cls, "fit_cov", None) not in (None, estimators.Estimator.fit_cov)


def _fit_cost(name: str, options: dict, gradient: GradientSettings, P: int, budget: Budget) -> tuple[float, float]:
    """(renders, spp summed over them) of one fit, estimated from the estimator's options (its constructor's
    defaults filled in): grid-search refine_evals (its grid is the bank's, counted once in `cost`); surrogate none (its
    lattice is the bank's too); multi-start
    `starts` × its base estimator; otherwise iterations (capped by the budget) × (a render + the gradient's
    renders: 2 per FD parameter and round, AD_PASS_RENDERS per AD pass); the iterations are the estimator's
    `expected_iterations()` where it has one (a stopping rule that ends fits well before the cap)."""
    try:
        sig = inspect.signature(estimators.factory(name))
        o = {k: v.default for k, v in sig.parameters.items() if v.default is not inspect.Parameter.empty}
    except (TypeError, ValueError, KeyError, ImportError):
        o = {}
    o.update(options)
    spp = o.get("spp", 256)
    if spp is None:  # a default the estimator resolves when built (mle-adam's follows its lr)
        try:
            spp = getattr(estimators.get(name, **options), "spp", None) or 256
        except (TypeError, ValueError, KeyError, ImportError):
            spp = 256
    if isinstance(spp, (list, tuple)):  # an spp schedule [[fraction, spp], ...]
        spp = max(int(n) for _, n in spp)
    if name == "multi-start":
        r, n = _fit_cost(o.get("base", "mle-adam"), o.get("options") or {}, gradient, P, budget)
        return o.get("starts", 4) * r + 1, o.get("starts", 4) * n + spp
    if name == "surrogate":  # its lattice is a grid the bank renders once (counted in `cost`); a fit renders nothing
        return 0, 0
    if name == "grid-search":
        refine = o.get("refine_evals", 150) if o.get("refine", True) else 0
        return refine, refine * (o.get("refine_spp") or spp)
    n_ad = P if gradient.method == "ad" else len(gradient.ad_params) if gradient.method == "mixed" else 0
    grad = 2 * gradient.rounds * (P - n_ad) + (AD_PASS_RENDERS if n_ad else 0)
    try:  # an estimator that stops on its own rule plans fewer iterations than its cap (mle-adam's lr "auto")
        planned = estimators.get(name, **options).expected_iterations()
    except (AttributeError, TypeError, ValueError, KeyError, ImportError):
        planned = int(o.get("iterations", 100))
    iterations = budget.cap(int(planned))
    per = 1 + grad
    if budget.renders:
        iterations = min(iterations, max(1, budget.renders // per))
    return iterations * per, iterations * (spp + grad * (gradient.spp or spp))


def bounds_map(rows: list[dict], want) -> dict:
    """(noise, θ index) → {bound: `bound_entry`} for `montecarlo.summarize`."""
    return {(r["noise_index"], r["theta_index"]): {b: bound_entry(r, b) for b in want} for r in rows}


# -- the study ------------------------------------------------------------------------------------
def run(ctx, cfg: dict) -> dict:
    """Plan, render the clean images (the bank's TRUTH set: the observation's mean, never seen by an
    estimator), ask the bound service for every bound, run (or resume) the trials, summarise. The result's
    `renders` counts renders + AD passes in every process: all fits in trials.jsonl, and the clean and
    bound renders this call made (a resumed run reads those from the run's render store)."""
    t0 = time.perf_counter()
    sid = cfg.get("id") or NAME
    p = plan(ctx, cfg)
    for s in p.settings:
        if s.gradient.chosen:
            ctx.log(f"[{sid}] {s.label}: gradient auto → {s.gradient.chosen}")
    folder = ctx.study_dir(cfg)
    before = ctx.bank.renders
    params = ctx.model.params
    svc = BoundService(ctx.bank, ctx.noises, cfg["level"])
    grid = params.grid(cfg["hcr_grid"])
    # the estimators' grid is the mean of the bound's replicate sets (R × bound_spp samples, no new render)
    reps = svc.replicates(grid, p.bound_spp, cfg["seeds"], p.replicates, "bank grid")
    bank_grid = BankGrid(grid, reps.mean(dim=0), p.replicates * p.bound_spp)
    # the settings' own grids (grid-search, surrogate): the first `sets` replicates of the bound sets at their spp and
    # seeds (the surrogate's lattice: common, `Estimator.grid_seeds`), one render per (θ, spp, seed); several sets
    # are passed as one grid, its θ repeated per set (`Estimator.grid_wanted`)
    grids = {label: tuple(BankGrid(np.tile(thetas, (sets, 1)), svc.replicates(thetas, spp, seeds, sets,
                                                                              f"{label} grid").flatten(0, 1), spp)
                          for thetas, spp, sets, seeds in gs)
             for label, gs in p.grids.items()}
    bound_rows, zzb, precision = [], {}, []
    tseed = ctx.seed_for(f"trials {sid}")  # the trials' noise, start and fit seeds: a stream of this study's own
    if p.mode == "bayesian":
        curve = svc.curve(grid[:, 0], p.bound_spp, cfg["seeds"], p.replicates, crlb=False, zzb=True,
                          noises=list(p.noises))
        zzb = {j: b for j, b in curve.zzb.items() if b is not None}
        if zzb:
            write_csv(folder / "zzb.csv", [{"noise_index": j, "noise": str(p.noises[j]), **b.columns(), **b.extra}
                                           for j, b in zzb.items()])
        cleans = list(ctx.bank.at(p.thetas, p.n_eff, TRUTH, desc="clean images (one per trial)"))
        trials = make_bayes_trials(p.thetas, p.settings, p.noises, cleans, tseed, p.budget, cfg["traces"],
                                   bank_grid, grids)
    else:
        sets = ctx.bank.sets(p.thetas, p.n_eff // p.clusters, TRUTH, range(p.clusters), desc="clean images")
        cleans = {(i, c): sets[c, i] for c in range(p.clusters) for i in range(len(p.thetas))}
        for i in range(len(p.thetas)):
            mean = sum(cleans[i, c] for c in range(p.clusters)) / p.clusters
            # a transient capture (scan_y, scan_x, T, C) goes in as T·C channels of its scan grid
            io.write_exr(folder / "images" / f"clean_{i:03d}.exr", mean.reshape(*mean.shape[:2], -1))
        want = cfg["bounds"]
        points = svc.at(p.thetas, p.bound_spp, want, cfg["seeds"], p.replicates, cfg["hcr_grid"], cfg["hcr_offsets"],
                        cfg["fd_step"], cfg["levels"], noises=list(p.noises), step_tol=cfg["step_tol"],
                        max_halvings=cfg["max_halvings"], **precise.at_kwargs(cfg)) if want else []
        precision = precise.records(points, len(p.thetas), params.names)
        bound_rows = [{"theta_index": i % len(p.thetas), **pt.row(params.names)} for i, pt in enumerate(points)]
        write_csv(folder / "bounds.csv", bound_rows)
        trials = make_trials(p.thetas, p.n, p.settings, p.noises, cleans, tseed, p.budget, cfg["start_width"],
                             cfg["traces"], bank_grid, p.clusters, grids)
    renders = ctx.bank.renders - before
    records = run_trials(ctx.bank.executor, trials, folder / LOG_NAME, resume=ctx.resume, progress=ctx.progress)
    labels = [s.label for s in p.settings]
    mark = ctx.bank.renders
    predictions = {} if p.mode == "bayesian" or cfg["predict_jacobians"] < 1 else \
        predict(ctx, cfg, p, cleans, records, svc)
    renders += ctx.bank.renders - mark
    if p.mode == "bayesian":
        zmap = {j: bound_entry(b.columns(), "zzb") for j, b in zzb.items()}
        rows = summarize_bayes(records, zmap, labels, cfg["level"])
    else:
        rows = summarize(records, params.names, bounds_map(bound_rows, cfg["bounds"]), cfg["far_above"],
                         cfg["bootstrap"], ctx.seed_for("summary"), labels=labels, level=cfg["level"],
                         predictions=predictions)
    write_csv(folder / "summary.csv", rows)
    errors = sorted({r["error"] for r in records if r["error"]})
    fit_renders = sum(r["renders"] + r["grad_passes"] for r in records)
    return {"id": sid, "mode": p.mode, "theta": p.thetas.tolist(), "params": list(params.names),
            "units": list(params.units), "n": p.n, "n_eff": p.n_eff, "truth_replicates": p.clusters,
            "bound_spp": p.bound_spp, "replicates": p.replicates, "seeds": cfg["seeds"], "level": cfg["level"],
            "estimators": labels,
            "gradients": {s.label: gradient_label(s.gradient) + (f" (auto: {s.gradient.chosen})" if s.gradient.chosen
                                                                 else "") for s in p.settings},
            "noise": {str(j): repr(n) for j, n in p.noises.items()},
            "bounds": [] if p.mode == "bayesian" else cfg["bounds"],
            "bound_notes": {b: BOUND_NOTES[b] for b in cfg["bounds"]}, "fd_step": cfg["fd_step"],
            "far_above": cfg["far_above"], "trials": len(records), "seconds": time.perf_counter() - t0,
            "bank_renders": renders, "fit_renders": fit_renders, "renders": renders + fit_renders,
            "summary": rows, "bound_rows": bound_rows,
            **({"precision": precision, "seconds_per_sample": ctx.rate} if precision else {}),
            "zzb": {str(j): {"log10": b.log10, "upper": b.upper, "point": b.point, "flags": list(b.flags),
                             "reason": b.reason} for j, b in zzb.items()},
            "errors": errors[:20],
            "files": [LOG_NAME, "summary.csv"] + (["zzb.csv"] if zzb else ["bounds.csv", "plots/mse_vs_theta.png"])
            + ["plots/speed_vs_error.png"]}


# -- predicted variance --------------------------------------------------------------------------------
def gradient_task(model, item: tuple) -> tuple:
    """Executor task: (tag, θ, spp, seed, GradientSettings) → (tag, Jacobian (P, *S) float32, renders + AD passes)."""
    tag, theta, spp, seed, settings = item
    before = model.stats.snapshot()
    J = jacobian(model, theta, spp, seed, settings)
    used = model.stats.since(before)
    return tag, J, used.renders + used.grad_passes


def _fit_spp(est) -> int:
    """The spp of an estimator's fit renders (the largest of a schedule; 1 when it names none)."""
    spp = getattr(est, "spp", 1)
    return int(max(n for _, n in spp)) if isinstance(spp, (tuple, list)) else int(spp)


def start_cov(params, theta: np.ndarray, width: float | None, est, grid_points: int,
              bank_var: np.ndarray | None = None, lin_sandwich=None) -> tuple[np.ndarray, str]:
    """(second moment (P, P), about what) of the fits' starts: uniform in θ* ± width·|Θ|/2 (clipping ignored) or
    over Θ (width None: |Θ|²/12 plus the offset of Θ's middle), about θ*; a profile start (the NLL minimum of y
    over the bank grid) about ê: the grid renders' own noise through the score, `lin_sandwich(bank_var)`, plus for
    P > 1 a grid cell's spacing²/12 (for a scalar θ the parabola through the minimum and its neighbours has its
    vertex at ê when the NLL is quadratic, as in the linear model)."""
    span = params.upper - params.lower
    if getattr(est, "start", "given") == "profile":
        cov = np.diag((span / max(grid_points - 1, 1)) ** 2 / 12) if params.dim > 1 else np.zeros((1, 1))
        return (cov + lin_sandwich(bank_var) if lin_sandwich is not None else cov), "target"
    if width is None:
        return np.diag(span**2 / 12 + (0.5 * (params.lower + params.upper) - theta) ** 2), "truth"
    return np.diag((width * span) ** 2 / 12), "truth"


def predict(ctx, cfg: dict, p: Plan, cleans: dict, records: list[dict], svc: BoundService) -> dict:
    """(noise, θ index, label) → each local-trials row's `Prediction` (or why none): the estimator's
    `predicted_variance` from a `Linearisation` at θ* built from the bank. J: the bound service's R independent
    central-FD rounds at the bound spp and `fd_step` (`BoundService.fd_rounds`: the renders of `at`'s first FD
    stage, so no new render when the study asked for bounds; unbiased products); the response J₀ (`predict.
    Linearisation.response`): the same rounds at the finest of the bound's halved steps ξ / 2^k, k ≤ max_halvings,
    whose G = JᵀW J₀ is resolved (`predict.choose_response`; none: J itself); Σ_render(s): the model's own
    variance where it has one (the analytic toys, per element), else the per-pixel channel covariance of the bound
    service's R replicate renders at θ* × bound_spp / s (`predict.render_covariance`: a pixel's channels share its
    light paths); Σ_truth = Σ_render(N_eff / clusters); the fits' Jacobian noise from
    `predict_jacobians` Jacobians with the setting's own gradient (`Estimator.stand_in` at θ*) at its spp; the
    start from the study's start rule."""
    model, params, R, K = ctx.model, ctx.model.params, p.replicates, cfg["predict_jacobians"]
    if not any(_predicts(s.name) for s in p.settings):
        return {(j, i, s.label): getattr(estimators.factory(s.name), "no_prediction", Estimator.no_prediction)
                for s in p.settings for i in range(len(p.thetas)) for j in p.noises}
    reps = svc.replicates(p.thetas, p.bound_spp, cfg["seeds"], R, "bound renders at θ*").double()  # (R, T, *S)
    own = getattr(model, "noise_variance", None)
    xi = per_theta(cfg["fd_step"], len(p.thetas))  # θ*'s first FD step (T,)
    Js = svc.fd_rounds(p.thetas, p.bound_spp, cfg["seeds"], R, xi)  # (R, T, P, N): the bound's own
    # the response J₀: the same rounds at the bound's finer steps ξ / 2^k (rendered by `at` where F rose), the
    # finest whose G = JᵀW J₀ is resolved (`predict.choose_response`)
    steps = [xi / 2**k for k in range(1, cfg["max_halvings"] + 1)] if own is None else []
    finer = [(h, svc.fd_rounds(p.thetas, p.bound_spp, cfg["seeds"], R, h)) for h in steps]
    out: dict = {}
    for si, s in enumerate(p.settings):
        est = estimators.get(s.name, **s.options)
        spp = _fit_spp(est)
        grads: dict[int, list] = {}
        if _predicts(est):
            purpose = f"predict {cfg.get('id') or NAME}"
            items = [((i, k), p.thetas[i].tolist(), spp, ctx.seed_for(purpose, si, i, k),
                      est.stand_in(params, p.thetas[i], s.gradient)) for i in range(len(p.thetas)) for k in range(K)]
            for (i, _), J in ctx.bank.map(gradient_task, items, f"{s.label} Jacobian noise"):
                grads.setdefault(i, []).append(J.double().reshape(params.dim, -1).numpy())
        for i, theta in enumerate(p.thetas):
            g = est.stand_in(params, theta, s.gradient)
            L = sum(cleans[i, c] for c in range(p.clusters)).double() / p.clusters
            # the model's own variance is per element; a render's error is shared by a pixel's channels (`predict`)
            C = 1 if own is not None else int(L.shape[-1])
            if own is not None:
                def render_var(n: int, L=L) -> np.ndarray:
                    return own(L, n).reshape(-1).numpy()
            else:
                var = render_covariance(reps[:, i].numpy(), C) if R > 1 else np.zeros((L.numel() // C, C, C))

                def render_var(n: int, var=var) -> np.ndarray:
                    return var * p.bound_spp / n
            jcov = jacobian_covariance(np.stack(grads[i]), spp, g, C) if len(grads.get(i, [])) > 1 else None
            for j, noise in p.noises.items():
                key = (j, i, s.label)
                if not _predicts(est):
                    out[key] = getattr(est, "no_prediction", Estimator.no_prediction)
                    continue
                Ji, wi = Js[:, i].reshape(R, params.dim, -1), weight(noise, L)
                resp = choose_response(Ji.numpy(), [(float(h[i]), J0[:, i].reshape(R, params.dim, -1).numpy())
                                                    for h, J0 in finer], wi)
                lin = Linearisation(theta.copy(), Ji, wi, variance(noise, L), render_var(p.n_eff // p.clusters),
                                    render_var, jcov, np.zeros((params.dim, params.dim)), channels=C,
                                    response=None if resp is None else torch.from_numpy(resp[1]))
                fits = [r for r in records if r["error"] is None and r["estimator"] == s.label and r["noise"] == j
                        and r["theta_index"] == i]
                its, sts = [r["iterations"] for r in fits], [r.get("status", "") for r in fits]
                try:
                    cov, about = start_cov(params, theta, cfg["start_width"], est, cfg["hcr_grid"],
                                           render_var(R * p.bound_spp), lin.sandwich)
                    lin = dataclasses.replace(lin, start_cov=cov, start_about=about)
                    pred = est.predicted_variance(Problem(model, noise, g), lin, its or None, p.budget,
                                                  sts or None)
                except (ValueError, np.linalg.LinAlgError) as e:
                    out[key] = f"no prediction: {e}"
                    continue
                if pred is not None and steps:
                    pred = dataclasses.replace(pred, note=pred.note + (
                        f"; response from FD at ξ = {resp[0]:.3g}" if resp is not None else
                        f"; response: the ξ = {xi[i]:g} Jacobian (no finer step resolved)"))
                out[key] = pred if pred is not None else est.no_prediction
    return out


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
        elif k == "segments" and isinstance(v, list):  # the surrogate's lattice segments, each at its own spp
            v = [_smoke_options(seg) if isinstance(seg, dict) else seg for seg in v]
        out[k] = v
    return out


def _smoke_gradient(gradient: dict) -> dict:
    g = {**gradient, "rounds": 1}
    if g.get("spp"):
        g["spp"] = min(g["spp"], SMOKE_OPTIONS["spp"])
    return g


def smoke(block: dict) -> dict:
    """A reduced copy of a validated `trials` block that runs in seconds through the same code path:
    2 θ* (the list's ends; bayesian: 2 trials), 2 trials, N_eff ≤ 32 spp over ≤ 2 clean replicates, bound
    renders ≤ 8 spp × 2 replicates (3 with a `precision`, whose budget becomes 1 pixel-sample: the pilot and the
    plan, no fresh look), HCR grid ≤ 5 points per parameter and ≤ 2 offsets, spp levels [8, 16],
    ≤ 20 bootstrap resamples, at most 3 iterations per fit (the budget, which caps plug-in estimators too)
    and the built-in estimators' options capped (`SMOKE_OPTIONS`: spp ≤ 4, also a lattice segment's, grid num ≤ 5,
    starts ≤ 2, ...);
    gradient renders ≤ 4 spp and 1 FD round; a first FD step per θ* follows its θ*."""
    b = copy.deepcopy(block)
    if b["theta"] is not None:
        b["theta"] = smoke_grid(b["theta"], 2)
    if isinstance(b["fd_step"], list):  # one per θ*: those of the θ* kept, the list's ends
        b["fd_step"] = smoke_grid(b["fd_step"], 2)
    iters = b["budget"].get("iterations")
    b["budget"] = {**b["budget"], "iterations": min(iters or SMOKE_OPTIONS["iterations"], SMOKE_OPTIONS["iterations"])}
    b["estimators"] = [{**e, "options": _smoke_options(e["options"]), "gradient": _smoke_gradient(e["gradient"])}
                       for e in b["estimators"]]
    reps = min(b["truth_replicates"], 2)
    b.update(n=min(b["n"], 2), n_eff=reps * min(b["n_eff"] // b["truth_replicates"], 16), truth_replicates=reps,
             bound_spp=min(b["bound_spp"] or b["n_eff"], 8), replicates=2, hcr_grid=min(b["hcr_grid"], 5),
             hcr_offsets=min(b["hcr_offsets"], 2), levels=[8, 16], bootstrap=min(b["bootstrap"], 20))
    if b["precision"] is not None:  # confidence limits need 3 sets; `precise.smoke`: the pilot and the plan only
        b["replicates"] = 3
    return precise.smoke(b)


def report(study_dir, results: dict) -> str:
    """Markdown: what was run; per noise model the paper-format table and our comparison (HCR interval,
    CRLB, measured bias with its test, the verdict against each bound, stated definitions), or in bayesian
    mode the Bayesian MSE against the ZZB; failures; the plots (drawn here from results.json)."""
    rows, bounds = results["summary"], results["bounds"]
    study_dir = Path(study_dir)
    bayes = results.get("mode") == "bayesian"
    noise_names = {int(j): n for j, n in results["noise"].items()}
    if not bayes:
        plot_mse(rows, results["bound_rows"], bounds, results["params"], results["units"], noise_names,
                 study_dir / "plots" / "mse_vs_theta.png")
    plot_speed(rows, mse_units(results["units"]), study_dir / "plots" / "speed_vs_error.png", bayes=bayes)
    failed = sum(r["n_failed"] for r in rows)
    nonconv = sum(r["n_nonconverged"] for r in rows)
    units = mse_units(results["units"])
    lvl = f"{results['level']:.0%}"
    what = (f"{results['n']} trials, each with its own θ* drawn from a uniform prior over Θ and a uniform start over Θ"
            if bayes else f"{results['n']} trials at each of {len(results['theta'])} θ*")
    lines = [f"Estimators against the bounds that apply to them ({results.get('mode', 'local')} protocol): {what}; "
             f"parameters {results['params']} ({', '.join(results['units'])}); estimators {results['estimators']}; "
             f"noise {', '.join(results['noise'].values())}. "
             + (f"Clean images at N_eff = {results['n_eff']} spp" if bayes or results["truth_replicates"] == 1 else
                f"Clean images: N_eff = {results['n_eff']} spp per θ* in {results['truth_replicates']} independent "
                f"renders of {results['n_eff'] // results['truth_replicates']} spp; trial k's observation has the "
                f"mean of render k mod {results['truth_replicates']}, so each observation's mean is a "
                f"{results['n_eff'] // results['truth_replicates']}-spp image")
             + f"; bound renders {results['bound_spp']} spp × {results['replicates']} replicates, {results['seeds']} "
             f"seeds. {results['trials']} fits recorded, {failed} failed, {nonconv} did not converge (statuses "
             f"below). {results['seconds']:.1f} s in all; renders: {results['bank_renders']} for the clean images "
             f"and bounds (shared by every trial), {results['fit_renders']} by the fits (+ AD passes).", ""]
    lines += [f"- gradient of **{label}**: {g}" for label, g in results.get("gradients", {}).items()]
    if bayes:
        lines += _bayes_section(rows, results, units)
    else:
        lines += _local_section(rows, results, bounds, units, lvl)
    if results.get("precision"):
        lines += ["", f"### Precision of the bounds at θ* ({units})", ""]
        lines += precise.table(results["precision"], units, results.get("seconds_per_sample"))
    if results["errors"]:
        lines += ["", "Failed fits (distinct errors):", ""] + [f"- `{e}`" for e in results["errors"]]
    lines += _stalled(study_dir / LOG_NAME)
    rel = study_dir.name
    if not bayes:
        lines += ["", f"![MSE and bounds against θ*]({rel}/plots/mse_vs_theta.png)"]
    lines += [f"![speed against error]({rel}/plots/speed_vs_error.png)", ""]
    return "\n".join(lines)


def _stalled(log: Path, most: int = 5) -> list[str]:
    """Report lines naming why fits ended "stalled" (each fit's own reason from trials.jsonl, up to `most` per
    estimator with the count), so no stalled fit goes unexplained; none when no fit stalled or there is no log."""
    if not log.exists():
        return []
    why: dict[str, list[str]] = {}
    for r in read_log(log):
        if r.get("status") == "stalled":
            why.setdefault(r["estimator"], []).append(str(r.get("reason", "")))
    if not why:
        return []
    lines = ["", "Stalled fits (each fit's reason for stopping short, `reason` in trials.jsonl):", ""]
    for label, rs in why.items():
        lines += [f"- **{label}** ({len(rs)} stalled): " + "; ".join(f"`{r}`" for r in rs[:most])
                  + (f"; … {len(rs) - most} more" if len(rs) > most else "")]
    return lines


def _local_section(rows: list[dict], results: dict, bounds: list, units: str, lvl: str) -> list[str]:
    tests = max((r.get("verdict_tests", 0) for r in rows), default=0)
    each = min((r.get("verdict_level", 1.0) for r in rows), default=1.0)
    lines = ["", "MSE = mean ‖θ̂ − θ*‖² over the fits that did not fail (the failed ones are counted beside it and "
             "named in the verdict), with its one-sided limits. Bounds:", ""]
    lines += [f"- **{b}**: {results['bound_notes'][b]}" for b in bounds]
    lines += ["", f"Verdicts against a bound are one-sided tests at {lvl} for the table ({tests} tests, Bonferroni: "
              f"each at {each:.2%}): **below** = the MSE's upper limit under the bound's lower end; **above** = "
              "its lower limit over the upper end (a better estimator may exist; never against an open end); "
              "**inside** = neither; **undetermined** = the bound's ends are crossed; **not tested** = no valid "
              "test (fewer than 3 successful fits, one fit holding a share of the squared errors that errors with "
              "t5's tails seldom give, or a deciding end that is not a confidence limit), with the reason. The MSE's "
              "limits treat it as right-skewed (a scaled χ² split over the clean-image renders: trials that share one "
              "are a cluster; degrees of freedom shrunk by the squared errors' kurtosis, never below a Gaussian "
              "error's; Satterthwaite lower limit; upper limit the larger of Graybill–Wang's and the score limit), so "
              "an efficient estimator with tails up to Laplace's or t5's is called below its bound at most at about "
              "the stated level (measured ≤ 6.8 % at 5 %); rare gross errors that the trials happen not to contain "
              "no test can see (`nlosbench.verdicts`). An unbiased estimator can still be below by chance at "
              f"that rate; below at {lvl} means bias (the measured bias is given) or a bug. **MSE / b** is over b's "
              "quoted value, with [≤ its joint one-sided upper limit] over b's true value at b's level (the MSE's and "
              "the bound's uncertainty together: MOVER on the log ratio, `mse_over_<b>_upper` in summary.csv). "
              "**Power**: how often a verdict's test calls an MSE at 0.4× the bound's lower end below it (Gaussian "
              "errors; the row's trials, clean images and their share of the MSE), and the clean images (same trials "
              "per image) that would make it 80 %. Var is shown without "
              "a verdict against a bound (that would need the bias gradient); it is tested against the **predicted** "
              "variance of its estimator's linearised update at θ* (`Estimator.predicted_variance`: the "
              "observation's noise and the clean image's rendering noise through F⁻¹JᵀW, plus what the fit's own "
              "renders, noisy Jacobians and unfinished contraction from the start leave; none for grid-search and "
              "multi-start, with the reason), by the same one-sided tests on the centred errors (Bonferroni over the "
              "rows with a prediction): **as predicted**, **above prediction** (optimisation error or a local minimum: "
              "the fit statuses are named), **below prediction** (the model of the fit overstates its noise; fits "
              "that stopped on a rejected step are counted, and where they are most of the fits the prediction, a "
              "recursion of fits that apply every step, does not apply to them). "
              "Predicted MSE = predicted Var + the measured bias² (the bias is not predicted; shown for comparison "
              "only). The bias "
              "test: mean error against its SE over the clean-image replicates (which holds the clean image's own "
              "Monte Carlo error), Student t with (clean-image replicates − 1) degrees of freedom, two-sided 95 %; "
              "p is its two-sided p-value (with 4 replicates a t below 3.18 is not significant at 95 %: more "
              "`truth_replicates` make the test sharper). An estimator that reuses its own renders in every fit (the "
              "surrogate's lattice) shares their error as one offset of the run: its predicted variance is added to "
              "the SE² (`bias_se_shared` in summary.csv) and the degrees of freedom become Satterthwaite's."]
    for j in sorted({r["noise"] for r in rows}):
        lines += ["", f"### The paper's format (noise {j}: {results['noise'][str(j)]}; {units})", ""]
        paper = [b for b in ("hcr_neff", "hcr_hat") if b in bounds]
        lines += paper_table(rows, results["bound_rows"], paper, results["params"], results["units"], j)
        lines += ["", f"### Against the bounds that apply (noise {j}; {units})", ""]
        head = ["θ*", "estimator", "n (failed)", "MSE [lower, upper limit]", "predicted MSE", "Var",
                "predicted Var: verdict", "bias ± SE (t, p)"]
        head += [c for b in bounds if b in ("hcr", "crlb") for c in (f"{b} [{lvl} ends]", f"MSE / {b} [≤ upper]")]
        head += ["verdict", "power at 0.4×", "fit status", "s / trial", "renders / trial", "pixel-samples / trial"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in (r for r in rows if r["noise"] == j):
            b = next((b for b in results["bound_rows"]
                      if b["noise_index"] == j and b["theta_index"] == r["theta_index"]), {})
            theta = ", ".join(fmt(r[f"theta_{n}"], 4) for n in results["params"])
            bias = ", ".join(f"{fmt(r[f'bias_{n}'], 3)} ± {fmt(r[f'bias_se_{n}'], 2)}" for n in results["params"])
            cells = [theta, r["estimator"], f"{r['n']} ({r['n_failed']})", _mse_cell(r, "mse"),
                     fmt(r.get("mse_predicted", math.nan)), fmt(r["var"]), _predicted_cell(r),
                     f"{bias} ({fmt(r['bias_t_stat'], 2)}, {fmt(float(r.get('bias_p', 'nan')), 2)})"]
            for k in (k for k in bounds if k in ("hcr", "crlb")):
                cells.append(f"{fmt_log10(float(b[f'log10_{k}']))} [{_end(b, k, 'lower')}, {_end(b, k, 'upper')}]"
                             if b else "–")
                cells.append(f"{fmt(r.get(f'mse_over_{k}', math.nan))} "
                             f"[≤ {fmt(r.get(f'mse_over_{k}_upper', math.nan))}]")
            cells += [_verdict(r, bounds), _power_cell(r, "mse"), r.get("status", ""), fmt(r["mean_seconds"]),
                      fmt(r["mean_renders"] + r["mean_grad_passes"]), fmt(r.get("mean_samples", math.nan), 2)]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    if any(b.get(f"{k}_{e}_note") for b in results["bound_rows"] for k in ("hcr", "crlb") for e in ("lower", "upper")):
        lines += ["", "† not a confidence limit (why: `<bound>_lower_note` / `_upper_note` in bounds.csv); ∞: an open "
                      "upper end."]
    notes = [(r, b) for r in rows for b in bounds if b in ("hcr", "crlb") and r.get(f"vs_{b}", "").startswith("below")]
    lines += ["", f"**Below an interval** (at {lvl}: bias, or a bug): " + ("; ".join(
        f"{r['estimator']} at θ* #{r['theta_index']} ({b}): " + (
            f"explained by its measured bias {fmt(r['bias'], 3)} ± {fmt(r['bias_se'], 2)} "
            f"(t = {fmt(r['bias_t_stat'], 2)}, p = {fmt(float(r.get('bias_p', 'nan')), 2)})"
            if r["biased"] else f"no significant bias at n = {r['n']} (|bias| {fmt(r['bias'], 3)} ± "
            f"{fmt(r['bias_se'], 2)}): a bias too small to see with these trials, or an estimator to investigate")
        for r, b in notes) or "none.")]
    if any(r["far_above"] for r in rows):
        lines += [f"**Far above** (MSE > {results['far_above']:g} × the quoted bound): " + "; ".join(
            f"{r['estimator']} at θ* #{r['theta_index']} ({r['far_above']})" for r in rows if r["far_above"])]
    return lines


def _power_cell(r: dict, key: str) -> str:
    """The power of a row's verdicts (`montecarlo.power_columns`): "9 % (80 %: 16 clean images, 48 trials)"."""
    p = r.get(f"{key}_power", math.nan)
    if not isinstance(p, (int, float)) or math.isnan(p):
        return "–"
    images, trials = int(r.get(f"{key}_power_clean_images", 0)), int(r.get(f"{key}_power_trials", 0))
    plan = "reached" if trials == r["n"] - r["n_failed"] else "not within 4096 trials" if not trials else (
        f"{trials} independent trials" if images == trials else f"{images} clean images, {trials} trials")
    return f"{p:.0%} (80 %: {plan})"


def _predicted_cell(r: dict) -> str:
    """The predicted variance and the verdict of the measured one against it, or why there is none."""
    v = r.get("var_predicted", math.nan)
    if isinstance(v, float) and math.isnan(v):
        return f"– ({r['predicted_note']})" if r.get("predicted_note") else "–"
    return f"{fmt(v)}: {r.get('vs_predicted', '')}"


def _end(b: dict, kind: str, end: str) -> str:
    """A bound's end for a table: its value (∞ open, – not computed), † when it is not a confidence limit."""
    return fmt_end(b.get(f"{kind}_{end}")) + ("†" if b.get(f"{kind}_{end}_note") else "")


def _verdict(r: dict, bounds: list) -> str:
    parts = []
    for b in (b for b in bounds if b in ("hcr", "crlb")):
        v = r.get(f"vs_{b}", "")
        if v.startswith("below"):
            v += ("; biased, bias = " if r["biased"] else "; no significant bias, bias = ") + \
                f"{fmt(r['bias'], 3)} ± {fmt(r['bias_se'], 2)}"
        if v:
            parts.append(f"{b} {v}")
    return "; ".join(parts) or "–"


def _mse_cell(r: dict, key: str) -> str:
    """MSE [lower, upper limit] (at the verdict's level), or the MSE with why it is not tested."""
    if r.get(f"{key}_untested"):
        return f"{fmt(r[key])} (not tested)"
    return f"{fmt(r[key])} [{fmt(r.get(f'{key}_lower', math.nan), 2)}, {fmt(r.get(f'{key}_upper', math.nan), 2)}]"


def _bayes_section(rows: list[dict], results: dict, units: str) -> list[str]:
    lvl = f"{results['level']:.0%}"
    each = min((r.get("verdict_level", 1.0) for r in rows), default=1.0)
    lines = ["", f"### Bayesian MSE against the Ziv–Zakai bound ({units})", "",
             "The ZZB bounds E[(θ̂ − θ)²] averaged over the prior for every estimator, biased or not (valley-filled, "
             "a lower sum over a uniform grid; its lower end is a one-sided confidence limit from the replicate "
             "render sets). The Bayesian MSE over the successful fits (n stated, failures counted) with its "
             f"one-sided limits (independent trials: a scaled χ²); the verdicts are one-sided tests at {lvl} for the "
             f"table (Bonferroni: each at {each:.2%}), the same vocabulary and power column as the local table. "
             f"**below** at {lvl}: "
             "a bug, or a ZZB grid too coarse (see its flags); any estimator is below by chance at most at that "
             "rate.", "",
             "| noise | estimator | n (failed) | Bayesian MSE [lower, upper limit] | ZZB lower end [upper end] | "
             "verdict | power at 0.4× | fit status | s / trial | renders / trial |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        z = results["zzb"].get(str(r["noise"]))
        zz = "–" if z is None else f"{fmt_log10(z['log10'])} [{fmt_end(z['upper'])}]" + \
            (f" ({', '.join(z['flags'])})" if z["flags"] else "")
        lines.append(f"| {r['noise']} | {r['estimator']} | {r['n']} ({r['n_failed']}) | "
                     f"{_mse_cell(r, 'bayes_mse')} | {zz} | {r.get('vs_zzb', '–')} | {_power_cell(r, 'bayes_mse')} | "
                     f"{r.get('status', '')} | {fmt(r['mean_seconds'])} | {fmt(r['mean_renders'])} |")
    return lines
