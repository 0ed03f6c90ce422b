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
    it may underflow to 0 but `log10` stays exact. Returned by `hcr` and `hcr_from_lambda`; each
    parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    value : float
        The bound sup_k ‖Δ_k‖²/(exp(λ_k) − 1), parameter units² (0 where it underflows or no Δ is usable).
    log10 : float
        log10 of the bound, exact even where `value` underflows; −inf when no Δ is usable.
    delta : float or ndarray of shape (P,) or None
        The Δ at the sup (a float for scalar θ); None when no Δ is usable.
    index : int
        Index k of that Δ among the K offsets; −1 when none is usable.
    functional : ndarray of shape (K,)
        log10 f_k = log10 ‖Δ_k‖²/(exp(λ_k) − 1) for every k: −inf where Δ_k gives no bound (λ = +inf,
        Δ = 0, outside [lower, upper]), +inf where λ_k ≤ 0 with Δ_k ≠ 0 (the render did not change:
        unresolved, `unresolved` is set).
    lam : ndarray of shape (K,)
        The χ² exponents λ_k used, float64.
    usable : ndarray of bool, shape (K,)
        The Δ_k that enter the sup (0 < λ_k < ∞, Δ_k ≠ 0, inside the bounds).
    at_edge : {"smallest", "largest"} or None
        "smallest" or "largest" when the sup sits at the smallest/largest |Δ| on its side of θ* (by ‖Δ‖
        over all Δ for vector θ): a finer or wider Δ grid may raise the bound; else None.
    unresolved : bool
        Some Δ ≠ 0 inside the bounds has λ ≤ 0 (an infinite functional).
    reason : str
        Why the bound is what it is (no usable Δ, sup at an edge, unresolved Δ); "" when nothing to say.
    component_value : ndarray of shape (P,)
        Per-component bounds on Var(θ̂_j), max_k Δ_kj²/(exp(λ_k) − 1), units² (P = 1 for scalar θ, equal
        to the total).
    component_log10 : ndarray of shape (P,)
        log10 of `component_value`, exact.
    component_index : ndarray of int, shape (P,)
        Index k of the maximising Δ per component; −1 where none.

    Examples
    --------
    λ = 2000 at Δ = 1: the bound 1/(e²⁰⁰⁰ − 1) underflows, its log10 does not:

    >>> import numpy as np
    >>> r = nb.bounds.hcr_from_lambda(np.array([2000.0]), np.array([1.0]))
    >>> r.value, round(r.log10, 1), r.usable.tolist()
    (0.0, -868.6, [True])
    """

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

    For an unbiased estimator, MSE(θ̂) ≥ sup_k ‖Δ_k‖²/(exp(λ_k) − 1), evaluated in the log domain (see
    the module docstring).

    Parameters
    ----------
    lam : array_like of shape (K,)
        λ_k = log(1 + χ²(p_θ*+Δ_k ‖ p_θ*)), float64; +inf allowed (that Δ gives no bound), ≤ 0 means
        unresolved. NaN or −inf is an error.
    deltas : array_like of shape (K,) or (K, P)
        Offsets Δ_k in parameter units.
    lower, upper : float or array_like of shape (P,), optional
        Limits on Δ (e.g. Θ − θ*): offsets outside [lower, upper] are skipped. None: no limit.

    Returns
    -------
    HCRResult
        The bound (parameter units²) with its exact log10, the maximising Δ, per-component bounds and
        flags (`at_edge`, `unresolved`, `reason`).

    Examples
    --------
    A model with λ(Δ) = F·Δ² and F = 1 (CRLB = 1): the sup is at the smallest Δ tested, below the CRLB.

    >>> import numpy as np
    >>> deltas = np.array([0.25, 0.5, 1.0])
    >>> r = nb.bounds.hcr_from_lambda(deltas**2, deltas)
    >>> round(r.value, 4), r.delta, r.at_edge
    (0.9691, 0.25, 'smallest')
    """
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

    λ_k = noise.chi2_exponent(L0, L_alt[k]), then `hcr_from_lambda`.

    Parameters
    ----------
    L0 : torch.Tensor or array_like of shape (*S)
        The noise-free image at θ*, radiance units (any float dtype and device).
    L_alt : torch.Tensor or array_like of shape (K, *S)
        The images at θ* + Δ_k.
    deltas : array_like of shape (K,) or (K, P)
        Offsets Δ_k in parameter units.
    noise : NoiseModel
        The observation model (e.g. `nlosbench.noise.AWGN`, `nlosbench.noise.Poisson`).
    lower, upper : float or array_like of shape (P,), optional
        Limits on Δ (e.g. Θ − θ*): offsets outside are skipped. None: no limit.

    Returns
    -------
    HCRResult
        The bound on the MSE (parameter units²) with its exact log10; see `hcr_from_lambda`.

    See Also
    --------
    nlosbench.bounds.crlb : The CRLB, the HCR's Δ → 0 limit, from a Fisher matrix.
    nlosbench.bounds.hcr_interval : The HCR and CRLB with one-sided confidence ends from replicate render sets.
    nlosbench.bounds.ziv_zakai : The Ziv–Zakai bound on the Bayesian MSE over a prior on Θ (any estimator).
    nlosbench.bounds.zzb_interval : The Ziv–Zakai bound with confidence ends from replicate render sets.
    nlosbench.bounds.pairwise_ustat : Unbiased λ for every pair of grid points from replicate renders.
    nlosbench.bounds.u_statistic : The unbiased estimate and its jackknife from a replicate Gram array.

    Examples
    --------
    L(θ) = θ·g under AWGN with σ = 3 and ‖g‖² = 9: F = ‖g‖²/σ² = 1 per unit θ².

    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> deltas = np.array([0.25, 0.5, 1.0])
    >>> L_alt = torch.stack([(1.0 + d) * g for d in deltas])
    >>> r = nb.bounds.hcr(g, L_alt, deltas, nb.noise.AWGN(3.0))
    >>> round(r.value, 4), r.delta
    (0.9691, 0.25)
    """
    return hcr_from_lambda(noise.chi2_exponent(L0, L_alt), deltas, lower, upper)
