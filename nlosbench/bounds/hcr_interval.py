"""The HCR at θ* as a confidence interval that includes its Δ → 0 term, from replicated Monte Carlo renders.

The HCR on the MSE is a sup over every Δ ≠ 0 of f(Δ) = ‖Δ‖² / (exp λ(Δ) − 1); as Δ → 0, f tends to 1/F for
a scalar θ. For a vector θ the Δ → 0 limit is 1/λ_min(F), weaker than the CRLB trace(F⁻¹); both the sup and
trace(F⁻¹) bound the MSE of an unbiased estimator, so the HCR here is the larger of the two, and it never
sits below the CRLB. From renders the limit cannot be reached by refining Δ: with independent seeds λ̃ keeps a
C/N floor, with common random numbers visibility jumps make λ̃ ∝ |Δ|; so the limit enters as its own term,
the CRLB term, from an unbiased Fisher information at an FD step shown converged (`fd_step`).

Inputs are U-statistics over R independent replicates (`ustat`): λ̂(Δ_k) from the replicate differences
L̃_r(θ*+Δ_k) − L̃_r(θ*) (each replicate may use common random numbers across θ), and F̂ from R FD
Jacobians (a `StepFisher`: every FD stage tried), each with its SE and degrees of freedom. With one-sided
Student-t limits at level 1 − α (score-type where the noise × noise part of the SE is known, R ≥ 4: `ustat.limits`):

  lower end (the bound to quote): max over Δ of f(λ_U(Δ)) and the CRLB term's lower end (F's largest upper
      limit over the FD stages and variants, `fd_step.lower_candidates`), every limit at one per-term level p
      from a joint critical value (below). Where that end is set by the CRLB term and the FD step did not
      converge, it is labelled "not a confidence limit" (`lower_note`);
  upper end: the same with the lower limits λ_L and the CRLB term's upper end, each at α (one term suffices): the HCR
      over the tested Δ and Δ → 0 is f at one fixed (unknown) term k*, the one whose true f is largest, and max_k
      f(λ_L(Δ_k)) ≥ f(λ_L(Δ_k*)) ≥ f(λ(Δ_k*)) unless λ_L(Δ_k*) > λ(Δ_k*), an event of probability ≤ α; so P(upper end ≥
      HCR over the tested terms) ≥ 1 − α. If any tested Δ is unresolved (λ_L ≤ 0, f(λ_L) = +∞ at that Δ), the upper end
      is open (+inf). Where the CRLB term's upper end is not a confidence limit (F still falls at the last FD halving)
      neither is this end (`upper_note`). It bounds the HCR over the tested Δ and Δ → 0 (a sup over more Δ may be
      higher: the tested set is a grid);
  point: the same with the estimates themselves;
  point_loo: the point without each replicate (from the U-statistics' leave-one-outs), for jackknifes of
      functions of several bounds over the same replicate sets (e.g. a ratio of two models' bounds).
The lower end's level. The end is too high only if some term's limit is: λ_U(Δ_k) < λ(Δ_k) at a Δ_k whose
f(λ_U) exceeds the sup S, or every candidate F below F* (the CRLB term's lower end covers if the candidate c*
whose target is at least F* covers: the step check's assumption). So the terms need their limits *jointly*, but
only those that could exceed S. A Berger–Boos argument spends α₁ = `SCREEN`·α on finding them:
  1. on the event G that every λ(Δ_k) lies within its two-sided limits at level 1 − α₁/(2K + 1) and F* below c*'s
     upper limit (K tested Δ with an SE; P(G) ≥ 1 − α₁, Bonferroni), S ≥ B, the largest term at those limits;
  2. a term at Δ_k then exceeds S only if its estimate falls g_k = max(0, (λ_lo(Δ_k) − f⁻¹(B))/SE) SEs further than
     its own limit allows (λ_lo the screening lower limit, f⁻¹(B) = log1p(‖Δ‖²/B): the λ at which f equals B), and
     the least favourable truth in G puts every gap there;
  3. the critical value q (normal scale) is the smallest with P(max(max_k (Z_k − g_k), Z_c) > q) ≤ α − α₁ for
     every candidate c (c* is unknown), Z the joint normal of the terms' standardised errors. Their correlations
     come from the per-pixel-group jackknife (`ustat.covariance`; terms at nearby Δ and the FD variants share their
     renders and are nearly one statistic: the offsets ±ξ *are* the first stage's one-sided differences), q from
     `DRAWS` Monte Carlo draws with a fixed seed; without correlations (a UStat without `terms`, a vector θ) the
     union bound Σ_k Q(q + g_k) + Q(q) = α − α₁ instead. Each term's limit is then Student-t at level p = Φ(q).
So P(lower end > S) ≤ α₁ + (α − α₁) = α (up to the normal approximation of each term, as for every end). A Δ
whose λ lies more than t₁ + `FAR` SEs above f⁻¹(B) drops out; where the sup is one term (or terms that move as one)
p = 1 − α + α₁. On spot_rgb (the CRLB term sets the sup, ±ξ move with it, the far Δ's λ ≈ 250 ± 40 are only 4–6 SEs
from reaching it and keep small gaps) p is 0.954 in the median seed and up to 0.975 in 5 % of them; over 2000 seeds
the lower end missed the exact HCR 3.3 % of the time, the CRLB term's own 3.6 %, where Bonferroni over every tested Δ
missed 0.55 % (1 in the first 1000).
Ends can cross (lower > upper) where limits of different terms disagree: flagged `ends-crossed`, and a verdict
against such an interval is undetermined.
With R < 3 there is no standard error: both ends are the point estimate, flagged `estimate_only`.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq
from scipy.special import ndtr, ndtri

from nlosbench.bounds.fd_step import StepFisher, crlb_term, lower_candidates, single
from nlosbench.bounds.hcr import LN10, log_expm1
from nlosbench.bounds.ustat import UStat, covariance, limits, t_quantile

#: the share of α that screens which terms could reach the sup (the module docstring's α₁ / α)
SCREEN = 0.05
#: Monte Carlo draws of the joint critical value (a fixed seed: the same statistics give the same ends), and the
#: most terms it takes (more: the union bound)
DRAWS, MOST_TERMS = 2**13, 256
#: a term this many SEs (its gap) from reaching the sup is left out of the joint critical value (P < 1e-15)
FAR = 8.0


@dataclass
class HCRInterval:
    """log10 ends of the HCR (units²) with the terms that set them ("Δ = 0.03", "Δ → 0", or "none").

    Returned by `hcr_interval`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    point : float
        log10 of the point estimate.
    lower : float
        log10 of the lower end (quote it): a one-sided lower confidence limit at `level`.
    upper : float
        log10 of the upper end (+inf: open).
    point_term, lower_term, upper_term : str
        The term that sets each (e.g. "Δ = +0.03", "Δ → 0", "unresolved Δ", "none").
    level : float
        The confidence level of each end.
    replicates : int
        R, the replicates the statistics come from.
    estimate_only : bool
        R < 3: no standard error, both ends are the point estimate.
    crlb : float
        log10 of the CRLB term alone (1/F̂ or trace F̂⁻¹), units².
    crlb_lower, crlb_upper : float
        Its ends (over every FD stage).
    unresolved : list, optional
        The Δ (rows of `deltas`) whose λ_L ≤ 0, which open the upper end.
    lower_note : str, optional
        Why the lower end is not a confidence limit ("" when it is).
    step_flags : tuple of str, optional
        The FD step's flags.
    upper_note : str, optional
        Why a finite upper end is not a confidence limit: the CRLB term's (its F still falls), whatever term sets
        the end (the true Δ → 0 term may exceed every other term's limit).
    point_loo : ndarray of shape (R,), optional
        log10 point estimate without replicate k (empty when R < 3).
    tested : int, optional
        The number of tested Δ inside the limits.
    term_level : float, optional
        The one-sided level p of each term's limit in the lower end (joint over the terms that could reach the sup:
        see the module docstring; NaN without standard errors).

    Examples
    --------
    Two replicates give an estimate without a standard error, and say so:

    >>> import numpy as np
    >>> lam = nb.bounds.UStat(np.array([0.25, 1.0]), np.full(2, np.nan), np.empty((0, 2)), 2)
    >>> F = nb.bounds.UStat(np.array([[1.0]]), np.array([[np.nan]]), np.empty((0, 1, 1)), 2)
    >>> iv = nb.bounds.hcr_interval(lam, np.array([0.5, 1.0]), F)
    >>> iv.flags, iv.lower == iv.point == iv.upper
    (('estimate-only',), True)
    """

    point: float
    lower: float
    upper: float
    point_term: str
    lower_term: str
    upper_term: str
    level: float
    replicates: int
    estimate_only: bool
    crlb: float
    crlb_lower: float
    crlb_upper: float
    unresolved: list = field(default_factory=list)
    lower_note: str = ""
    step_flags: tuple = ()
    upper_note: str = ""
    point_loo: np.ndarray = field(default_factory=lambda: np.empty(0), compare=False)
    tested: int = 0
    term_level: float = math.nan

    @property
    def flags(self) -> tuple[str, ...]:
        """Short tags: estimate-only, unresolved-delta, upper-unbounded, ends-crossed, then the FD step's."""
        out = []
        if self.estimate_only:
            out.append("estimate-only")
        if self.unresolved:
            out.append("unresolved-delta")
        if math.isinf(self.upper):
            out.append("upper-unbounded")
        if self.lower > self.upper:
            out.append("ends-crossed")
        return tuple(out) + tuple(self.step_flags)


def _log10_f(norm2: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """log10 of ‖Δ‖²/(exp λ − 1) for λ > 0 (−inf where λ ≤ 0: left out of a max)."""
    out = np.full(lam.shape, -np.inf)
    ok = lam > 0
    out[ok] = (np.log(norm2[ok]) - log_expm1(np.where(np.isfinite(lam[ok]), lam[ok], 1e300))) / LN10
    out[ok & ~np.isfinite(lam)] = -np.inf
    return out


def _pick(values: np.ndarray, names: list[str]) -> tuple[float, str]:
    if values.size == 0 or not np.any(values > -np.inf):
        return -math.inf, "none"
    k = int(np.argmax(values))
    return float(values[k]), names[k]


def lower_level(lam: UStat, valid: np.ndarray, norm2: np.ndarray, sf: StepFisher, level: float) -> float:
    """The one-sided level p of every term's limit in the lower end (the module docstring's screening and joint
    critical value): λ over K offsets (est, se, dof (K,), terms (R, K, M) or None), `valid` (K,) the offsets inside
    the limits, norm2 (K,) their ‖Δ‖² (units²), sf the CRLB term's FD stages."""
    alpha = 1.0 - level
    a1, a2 = SCREEN * alpha, (1.0 - SCREEN) * alpha
    ks = np.flatnonzero(valid & (np.nan_to_num(lam.se) > 0))  # an exact λ (SE 0) never misses
    se, est = lam.se[ks], lam.est[ks]
    l1 = 1.0 - a1 / (2 * ks.size + 1)
    t1 = np.nan_to_num(t_quantile(l1, lam.dof[ks]), nan=np.inf)
    everyone = lower_candidates(sf)
    scalar = all(u.est.shape == (1, 1) for u in everyone)  # a vector θ's trace(F⁻¹) has no per-pixel terms
    B = max([crlb_term(sf, l1).lower, *_log10_f(norm2[ks], est + t1 * se)])  # log10 of S's lower limit on G
    with np.errstate(invalid="ignore"):
        lam_b = np.logaddexp(0.0, np.log(norm2[ks]) - B * LN10)  # f(λ) = B: λ = log1p(‖Δ‖²/B)
        gaps = np.nan_to_num(np.maximum((est - t1 * se - lam_b) / se, 0.0), nan=0.0)
    near = gaps < FAR
    ks, gaps = ks[near], gaps[near]
    cands = [u for u in everyone if scalar and float(u.se[0, 0]) > 0]  # an exact F (SE 0) never misses
    joint = scalar and lam.terms is not None and all(
        u.terms is not None and (u.terms.shape[0], u.terms.shape[-1]) == (lam.terms.shape[0], lam.terms.shape[-1])
        for u in cands)
    if scalar and not cands and not ks.size:
        return level
    if not joint or ks.size + len(cands) > MOST_TERMS:  # the union bound Σ_k Q(q + g_k) + Q(q) = α₂
        def excess(q: float) -> float:
            return float(ndtr(-(q + gaps)).sum() + ndtr(-q) - a2)
        lo = float(ndtri(1.0 - a2))  # the CRLB term alone; every gap > 0 only lowers the sum
        return float(ndtr(lo if excess(lo) <= 0 else brentq(excess, lo, float(ndtri(1 - a2 / (ks.size + 1))) + 1.0)))
    T = np.concatenate([np.moveaxis(lam.terms[:, ks], 1, 0)] + [u.terms.reshape(1, u.terms.shape[0], -1)
                                                                 for u in cands])  # (J, R, M)
    w, V = np.linalg.eigh(_correlation(covariance(T)))
    Z = np.einsum("ij,jd->id", V * np.sqrt(np.clip(w, 0.0, None)), _draws(len(T)))  # (J, DRAWS), no BLAS threads
    m = (Z[:ks.size] - gaps[:, None]).max(axis=0) if ks.size else np.full(DRAWS, -np.inf)
    top = int(math.ceil((1.0 - a2) * DRAWS)) - 1  # the (1 − α₂) quantile of each max: its order statistic
    q = max(float(np.partition(np.maximum(m, z), top)[top]) for z in Z[ks.size:]) if cands \
        else float(np.partition(m, top)[top])
    return float(ndtr(q))


def _correlation(C: np.ndarray) -> np.ndarray:
    """The correlation matrix of covariance C (J, J); a statistic whose jackknife variance is 0 (the same in every
    leave-one-out: an exact model's renders, whose unbiased SE may still be a float32 rounding residue > 0) is taken
    as uncorrelated with the others, which can only raise the joint critical value (a max of independent errors
    has the largest quantile)."""
    sd = np.sqrt(np.diag(C))
    ok = sd > 0
    R = np.eye(len(C))
    R[np.ix_(ok, ok)] = C[np.ix_(ok, ok)] / np.outer(sd[ok], sd[ok])
    return R


@functools.lru_cache(maxsize=8)
def _draws(J: int) -> np.ndarray:
    """DRAWS standard normal vectors (J, DRAWS) from a fixed seed, made once per J."""
    out = np.random.default_rng(0).standard_normal((J, DRAWS))
    out.flags.writeable = False
    return out


def hcr_interval(lam: UStat, deltas, fisher: UStat | StepFisher, level: float = 0.95, lower=None,
                 upper=None) -> HCRInterval:
    """The HCR interval at θ* (see the module docstring).

    Parameters
    ----------
    lam : UStat
        U-statistic of λ over K offsets (est, se: (K,); loo: (R, K)), e.g. `u_statistic` of the
        replicate-difference Grams or one row of `pairwise_ustat`.
    deltas : array_like of shape (K,) or (K, P)
        Offsets Δ_k, parameter units.
    fisher : UStat or StepFisher
        The Fisher information of the Δ → 0 term: a `fd_step.StepFisher` (every FD stage, with the step
        check; the bound service builds it) or one UStat of F (est, se: (P, P); loo (R, P, P) for a vector
        θ; no step check), 1/(parameter units)².
    level : float, optional
        One-sided confidence of each end, in (0, 1) (the lower end's terms jointly: see the module docstring).
    lower, upper : float or array_like of shape (P,), optional
        Limits on Δ (Θ − θ*): offsets outside are left out. None: no limit.

    Returns
    -------
    HCRInterval
        log10 point estimate and ends of the HCR (parameter units²), with the terms that set them.

    See Also
    --------
    nlosbench.bounds.hcr : The HCR at θ* from one set of renders (a plug-in: rendering noise biases it low).
    nlosbench.bounds.crlb : The CRLB, the HCR's Δ → 0 limit, from a Fisher matrix.
    nlosbench.bounds.ziv_zakai : The Ziv–Zakai bound on the Bayesian MSE over a prior on Θ (any estimator).
    nlosbench.bounds.zzb_interval : The Ziv–Zakai bound with confidence ends from replicate render sets.
    nlosbench.bounds.pairwise_ustat : Unbiased λ for every pair of grid points from replicate renders.
    nlosbench.bounds.u_statistic : The unbiased estimate and its jackknife from a replicate Gram array.

    Examples
    --------
    λ(Δ) = F·Δ² with F = 1 (CRLB = 1), estimated from R = 10 replicates: the Δ → 0 term sets every end.

    >>> import numpy as np
    >>> lam = nb.bounds.UStat(np.array([0.25, 1.0]), np.array([0.01, 0.02]), np.empty((0, 2)), 10)
    >>> F = nb.bounds.UStat(np.array([[1.0]]), np.array([[0.05]]), np.empty((0, 1, 1)), 10)
    >>> iv = nb.bounds.hcr_interval(lam, np.array([0.5, 1.0]), F)
    >>> round(iv.lower, 3), iv.point, round(iv.upper, 3), iv.lower_term
    (-0.047, 0.0, 0.042, 'Δ → 0')
    """
    d = np.asarray(deltas, dtype=np.float64)
    D = d.reshape(d.shape[0], -1)
    K, P = D.shape
    sf = fisher if isinstance(fisher, StepFisher) else single(fisher)
    if lam.est.shape != (K,):
        raise ValueError(f"λ statistics for {lam.est.shape} offsets, but {K} deltas")
    if sf.final.est.shape != (P, P):
        raise ValueError(f"F must be ({P}, {P}) for {P}-dimensional Δ, got {sf.final.est.shape}")
    lo = -np.inf if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.inf if upper is None else np.asarray(upper, dtype=np.float64)
    norm2 = (D * D).sum(axis=1)
    valid = ((D >= lo) & (D <= hi)).all(axis=1) & (norm2 > 0)
    R = min(lam.replicates, sf.final.replicates)
    estimate_only = R < 3
    names = [f"Δ = {', '.join(f'{v:+.4g}' for v in row)}" for row in D] + ["Δ → 0"]
    p = math.nan if estimate_only else lower_level(lam, valid, norm2, sf, level)
    t, t1 = (np.zeros(K), np.zeros(K)) if estimate_only else (
        np.nan_to_num(t_quantile(v, lam.dof), nan=np.inf) for v in (p, level))
    term = crlb_term(sf, level if estimate_only else p)  # its lower end for the lower end (the joint level)
    upper_term = crlb_term(sf, level)  # its upper end for the upper end (one term: see the module docstring)

    se = np.nan_to_num(lam.se)
    lam_hi = np.where(valid, limits(lam.est, se, t, lam.noise)[1], -np.inf)  # score-type where known (`limits`)
    lam_lo = np.where(valid, limits(lam.est, se, t1, lam.noise)[0], -np.inf)
    lam_pt = np.where(valid, lam.est, -np.inf)
    unresolved = valid & ~(lam_lo > 0)

    point, point_term = _pick(np.append(_log10_f(norm2, lam_pt), term.point), names)
    low, low_term = _pick(np.append(_log10_f(norm2, lam_hi), term.lower), names)
    if unresolved.any():  # f(λ_L) = +inf at an unresolved Δ: nothing bounds the sup from above
        up, up_term = math.inf, "unresolved Δ"
    else:
        up, up_term = _pick(np.append(_log10_f(norm2, lam_lo), upper_term.upper), names)
    point_loo = np.empty(0)
    if not estimate_only and lam.loo.size and term.loo.size:
        point_loo = np.array([_pick(np.append(_log10_f(norm2, np.where(valid, lam.loo[k], -np.inf)), term.loo[k]),
                                    names)[0] for k in range(R)])
    return HCRInterval(point=point, lower=low, upper=up, point_term=point_term, lower_term=low_term,
                       upper_term=up_term, level=level, replicates=R, estimate_only=estimate_only,
                       crlb=term.point, crlb_lower=term.lower, crlb_upper=upper_term.upper,
                       unresolved=[D[k].tolist() if P > 1 else float(D[k, 0]) for k in np.flatnonzero(unresolved)],
                       lower_note=term.lower_note if low_term == "Δ → 0" else "", step_flags=term.flags,
                       upper_note="" if up == math.inf else upper_term.upper_note,
                       point_loo=point_loo, tested=int(valid.sum()), term_level=p)
