"""The HCR at θ* as a confidence interval that includes its Δ → 0 term, from replicated Monte Carlo renders.

The HCR is a sup over every Δ ≠ 0 of f(Δ) = ‖Δ‖² / (exp λ(Δ) − 1); as Δ → 0, f tends to the CRLB term
1/F for a scalar θ (1/λ_min(F) in the MSE form for a vector θ), so a correct HCR is never below it.
From renders the limit cannot be reached by refining Δ: with independent seeds λ̃ keeps a C/N floor, with
common random numbers visibility jumps make λ̃ ∝ |Δ|; so the limit enters as its own term, with F from an
unbiased Fisher information (`unbiased_fisher`).

Inputs are U-statistics over R independent replicates (`ustat`): λ̂(Δ_k) from the replicate differences
L̃_r(θ*+Δ_k) − L̃_r(θ*) (each replicate may use common random numbers across θ), and F̂ from R FD
Jacobians, each with its SE and degrees of freedom. With one-sided Student-t limits at level 1 − α,
Bonferroni over the K tested Δ and the Δ → 0 term (each at α/(K+1)):

  lower end (the bound to quote): max over Δ of f(λ_U(Δ)) and the Δ → 0 term at F_U, where λ_U, F_U are
      upper confidence limits — so P(lower end ≤ true HCR) ≥ 1 − α (a Δ whose λ_U ≤ 0 is left out, which
      only lowers the end);
  upper end: the same with the lower limits λ_L, F_L over the *resolved* Δ (λ_L > 0; the others are listed)
      and the Δ → 0 term (+inf when F_L ≤ 0: no resolved information); it bounds, at the same level, the
      HCR over the resolved Δ and Δ → 0;
  point: the same with the estimates themselves;
  point_loo: the point without each replicate (from the U-statistics' leave-one-outs), for jackknifes of
      functions of several bounds over the same replicate sets (e.g. a ratio of two models' bounds).
With R < 3 there is no standard error: both ends are the point estimate, flagged `estimate_only`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nlosbench.bounds.hcr import LN10, log_expm1
from nlosbench.bounds.ustat import UStat, t_quantile


@dataclass
class HCRInterval:
    """log10 ends of the HCR (units²) with the terms that set them ("Δ = 0.03", "Δ → 0", or "none").

    point/lower/upper: log10 of the point estimate, the lower end (quote it) and the upper end (+inf:
    no resolved information); level: the confidence level of each end; replicates: R; estimate_only: R < 3;
    unresolved: the Δ (rows of `deltas`) whose λ_L ≤ 0, left out of the upper end; crlb: log10 of the
    CRLB term alone (1/F̂ or 1/λ_min(F̂)) with its ends (crlb_lower from F_U, crlb_upper from F_L);
    point_loo: (R,) log10 point estimate without replicate k (empty when R < 3)."""

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
    point_loo: np.ndarray = field(default_factory=lambda: np.empty(0), compare=False)

    @property
    def flags(self) -> tuple[str, ...]:
        out = []
        if self.estimate_only:
            out.append("estimate-only")
        if self.unresolved:
            out.append("unresolved-delta")
        if math.isinf(self.upper):
            out.append("upper-unbounded")
        return tuple(out)


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


def hcr_interval(lam: UStat, deltas, fisher: UStat, level: float = 0.95, lower=None, upper=None) -> HCRInterval:
    """The HCR interval at θ* (see the module docstring).

    lam: U-statistic of λ over K offsets (est, se: (K,)); deltas: (K,) or (K, P) in parameter units;
    fisher: U-statistic of F (est, se: (P, P); loo (R, P, P) for a vector θ); lower/upper: limits on Δ
    (Θ − θ*): offsets outside are left out."""
    d = np.asarray(deltas, dtype=np.float64)
    D = d.reshape(d.shape[0], -1)
    K, P = D.shape
    if lam.est.shape != (K,):
        raise ValueError(f"λ statistics for {lam.est.shape} offsets, but {K} deltas")
    if fisher.est.shape != (P, P):
        raise ValueError(f"F must be ({P}, {P}) for {P}-dimensional Δ, got {fisher.est.shape}")
    lo = -np.inf if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.inf if upper is None else np.asarray(upper, dtype=np.float64)
    norm2 = (D * D).sum(axis=1)
    valid = ((D >= lo) & (D <= hi)).all(axis=1) & (norm2 > 0)
    R = min(lam.replicates, fisher.replicates)
    estimate_only = R < 3
    tests = int(valid.sum()) + 1
    names = [f"Δ = {', '.join(f'{v:+.4g}' for v in row)}" for row in D] + ["Δ → 0"]
    t = np.zeros(K) if estimate_only else np.nan_to_num(t_quantile(level, lam.dof, tests), nan=np.inf)

    f_est, f_se, f_df = _info(fisher)  # the Δ → 0 information: F (scalar) or λ_min(F)
    tf = 0.0 if estimate_only else float(np.nan_to_num(t_quantile(level, f_df, tests), nan=np.inf))
    f_lo, f_hi = (f_est - tf * f_se, f_est + tf * f_se) if not estimate_only else (f_est, f_est)

    def crlb_term(info: float) -> float:
        return -math.log10(info) if info > 0 else math.inf

    lam_hi = np.where(valid, lam.est + t * np.nan_to_num(lam.se), -np.inf)
    lam_lo = np.where(valid, lam.est - t * np.nan_to_num(lam.se), -np.inf)
    lam_pt = np.where(valid, lam.est, -np.inf)
    unresolved = valid & ~(lam_lo > 0)

    point, point_term = _pick(np.append(_log10_f(norm2, lam_pt), crlb_term(f_est)), names)
    # the lower end: a Δ→0 term from F_U ≤ 0 would claim an infinite bound; it is left out (lower end stays safe)
    low, low_term = _pick(np.append(_log10_f(norm2, lam_hi), crlb_term(f_hi) if f_hi > 0 else -np.inf), names)
    up_f = np.where(unresolved, -np.inf, _log10_f(norm2, lam_lo))
    up, up_term = _pick(np.append(up_f, crlb_term(f_lo)), names)
    point_loo = np.empty(0)
    if not estimate_only and lam.loo.size and fisher.loo.size:
        info_loo = _info_loo(fisher)
        point_loo = np.array([_pick(np.append(_log10_f(norm2, np.where(valid, lam.loo[k], -np.inf)),
                                              crlb_term(info_loo[k])), names)[0] for k in range(R)])
    return HCRInterval(point=point, lower=low, upper=up, point_term=point_term, lower_term=low_term,
                       upper_term=up_term, level=level, replicates=R, estimate_only=estimate_only,
                       crlb=crlb_term(f_est), crlb_lower=crlb_term(f_hi), crlb_upper=crlb_term(f_lo),
                       unresolved=[D[k].tolist() if P > 1 else float(D[k, 0]) for k in np.flatnonzero(unresolved)],
                       point_loo=point_loo)


def _info_loo(fisher: UStat) -> np.ndarray:
    """The Δ → 0 information without each replicate (R,): F̂_(−k) (scalar θ) or λ_min(F̂_(−k))."""
    if fisher.loo.shape[1:] == (1, 1):
        return fisher.loo[:, 0, 0].astype(np.float64)
    return np.array([np.linalg.eigvalsh(0.5 * (Fk + Fk.T))[0] for Fk in fisher.loo])


def _info(fisher: UStat) -> tuple[float, float, float]:
    """(information, its SE, the SE's degrees of freedom) of the Δ → 0 term: F for a scalar θ; λ_min(F) for
    a vector θ (SE from the leave-one-out F̂s, R − 1 degrees of freedom). NaN SE without leave-one-outs."""
    F = fisher.est
    if F.shape == (1, 1):
        return float(F[0, 0]), float(fisher.se[0, 0]), float(fisher.dof[0, 0])
    est = float(np.linalg.eigvalsh(F)[0])
    if fisher.loo.size == 0:
        return est, math.nan, math.nan
    R = fisher.loo.shape[0]
    loo = _info_loo(fisher)
    return est, float(np.sqrt((R - 1) / R * ((loo - loo.mean()) ** 2).sum())), R - 1.0
