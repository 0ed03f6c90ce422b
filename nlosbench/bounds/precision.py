"""Precision on demand: replicate render sets added only where a bound's interval is wider than asked,
with confidence limits that survive the data-dependent stopping.

Precision of an interval bound (kinds "hcr" and "crlb": log10 ends `lower`, `upper` and estimate `point`)
is its relative half-width in linear units,

    reached = max(10^(upper − point), 10^(point − lower)) − 1,

+inf where an end is open (±inf), the point is not finite, or an end is not a confidence limit (a
lower_note / upper_note). A θ* meets the target p when every interval bound asked for, for every noise
model, has reached ≤ p.

The stopping rule (`refine`). Let α = 1 − level and K = `looks`. α is spent along the path (`spending`): the
pilot's ends at level 1 − α₀ with α₀ = α/20, fresh look k's at 1 − α_k with α₀ + Σ_k α_k = α (K = 2, the default:
α₁ = 0.95 α; K = 3: 0.8 and 0.2 of 0.95 α; each later look a quarter of the one before). K = 1 is the pilot alone, at
level 1 − α (no fresh look is ever made, so nothing is spent on one): each θ* says whether it met p and what one
fresh look would cost (`extra_pixel_samples`), a survey at a fixed cost.
  look 0, the pilot: the R0 replicate sets 0 … R0 − 1 at level 1 − α₀. θ* that meet p stop here (only then, or
      where no fresh look is made, is the pilot's interval reported).
  plan: for every other θ*, from the pilot alone, R* = the smallest number of fresh sets on the ladder
      4, 6, 8, 12, 16, 24, … (at most what the budget allows it alone) predicted to reach AIM·p at level 1 − α₁,
      its FD step checks passing with probability POWER (below; the margins make one fresh look usually enough),
      with the FD window (`Window`: which of the pilot's steps
      the looks render, the step check predicted too) and, where only interval bounds are asked for, the tested Δ
      (`tested_deltas`) that make it cheapest; where none is (the pilot's estimates, held fixed, say more sets
      never suffice: FD stages or λ̂ that disagree by noise alone look like that at a small pilot), an
      exploratory R* = EXPLORE·R0 within the budget;
  looks k = 1 … K − 1: look 1 R* sets of its own, look k ≥ 2 planned the same way from look k − 1's data alone
      (its sets, FD window and Δ, at level 1 − α_k: a pilot of 4 sets cannot see what a look of 64 shows, such as
      the one-sided FD bias past the corner; `Fit.windows`), or where none is predicted to suffice twice look
      k − 1's sets, exploratory; each after every set rendered before it at any θ* (look 1 of the
      first wave the sets R0 … R0 + R* − 1), at level 1 − α_k; stop at the first look that meets p. Looks are made
      in waves: those whose worst-case cost fits what is left of the budget (cheapest first), then, against what
      they actually spent, the others; exploratory looks only once every planned one has been admitted or left out;
      a θ* whose look fits in no wave gets no more looks.
The reported interval is that of the last look made.

Proof that P(reported interval misses the true value) ≤ α whatever the stopping. Let E_k be the event that look
k's interval misses and A_k the event that look k is made (A_0 always). The reported interval is that of some
look made, so a miss implies E_k ∩ A_k for the k reported, and P(miss) ≤ Σ_k P(E_k ∩ A_k). Whether look k is made
(and its R, FD window and tested Δ) is decided from the sets rendered before it: the pilot, its looks 1 … k − 1
and the looks of other θ* in earlier waves (and the Poisson weight render, independent of every replicate set and
the same at every look). Look k's sets come after all of those (with common seeds another θ*'s look renders
this θ*'s sets too, as test points or FD neighbours, so "after its own earlier looks" would not be enough), and
the bank derives their seeds from their replicate indices (nothing is drawn), so they are independent of that
decision: given the past, look k is a fixed procedure on a fixed number of fresh sets, a fixed-R interval
at level 1 − α_k, and P(E_k | past) ≤ α_k. Hence P(E_k ∩ A_k) = E[1_{A_k} P(E_k | past)] ≤ α_k P(A_k), and
P(miss) ≤ Σ_k α_k P(A_k) ≤ α₀ + Σ_{k≥1} α_k = α. (Nested looks — look k's sets a prefix of look k + 1's — would
break the independence: the miss of look k + 1 would not be independent of reaching it; a union bound over the
looks would then need every look at 1 − α/K.) The argument is exact given that each fixed-R interval has its
stated level; that is the t-approximation of `ustat` and `fd_step`, the same as without a target: from 4 sets on
the unbiased standard errors, at their level, so the fresh looks' ladder starts at 4; a pilot of 3 sets has the
jackknife's, conservative. Nearly every run that does not meet p at the pilot reaches look 1, so the reported
ends miss about α₁ = 0.95 α of the time (K = 2). (For the HCR "the true value" of a look that tests fewer Δ is its
HCR over those Δ and Δ → 0, which its upper end bounds; its lower end is then a lower limit of that, so also of the
HCR over every Δ, which is no smaller.)

Planning model. A U-statistic over R replicates of Σ_pixels w·x_r·x_s, with per-pixel mean d and variance s²
of x (independent pixels), has

    Var = a/R + b/(R(R − 1)),  a = 4 Σ w² d² s²,  b = 2 Σ w² s⁴.

`variance_terms` estimates a and b from a look's raw replicate data (λ(Δ): the replicate differences D
(R, K, N); F: the FD rounds (R, P, N) of every stage and variant): from R ≥ 4 replicates without any
distributional assumption (Hoeffding's parts, from the unbiased per-pixel estimates `ustat` uses for the
intervals), from 3 with Gaussian moments, which a path tracer's heavy-tailed errors inflate. `Fit.bounds` builds UStats
with the look's estimates and SE √(a/R + b/(R(R − 1))) (degrees of freedom the look's Satterthwaite df ×
(R − 1)/(R0 − 1); for a vector θ, leave-one-outs scaled to that variance) and calls the same interval code as
the service (`hcr_interval`, `crlb_term`), so an open end (λ_L ≤ 0), the lower end's joint level and the FD stages
are predicted the way they are computed. Where a look's λ̂(Δ) ≤ 0 (no information on λ at that Δ), the plan uses the
local quadratic ΔᵀF̂Δ instead. Plans only choose R; the proof above does not depend on them. This is not
n·(width/target)² (SE ∝ R^−½): where the noise × noise part b dominates, SE falls like 1/R.

Budget: the call is charged by request (the bank's `Ledger`): every distinct render or Jacobian its looks ask for
costs its spp × H × W per render (an FD Jacobian 2 renders per parameter and round) whether it is rendered, read
from the store or served from a cache, so its decisions are the same cold, warm, resumed or after another study.
The pilot is always made; a θ*'s fresh look is made only if the pixel-samples charged so far plus the worst-case
cost (every FD halving taken) of the looks admitted with it in its wave stay within the budget: one dear θ* does
not stop the looks of the others, and what a wave did not spend (a look stops halving where its check passes) admits
the next. (Which θ* a wave admits depends on the others' data; each θ*'s look k is still a fixed procedure on its
fixed sets, after every set that decided it, and the proof above bounds every look, made or not.) What this
process rendered is reported beside it, never used.
A target without a budget never runs unbounded: its budget is the default ceiling, CEILING × the pixel-samples
charged to its pilot (the pilot included: the whole call costs at most CEILING pilots), whichever caller asks
(`BoundService.at`, `fisher`, the bounds `curve` quotes, `nlosbench bound --precision`). What it could not meet
within the ceiling the record says (`note`) with the predicted cost to finish (`extra_pixel_samples`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.stats import norm

from nlosbench.bounds.fd_step import Halving, Stage, StepFisher, crlb_term, one_sided_gap, one_sided_t, settled_from
from nlosbench.bounds.hcr import LN10, log_expm1
from nlosbench.bounds.hcr_interval import hcr_interval
from nlosbench.bounds.ustat import (
    UStat,
    check_group,
    group_variances,
    grouped,
    noise_part,
    pair_squares,
    pixel_terms,
    t_quantile,
)

#: interval bound kinds a precision target applies to
KINDS = ("hcr", "crlb")
#: the most fresh sets a first look considers, and the most a prediction of what more would cost considers
MAX_SETS, MAX_PREDICT = 1024, 2**20
#: without a budget, a precision target spends at most CEILING × its pilot's pixel-samples (the pilot included)
CEILING = 16
#: fresh sets of an exploratory first look, in pilots, where the pilot predicts that no number of sets suffices
EXPLORE = 4
#: a plan asks for the sets predicted to reach AIM × the target: the pilot's estimates are noisy, and one fresh look
#: must usually meet it (a second one is at a stricter level and on sets of its own)
AIM = 0.8
#: a plan predicts an FD step check passed only where it passes with probability ≈ POWER (if the pilot's estimates are
#: right): the contrast's upper limit plus Φ⁻¹(POWER) of its SE below 0. At the look's level alone a check predicted to
#: pass passes half the time (the decisive curve's looks planned so: 13 of its 27 NLOS points' checks did not pass)
POWER = 0.9
Z_POWER = float(norm.ppf(POWER))


def check_precision(precision, budget, looks, want: Sequence[str], replicates: int) -> None:
    """ValueError (one line) unless precision is None or a finite number > 0 (relative half-width; or a sequence of
    them, one per θ), budget
    None or a positive integer (pixel-samples, only with a precision), looks an integer ≥ 1, and, with a
    precision, an interval bound (hcr, crlb) is asked for from ≥ 3 replicates."""
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1):
        raise ValueError(f"budget must be a positive integer number of pixel-samples or None, got {budget!r}")
    if isinstance(looks, bool) or not isinstance(looks, (int, np.integer)) or looks < 1:
        raise ValueError(f"looks must be an integer >= 1 (the pilot, then at most looks − 1 fresh looks), "
                         f"got {looks!r}")
    if precision is None:
        if budget is not None:
            raise ValueError("a budget needs a precision target (precision=...)")
        return
    values = np.asarray(precision, dtype=object).reshape(-1)
    if values.size == 0 or any(isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or
                               not (math.isfinite(v) and v > 0) for v in values):
        raise ValueError(f"precision must be a finite number > 0 (relative half-width, e.g. 0.25) or one per θ, "
                         f"got {precision!r}")
    if not set(KINDS) & set(want):
        raise ValueError(f"a precision target needs an interval bound (one of {list(KINDS)}) in want, got {list(want)}")
    if replicates < 3:
        raise ValueError(f"a precision target needs replicates >= 3 (confidence limits), got {replicates}")


def ceiling(pilot: int) -> int:
    """The budget of a precision target given none (pixel-samples): CEILING × `pilot`, the pixel-samples charged to
    its pilot, so the whole call, pilot included, costs at most CEILING pilots."""
    return CEILING * int(pilot)


def reached(b) -> float:
    """Precision reached by an interval Bound (linear units): max(10^(upper − point), 10^(point − lower)) − 1;
    +inf for an open end, a non-finite point or an end that is not a confidence limit."""
    ends = (b.lower, b.upper, b.point)
    if any(v is None or not math.isfinite(v) for v in ends) or b.lower_note or b.upper_note:
        return math.inf
    decades = max(b.upper - b.point, b.point - b.lower, 0.0)
    return math.inf if decades > 300 else 10.0 ** decades - 1.0  # (an end hundreds of decades off overflows)


@dataclass(frozen=True)
class Raw:
    """What a plan needs from one look at one θ* for one noise model: λ's replicate differences D (R, K, N)
    and U-statistic (None without "hcr"), the StepFisher and the FD stages (rounds (R, P, N)), the weight w
    (N,), the tested Δ (K,) or (K, P) and their limits (Θ − θ*), H·W pixels, the values per pixel that share
    path samples (`group`, the model's channels), and whether the CRLB quoted is the FD-smoothed model's
    (`smoothed`: `fd_step.crlb_term`)."""

    D: np.ndarray | None
    lam: UStat | None
    sf: StepFisher | None
    stages: list[Stage]
    w: np.ndarray
    deltas: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    pixels: int
    group: int = 1
    smoothed: bool = False

    def subset(self, mask: np.ndarray) -> Raw:
        """The same look with only the tested Δ of `mask` (K,)."""
        lam = self.lam
        lam = UStat(lam.est[mask], lam.se[mask], lam.loo[:, mask] if lam.loo.size else lam.loo, lam.replicates,
                    np.array(lam.dof[mask]), noise=None if lam.noise is None else lam.noise[mask])
        return Raw(self.D[:, mask], lam, self.sf, self.stages, self.w, self.deltas[mask], self.lower, self.upper,
                   self.pixels, self.group, self.smoothed)


@dataclass(frozen=True)
class SetCost:
    """Worst-case renders per replicate set: `grid` test-grid renders (shared by every θ*), per θ* its own
    `per_theta` (T,) (θ* and offsets), `fd` FD renders per θ* and stage, at most `stages` stages, and `center`
    renders of θ* under the FD stencils' own seed (independent seeds: the one-sided differences' centre, the same
    at every stage). A θ* whose look tests only some Δ (`tested`: how many) renders θ* and those Δ instead of the
    grid and its offsets."""

    grid: int
    per_theta: np.ndarray
    fd: int
    stages: int
    center: int = 0

    def look(self, new: dict[int, tuple], grid_new: int) -> int:
        """Worst-case renders of a look: new {θ index: (sets before, sets now, stages cached per set, stages of
        its window, Δ tested or None)} and `grid_new` test-grid sets not rendered yet (for the θ* testing the
        whole grid); every FD stage not cached may be needed, and tested Δ are counted per θ* (not shared)."""
        n = self.grid * grid_new if any(v[4] is None for v in new.values()) else 0
        for i, (before, now, cached, stages, tested) in new.items():
            n += (int(self.per_theta[i]) if tested is None else 1 + tested) * (now - before)
            n += self.center * (now - before) + self.fd * ((now - before) * stages + before * (stages - cached))
        return n

    def one(self, i: int, stages: int, tested: int | None = None) -> int:
        """Renders of one more set for θ* i alone, with `stages` FD stages and `tested` Δ (None: the grid and the
        offsets)."""
        return (self.grid if tested is None else 0) + self.own(i, stages, tested)

    def own(self, i: int, stages: int, tested: int | None = None) -> int:
        """Renders of one set that are θ* i's own: θ* and its offsets (or θ* and its `tested` Δ) and the FD stencils
        of `stages` stages, not the test grid every θ* shares."""
        return (int(self.per_theta[i]) if tested is None else 1 + tested) + self.center + self.fd * stages


@dataclass(frozen=True)
class Precision:
    """What a precision target got at one θ* for one noise model.

    target: the relative half-width asked for; reached: {kind: precision reached} for this noise model; met: every
    interval bound of every noise model at this θ* reached the target; looks: looks made for this θ* (1: the pilot
    only); pilot_sets / fresh_sets: replicate sets of the pilot and of the reported look (0: the pilot's are reported),
    from replicate index first_set on (0: the pilot's; a look made in a later wave starts past every set rendered before
    it); level: the one-sided level of the reported look's ends (the pilot 1 − α/20, fresh look k 1 − α_k: `spending`);
    pixel_samples: charged to the whole call (every θ*; spp × H × W per render requested, however served: what the
    budget decides on); own_pixel_samples: this θ*'s own share, its replicate sets' renders over the pilot and every
    look made (`SetCost.own`: θ* and its offsets or tested Δ, the FD stencils of each stage rendered; not the test
    grid every θ* shares, nor a weight render; a render another θ* asked for too, as common seeds make of
    neighbouring stencils, counted in each); rendered: the pixel-samples of those renders this process made (0 when
    all were cached);
    extra_sets / extra_pixel_samples: the fresh sets and pixel-samples of one more look of its own predicted to meet it,
    from the reported look's data (0 when met, +inf when no number of sets is predicted to); note: why it stopped;
    budget: the pixel-samples the call was capped at (the budget given, else the default ceiling `ceiling`);
    finer_step: set by a curve's prediction (`BoundService.curve(predict=…)`; False elsewhere): no number of sets is
    predicted to meet it at the grid's FD step because F still rises at its finest step (an edge: a finer step may
    settle it)."""

    target: float
    reached: dict[str, float]
    met: bool
    looks: int
    pilot_sets: int
    fresh_sets: int
    level: float
    pixel_samples: int
    extra_sets: float = 0.0
    extra_pixel_samples: float = 0.0
    note: str = ""
    budget: int = 0
    first_set: int = 0
    finer_step: bool = False
    own_pixel_samples: int = 0
    #: what this process happened to render: not part of the result (records that decide alike compare equal)
    rendered: int = field(default=0, compare=False)

    @property
    def worst(self) -> float:
        """The largest precision reached over the bound kinds."""
        return max(self.reached.values(), default=math.inf)

    def columns(self) -> dict:
        """CSV cells precision_target, precision_reached (the worst kind), precision_pixel_samples,
        precision_own_pixel_samples, precision_extra_pixel_samples."""
        return {"precision_target": self.target, "precision_reached": self.worst,
                "precision_pixel_samples": self.pixel_samples, "precision_own_pixel_samples": self.own_pixel_samples,
                "precision_extra_pixel_samples": self.extra_pixel_samples}


# -- the planning model ---------------------------------------------------------------------------------
def variance_terms(X: np.ndarray, w, group: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(a (K,), b (K,)) of the U-statistics of Σ_values w·x_r·x_s over R replicates X (R, K, N) (w scalar or
    (N,)), the N values in groups of `group` consecutive ones that share path samples (a pixel's channels, N = M·C):
    Var ≈ a/R + b/(R(R − 1)).

    R ≥ 4: distribution-free. Per group m, with the kernel H_rs = Σ_{ω∈m} w x_r x_s, Hoeffding's parts ζ₁ = Cov(H_rs,
    H_rt) (signal × noise) and ζ₂ = Var H_rs give Var U_m = (4(R − 2)ζ₁ + 2ζ₂)/(R(R − 1)) exactly, so a = 4 Σ_m ζ₁ and
    b = 2 Σ_m (ζ₂ − 2ζ₁): b/(R(R − 1)) is the noise × noise part `ustat.noise_part` takes from the unbiased variance
    (clipped to [0, V], so a, b ≥ 0 and a/R + b/(R(R − 1)) = V, the look's own SE²). Its estimates (the group variances
    v_m and Q_m = Σ_{r≠s} H_rs²) need no distributional assumption: a path tracer's pixel errors are
    heavy-tailed (a few bright paths), and the Gaussian moments below overstate their s⁴ by the kurtosis (Π hallway
    40 × 30 at 1.12 m, central FD at 96 spp: b 2.3× the distribution-free value from 12 sets, 4.4× from 3, and a 35×
    from 3: a 3-set pilot plans far more sets than it needs).

    R ≤ 3 (no unbiased estimate of a fourth moment from three values): Gaussian errors assumed, per group m of mean
    d and error covariance S (C, C) over replicates,

        a = 4 Σ_m (w∘d)ᵀ S (w∘d),    b = 2 Σ_m Σ_cc' w_c w_c' S_cc'²

    (C = 1: a = 4 Σ w² d² s², b = 2 Σ w² s⁴). From the mean x̄ and the sample covariance Ŝ over
    replicates (ν = R − 1 degrees of freedom, Wishart moments, x̄ and Ŝ independent): S_cc'² ≈
    ν(ν Ŝ_cc'² − Ŝ_cc Ŝ_c'c')/((ν + 2)(ν − 1)) (for c = c': ŝ⁴ (R − 1)/(R + 1)), and d_c d_c' S_cc' ≈
    x̄_c x̄_c' Ŝ_cc' − S_cc'²/R, summed over groups and a's sum clipped at 0. (Clipping per group instead would
    add ≈ s⁴/R from every signal-free pixel; the plug-in ŝ⁴ is 2× s⁴ at R = 3: measured on blob2d, both doubled
    the predicted SE where b dominates.) R = 2: the diagonal formula, no cross terms."""
    X = np.asarray(X, dtype=np.float64)
    R, K, N = X.shape
    C = check_group(group, N)
    w = np.broadcast_to(np.asarray(w, dtype=np.float64), (N,))
    return (_free_terms if R >= 4 else _gaussian_terms)(X, w, C)


def _gaussian_terms(X: np.ndarray, w: np.ndarray, C: int) -> tuple[np.ndarray, np.ndarray]:
    """`variance_terms` under Gaussian errors (its docstring), X (R, K, N) float64, w (N,)."""
    R, K, N = X.shape
    x = X.reshape(R, K, N // C, C)
    m = x.mean(axis=0)  # (K, M, C)
    dev = x - m
    S = np.einsum("rkmc,rkmd->kmcd", dev, dev) / (R - 1.0)  # (K, M, C, C)
    nu = R - 1.0
    diag = np.einsum("kmcc->kmc", S)
    if R > 2:
        S2 = nu * (nu * S * S - diag[..., :, None] * diag[..., None, :]) / ((nu + 2.0) * (nu - 1.0))
    else:
        S2 = np.zeros_like(S)
        idx = np.arange(C)
        S2[..., idx, idx] = diag * diag * (R - 1.0) / (R + 1.0)
    wv = w.reshape(N // C, C)  # (M, C)
    ww = wv[:, :, None] * wv[:, None, :]  # (M, C, C)
    wm = wv * m  # (K, M, C)
    a = 4.0 * (np.einsum("kmc,kmcd,kmd->k", wm, S, wm) - (ww * S2).sum(axis=(-2, -1)).sum(axis=-1) / R)
    return np.clip(a, 0.0, None), 2.0 * (ww * S2).sum(axis=(1, 2, 3))


def _free_terms(X: np.ndarray, w: np.ndarray, C: int) -> tuple[np.ndarray, np.ndarray]:
    """`variance_terms` from R ≥ 4 replicates X (R, K, N), weights w (N,): the unbiased variance V = Σ_m v_m of the
    U-statistic at R split by `ustat.noise_part` into its noise × noise part b/(R(R − 1)) and the rest a/R, so
    a/R + b/(R(R − 1)) = V where V > 0. Where V ≤ 0 (signal and noise both tiny beside the spread of the estimate,
    where `sum_terms` falls back to the jackknife) the Gaussian moments of `variance_terms` instead."""
    R, K, N = X.shape
    wk = np.broadcast_to(w, (K, N))
    per, lo = pixel_terms(X, wk)
    u, q = grouped(per, C), pair_squares([X], [1.0], wk, C)
    v = group_variances(u, grouped(lo, C), q, R)
    V, noise = v.sum(axis=1), noise_part(u, v, q, R)
    a, b = R * (V - noise), R * (R - 1.0) * noise
    if np.all(V > 0):
        return a, b
    ga, gb = _gaussian_terms(X, w, C)
    return np.where(V > 0, a, ga), np.where(V > 0, b, gb)


def _var(a, b, R: int):
    return a / R + b / (R * (R - 1.0))


def _predict_ustat(u: UStat, ab: tuple[np.ndarray, np.ndarray], R: int) -> UStat:
    """u as it would be from R replicates: the same estimate, SE √(a/R + b/(R(R−1))) from the variance terms
    ab = (a, b), df × (R − 1)/(R0 − 1). For F (P, P) with P > 1 (a jackknife over rounds): the R0 leave-one-outs
    rescaled so that their jackknife variance, taken with R replicates, is u's scaled by the predicted variance
    ratio (`_rescale`; no R-row array: R reaches MAX_PREDICT)."""
    R0, (a, b) = u.replicates, ab
    if u.est.ndim == 1 or u.est.shape == (1, 1):
        se = np.sqrt(np.maximum(_var(a, b, R), 0.0)).reshape(u.est.shape)
        noise = None if u.noise is None else (np.asarray(b, dtype=np.float64) / (R * (R - 1.0))).reshape(u.est.shape)
        return UStat(u.est, se, np.empty((0,) + u.est.shape), R, u.dof * (R - 1.0) / (R0 - 1.0), noise=noise)
    return _rescale(u, _se_ratio(ab, R0, R), R)


def _rescale(u: UStat, ratio: np.ndarray, R: int) -> UStat:
    """u (from its R0 replicates) with its SE (and a vector θ's leave-one-outs) scaled by `ratio` (P,), the
    predicted SE ratio of each parameter at R replicates, and df × (R − 1)/(R0 − 1). `crlb_term` takes the
    jackknife as (R − 1)/R Σ (loo − mean)² over the rows given with R = u.replicates, so the R0 deviations are
    scaled to carry the variance of R."""
    R0 = u.replicates
    df = u.dof * (R - 1.0) / (R0 - 1.0)
    c2 = np.sqrt(np.outer(ratio, ratio)) if u.est.ndim == 2 else ratio
    if not u.loo.size:
        return UStat(u.est, u.se * c2, u.loo, R, df)
    dev = u.loo - u.loo.mean(axis=0)
    s = np.sqrt(c2 * c2 * (R0 - 1.0) / R0 * R / (R - 1.0))
    return UStat(u.est, u.se * c2, u.est + s * dev, R, df)


def _se_ratio(ab: tuple[np.ndarray, np.ndarray], R0: int, R: int) -> np.ndarray:
    """√(Var(R)/Var(R0)) per parameter under the planning model."""
    a, b = ab
    v0 = _var(a, b, R0)
    return np.sqrt(np.divide(_var(a, b, R), v0, out=np.ones_like(a), where=v0 > 0))


def rose(raw: Raw) -> bool:
    """Whether the look of `raw` showed F rising at some FD halving (`settled_from` > 0: an edge)."""
    return raw.sf is not None and settled_from(raw.sf) > 0


@dataclass(frozen=True)
class Window:
    """The FD stages a fresh look renders: the pilot's stages `start` … `start + halvings` (steps ξ0/2^start …),
    halved at the look by the service's rule (`fd_step`) at most `halvings` times."""

    start: int
    halvings: int


@dataclass(frozen=True)
class Fit:
    """The planning model of one look at one θ* for one noise model: its Raw and the variance terms (a, b) of
    λ (per Δ) and of F (per stage and variant, per parameter); edge: this look or an earlier one at θ* showed F
    rising at some halving (`settled_from`)."""

    raw: Raw
    lam: tuple | None
    stages: list[dict[str, tuple]]
    edge: bool = False

    @classmethod
    def of(cls, raw: Raw, edge: bool = False) -> Fit:
        """The variance terms of `raw` (`variance_terms`); `edge`: an earlier look at θ* showed F rising (a look that
        starts past the rise does not see it, and F may still creep up past its finest step)."""
        lam = variance_terms(raw.D, raw.w, raw.group) if raw.D is not None else None
        return cls(raw, lam, [{name: variance_terms(J, raw.w, raw.group) for name, J in stage.rounds.items()}
                              for stage in raw.stages], edge or rose(raw))

    def windows(self, most: int | None = None) -> list[Window]:
        """The windows a look may use: starting at any stage from the first the pilot did not show biased low
        (`settled_from`), with at least one halving (one stage alone has no step check, so its lower end would not be a
        confidence limit). Where the pilot or an earlier look showed F rising at some halving (`edge`: the step smooths
        the derivative of an edge) and `most` is given, a window halves on up to the service's `most` halvings of the
        first step: F may still creep up (F(ξ/2)/F(ξ) ≈ 1.05 per halving in line of sight) where the pilot could not
        tell, and a window cut short there fails for good; a look stops halving where its own check passes, so the finer
        stages cost only where needed. Where no halving rose (L(θ) smooth at the first step), any window of the pilot's
        stages: there a look that halves past an unresolved check only adds FD noise (4× per halving in the variance of
        F; measured on the Π hallway beyond the corner: 3 of 34 points met ±25 % against 18)."""
        n, first = len(self.raw.stages), settled_from(self.raw.sf)
        if not self.edge or most is None:  # no halving shown to raise F: any window the pilot's stages allow
            return [Window(s, h) for s in range(first, n - 1) for h in range(1, n - s)] + self._finer(most)
        return [Window(s, max(n - 1, most) - s) for s in range(first, n - 1)]

    def _finer(self, most: int | None) -> list[Window]:
        """One-halving windows past the pilot's finest stage, their finest stage down to `most`, where the pilot's
        step settled (`StepFisher.steady`, scalar θ) but its finest stage's one-sided F lie beyond their noise from
        the central one (`fd_step.one_sided_gap`): the ends take those one-sided F, so that gap (the step's bias
        where L(θ) bends: the Π hallway just past the corner, ±24 % at 1.5 cm) sets the width, and more sets at the
        pilot's steps never narrow it; a finer step does (`_continued` predicts it)."""
        sf = self.raw.sf
        if most is None or sf is None or not sf.checked or not sf.steady or one_sided_gap(sf, sf.level) == 0:
            return []
        return [Window(s, 1) for s in range(len(sf.stats) - 1, most)]

    def _continued(self, last: int) -> tuple[list, list, list, list]:
        """The pilot's (stats, variance terms, halvings, steps) continued to stage `last` past its finest one n − 1
        (unchanged where last ≤ n − 1), scalar θ. Stage n − 1 + m is predicted from the finest: its central F the same
        (the pilot's step settled), each one-sided F's gap to it halved per halving (its bias ∝ ξ), and the variance
        of the FD rounds' noise ×γ per halving, so the signal × noise term a ×γ^m and the noise × noise term b ×γ^2m.
        γ is the pilot's own last halving's √(b(ξ/2)/b(ξ)) of the central F, within [1, 4]: 4 where ΔL's noise does
        not cancel between θ ± ξ (J = ΔL/ξ: `Halving.hopeless`), 1 where it cancels as a smooth noise does; measured
        on the Π hallway past the corner at 384 spp, b ×5–12 per halving from 4 sets (γ 2.3–3.5), ×6.6–6.8 from 32
        and 96 (γ ≈ 2.6). Each new halving at ratio 1,
        its contrast's SE the pilot's last one scaled like the finer stage's SE, its extrapolation the central F with
        that SE."""
        sf, terms = self.raw.sf, self.stages
        n, R0 = len(sf.stats), sf.final.replicates
        stats, terms, halvings, steps = list(sf.stats), list(terms), list(sf.halvings), list(sf.steps)
        finest, h0 = sf.stats[-1], sf.halvings[-1]  # (`_finer`: the step was checked)
        c = finest["central"]
        se0 = float(c.se[0, 0])
        b_fine, b_coarse = float(self.stages[n - 1]["central"][1][0]), float(self.stages[n - 2]["central"][1][0])
        gamma = min(max(math.sqrt(b_fine / b_coarse), 1.0), 4.0) if b_fine > 0 and b_coarse > 0 else 4.0
        for m in range(1, last - n + 2):
            ab = {name: (a * gamma**m, b * gamma ** (2 * m)) for name, (a, b) in self.stages[n - 1].items()}
            stage = {}
            for name, u in finest.items():
                est = c.est + (u.est - c.est) / 2.0**m
                stage[name] = _predict_ustat(replace(u, est=est), ab[name], R0)
            grow = float(stage["central"].se[0, 0]) / se0 if se0 > 0 else 2.0**m
            contrasts = {key: (-sf.step_tol * fa, se * grow, df, fa) for key, (_, se, df, fa) in h0.contrasts.items()}
            extra = {name: replace(u, est=c.est, se=u.se * grow, loo=u.loo[:0], terms=None)
                     for name, u in h0.extrapolated.items()}
            halvings.append(Halving(steps[-1], 1.0, h0.se * grow, True, False, contrasts, extra))
            stats.append(stage)
            terms.append(ab)
            steps.append(steps[-1] / 2.0)
        return stats, terms, halvings, steps

    def step_fisher(self, R: int, level: float, window: Window) -> StepFisher:
        """The StepFisher a look at R fresh sets is predicted to give over `window`: each stage's F with its SE
        at R (`_predict_ustat`), each halving's paired contrasts and extrapolations with their SEs scaled like
        the finer stage's, and the look stopping at the first halving predicted converged (the service's rule),
        so a check that stays unresolved is predicted as such (its lower end labelled, the target unmet).
        Estimates the pilot cannot tell apart are predicted equal (scalar θ): a stage or variant whose F is within
        the pilot's t·SE of the window's first central F (the least noisy) is predicted at that F, and a halving not
        shown to change F is predicted at ratio 1 — otherwise noise held fixed (a one-sided F 2× the central one
        at a small pilot) would predict that no number of sets suffices — or, where the pilot saw F rise at an
        earlier halving (an edge), at the pilot's own ratio clipped to [1, 1 + tol/2]: past an edge F creeps up by a
        few per cent per halving (Π hallway in line of sight: 1.03–1.06), and a plan at ratio 1 asks for too few
        sets to show it below 1 + tol. Plans only choose R and the window; the
        looks' limits do not depend on them."""
        sf, R0 = self.raw.sf, self.raw.sf.final.replicates
        n = len(sf.stats)
        t0 = one_sided_t(level, R0 - 1.0, 1.0)
        edge = self.edge  # the pilot (or an earlier look) saw F rise at some halving
        # a window past the pilot's finest stage (`_finer`) continues its stages by prediction
        pilot_stats, terms, pilot_halvings, pilot_steps = self._continued(window.start + window.halvings) if (
            not edge and window.start + window.halvings >= n) else (sf.stats, self.stages, sf.halvings, sf.steps)
        ref = pilot_stats[window.start].get("central")
        scalar = ref is not None and ref.est.shape == (1, 1)

        def stage(k: int) -> dict[str, UStat]:
            out = {}
            for name, u in pilot_stats[k].items():  # (a predicted stage's one-sided gap is its bias, not noise)
                if scalar and k < n and abs(float(u.est[0, 0] - ref.est[0, 0])) <= t0 * math.hypot(
                        float(u.se[0, 0]), float(ref.se[0, 0])):
                    u = replace(u, est=ref.est)
                out[name] = _predict_ustat(u, terms[k][name], R)
            return out

        stats, halvings = [], []
        stop = min(window.start + window.halvings, len(pilot_stats) - 1)  # no prediction beyond those stages
        for k in range(window.start, stop + 1):
            stats.append(stage(k))
            if k == stop:
                break
            h = pilot_halvings[k]  # the pilot's (or the predicted) comparison of stages k and k + 1
            ratio = {name: _se_ratio(ab, R0, R) for name, ab in terms[k + 1].items()}
            converged, rising, falling, dropping = True, False, False, False
            tol = sf.step_tol
            for (name, j), (est, se, df, fa) in h.contrasts.items():
                if abs(est + tol * fa) <= t0 * se:  # F(ξ/2) − F(ξ) within the noise: predicted equal or, past an
                    # edge, at the pilot's ratio within [1, 1 + tol/2] (F creeps up per halving there)
                    r = min(max(est / fa + 1.0 + tol, 1.0), 1.0 + tol / 2) if edge and fa > 0 else 1.0
                    est = (r - 1.0 - tol) * fa
                se_r = se * float(ratio[name][j]) if name in ratio else se
                t = one_sided_t(level, df * (R - 1.0) / (R0 - 1.0), se_r)
                converged &= bool(est + (t + Z_POWER) * se_r <= 0) and fa > 0
                rising |= bool(est - t * se_r > 0)
                # F(ξ/2) − F(ξ)/(1 + tol) from the same contrast (its SE taken as the contrast's)
                below = est + (1.0 + tol - 1.0 / (1.0 + tol)) * fa
                falling |= bool(below + t * se_r < 0) and fa > 0
                dropping |= bool(below < 0) and fa > 0
            extra = {name: _rescale(u, ratio[name], R) for name, u in h.extrapolated.items() if name in ratio}
            if scalar and not h.rising:  # the stages agree within the noise: the extrapolation adds nothing
                extra = {name: replace(u, est=ref.est) for name, u in extra.items()}
            halvings.append(Halving(h.step, h.ratio, h.se * float(np.max(ratio.get("central", [1.0]))), converged,
                                    rising, {}, extra, falling, dropping))
            if halvings[-1].stops:  # where the look's own halving stops
                stats.append(stage(k + 1))
                break
        steps = pilot_steps[window.start:window.start + len(stats)]
        return StepFisher(stats, steps, halvings, step_tol=sf.step_tol, spp=sf.spp, level=level)

    def bounds(self, kinds: Sequence[str], R: int, level: float,
               window: Window | None = None) -> dict[str, tuple[float, float, float, str]]:
        """{kind: (lower, point, upper, lower_note, upper_note)} log10 ends predicted at R fresh replicate sets
        through the interval code itself (`hcr_interval`, `crlb_term`), the FD stages those of `window` (None: the
        first window the pilot allows, as many halvings as it made)."""
        raw = self.raw
        window = window or (self.windows() or [None])[0]
        if window is None:  # one stage (or AD): no step check to predict, every stage as it is
            pred = StepFisher([{name: _predict_ustat(u, self.stages[k][name], R) for name, u in st.items()}
                               for k, st in enumerate(raw.sf.stats)], raw.sf.steps, raw.sf.halvings,
                              step_tol=raw.sf.step_tol, spp=raw.sf.spp, level=level)
        else:
            pred = self.step_fisher(R, level, window)
        out = {}
        if "crlb" in kinds:
            t = crlb_term(pred, level, smoothed=raw.smoothed)
            out["crlb"] = (t.lower, t.point, t.upper, t.lower_note or t.zero_note, t.upper_note)
        if "hcr" in kinds and self.lam is not None:
            # a look's λ̂ ≤ 0 says nothing about λ (that Δ would never resolve): plan with the local quadratic
            # ΔᵀF̂Δ there instead (a guess for the plan only; the looks' limits do not depend on it)
            D = raw.deltas.reshape(len(raw.deltas), -1)
            quad = np.einsum("kp,pq,kq->k", D, raw.sf.final.est, D)
            lam = _predict_ustat(raw.lam, self.lam, R)
            lam = replace(lam, est=np.where(raw.lam.est > 0, raw.lam.est, quad))
            iv = hcr_interval(lam, raw.deltas, pred, level, raw.lower, raw.upper)
            out["hcr"] = (iv.lower, iv.point, iv.upper, iv.lower_note, iv.upper_note)
        return out


@dataclass(frozen=True)
class _Ends:
    lower: float
    point: float
    upper: float
    lower_note: str = ""
    upper_note: str = ""


def predicted_reached(fits: Sequence[Fit], kinds: Sequence[str], R: int, level: float,
                      window: Window | None = None) -> float:
    """The worst precision reached predicted at R fresh sets over the noise models' fits."""
    return max((reached(_Ends(*e)) for f in fits for e in f.bounds(kinds, R, level, window).values()),
               default=math.inf)


def ladder(cap: int, above: int = 0, least: int = 4) -> list[int]:
    """Set counts 3, 4, 6, 8, 12, 16, 24, … in (above, cap], from `least` on: a fresh look has at least 4 sets, so
    its standard errors are the unbiased ones (`ustat`; the jackknife of 3 is conservative)."""
    out, k = [], 0
    while 3 * 2**k <= cap:
        out += [n for n in (3 * 2**k, 4 * 2**k) if max(above + 1, least) <= n <= cap]
        k += 1
    return out


def spending(alpha: float, K: int) -> list[float]:
    """α spent per look over K looks: the pilot α/20, fresh look k (1 … K − 1) 0.95·α·4^−(k−1)/Σ_j 4^−(j−1) (K = 2:
    0.95 α; K = 3: 0.76 α and 0.19 α, i.e. 0.8 and 0.2 of 0.95 α; each later look a quarter of the one before). They
    sum to α (module docstring: the pathwise proof). K = 1, the pilot alone (no fresh look is ever made): all of α."""
    if K == 1:
        return [alpha]
    shares = [4.0 ** -(k - 1) for k in range(1, K)]
    return [alpha / 20.0] + [0.95 * alpha * w / sum(shares) for w in shares]


@dataclass(frozen=True)
class Plan:
    """A plan for one θ*: `sets` fresh replicate sets (None: none predicted to meet the target) over the FD
    `window` (None: the pilot's stages as they are) testing the Δ of `tested` (a mask over the pilot's tested Δ;
    None: all), and the precision predicted there (at the largest count considered when none meets)."""

    sets: int | None
    window: Window | None
    predicted: float
    tested: np.ndarray | None = None


def tested_deltas(raws: Sequence[Raw], target: float, level: float) -> np.ndarray | None:
    """The pilot's tested Δ a look needs (a mask; None without an HCR): those whose term f(λ_L) = ‖Δ‖²/expm1(λ_L),
    λ_L the pilot's one-sided lower limit at `level`, reaches the pilot's HCR point / (1 + target)² (λ_L ≤ 0:
    f = ∞, kept), for any noise model, and at least the largest. The others were shown far below the sup. A look
    that tests fewer Δ still gives a lower end that is a lower confidence limit of the HCR (a sup over fewer Δ is
    no larger); its upper end bounds the HCR over the Δ it tested and Δ → 0, as every upper end bounds the HCR
    over its tested set."""
    keep = None
    for raw in raws:
        if raw.lam is None:
            return None
        t = np.nan_to_num(t_quantile(level, raw.lam.dof), nan=np.inf)
        lam_l = raw.lam.est - t * np.nan_to_num(raw.lam.se)
        D = raw.deltas.reshape(len(raw.deltas), -1)
        log_f = np.full(len(D), np.inf)  # log10 f(λ_L), in the log domain (λ_L may be in the thousands)
        ok = lam_l > 0
        log_f[ok] = (np.log((D[ok] * D[ok]).sum(axis=1)) - log_expm1(lam_l[ok])) / LN10
        iv = hcr_interval(raw.lam, raw.deltas, raw.sf, level, raw.lower, raw.upper)
        mask = log_f >= iv.point - 2.0 * math.log10(1.0 + target)
        if len(log_f):
            mask[int(np.argmax(log_f))] = True  # at least the largest term: a look always tests some Δ ≠ 0
        keep = mask if keep is None else keep | mask
    return keep


def plan(raws: Sequence[Raw], kinds: Sequence[str], target: float, level: float, cap: int,
         set_cost: Callable[[int, int | None], int] | None = None, subset: bool = False,
         most: int | None = None, edge: bool = False) -> Plan:
    """The cheapest (ladder count up to cap, FD window) predicted to meet `target` with a margin (to reach
    AIM × target): per window the smallest count that reaches it, then the least renders, count × set_cost(stages
    in the window, Δ tested) (None: the count alone). Coarser windows have less FD noise but may not be shown
    converged; with `subset`, the look tests only the Δ `tested_deltas` keeps; a window may halve up to `most` times
    (`Fit.windows`; `edge`: an earlier look showed F rising, `Fit.of`). Window and Δ are functions of the looks
    before (the coverage proof in the module docstring needs nothing more)."""
    tested = tested_deltas(raws, target, level) if subset and "hcr" in kinds else None
    fits = [Fit.of(r if tested is None else r.subset(tested), edge) for r in raws]
    n_tested = None if tested is None else int(tested.sum())
    steps = ladder(cap)
    windows = fits[0].windows(most) or [None]
    best, fallback = None, Plan(None, windows[-1], math.inf, tested)
    for win in windows:
        top = predicted_reached(fits, kinds, steps[-1], level, win) if steps else math.inf
        if top < fallback.predicted:
            fallback = Plan(None, win, top, tested)
        if top > AIM * target:  # not even at the cap (the prediction falls with R): no scan
            continue
        for R in steps:
            got = predicted_reached(fits, kinds, R, level, win)
            if got <= AIM * target:
                stages = win.halvings + 1 if win else len(raws[0].stages)
                cost = R * (set_cost(stages, n_tested) if set_cost else 1)
                if best is None or cost < best[0]:
                    best = (cost, Plan(R, win, got, tested))
                break
    return best[1] if best else fallback


# -- the looks --------------------------------------------------------------------------------------------
def _worst_case(cost: SetCost, new: dict, now: dict, ids: list[int], grid_done: int) -> int:
    """Worst-case renders of a look made by the θ* `ids` alone (`SetCost.look` over their entries of `new`)."""
    return cost.look({i: new[i] for i in ids}, max(0, max(now[i] for i in ids) - grid_done))


@dataclass
class _State:
    points: dict = field(default_factory=dict)  # (noise, θ index) → BoundPoint
    raws: dict = field(default_factory=dict)  # (noise, θ index) → Raw
    looks: dict = field(default_factory=dict)  # θ index → looks made
    fresh: dict = field(default_factory=dict)  # θ index → (first set, fresh sets) of the reported look ((0, 0): pilot)
    level: dict = field(default_factory=dict)  # θ index → the one-sided level of the reported look's ends
    stages: dict = field(default_factory=dict)  # θ index → FD stages of its last look
    start: dict = field(default_factory=dict)  # θ index → its last look's first FD stage (0: the first step's)
    edge: dict = field(default_factory=dict)  # θ index → some look showed F rising at a halving (`rose`)
    own: dict = field(default_factory=dict)  # θ index → its own renders over every look (`SetCost.own`)
    notes: dict = field(default_factory=dict)


def refine(look: Callable, T: int, noises: Sequence[int], R0: int, target, budget: int | None, K: int,
           alpha: float, cost: SetCost, spp: int, bank) -> list:
    """The stopping rule of the module docstring over T θ*, each with its target (one float, or (T,)).
    look(index array, R, first, level, keep, window, tested) gives the BoundPoints (noise-major) of those θ* from
    replicate sets first … first + R − 1 at `level`, their FD stages those of `window` (None: the service's own)
    and their tested Δ those of `tested` ({position: mask over the pilot's Δ}; None: all), filling keep {(noise,
    position): Raw}. The call is charged by request (`bank.ledger()`); `spp` turns SetCost's renders into
    pixel-samples; `budget` None: the default ceiling (`ceiling` of the pilot's pixel-samples). Returns the
    BoundPoints (noise-major), each with its `precision` record."""
    with bank.ledger() as spend:
        return _refine(look, T, noises, R0, target, budget, K, alpha, cost, spp, spend)


def _refine(look: Callable, T: int, noises: Sequence[int], R0: int, target, budget: int | None, K: int,
            alpha: float, cost: SetCost, spp: int, spend) -> list:
    levels = [1.0 - a for a in spending(alpha, K)]
    # what plans and predictions aim at: the first fresh look's level (K = 1: the level of a run that has one)
    level = levels[1] if K > 1 else 1.0 - spending(alpha, 2)[1]
    goal = np.broadcast_to(np.asarray(target, dtype=np.float64).reshape(-1), (T,))
    st = _State()

    def run(idx: np.ndarray, R: int, first: int, k: int, window: Window | None = None,
            tested: dict | None = None) -> None:
        keep: dict = {}
        pts = look(idx, R, first, levels[k], keep, window,
                   None if tested is None else {n: tested[int(i)] for n, i in enumerate(idx)})
        for m, j in enumerate(noises):
            for n, i in enumerate(idx):
                st.points[j, int(i)] = pts[m * len(idx) + n]
                st.raws[j, int(i)] = keep[j, n]
        for i in idx:
            st.looks[int(i)], st.fresh[int(i)], st.level[int(i)] = k + 1, ((first, R) if first else (0, 0)), levels[k]
            st.stages[int(i)] = max(len(st.raws[j, int(i)].stages) for j in noises)
            st.own[int(i)] = st.own.get(int(i), 0) + R * cost.own(
                int(i), st.stages[int(i)], None if tested is None or tested.get(int(i)) is None
                else int(tested[int(i)].sum()))
            st.start[int(i)] = window.start if window else 0
            st.edge[int(i)] = st.edge.get(int(i), False) or any(rose(st.raws[j, int(i)]) for j in noises)

    def kinds(i: int) -> list[str]:
        return [k for k in KINDS if k in st.points[noises[0], i].bounds]

    def worst(i: int) -> float:
        return max(reached(st.points[j, i].bounds[k]) for j in noises for k in kinds(i))

    def planned(i: int, at: float = level) -> Plan:
        # fewer tested Δ only where no Barankin or HCR-hat is asked for (they keep the whole grid); the paper's
        # hcr_neff, which comes with "hcr", is a sup like the HCR's and lives where it does
        subset = set(st.points[noises[0], i].bounds) <= {*KINDS, "hcr_neff"}
        s = st.start[i]  # the plan's windows count from its latest look's first stage, the looks' from the first step
        pl = plan([st.raws[j, i] for j in noises], kinds(i), goal[i], at, MAX_PREDICT,
                  lambda stages, tested: cost.one(i, stages, tested), subset, cost.stages - 1 - s, st.edge[i])
        return replace(pl, window=Window(pl.window.start + s, pl.window.halvings)) if s and pl.window else pl

    def n_tested(pl: Plan) -> int | None:
        return None if pl.tested is None else int(pl.tested.sum())

    run(np.arange(T), R0, 0, 0)
    pixels = st.raws[noises[0], 0].pixels
    per_sample = spp * pixels

    def spent() -> int:
        return spend.pixel_samples

    cap = ceiling(spent()) if budget is None else budget
    cap_text = "the budget" if budget is not None else (
        f"the default ceiling of {cap:.3g} pixel-samples, {CEILING} × the pilot's (a budget raises it)")
    active = [i for i in range(T) if worst(i) > goal[i]]
    for i in range(T):
        st.notes[i] = "met at the pilot" if i not in active else "" if K > 1 else "not met: the pilot alone (looks 1)"
    if K == 1:
        active = []
    # plan from the pilot alone; the budget caps each θ*'s first look at what it could spend alone (with its planned
    # window and Δ); the looks below then admit the θ* cheapest first while the whole look fits
    plans = {i: planned(i) for i in active}
    star: dict[int, tuple[int, Plan]] = {}
    for i in active:
        pl = plans[i]
        stages = pl.window.halvings + 1 if pl.window else cost.stages
        r_max = max((R for R in ladder(MAX_SETS) if spent() + cost.look(
            {i: (0, R, 0, stages, n_tested(pl))}, R) * per_sample <= cap), default=0)
        if pl.sets is None and r_max:  # the pilot's FD stages or λ̂ may disagree by noise alone: look anyway
            star[i] = (min(r_max, EXPLORE * R0), pl)
            st.notes[i] = (f"the pilot predicts no number of sets meets the target ({pl.predicted:.3g} at "
                           f"{MAX_PREDICT} sets, holding its estimates fixed): an exploratory look at {star[i][0]} "
                           "fresh sets")
        elif pl.sets is None or not r_max:
            st.notes[i] = f"not met: {cap_text} allows no fresh look"
        else:
            star[i] = (min(pl.sets, r_max), pl)
    grid_done = 0  # test-grid sets rendered after the pilot's (a prefix: every look starts past it)
    first = {i: R0 for i in star}  # the next fresh set of each θ*
    for k in range(1, K):
        waiting = [i for i in star if worst(i) > goal[i]]
        for i in waiting if k > 1 else []:  # re-planned from its latest look, at this look's level
            pl, (sets_before, before) = planned(i, levels[k]), star[i]
            if before.tested is not None and pl.tested is not None:  # a mask over the latest look's (tested) Δ
                full = before.tested.copy()
                full[np.flatnonzero(full)] = pl.tested
                pl = replace(pl, tested=full)
            star[i] = (min(pl.sets, MAX_SETS), pl) if pl.sets is not None else (2 * sets_before, pl)
            st.notes[i] = "" if pl.sets is not None else "(exploratory)"
        # waves: the θ* whose look fits what is left, cheapest first; the others wait for the next wave, against what
        # the looks before actually spent (a look stops halving where its check passes, so most spend far less than
        # their worst case); left out for good when none fits. Exploratory looks come only after every planned one
        # has been admitted or left out: a planned look is predicted to meet its target, an exploratory one is not
        while waiting:
            for i in waiting:  # past every set rendered so far (at any θ), so independent of what admits the look
                first[i] = max(first[i], R0 + grid_done)
            sets = {i: star[i][0] for i in waiting}  # look k's own sets, disjoint from earlier ones
            now = {i: first[i] - R0 + sets[i] for i in waiting}  # the test-grid sets after the pilot's it needs
            stages = {i: star[i][1].window.halvings + 1 if star[i][1].window else cost.stages for i in waiting}
            new = {i: (0, sets[i], 0, stages[i], n_tested(star[i][1])) for i in waiting}
            waiting.sort(key=lambda i: (star[i][1].sets is None, _worst_case(cost, new, now, [i], grid_done), i))
            todo = []
            sure = [i for i in waiting if star[i][1].sets is not None]  # planned: predicted to meet the target
            for i in waiting:
                if star[i][1].sets is None and any(j not in todo for j in sure):
                    continue  # exploratory looks only once every planned one is admitted or left out
                if _worst_case(cost, new, now, [*todo, i], grid_done) * per_sample <= cap - spent():
                    todo.append(i)
            waiting = [i for i in waiting if i not in todo]
            if not todo:  # each alone exceeds what is left: the planned ones are out, then the exploratory ones
                out = [i for i in waiting if i in sure] or waiting
                for i in out:
                    st.notes[i] = (f"not met: its look {k} (worst case "
                                   f"{_worst_case(cost, new, now, [i], grid_done) * per_sample} pixel-samples) "
                                   f"would exceed {cap_text} ({cap - spent()} left)")
                    del star[i]
                waiting = [i for i in waiting if i not in out]
                continue
            groups = {(first[i], sets[i], star[i][1].window) for i in todo}
            for f, R, win in sorted(groups, key=lambda g: (g[0], g[1], repr(g[2]))):
                idx = np.array([i for i in todo if (first[i], sets[i], star[i][1].window) == (f, R, win)])
                run(idx, R, f, k, win, {int(i): star[int(i)][1].tested for i in idx})
            grid_done = max(grid_done, max(now[i] for i in todo))  # the admitted θ* only
            for i in todo:
                first[i] += sets[i]
                st.notes[i] = (f"met at look {k}" if worst(i) <= goal[i] else f"not met after look {k}") + (
                    " (exploratory)" if "exploratory" in st.notes[i] else "")
    total = spent()
    extra, extra_px = {}, {}
    for i in range(T):  # where unmet: predicted from the reported look's own data, the sets of one more fresh look
        extra[i] = extra_px[i] = 0.0
        if worst(i) > goal[i]:  # (a fresh look's tested Δ may be a subset already: the plan's mask is over them)
            pl = plans[i] if st.looks[i] == 1 and i in plans else planned(i)  # the pilot's plan, made once
            extra[i] = math.inf if pl.sets is None else float(pl.sets)
            gap = max(  # does the step's bias set the width (the one-sided F the ends take, guarding a kink)?
                (one_sided_gap(st.raws[j, i].sf, st.level[i]) for j in noises if st.raws[j, i].sf is not None),
                default=0.0)
            if gap > 0:
                st.notes[i] += (f"; at its finest FD step the one-sided F lie up to ±{100 * gap:.2g} % from the "
                                "central one, beyond their noise (the step's bias, which the ends take to guard a "
                                "kink): a finer step narrows them, more sets at that step do not")
            stages = pl.window.halvings + 1 if pl.window else st.stages[i]
            extra_px[i] = extra[i] * cost.one(i, stages, n_tested(pl)) * per_sample
    out = []
    for j in noises:
        for i in range(T):
            pt = st.points[j, i]
            pt.precision = Precision(
                float(goal[i]), {k: reached(pt.bounds[k]) for k in kinds(i)}, bool(worst(i) <= goal[i]),
                st.looks[i], R0, st.fresh[i][1], st.level[i], int(total), extra[i], extra_px[i], st.notes[i],
                budget=int(cap), first_set=st.fresh[i][0], own_pixel_samples=int(st.own[i] * per_sample),
                rendered=int(spend.rendered))
            out.append(pt)
    return out
