"""Hammersley–Chapman–Robbins bound from an image at θ* and images at θ* + Δ_k.

For an unbiased estimator, Var(θ̂_j) ≥ sup_Δ Δ_j² / (exp(λ(Δ)) − 1) and
MSE(θ̂) ≥ sup_Δ ‖Δ‖² / (exp(λ(Δ)) − 1), with λ = log(1 + χ²(p_θ*+Δ ‖ p_θ*)).
The functional is evaluated in the log domain, so a bound that underflows (λ = 1e6) still has a
finite, exact log10, and λ = 1e-14 keeps full relative accuracy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from nlosbench.noise import NoiseModel

LN10 = math.log(10.0)


def log_expm1(lam: np.ndarray) -> np.ndarray:
    """log(exp(λ) − 1) for λ > 0, float64, without overflow or cancellation (λ = +inf → +inf)."""
    lam = np.asarray(lam, dtype=np.float64)
    small = lam <= 1.0
    out = np.empty_like(lam)
    out[small] = np.log(np.expm1(lam[small]))
    out[~small] = lam[~small] + np.log1p(-np.exp(-lam[~small]))
    return out


def as_numpy(x) -> np.ndarray:
    """Tensor (any device) or array-like → float64 numpy array."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


@dataclass
class HCRResult:
    """HCR bound over a set of K test offsets Δ_k (parameter units; bounds in units²).

    `value` = sup_k ‖Δ_k‖²/(exp(λ_k) − 1) over the usable Δ (0 < λ < ∞, Δ ≠ 0, inside the bounds);
    it may underflow to 0 but `log10` stays exact. `functional` is log10 f_k for every k: −inf where
    Δ_k gives no bound (λ = +inf, Δ = 0, outside [lower, upper]), +inf where λ_k ≤ 0 with Δ_k ≠ 0
    (the render did not change: unresolved, `unresolved` is set). `at_edge` is "smallest" or
    "largest" when the sup sits at the smallest/largest |Δ| on its side of θ* (by ‖Δ‖ over all
    Δ for vector θ), else None. Per-component bounds Δ_kj²/(exp(λ_k) − 1) are in `component_*`
    (P = 1 for scalar θ, equal to the total)."""

    value: float
    log10: float
    delta: float | np.ndarray | None
    index: int
    functional: np.ndarray
    lam: np.ndarray
    usable: np.ndarray
    at_edge: str | None
    unresolved: bool
    reason: str
    component_value: np.ndarray
    component_log10: np.ndarray
    component_index: np.ndarray


def hcr_from_lambda(lam, deltas, lower=None, upper=None) -> HCRResult:
    """HCR bound from χ² exponents.

    lam: (K,) λ_k (float64, +inf allowed, ≤ 0 means unresolved); deltas: (K,) or (K, P) offsets
    Δ_k in parameter units; lower/upper: scalar or (P,) limits on Δ (offsets outside are skipped)."""
    lam = as_numpy(lam).reshape(-1)
    d = as_numpy(deltas)
    K = lam.size
    if d.ndim not in (1, 2) or d.shape[0] != K:
        raise ValueError(f"deltas must have shape ({K},) or ({K}, P), got {d.shape}")
    if np.isnan(lam).any() or (lam == -np.inf).any():
        raise ValueError("lam contains NaN or -inf")
    if not np.isfinite(d).all():
        raise ValueError("deltas contains NaN or Inf")
    scalar = d.ndim == 1
    D = d.reshape(K, -1)
    lo = -np.inf if lower is None else as_numpy(lower)
    hi = np.inf if upper is None else as_numpy(upper)
    norm2 = (D * D).sum(axis=1)
    valid = ((D >= lo) & (D <= hi)).all(axis=1) & (norm2 > 0)
    usable = valid & (lam > 0) & np.isfinite(lam)
    unres = valid & (lam <= 0)

    le = log_expm1(np.where(usable, lam, 1.0))
    with np.errstate(divide="ignore"):
        logf = np.where(usable, np.log(norm2) - le, -np.inf)
        logc = np.where(usable[:, None], 2.0 * np.log(np.abs(D)) - le[:, None], -np.inf)
    logf[unres] = np.inf

    reasons = []
    k = int(np.argmax(np.where(usable, logf, -np.inf))) if usable.any() else -1
    if k < 0 and unres.any():
        reasons.append("no Δ with 0 < λ < inf: log10 = -inf stands for 'no finite bound', not a bound of 0")
    elif k < 0:
        reasons.append("no usable Δ (every Δ has λ = +inf, Δ = 0 or lies outside the bounds)")
    at_edge = _edge(D, norm2, valid, k, scalar)
    if at_edge == "smallest":
        reasons.append("sup at the smallest |Δ| on its side: a finer Δ grid near 0 may raise it")
    elif at_edge == "largest":
        reasons.append("sup at the largest |Δ| on its side: a wider Δ range may raise it")
    if unres.any():
        reasons.append(f"{int(unres.sum())} Δ with λ ≤ 0 (image unchanged or λ̂ ≤ 0): "
                       "infinite functional, bound unresolved")
    logb = logf[k] if k >= 0 else -np.inf
    kc = np.argmax(logc, axis=0)
    logc_best = logc[kc, np.arange(D.shape[1])]
    return HCRResult(
        value=float(np.exp(logb)),
        log10=float(logb / LN10),
        delta=None if k < 0 else (float(D[k, 0]) if scalar else D[k].copy()),
        index=k,
        functional=logf / LN10,
        lam=lam,
        usable=usable,
        at_edge=at_edge,
        unresolved=bool(unres.any()),
        reason="; ".join(reasons),
        component_value=np.exp(logc_best),
        component_log10=logc_best / LN10,
        component_index=np.where(np.isfinite(logc_best), kc, -1),
    )


def _edge(D: np.ndarray, norm2: np.ndarray, valid: np.ndarray, k: int, scalar: bool) -> str | None:
    """"smallest"/"largest" if Δ_k has the extreme magnitude among valid Δ on its side, else None."""
    if k < 0:
        return None
    same = valid & (np.sign(D[:, 0]) == np.sign(D[k, 0])) if scalar else valid
    mags = norm2[same]
    if norm2[k] <= mags.min():
        return "smallest"
    if norm2[k] >= mags.max():
        return "largest"
    return None


def hcr(L0, L_alt, deltas, noise: NoiseModel, lower=None, upper=None) -> HCRResult:
    """HCR bound at θ* from its image L0 (*S) and images L_alt (K, *S) at θ* + Δ_k.

    deltas: (K,) or (K, P) in parameter units; lower/upper: limits on Δ (e.g. Θ − θ*)."""
    return hcr_from_lambda(noise.chi2_exponent(L0, L_alt), deltas, lower, upper)
