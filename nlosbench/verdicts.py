"""Verdicts of a Monte Carlo MSE against a bound: one-sided tests valid for a right-skewed statistic at small n,
for errors with tails up to Laplace's and Student t₅'s.

The MSE of n fits is the mean of the squared errors s_k = ‖θ̂_k − θ*‖², a right-skewed statistic: a symmetric
MSE ± 2 SE calls an efficient estimator "below" its bound far more often than its level says (18 % of runs at
n = 8 with Gaussian errors). The limits come from the exact decomposition of the sum of squared errors over the
clean-image clusters (trials that share a clean image, one of C independent renders whose Monte Carlo error moves
every fit of the cluster alike; independent trials: each its own cluster):

    n·MSE̅ = Σ_c m_c ‖ē_c‖²  +  Σ_k ‖e_k − ē_c(k)‖²,    MS_B = first / C,  MS_W = second / (n − C).

For Gaussian errors e = μ + b_c + ε the two parts are independent weighted sums of χ²_1 terms with at least C and
n − C degrees of freedom, so MSE̅ = (C/n)·MS_B + ((n − C)/n)·MS_W is a positive combination of two mean squares
(the classical variance-components problem). Tails heavier than Gaussian widen the spread of every part: a
squared error of kurtosis γ = E s² / (E s)² (3 for one Gaussian error, less for several) scales each part's
variance by (γ − 1)/2, i.e. shrinks its degrees of freedom ν_i by κ = 2/(γ − 1). γ is estimated from the sample,
γ̂ = mean(s²)/MSE̅² ≤ n, corrected for its ratio bias (E[mean s²] / E[MSE̅]² = γ / (1 + (γ − 1)/n) for
independent s_k): γ̃ = γ̂ (n − 1)/(n − γ̂), and floored at the Gaussian 3, γ̄ = max(γ̃, 3) (a sample from
heavy tails that happens to miss them looks light-tailed: the floor keeps such samples from narrowing the limits).
Then, at one-sided level α each (the caller's, Bonferroni over a table's tests):

* `lower` (decides "above": lower > the upper end): Satterthwaite's MSE̅·ν/χ²_{1−α,ν}, ν = (Σ c_i MS_i)² /
  Σ (c_i MS_i)²/(κ ν_i);
* `upper` (decides "below": upper < the bound's lower end): the larger of Graybill and Wang's modified
  large-sample limit MSE̅ + √Σ (H_i c_i MS_i)², H_i = κν_i/χ²_{α,κν_i} − 1 (exact for one Gaussian part, the χ²
  test of a variance), and the score limit MSE̅ / (1 − t_{α,ν₀−1}·SE/MSE̅), SE² = Σ 2(c_i MS_i)²/(κν_i), ν₀ the
  Gaussian Satterthwaite ν (n for independent trials); +inf where t·SE ≥ MSE̅. The score limit's variance is
  the null's (the MSE's SE scales with the tested value, not with the sample's MSE, which is small exactly when
  the sample missed the tails): the χ² forms with a shrunk ν call Laplace and t₅ errors "below" in 10–11 % of
  runs at n = 30, the score limit in ≤ 7 %.

Measured with tests/test_verdicts.py's simulation (20 000 runs each; MSE equal to the bound; α = 5 %; one and two
parameters; independent, or C = 4 clusters holding 30 % or 90 % of the MSE): false "below" ≤ 2.7 % (Gaussian),
≤ 6.3 % (Laplace), ≤ 6.8 % (t₅) at n = 8, 12 and 30; false "above" ≤ 4.5 % (Gaussian), ≤ 5.6 % (Laplace and t₅
with independent trials; 7.6 % with 90 % of the MSE in 4 clusters); "not tested" ≤ 4 % (Laplace, t₅). The price
is power, which the summary states per row (`power`): an MSE at 0.4× the bound is called "below" with Gaussian
errors in 15 % of runs at n = 12 and 87 % at n = 30 (independent trials), 9 % and 42 % with C = 4 clusters
holding 30 % of the MSE, 5 % at n = 30 with 90 %; `power_plan` says how many clean images would give 80 %.

No limit on a mean is valid at small n when the tails are heavier still: where one fit holds a share of Σ s_k
that errors with t₅'s tails seldom give (Cochran's test at `TAIL_LEVEL`), or fewer than `MIN_FITS` fits
succeeded, the verdict is "not tested" with the reason. Heavy tails that the sample happens not to contain cannot
be seen by any test (P(no gross error among 30 at 5 %) = 21 %): with t₃ errors the false "below" rate is 6 % at
n = 12 and 18 % at n = 30 (13 % "not tested"), with 5 % gross errors at ±4.5 core SDs 4 % and 24 % (19 % not
tested), with 2 % at ±10 SDs 20 % and 61 % (27 % not tested): such an estimator's verdicts hold for its core.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: level of the heavy-tail check (`max_share`): Gaussian errors make an MSE "not tested" at most this often (Laplace
#: and t₅ errors at n = 30 in 3–4 % of runs, t₃ in 13 %, 5 % gross errors at 4.5 SDs in 19 %)
TAIL_LEVEL = 1e-4
#: fewest successful fits for a test
MIN_FITS = 3


@dataclass(frozen=True)
class MSELimits:
    """The MSE of n successful fits (units²) and its one-sided limits at 1 − alpha each: upper (for "below"),
    lower (for "above"); se (its SE under the kurtosis γ̄), dof (Satterthwaite's ν), clusters C, kappa (the tail
    shrink κ = 2/(γ̄ − 1)), `reason` (non-empty: not testable, e.g. heavy tails; the limits are then NaN),
    kurtosis (γ̃, `limits_batch`) and between (the clean-image clusters' estimated share of the MSE)."""

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
    kurtosis: float = math.nan
    between: float = 0.0


def limits_batch(E: np.ndarray, clusters: np.ndarray | None, alpha: float) -> dict[str, np.ndarray]:
    """`mse_limits` over a batch: E (..., n, P) errors, clusters (n,) shared by the batch (None: independent
    trials, each its own cluster). Returns arrays (...) mse, se (the MSE's SE under the kurtosis γ̄), lower,
    upper, dof (Satterthwaite's, of the shrunk parts), kappa (the shrink κ = 2/(γ̄ − 1) ≤ 1), kurtosis (γ̃, the
    bias-corrected kurtosis of the squared errors; +inf where the sample cannot bound it), share (the largest
    fit's share of Σ s), between (the clean-image clusters' estimated share of the MSE, 0 for independent
    trials). float64."""
    from scipy import stats

    E = np.asarray(E, dtype=np.float64)
    n = E.shape[-2]
    sq = (E**2).sum(axis=-1)
    mse = sq.mean(axis=-1)
    ids, inv = np.unique(np.arange(n) if clusters is None else np.asarray(clusters), return_inverse=True)
    C = len(ids)
    if C == n:  # independent trials: one part, Σ s_k with n degrees of freedom
        parts = [(1.0, mse, n)]
    else:
        order = np.argsort(inv, kind="stable")
        m = np.bincount(inv).astype(np.float64)
        starts = np.concatenate([[0], np.cumsum(m)[:-1]]).astype(int)
        means = np.add.reduceat(E[..., order, :], starts, axis=-2) / m[:, None]  # cluster means (..., C, P)
        within = E - means[..., inv, :]
        parts = [(C / n, np.einsum("c,...cp->...", m, means**2) / C, C),  # between: Σ m_c ‖ē_c‖², uncentred
                 ((n - C) / n, (within**2).sum(axis=(-2, -1)) / (n - C), n - C)]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        g = np.where(mse > 0, (sq**2).mean(axis=-1) / mse**2, 1.0)  # ≤ n
        kurt = np.where(g < n, g * (n - 1) / (n - g), np.inf)  # E[mean s²] / E[s̄]² = γ / (1 + (γ − 1)/n)
        kappa = 2 / (np.maximum(kurt, 3.0) - 1)  # γ̄ = max(γ̃, 3): never lighter than one Gaussian error's
        up2 = var_m = var_g = 0.0
        for c, ms, df in parts:
            d, term = df * kappa, c * ms
            up2 = up2 + ((d / stats.chi2.ppf(alpha, d) - 1) * term) ** 2  # Graybill–Wang
            var_m = var_m + 2 * term**2 / d
            var_g = var_g + 2 * term**2 / df
        dof = np.where(var_m > 0, 2 * mse**2 / var_m, np.inf)  # Satterthwaite, tails included
        nu = np.where(var_g > 0, 2 * mse**2 / var_g, np.inf)  # Satterthwaite, Gaussian parts (n when independent)
        lower = np.where(np.isfinite(dof), mse * dof / stats.chi2.ppf(1 - alpha, dof), mse)
        r = stats.t.ppf(1 - alpha, np.maximum(nu - 1, 1)) * np.sqrt(var_m) / mse  # the score limit's t·SE / U
        score = np.where(r < 1, mse / (1 - r), np.where(mse > 0, np.inf, 0.0))
        share = np.where(mse > 0, sq.max(axis=-1) / sq.sum(axis=-1), 0.0)
        between = np.nan_to_num(np.clip((parts[0][1] - parts[1][1]) / (parts[0][1] + (n / C - 1) * parts[1][1]),
                                        0, 1)) if len(parts) == 2 and C > 1 else np.zeros(mse.shape)
    return {"mse": mse, "se": np.sqrt(var_m), "lower": lower, "upper": np.maximum(mse + np.sqrt(up2), score),
            "dof": dof, "kappa": kappa, "kurtosis": kurt, "share": share, "between": between}


def max_share(n: int) -> float:
    """The largest share of Σ s_k one of n fits may hold before the tails count as too heavy for a test (Cochran's
    test of the largest of n χ²_1 terms at `TAIL_LEVEL`, Bonferroni form: a share that Gaussian errors never give
    and Laplace or t₅ errors seldom)."""
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
        reason = (f"heavy tails: one fit holds {r['share']:.0%} of the summed squared errors, a share that errors "
                  f"with tails up to Laplace's or t5's seldom reach at n = {n} (no limit on a mean is valid there)")
    lo, up = (math.nan, math.nan) if reason else (r["lower"], r["upper"])
    C = n if clusters is None else len(np.unique(clusters))
    return MSELimits(r["mse"], r["se"], lo, up, r["dof"], C, r["kappa"], n, alpha, reason, r["kurtosis"],
                     r["between"])


#: the MSE / bound ratio at which `power` states a verdict's power, and the power a plan aims at
POWER_RATIO, POWER_TARGET = 0.4, 0.8


@functools.lru_cache(maxsize=4096)
def power(n: int, clusters: int, between: float, alpha: float, ratio: float = POWER_RATIO, runs: int = 2000) -> float:
    """How often the test says "below" (`limits_batch`'s upper limit under the bound, and tested: `max_share`)
    when the MSE is `ratio` × the bound: n trials over `clusters` clean images (trial k in image k mod C; C = n,
    or one image as in `mse_limits`: independent), whose shared error holds `between` of the MSE, Gaussian
    errors of one parameter (the heaviest Gaussian tails: several parameters give more power), one-sided level
    alpha. Simulated with `runs` draws from a fixed seed (SE ≤ 0.5/√runs, 0.011 at 2000)."""
    rng = np.random.default_rng(20_240_611)
    C = n if clusters <= 1 else min(int(clusters), n)
    e = rng.standard_normal((runs, n, 1)) * math.sqrt(ratio * (1 - between))
    ids = np.arange(n) % C if C < n else None
    if ids is not None:
        e += rng.standard_normal((runs, C, 1))[:, ids] * math.sqrt(ratio * between)
    r = limits_batch(e, ids, alpha)
    return float(np.mean((r["share"] <= max_share(n)) & (r["upper"] < 1.0)))


def power_plan(n: int, clusters: int, between: float, alpha: float, ratio: float = POWER_RATIO,
               target: float = POWER_TARGET, most: int = 4096) -> tuple[float, int, int]:
    """(power of this design, clean images and trials that reach `target`): `power` at (n, clusters), then with
    the clean images and trials doubled together (the same trials per clean image) until the power reaches
    `target`; (power, 0, 0) where no design of at most `most` trials does. `between` is rounded to 0.1 (the
    estimate from C clean images is far coarser)."""
    between = round(min(max(float(between), 0.0), 1.0) * 10) / 10
    clusters = n if clusters <= 1 else min(int(clusters), n)  # one clean image: independent trials (`power`)
    now = power(n, clusters, between, alpha, ratio)
    k, p = 0, now
    while p < target:
        k += 1
        if n << k > most:
            return now, 0, 0
        p = power(n << k, clusters << k, between, alpha, ratio)
    return now, clusters << k, n << k


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
