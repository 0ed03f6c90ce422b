"""Verdicts of a Monte Carlo MSE against a bound: one-sided tests valid for a right-skewed statistic at small n.

The MSE of n fits is the mean of the squared errors s_k = ‖θ̂_k − θ*‖², a right-skewed statistic: a symmetric
MSE ± 2 SE calls an efficient estimator "below" its bound far more often than its level says (18 % of runs at
n = 8 with Gaussian errors). Here the limits come from the exact decomposition of the sum of squared errors over
the clean-image clusters (trials that share a clean image, one of C independent renders whose Monte Carlo error
moves every fit of the cluster alike; independent trials: each its own cluster):

    n·MSE̅ = Σ_c m_c ‖ē_c‖²  +  Σ_k ‖e_k − ē_c(k)‖²,    MS_B = first / C,  MS_W = second / (n − C).

For errors e = μ + b_c + ε with Gaussian b_c ~ N(0, T) and ε ~ N(0, S), the two parts are independent and each
is a weighted sum of χ²_1 terms (noncentral where μ ≠ 0) with at least C and n − C degrees of freedom (exactly
that for one parameter, more for several), so MSE̅ = (C/n)·MS_B + ((n − C)/n)·MS_W is a positive combination of
two mean squares, the classical variance-components problem:

* `upper` (decides "below": upper < the bound's lower end): Graybill and Wang's modified large-sample limit
  MSE̅ + √Σ (H_i c_i MS_i)², H_i = ν_i/χ²_{α,ν_i} − 1, exact for one part (the χ² test of a variance) and
  conservative with two (no cluster-variance estimate, which would need ≥ 12 clusters for a bootstrap);
* `lower` (decides "above": lower > the upper end): Satterthwaite's MSE̅·ν/χ²_{1−α,ν}, ν = (Σ c_i MS_i)² /
  Σ (c_i MS_i)²/ν_i (chosen by simulation: the modified large-sample lower limit and Satterthwaite's upper
  limit are each liberal here, up to 6.7 % and 10.8 % at α = 5 %);
* tails heavier than Gaussian shrink every ν_i by κ = 2·MSE̅²/Var̂(s) ≤ 1 (the sample's shape against the χ²_1
  one, the heaviest a Gaussian error has): wider limits;
* α is the caller's one-sided level, Bonferroni over a table's tests.

Measured with tests/test_verdicts.py's simulation (20 000 runs each; n = 8, 12, 30; one and two parameters;
independent, or C = 4 clusters holding 30 % or 90 % of the MSE): an efficient estimator is called "below" in ≤ 4.5 %
and "above" in ≤ 4.6 % of runs at α = 5 % (the old MSE ± 2 SE: 18 % "below" at n = 8), and Gaussian errors are
refused as heavy-tailed in ≤ 1.1 %. The price of not knowing the cluster variance: at n = 30 with C = 4 an estimator
at 0.4× the bound is called "below" in 80 % of runs (95 % with independent trials). No limit on a mean is valid at
small n when the tails are heavy: where one fit holds more of Σ s_k than Gaussian errors give (Cochran's test at
`TAIL_LEVEL`), or fewer than `MIN_FITS` fits succeeded, the verdict is "not tested" with the reason. Rare gross
errors that the sample happens not to contain cannot be seen by any test (P(none among 30 at 5 %) = 21 %): the
limits then hold for the estimator's Gaussian core: with 5 % gross errors of 4.5× the core's SD an efficient core is
called "below" its bound in ≤ 3.5 % of runs (10–38 % are "not tested"), while the upper limit falls under the
contaminated MSE in 6–33 % of runs.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: level of the heavy-tail check (`max_share`): Gaussian errors make an MSE "not tested" at most this often
TAIL_LEVEL = 0.01
#: fewest successful fits for a test
MIN_FITS = 3


@dataclass(frozen=True)
class MSELimits:
    """The MSE of n successful fits (units²) and its one-sided limits at 1 − alpha each: upper (for "below"),
    lower (for "above"); se (√ of the parts' variance), dof (Satterthwaite's ν), clusters C, kappa (the tail
    shrink κ), and `reason` (non-empty: not testable, e.g. heavy tails; the limits are then NaN)."""

    mse: float
    se: float
    lower: float
    upper: float
    dof: float
    clusters: int
    kappa: float
    n: int
    alpha: float
    reason: str = ""


def limits_batch(E: np.ndarray, clusters: np.ndarray | None, alpha: float) -> dict[str, np.ndarray]:
    """`mse_limits` over a batch: E (..., n, P) errors, clusters (n,) shared by the batch (None: independent
    trials, each its own cluster). Returns arrays (...) mse, se, lower, upper, dof (Satterthwaite's, of the
    shrunk parts), kappa (the tail shrink κ ≤ 1), share (the largest fit's share of Σ s). float64."""
    from scipy import stats

    E = np.asarray(E, dtype=np.float64)
    n = E.shape[-2]
    ids = np.unique(clusters) if clusters is not None else np.arange(n)
    M = ((np.asarray(clusters) if clusters is not None else np.arange(n))[:, None] == ids[None]).astype(np.float64)
    m, C = M.sum(axis=0), len(ids)
    sq = (E**2).sum(axis=-1)
    mse = sq.mean(axis=-1)
    means = np.einsum("nc,...np->...cp", M, E) / m[:, None]  # cluster means (..., C, P)
    parts = [(C / n, np.einsum("c,...cp->...", m, means**2) / C, C)]  # between: Σ m_c ‖ē_c‖², uncentred
    if n > C:
        within = E - np.einsum("nc,...cp->...np", M, means)
        parts.append(((n - C) / n, (within**2).sum(axis=(-2, -1)) / (n - C), n - C))
    var = sq.var(axis=-1, ddof=1) if n > 1 else np.full(mse.shape, math.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = np.clip(np.where(var > 0, 2 * mse**2 / var, 1.0), None, 1.0)  # < 1: tails beyond Gaussian
        up2 = var_m = 0.0
        for c, ms, df in parts:
            d, term = df * kappa, c * ms
            up2 = up2 + ((d / stats.chi2.ppf(alpha, d) - 1) * term) ** 2  # Graybill–Wang
            var_m = var_m + 2 * term**2 / d
        dof = np.where(var_m > 0, 2 * mse**2 / var_m, np.inf)  # Satterthwaite
        lower = np.where(np.isfinite(dof), mse * dof / stats.chi2.ppf(1 - alpha, dof), mse)
        share = np.where(mse > 0, sq.max(axis=-1) / sq.sum(axis=-1), 0.0)
    return {"mse": mse, "se": np.sqrt(var_m), "lower": lower, "upper": mse + np.sqrt(up2), "dof": dof,
            "kappa": kappa, "share": share}


def max_share(n: int) -> float:
    """The largest share of Σ s_k one of n fits may hold before the tails count as heavier than Gaussian errors
    give (Cochran's test of the largest of n χ²_1 terms at `TAIL_LEVEL`, Bonferroni form)."""
    from scipy import stats

    if n < 2:
        return 1.0
    return 1.0 / (1.0 + (n - 1) / float(stats.f.ppf(1 - TAIL_LEVEL / n, 1, n - 1)))


def mse_limits(E: np.ndarray, clusters: Sequence[int] | None = None, alpha: float = 0.05) -> MSELimits:
    """The MSE of errors E (n, P) (θ̂ − θ* of the successful fits) with its one-sided limits at 1 − alpha each;
    clusters (n,): the clean-image replicate of each trial (None or one value: independent trials, the MSE
    given that one clean image)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    E = np.asarray(E, dtype=np.float64)
    n = len(E)
    if n == 0:
        return MSELimits(math.nan, math.nan, math.nan, math.nan, math.nan, 0, math.nan, 0, alpha, "no successful fit")
    if clusters is not None and len(np.unique(clusters)) < 2:
        clusters = None  # one clean image: the trials are independent given it (its error is a fixed offset)
    r = {k: float(np.ravel(v)[0]) for k, v in limits_batch(E[None], None if clusters is None else
                                                            np.asarray(clusters), alpha).items()}
    reason = ""
    if n < MIN_FITS:
        reason = f"{n} successful fit{'s' if n > 1 else ''} (a test needs >= {MIN_FITS})"
    elif r["share"] > max_share(n):
        reason = (f"heavy tails: one fit holds {r['share']:.0%} of the summed squared errors, more than Gaussian "
                  f"errors give at n = {n} (no limit on a mean is valid there)")
    lo, up = (math.nan, math.nan) if reason else (r["lower"], r["upper"])
    C = n if clusters is None else len(np.unique(clusters))
    return MSELimits(r["mse"], r["se"], lo, up, r["dof"], C, r["kappa"], n, alpha, reason)


def verdict(lim: MSELimits, lower: float, upper: float, flags: Sequence[str] = (), lower_note: str = "",
            upper_note: str = "") -> str:
    """The MSE against a bound's log10 ends: "below" (the MSE's upper limit under the lower end), "above" (its
    lower limit over the upper end; an open upper end, +inf, never), "inside" (neither), "undetermined" (the
    ends are crossed: flag `ends-crossed`), "not tested: <reason>" (the MSE is not testable, or an end that
    decides is not a confidence limit: its note is non-empty); "" when no fit succeeded."""
    if math.isnan(lim.mse):
        return ""
    if "ends-crossed" in flags:
        return "undetermined: the bound's ends are crossed"
    if lim.reason:
        return f"not tested: {lim.reason}"
    below = math.isfinite(lower) and lim.upper < 10.0 ** min(lower, 300)
    above = math.isfinite(upper) and lim.lower > 10.0 ** min(upper, 300)
    if below and not lower_note:
        return "below"
    if above and not upper_note:
        return "above"
    notes = [(e, note) for e, note, decides in
             (("lower", lower_note, math.isfinite(lower)), ("upper", upper_note, math.isfinite(upper)))
             if note and decides]
    if len(notes) == 2 and notes[0][1] == notes[1][1]:
        return f"not tested: neither end is a confidence limit ({notes[0][1]})"
    return "not tested: " + "; ".join(f"the {e} end is not a confidence limit ({note})" for e, note in notes) \
        if notes else "inside"
