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
Student-t limits at level 1 − α:

  lower end (the bound to quote): max over Δ of f(λ_U(Δ)) and the CRLB term's lower end (F's largest upper
      limit over the FD stages), where λ_U is an upper confidence limit, Bonferroni over the K tested Δ and the
      Δ → 0 term (each at α/(K+1)): the end is too high only if λ_U(Δ) < λ(Δ) at *some* Δ, so
      P(lower end ≤ true HCR) ≥ 1 − α (a Δ whose λ_U ≤ 0 is left out, which only lowers the end). Where that
      end is set by the CRLB term and the FD step did not converge, it is labelled "not a confidence limit"
      (`lower_note`);
  upper end: the same with the lower limits λ_L and the CRLB term's upper end, each at α (no Bonferroni): the
      HCR over the tested Δ and Δ → 0 is f at one fixed (unknown) term k*, the one whose true f is largest,
      and max_k f(λ_L(Δ_k)) ≥ f(λ_L(Δ_k*)) ≥ f(λ(Δ_k*)) unless λ_L(Δ_k*) > λ(Δ_k*), an event of probability
      ≤ α; so P(upper end ≥ HCR over the tested terms) ≥ 1 − α. If any tested Δ is unresolved (λ_L ≤ 0,
      f(λ_L) = +∞ at that Δ), the upper end is open (+inf). It bounds the HCR over the tested Δ and Δ → 0 (a
      sup over more Δ may be higher: the tested set is a grid);
  point: the same with the estimates themselves;
  point_loo: the point without each replicate (from the U-statistics' leave-one-outs), for jackknifes of
      functions of several bounds over the same replicate sets (e.g. a ratio of two models' bounds).
Ends can cross (lower > upper) where the Bonferroni limits of different terms disagree: flagged
`ends-crossed`, and a verdict against such an interval is undetermined.
With R < 3 there is no standard error: both ends are the point estimate, flagged `estimate_only`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nlosbench.bounds.fd_step import StepFisher, crlb_term, single
from nlosbench.bounds.hcr import LN10, log_expm1
from nlosbench.bounds.ustat import UStat, t_quantile


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
    point_loo : ndarray of shape (R,), optional
        log10 point estimate without replicate k (empty when R < 3).
    tested : int, optional
        The number of tested Δ inside the limits (the lower end's Bonferroni share is over them and Δ → 0).

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
    point_loo: np.ndarray = field(default_factory=lambda: np.empty(0), compare=False)
    tested: int = 0

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
        One-sided confidence of each end, in (0, 1) (Bonferroni over the K tested Δ and the Δ → 0 term).
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
    (-0.051, 0.0, 0.042, 'Δ → 0')
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
    tests = int(valid.sum()) + 1
    names = [f"Δ = {', '.join(f'{v:+.4g}' for v in row)}" for row in D] + ["Δ → 0"]
    t, t1 = (np.zeros(K), np.zeros(K)) if estimate_only else (
        np.nan_to_num(t_quantile(level, lam.dof, n), nan=np.inf) for n in (tests, 1))
    term = crlb_term(sf, level, tests)  # its lower end for the lower end (Bonferroni share)
    upper_term = crlb_term(sf, level)  # its upper end for the upper end (no Bonferroni: see the module docstring)

    lam_hi = np.where(valid, lam.est + t * np.nan_to_num(lam.se), -np.inf)
    lam_lo = np.where(valid, lam.est - t1 * np.nan_to_num(lam.se), -np.inf)
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
                       point_loo=point_loo, tested=tests - 1)
