"""Monte Carlo trials of estimators and their summary against the bounds.

For each noise model j, θ* (index i) and trial k: a fresh noisy image y = noise.sample(L_θ*) of the
clean image (the observation's mean, from the bank's TRUTH set), a fresh start, and one fit per
estimator setting — every setting sees the same y and start (paired comparison). At a fixed θ* the
clean image comes in C independent replicates and trial k uses replicate k mod C (its `cluster`), so
the clean image's own Monte Carlo error enters the bias test's standard error and the MSE's limits
(`summarize`; the verdicts against the bounds are one-sided tests, `verdicts`). In the
Bayesian protocol every trial has its own θ* drawn from the prior (`summarize_bayes`). Seeds derive
from the study's seed (each study of a run has its own, so two studies never share a noise, start or fit
stream), the purpose and the indices: the noise of y from (j, i, k); the start and the fit's generator (its
render seeds) from (i, k), so the noise models are compared from the same starts too. Each finished trial
is appended to `trials.jsonl` (a `records.RecordLog`: flush + fsync per record, a torn last line cut on
resume), so a killed run resumes without losing or repeating a trial; the summary
sorts records first, so it does not depend on the order in which trials finished.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from . import estimators
from .estimators import Budget, Problem
from .estimators.base import BankGrid
from .estimators.predict import Prediction, cluster_share
from .forward.gradients import GradientSettings
from .forward.model import ForwardModel
from .noise import NoiseModel
from .params import ParamSpace
from .records import RecordLog
from .seeds import derive
from .verdicts import MIN_FITS, MSELimits, mse_limits, power_plan, verdict

LOG_NAME = "trials.jsonl"


@dataclass(frozen=True)
class Setting:
    """One estimator configuration in a comparison: registry name, options, label (unique in a run),
    and the gradient settings its problem carries."""

    name: str
    options: dict = field(default_factory=dict)
    label: str = ""
    gradient: GradientSettings = field(default_factory=GradientSettings)

    def __post_init__(self):
        if not self.label:
            object.__setattr__(self, "label", self.name)


@dataclass(frozen=True)
class Trial:
    """One fit of one setting: noise j, θ* index i, trial k; `clean` is the observation's mean at θ*
    (H, W, C), clean-image replicate `cluster`; `bank`: grid renders the estimator may use (Problem.bank);
    `grids`: the renders of the setting's own grids (`Estimator.grid_wanted`), made by the run's bank
    (Problem.grids)."""

    noise_index: int
    theta_index: int
    trial: int
    setting: Setting
    noise: NoiseModel
    theta_true: tuple
    clean: torch.Tensor
    seed: int
    budget: Budget = Budget()
    start_width: float | None = None
    keep_trace: bool = False
    cluster: int = 0
    bank: BankGrid | None = None
    grids: tuple[BankGrid, ...] = ()

    @property
    def key(self) -> tuple:
        return (self.noise_index, self.theta_index, self.trial, self.setting.label)


def record_key(rec: dict) -> tuple:
    """(noise j, θ* index i, trial k, estimator label) of a logged record: its `Trial.key`."""
    return (rec["noise"], rec["theta_index"], rec["trial"], rec["estimator"])


def make_trials(thetas: np.ndarray, n: int, settings: Sequence[Setting], noises: dict[int, NoiseModel],
                cleans: dict, seed: int, budget: Budget = Budget(), start_width: float | None = None,
                keep_trace: bool = False, bank: BankGrid | None = None, clusters: int = 1,
                grids: dict | None = None) -> list[Trial]:
    """All trials, in the order noise → θ* → trial → setting. thetas: (T, P); noises: index → model;
    cleans: (θ index, replicate) → image for replicates 0 … clusters − 1 (or θ index → image, one replicate);
    trial k uses replicate k mod clusters; grids: setting label → its grids' renders (`Trial.grids`)."""
    if n < 1:
        raise ValueError(f"n (trials per θ*) must be >= 1, got {n}")
    labels = [s.label for s in settings]
    if len(set(labels)) != len(labels):
        raise ValueError(f"estimator labels must be unique, got {labels}")

    def clean(i: int, c: int) -> torch.Tensor:
        return cleans[(i, c)] if (i, c) in cleans else cleans[i]

    grids = grids or {}
    return [Trial(j, i, k, s, noise, tuple(float(v) for v in thetas[i]), clean(i, k % clusters), seed, budget,
                  start_width, keep_trace, k % clusters, bank, grids.get(s.label, ()))
            for j, noise in noises.items() for i in range(len(thetas)) for k in range(n) for s in settings]


def make_bayes_trials(thetas: np.ndarray, settings: Sequence[Setting], noises: dict[int, NoiseModel],
                      cleans: Sequence[torch.Tensor], seed: int, budget: Budget = Budget(), keep_trace: bool = False,
                      bank: BankGrid | None = None, grids: dict | None = None) -> list[Trial]:
    """The Bayesian protocol: trial k has its own θ*_k (thetas (n, P), drawn from the prior by the caller)
    and clean image cleans[k]; starts are uniform over Θ. θ index = k, one trial each."""
    labels = [s.label for s in settings]
    if len(set(labels)) != len(labels):
        raise ValueError(f"estimator labels must be unique, got {labels}")
    grids = grids or {}
    return [Trial(j, k, 0, s, noise, tuple(float(v) for v in thetas[k]), cleans[k], seed, budget, None, keep_trace,
                  0, bank, grids.get(s.label, ()))
            for j, noise in noises.items() for k in range(len(thetas)) for s in settings]


def draw_start(params: ParamSpace, theta_true: np.ndarray, width: float | None, rng: np.random.Generator) -> np.ndarray:
    """A random start: uniform in Θ (width None), or uniform in θ* ± width·(upper − lower)/2 clipped to Θ."""
    if width is None:
        return params.sample_uniform(rng)
    half = 0.5 * width * (params.upper - params.lower)
    return rng.uniform(np.maximum(params.lower, theta_true - half), np.minimum(params.upper, theta_true + half))


_ESTIMATORS: dict[str, estimators.Estimator] = {}  # per process, so grid-search's grid renders are reused


def _estimator(setting: Setting):
    key = json.dumps([setting.name, setting.options], sort_keys=True, default=repr)
    if key not in _ESTIMATORS:
        _ESTIMATORS[key] = estimators.get(setting.name, **setting.options)
    return _ESTIMATORS[key]


def run_trial(model: ForwardModel, trial: Trial) -> dict:
    """Fit one trial on `model` (the worker's model); a fit that raises is recorded with its error."""
    j, i, k = trial.noise_index, trial.theta_index, trial.trial
    theta_true = np.array(trial.theta_true)
    rec = {"noise": j, "theta_index": i, "trial": k, "estimator": trial.setting.label, "name": trial.setting.name,
           "theta_true": list(trial.theta_true), "cluster": trial.cluster}
    y = trial.noise.sample(trial.clean, torch.Generator().manual_seed(derive(trial.seed, "trial-noise", j, i, k)))
    init = draw_start(model.params, theta_true, trial.start_width,
                      np.random.default_rng(derive(trial.seed, "trial-start", i, k)))
    rec["init"] = init.tolist()
    problem = Problem(model, trial.noise, trial.setting.gradient, derive(trial.seed, "problem"), trial.bank,
                      trial.grids)
    fields, est = fit_record(_estimator(trial.setting), problem, y, init,
                             np.random.default_rng(derive(trial.seed, "trial-fit", i, k)), trial.budget)
    rec.update(fields)
    if trial.keep_trace and est is not None:
        rec["trace"] = est.trace
    return rec


def fit_record(estimator: estimators.Estimator, problem: Problem, y: torch.Tensor, init=None,
               rng: np.random.Generator | None = None, budget: Budget = Budget()) -> tuple[dict, object | None]:
    """Fit y and return a trial record's fit fields (θ̂ or the error, status, iterations, cost) and the fit (None when
    it raised: a failed fit is a result, counted and shown in the summary, its cost read from the model's stats)."""
    model = problem.model
    before, t0 = model.stats.snapshot(), time.perf_counter()
    try:
        est = estimator.fit(problem, y, init, rng, budget)
    except Exception as e:  # noqa: BLE001 - a failed fit is a result: counted and shown in the summary
        used = model.stats.since(before)
        return {"theta_hat": None, "error": f"{type(e).__name__}: {e}", "converged": False, "status": "failed",
                "reason": "failed", "iterations": 0, "renders": used.renders, "grad_passes": used.grad_passes,
                "samples": used.samples, "seconds": time.perf_counter() - t0, "final_loss": None}, None
    return {"theta_hat": est.theta.tolist(), "error": None, "converged": est.converged, "status": est.status,
            "reason": est.reason, "iterations": est.iterations, "renders": est.renders,
            "grad_passes": est.grad_passes, "samples": est.samples, "seconds": est.seconds,
            "final_loss": est.final_loss}, est


def read_log(path: Path) -> list[dict]:
    """Records from a trials log (`records.RecordLog.read`: a torn last line, left by a run killed while
    writing it, is cut off with a warning; any other unreadable line is an error naming file and line)."""
    return RecordLog(path).read()


def run_trials(
    executor, trials: Sequence[Trial], path: Path, resume: bool = False, progress: Callable | None = None
) -> list[dict]:
    """Run the trials not yet in the log at `path` (all of them unless `resume`), appending each
    record as it finishes (flush + fsync). Returns every record of the planned trials.
    progress(iterable, total, desc) wraps the results (e.g. RunContext.progress)."""
    log = RecordLog(path)
    if not resume:
        log.reset()
    planned = {t.key for t in trials}
    records = [r for r in log.read() if record_key(r) in planned]
    done = {record_key(r) for r in records}
    todo = [t for t in trials if t.key not in done]
    with log:
        results = executor.imap_unordered(run_trial, todo)
        for rec in progress(results, total=len(todo), desc="trials") if progress else results:
            log.append(rec)
            records.append(rec)
    return records


# -- summary -------------------------------------------------------------------------------------
def _stats(E: np.ndarray) -> tuple[float, float, np.ndarray]:
    """MSE = mean ‖e‖², variance = trace of the sample covariance (ddof 1), bias = mean e; E (n, P)."""
    mse = float((E**2).sum(axis=1).mean())
    var = float(E.var(axis=0, ddof=1).sum()) if len(E) > 1 else math.nan
    return mse, var, E.mean(axis=0)


def _se(values) -> float:
    """Standard deviation of bootstrap replicates (NaN with fewer than 2)."""
    v = np.asarray(values, dtype=np.float64)
    return float(v.std(ddof=1)) if v.size > 1 else math.nan


def _ratio(mse: float, bound_log10: float) -> float:
    """MSE / bound through logs (a bound may underflow to 0 while its log10 stays exact); NaN when
    the MSE is unknown or the bound is unavailable (log10 = ±inf)."""
    if not math.isfinite(bound_log10) or math.isnan(mse):
        return math.nan
    if mse <= 0:
        return 0.0
    r = math.log10(mse) - bound_log10
    return 10.0**r if r < 300 else math.inf


def ratio_upper(E: np.ndarray, clusters: np.ndarray | None, bound: dict) -> float:
    """The one-sided upper confidence limit of MSE / B, B the bound's true value, joint over both uncertainties,
    at the bound's one-sided `level` (None: NaN): the MOVER limit on the log ratio (Zou and Donner's method of
    variance estimates recovered, the delta method with each part's own one-sided limit in place of a symmetric
    z·SE, so the MSE's right skew and the bound's asymmetric ends carry through),

        log r̂ + √( log(U_MSE / MSE̅)² + log(B̂ / B_lower)² ),   r̂ = MSE̅ / B̂,

    U_MSE = `verdicts.mse_limits`' upper limit of errors E (n, P) with clean-image clusters (n,) at α = 1 − level,
    B̂ = the bound's point estimate ("point", else "log10"), B_lower its lower end ("lower", log10; a confidence
    limit at `level`). NaN where the bound has no such end (no lower end, its `lower_note` set, no level) or the
    MSE is not testable; +inf where U_MSE is. Unitless."""
    level, point, low = bound.get("level"), bound.get("point", bound["log10"]), bound.get("lower")
    if level is None or low is None or bound.get("lower_note") or not (math.isfinite(point) and math.isfinite(low)):
        return math.nan
    lim = mse_limits(E, clusters, 1 - float(level))
    if lim.reason or not lim.mse > 0:
        return math.nan
    if not math.isfinite(lim.upper):
        return math.inf
    ln10 = math.log(10)
    half = math.hypot(math.log(lim.upper / lim.mse), (point - low) * ln10)
    return math.exp(min(math.log(lim.mse) - point * ln10 + half, 700.0))


def power_columns(lim: MSELimits) -> dict:
    """A row's power columns (`verdicts.power_plan`: Gaussian errors of one parameter, the row's n, clean-image
    clusters, their estimated share of the MSE and its verdicts' level): `mse_power`, how often its test calls an
    MSE at `verdicts.POWER_RATIO` (0.4) × the bound's lower end "below"; `mse_power_clean_images` and
    `mse_power_trials`, the design with the same trials per clean image that reaches `verdicts.POWER_TARGET`
    (80 %; 0: none of ≤ 4096 trials). NaN / 0 without MIN_FITS fits."""
    if lim.n < MIN_FITS:
        return {"mse_power": math.nan, "mse_power_clean_images": 0, "mse_power_trials": 0}
    p, c, n = power_plan(lim.n, lim.clusters, lim.between, lim.alpha)
    return {"mse_power": p, "mse_power_clean_images": c, "mse_power_trials": n}


def status_counts(records: Sequence[dict]) -> str:
    """How the fits stopped, e.g. "converged 4, stalled 2" (records without a status: from `converged`)."""
    counts: dict[str, int] = {}
    for r in records:
        k = r.get("status") or ("converged" if r.get("converged") else "failed")
        counts[k] = counts.get(k, 0) + 1
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))


def bias_test(E: np.ndarray, clusters: np.ndarray, level: float = 0.95, shared: np.ndarray | None = None) -> dict:
    """Is the mean error zero? E (n, P) errors θ̂ − θ*, clusters (n,) the clean-image replicate of each
    trial. With C ≥ 2 clusters the standard error comes from the C cluster means (their spread holds the
    clean image's own Monte Carlo error and the trials' noise), Student t with C − 1 degrees of freedom;
    with one cluster from the trials (the clean image's error then is not in it: `truth_in_se` False).
    `shared` (P,): the predicted variance of an offset every trial shares (an estimator's reused renders,
    `Estimator.shared_cov`), which no spread over trials can show: added to the SE² as a known variance, the
    degrees of freedom then Satterthwaite's, dof·(SE_total/SE)⁴.
    Returns bias (P,), its SE (P,), the largest |t|, its two-sided p-value (Bonferroni over P; with few
    clusters a moderate t is not significant, so the report gives t and p, not only the verdict), the degrees
    of freedom and `biased` (some component beyond the two-sided `level` quantile, Bonferroni over P)."""
    from scipy import stats

    P = E.shape[1]
    ids = np.unique(clusters)
    if len(ids) >= 2:
        means = np.stack([E[clusters == c].mean(axis=0) for c in ids])
        se, dof, in_se = means.std(axis=0, ddof=1) / math.sqrt(len(ids)), len(ids) - 1, True
        bias = means.mean(axis=0)
    else:
        bias = E.mean(axis=0)
        se, dof, in_se = (E.std(axis=0, ddof=1) / math.sqrt(len(E)) if len(E) > 1 else np.full(P, np.nan),
                          len(E) - 1, False)
    if shared is not None:
        total = np.sqrt(se**2 + np.asarray(shared, dtype=np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            dof = float(np.nanmin(dof * (total / se) ** 4)) if np.all(se > 0) else math.inf
        se = total
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.abs(bias) / se
    q = float(stats.t.ppf(1 - (1 - level) / (2 * P), dof)) if dof >= 1 else math.nan
    tmax = float(np.nanmax(t)) if np.isfinite(t).any() else math.nan
    p = min(1.0, 2 * P * float(stats.t.sf(tmax, dof))) if dof >= 1 and math.isfinite(tmax) else math.nan
    return {"bias": bias, "se": se, "t": tmax, "p": p, "dof": int(min(dof, 10**9)),
            "biased": bool(math.isfinite(tmax) and tmax > q), "clusters": int(len(ids)), "truth_in_se": in_se}


POINT_NOTE = "a plug-in point estimate"
ESTIMATE_NOTE = "a point estimate: fewer than 3 replicate sets"


def bound_entry(row: dict, kind: str) -> dict:
    """One bound's cells of a CSV row (`Bound.columns`) as `montecarlo.summarize` takes them: {log10, lower,
    upper, point, level, flags (a tuple), lower_note, upper_note} (ends, point, level and notes where present;
    point and level make the joint limit of MSE / bound, `montecarlo.ratio_upper`). A bound without ends
    (hcr_neff, hcr_hat, barankin: plug-in point estimates) gets `POINT_NOTE` on both ends, one flagged
    `estimate-only` (its ends are its point estimate) `ESTIMATE_NOTE`: no verdict is a test against them."""
    ends, point = ({e: float(row[f"{kind}_{e}"]) for e in keys if row.get(f"{kind}_{e}") not in (None, "")}
                   for keys in (("lower", "upper"), ("point", "level")))
    notes = {e: str(row[f"{kind}_{e}"]) for e in ("lower_note", "upper_note") if row.get(f"{kind}_{e}")}
    flags = tuple(f for f in str(row.get(f"{kind}_flags") or "").split(",") if f)
    if not ends or "estimate-only" in flags:
        note = ESTIMATE_NOTE if ends else POINT_NOTE
        notes = {"lower_note": note, "upper_note": note}
    return {"log10": float(row[f"log10_{kind}"]), **ends, **point, "flags": flags, **notes}


def summarize(
    records: Sequence[dict],
    names: Sequence[str],
    bounds: dict | None = None,
    far_above: float = 3.0,
    bootstrap: int = 1000,
    seed: int = 0,
    labels: Sequence[str] | None = None,
    level: float = 0.95,
    predictions: dict | None = None,
) -> list[dict]:
    """One row per (noise, θ*, estimator label): counts (failed shown and excluded from the statistics;
    each fit's stopping status counted), MSE over the successful fits with its SE and one-sided limits
    (`verdicts.mse_limits`: the clean-image replicates are its clusters) and the power of its verdicts
    (`power_columns`), variance with a bootstrap SE
    (`bootstrap` resamples of the trials), bias and the bias test (`bias_test`, its SE over clean-image
    replicates and, where the prediction has one, the shared offset of an estimator's reused renders: its SE in
    `bias_se_shared`), time and renders, and for every bound b in bounds[(noise, θ index)] = {b: {"log10", "lower",
    "upper", "flags", "lower_note", "upper_note"}} (log10: the value to quote; the ends where b is an interval;
    flags and notes optional; "point" and "level" where b has a point estimate and ends at a one-sided level) the
    ratio mse_over_b, its joint one-sided upper limit `mse_over_<b>_upper` (`ratio_upper`: over b's true value, with
    both the MSE's and b's uncertainty; NaN without b's lower confidence limit), and `vs_<b>` = `verdicts.verdict`
    (below / inside / above /
    undetermined / not tested: why), each a one-sided test at (1 − level)/m, m the (row, bound) pairs of that
    noise model's table that can be tested (`_testable`; Bonferroni), failed fits named after it. `far_above`
    lists the bounds with MSE / bound > far_above. Variance is never flagged against a bound (that needs the
    bias gradient). Rows follow `labels`.

    predictions[(noise, θ index, label)]: the estimator's `Prediction` (its linearised update's covariance), or
    a string saying why there is none. A row then gets `var_predicted` (`predicted_var`: the expectation of its
    `var` under the prediction, for its clean-image clusters), `mse_predicted` = var_predicted + bias² (the
    measured bias, for display only: it is not part of the prediction nor of its test), the parts, `var_over_
    predicted` and `vs_predicted` (`variance_verdict`, at (1 − level)/m, m the rows of that noise model's table
    with a prediction), or NaN and `predicted_note`."""
    groups: dict[tuple, list[dict]] = {}
    for r in sorted(records, key=record_key):
        groups.setdefault((r["noise"], r["theta_index"], r["estimator"]), []).append(r)
    labels = list(labels or sorted({k[2] for k in groups}))
    tests: dict[int, int] = {}
    predicted: dict[int, int] = {}
    for j, i, label in groups:
        tests[j] = tests.get(j, 0) + sum(map(_testable, (bounds or {}).get((j, i), {}).values()))
        predicted[j] = predicted.get(j, 0) + isinstance((predictions or {}).get((j, i, label)), Prediction)
    rows = []
    for (j, i, label), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], labels.index(kv[0][2]))):
        truth = np.array(rs[0]["theta_true"])
        ok = [r for r in rs if r["error"] is None]
        row = {
            "noise": j,
            "theta_index": i,
            **{f"theta_{n}": float(v) for n, v in zip(names, truth, strict=True)},
            "estimator": label,
            "name": rs[0]["name"],
            "n": len(rs),
            "n_failed": len(rs) - len(ok),
            "n_nonconverged": sum(1 for r in ok if not r["converged"]),
            "status": status_counts(rs),
        }
        E = np.array([r["theta_hat"] for r in ok], dtype=np.float64).reshape(len(ok), len(truth)) - truth
        pred = (predictions or {}).get((j, i, label), "not computed")
        clusters = np.array([r.get("cluster", 0) for r in ok])
        alpha = (1 - level) / max(tests.get(j, 0), 1)
        lim = mse_limits(E, clusters, alpha)
        row.update(mse=lim.mse, mse_se=lim.se, mse_lower=lim.lower, mse_upper=lim.upper, mse_dof=lim.dof,
                   mse_clusters=lim.clusters, mse_untested=lim.reason, verdict_level=1 - alpha,
                   verdict_tests=tests.get(j, 0), **power_columns(lim))
        if len(ok):
            _, var, bias = _stats(E)
            rng = np.random.default_rng(derive(seed, "bootstrap", j, i, labels.index(label)))
            boot = [_stats(E[rng.integers(0, len(E), len(E))]) for _ in range(bootstrap)]
            shared = np.diag(pred.shared) if isinstance(pred, Prediction) and pred.shared is not None else None
            bt = bias_test(E, clusters, level, shared)
            row.update(
                var=var,
                var_se=_se([b[1] for b in boot]),
                bias=float(np.linalg.norm(bias)),
                bias_se=float(np.linalg.norm(bt["se"])),
                bias_t_stat=bt["t"],
                bias_p=bt["p"],
                bias_dof=bt["dof"],
                biased=bt["biased"],
                bias_clusters=bt["clusters"],
                bias_se_has_truth_error=bt["truth_in_se"],
                bias_se_shared=math.nan if shared is None else float(np.sqrt(shared.sum())),
                **{f"bias_{n}": float(b) for n, b in zip(names, bias, strict=True)},
                **{f"bias_se_{n}": float(b) for n, b in zip(names, bt["se"], strict=True)},
            )
        else:
            row.update(var=math.nan, var_se=math.nan, bias=math.nan, bias_se=math.nan,
                       bias_t_stat=math.nan,
                       bias_p=math.nan, bias_dof=0, biased=False, bias_clusters=0, bias_se_has_truth_error=False,
                       bias_se_shared=math.nan,
                       **{f"bias_{n}": math.nan for n in names}, **{f"bias_se_{n}": math.nan for n in names})
        row.update(predicted_columns(pred, E, clusters, row,
                                     (1 - level) / max(predicted.get(j, 0), 1), ok))
        secs, rend, grads = ([r[k] for r in rs] for k in ("seconds", "renders", "grad_passes"))
        row.update(
            mean_seconds=float(np.mean(secs)),
            total_seconds=float(np.sum(secs)),
            mean_renders=float(np.mean(rend)),
            total_renders=int(np.sum(rend)),
            mean_grad_passes=float(np.mean(grads)),
            total_grad_passes=int(np.sum(grads)),
            mean_iterations=float(np.mean([r["iterations"] for r in rs])),
            mean_samples=float(np.mean([r.get("samples", math.nan) for r in rs])),  # pixel-samples (spp × pixels)
        )
        far = []
        for b, v in (bounds or {}).get((j, i), {}).items():
            row[b] = _exp10(v["log10"])
            row[f"mse_over_{b}"] = ratio = _ratio(row["mse"], v["log10"])
            row[f"mse_over_{b}_upper"] = ratio_upper(E, clusters, v)
            row[f"vs_{b}"] = _verdict(lim, v, row["n_failed"], row["n"])
            if ratio > far_above:
                far.append(b)
        row["far_above"] = ",".join(far)
        row["below"] = ",".join(b for b in (bounds or {}).get((j, i), {})
                                if row.get(f"vs_{b}", "").startswith("below"))
        rows.append(row)
    return rows


def predicted_var(pred: Prediction, clusters: np.ndarray) -> float:
    """The expectation of the trials' sample variance (trace, ddof 1) under `pred`: tr(obs + fit) + κ tr(truth),
    κ = `predict.cluster_share` of the trials' clean-image clusters (independent clean images: κ = 1; one: 0,
    where the clean image's error is a fixed offset, seen in the bias)."""
    return pred.var(cluster_share(clusters) if len(clusters) > 1 else math.nan)


def helmert(n: int) -> np.ndarray:
    """The (n − 1, n) Helmert contrasts: orthonormal rows orthogonal to the ones vector, so for n independent
    errors e_k with covariance Σ the rows of H E are n − 1 independent errors with covariance Σ and
    Σ‖(HE)_k‖² = Σ‖e_k − ē‖²."""
    H = np.zeros((n - 1, n))
    for k in range(1, n):
        H[k - 1, :k], H[k - 1, k] = 1.0, -k
        H[k - 1] /= math.sqrt(k * (k + 1))
    return H


def variance_verdict(E: np.ndarray, clusters: np.ndarray, var_pred: float, alpha: float, statuses: str,
                     rejected: int = 0) -> str:
    """The measured variance of errors E (n, P) against a predicted one, by `verdicts`' one-sided tests at alpha
    each (the MSE limits of the centred errors, whose mean square is the sample variance): "as predicted",
    "above prediction" (optimisation error or a local minimum; the fits' statuses named), "below prediction"
    (with the count of the `rejected` fits that stopped on a rejected step, and where they are most of the fits
    why the prediction does not apply to them), or "not tested: why". Independent trials (one clean image, or one
    each): the Helmert contrasts of E, n − 1 independent errors, so the limits are exact for Gaussian errors; C
    clusters of several trials: the centred errors scaled by √(n / (n − 1)) (their between-cluster part then
    counts C degrees of freedom, not C − 1)."""
    n = len(E)
    if n < 2 or not (var_pred > 0 and math.isfinite(var_pred)):
        return "not tested: " + ("fewer than 2 fits" if n < 2 else f"predicted variance {var_pred:g}")
    C = len(np.unique(clusters))
    if C in (1, n):
        lim = mse_limits(helmert(n) @ E, None, alpha)
    else:
        lim = mse_limits((E - E.mean(axis=0)) * math.sqrt(n / (n - 1)), clusters, alpha)
    lg = math.log10(var_pred)
    v = verdict(lim, lg, lg)
    below = "below prediction"
    if rejected:
        below += f" ({rejected} of {n} fits stopped on a rejected step" + (
            ": the prediction is the linearised recursion of fits that apply every step and does not model a fit "
            "that stops on a rejected step, so it does not apply to most of these fits)" if 2 * rejected > n else ")")
    return {"inside": "as predicted", "below": below,
            "above": f"above prediction (optimisation error or a local minimum; fits: {statuses})"}.get(v, v)


def predicted_columns(pred, E: np.ndarray, clusters: np.ndarray, row: dict, alpha: float,
                      fits: Sequence[dict]) -> dict:
    """The prediction's columns of a summary row (see `summarize`); `pred` a Prediction or why there is none;
    `fits` the successful fits' records (their statuses)."""
    if not isinstance(pred, Prediction) or not len(E):
        return {"var_predicted": math.nan, "mse_predicted": math.nan, "var_over_predicted": math.nan,
                "vs_predicted": "", "predicted_note": pred if isinstance(pred, str) else "no successful fit"}
    vp = predicted_var(pred, clusters)
    parts = pred.parts()
    return {"var_predicted": vp, "mse_predicted": vp + row["bias"] ** 2, "var_over_predicted": row["var"] / vp,
            "var_predicted_obs": parts["obs"], "var_predicted_truth": parts["truth"], "var_predicted_fit": parts["fit"],
            "vs_predicted": variance_verdict(E, clusters, vp, alpha, status_counts(fits),
                                             sum(r.get("status") == "step-rejected" for r in fits)),
            "predicted_note": pred.note}


def summarize_bayes(records: Sequence[dict], zzb: dict | None = None,
                    labels: Sequence[str] | None = None, level: float = 0.95) -> list[dict]:
    """The Bayesian protocol: one row per (noise, estimator label) over all trials (each its own θ* drawn
    from the prior and its own clean image, so the trials are independent): the Bayesian MSE E[(θ̂ − θ)²]
    (sum over components) over the successful fits with its SE and one-sided limits (`verdicts.mse_limits`),
    and against the ZZB (zzb[noise] = {"log10", "lower", "upper", "flags", "lower_note", "upper_note"} on the
    MSE averaged over the prior, for any estimator; flags and notes optional): `vs_zzb` = `verdicts.verdict`
    at (1 − level)/m each, m the rows with a testable ZZB (Bonferroni); "below" at that level means a bug, or
    a ZZB grid too coarse (see its flags)."""
    groups: dict[tuple, list[dict]] = {}
    for r in sorted(records, key=record_key):
        groups.setdefault((r["noise"], r["estimator"]), []).append(r)
    labels = list(labels or sorted({k[1] for k in groups}))
    alpha = (1 - level) / max(sum(1 for j, _ in groups if _testable((zzb or {}).get(j))), 1)
    rows = []
    for (j, label), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], labels.index(kv[0][1]))):
        ok = [r for r in rs if r["error"] is None]
        E = np.array([np.array(r["theta_hat"]) - np.array(r["theta_true"]) for r in ok],
                     dtype=np.float64).reshape(len(ok), len(rs[0]["theta_true"]))
        lim = mse_limits(E, None, alpha)
        row = {"noise": j, "estimator": label, "name": rs[0]["name"], "n": len(rs), "n_failed": len(rs) - len(ok),
               "n_nonconverged": sum(1 for r in ok if not r["converged"]), "status": status_counts(rs),
               "bayes_mse": lim.mse, "bayes_mse_se": lim.se, "bayes_mse_lower": lim.lower,
               "bayes_mse_upper": lim.upper, "bayes_mse_untested": lim.reason, "verdict_level": 1 - alpha,
               **{f"bayes_{k}": v for k, v in power_columns(lim).items()},
               "mean_seconds": float(np.mean([r["seconds"] for r in rs])),
               "mean_renders": float(np.mean([r["renders"] + r["grad_passes"] for r in rs]))}
        z = (zzb or {}).get(j)
        if z is not None:
            row.update(zzb=_exp10(z["log10"]), zzb_upper=_exp10(z.get("upper", z["log10"])),
                       mse_over_zzb=_ratio(lim.mse, z["log10"]), mse_over_zzb_upper=ratio_upper(E, None, z),
                       vs_zzb=_verdict(lim, z, row["n_failed"], row["n"]))
        rows.append(row)
    return rows


def _testable(bound: dict | None) -> bool:
    """Whether a verdict against `bound` can be a test (it counts in the Bonferroni correction): its ends are
    not crossed and at least one is a confidence limit (no note)."""
    return bound is not None and "ends-crossed" not in bound.get("flags", ()) and not (
        bound.get("lower_note") and bound.get("upper_note"))


def _verdict(lim: MSELimits, bound: dict, failed: int, n: int) -> str:
    """`verdicts.verdict` against a bound {log10, lower?, upper?, flags?, lower_note?, upper_note?} (a point
    bound: both ends at log10), the failed fits named after it."""
    v = verdict(lim, bound.get("lower", bound["log10"]), bound.get("upper", bound["log10"]), bound.get("flags", ()),
                bound.get("lower_note", ""), bound.get("upper_note", ""))
    return f"{v} ({failed} of {n} fits failed, not in the MSE)" if v and failed else v


def _exp10(lg: float) -> float:
    return math.inf if lg > 308 else (10.0 ** lg if lg > -400 else 0.0)
