"""Fisher information matrix and Cramér–Rao bound, with singular (non-identifiable) parameters
reported as such."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from nlosbench.bounds.hcr import as_numpy
from nlosbench.noise import NoiseModel, to_float64


def fisher_matrix(L, J, noise: NoiseModel) -> np.ndarray:
    """Fisher information (P, P) float64 of θ from the image L (*S) and its Jacobian J = ∂L/∂θ
    (P, *S) (or (*S) for scalar θ). Units: 1 / (parameter units)².

    Parameters
    ----------
    L : torch.Tensor or array_like of shape (*S)
        The noise-free image at θ, radiance units.
    J : torch.Tensor or array_like of shape (P, *S) or (*S)
        Its Jacobian ∂L/∂θ, radiance per parameter unit; the shape of L for a scalar θ (P = 1).
    noise : NoiseModel
        The observation model (its per-pixel Fisher information is summed over pixels).

    Returns
    -------
    ndarray of shape (P, P)
        F_jk = Σ_ω (per-pixel information of θ_j, θ_k), float64, 1/(parameter units)².

    Examples
    --------
    L(θ) = θ·g, so J = g; AWGN with σ = 3 and ‖g‖² = 9 gives F = ‖g‖²/σ² = 1.

    >>> import torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> nb.bounds.fisher_matrix(g, g, nb.noise.AWGN(3.0))
    array([[1.]])
    """
    J = to_float64(J, "J")
    if J.shape == np.shape(L):
        J = J[None]
    P = J.shape[0]
    return as_numpy(noise.fisher(L, J).reshape(P, P, -1).sum(dim=-1))


@dataclass
class CRLBResult:
    """Cramér–Rao bound from a Fisher matrix F (P, P).

    Returned by `crlb`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    component : ndarray of shape (P,)
        CRLB of each θ_j = (F⁻¹)_jj (parameter units²), +inf where θ_j is not identifiable.
    trace : float
        Σ component, the bound on the MSE of the vector θ (units²).
    F : ndarray of shape (P, P)
        The Fisher matrix, 1/(parameter units)².
    F_inv : ndarray of shape (P, P)
        F⁻¹, or the pseudo-inverse on the identifiable part when F is singular.
    cond : float
        Condition number of F scaled to unit diagonal (units-free; +inf when singular).
    singular : bool
        Some parameter is not identifiable.
    reason : str
        Which parameters are not identifiable and why ("" when none).

    Examples
    --------
    >>> r = nb.bounds.crlb([[4.0, 0.0], [0.0, 1.0]])
    >>> r.component.tolist(), r.trace, r.cond, r.singular
    ([0.25, 1.0], 1.25, 1.0, False)
    """

    component: np.ndarray
    trace: float
    F: np.ndarray
    F_inv: np.ndarray
    cond: float
    singular: bool
    reason: str


def crlb(F, rcond: float = 1e-12) -> CRLBResult:
    """CRLB from a symmetric positive semi-definite Fisher matrix F (P, P) (or a scalar).

    F is scaled to unit diagonal, then eigenvalues ≤ rcond·max are treated as zero; a parameter with
    F_jj = 0 (no effect on the image) or a component in that null space gets CRLB = +inf.

    Parameters
    ----------
    F : array_like of shape (P, P), or float
        The Fisher information, 1/(parameter units)² (e.g. from `fisher_matrix`): finite, symmetric, with
        a non-negative diagonal.
    rcond : float, optional
        Relative eigenvalue threshold below which the scaled F counts as singular.

    Returns
    -------
    CRLBResult
        Per-component bounds (parameter units²), their trace, F⁻¹ and what is not identifiable.

    See Also
    --------
    nlosbench.bounds.hcr : The HCR at θ* from one set of renders (a plug-in: rendering noise biases it low).
    nlosbench.bounds.hcr_interval : The HCR and CRLB with one-sided confidence ends from replicate render sets.
    nlosbench.bounds.ziv_zakai : The Ziv–Zakai bound on the Bayesian MSE over a prior on Θ (any estimator).
    nlosbench.bounds.zzb_interval : The Ziv–Zakai bound with confidence ends from replicate render sets.
    nlosbench.bounds.pairwise_ustat : Unbiased λ for every pair of grid points from replicate renders.
    nlosbench.bounds.u_statistic : The unbiased estimate and its jackknife from a replicate Gram array.

    Examples
    --------
    >>> r = nb.bounds.crlb([[4.0, 1.0], [1.0, 2.0]])
    >>> r.component
    array([0.28571429, 0.57142857])
    >>> r = nb.bounds.crlb([[4.0, 0.0], [0.0, 0.0]])
    >>> r.component, r.reason
    (array([0.25,  inf]), 'θ[1] has no effect on the image (F[1,1] = 0)')
    """
    F = np.atleast_2d(as_numpy(F))
    P = F.shape[0]
    if F.shape != (P, P) or not np.isfinite(F).all():
        raise ValueError(f"F must be a finite square matrix, got shape {F.shape}")
    scale = np.abs(F).max() if F.size else 0.0
    if not np.allclose(F, F.T, rtol=1e-10, atol=1e-12 * scale) or (np.diag(F) < 0).any():
        raise ValueError("F is not a Fisher matrix (must be symmetric with a non-negative diagonal)")
    d = np.diag(F)
    live = d > 0
    s = np.sqrt(d[live])
    e, V = np.linalg.eigh(F[np.ix_(live, live)] / np.outer(s, s))
    null = e <= rcond * (e.max() if e.size else 0.0)
    Vk = V[:, ~null]
    Finv_live = (Vk / e[~null]) @ Vk.T / np.outer(s, s)
    nonid_live = (V[:, null] ** 2).sum(axis=1) > 1e-8

    F_inv = np.zeros((P, P))
    F_inv[np.ix_(live, live)] = Finv_live
    component = np.full(P, np.inf)
    idx = np.flatnonzero(live)
    component[idx[~nonid_live]] = np.diag(Finv_live)[~nonid_live]

    reasons = [f"θ[{j}] has no effect on the image (F[{j},{j}] = 0)" for j in np.flatnonzero(~live)]
    if null.any():
        reasons.append(f"F is rank-deficient: θ{idx[nonid_live].tolist()} not identifiable "
                       f"(null directions of the scaled F: {np.round(V[:, null].T, 4).tolist()})")
    singular = bool(reasons)
    return CRLBResult(component=component, trace=float(component.sum()), F=F, F_inv=F_inv,
                      cond=float("inf") if singular else float(e.max() / e.min()),
                      singular=singular, reason="; ".join(reasons))


def crlb_log10(L, J, noise: NoiseModel) -> tuple[np.ndarray, str]:
    """log10 CRLB per parameter (P,) from an image L (*S) and its Jacobian J (P, *S), and a flag.

    Infinite Fisher information (a Poisson pixel rendered as exactly 0 whose neighbours are not) gives
    −inf, flagged; a singular F gives +inf for the non-identifiable components, flagged.

    Parameters
    ----------
    L : torch.Tensor or array_like of shape (*S)
        The noise-free image at θ.
    J : torch.Tensor or array_like of shape (P, *S) or (*S)
        Its Jacobian ∂L/∂θ.
    noise : NoiseModel
        The observation model.

    Returns
    -------
    log10 : ndarray of shape (P,)
        log10 of the CRLB of each parameter (units²).
    flag : str
        Why some entries are ±inf ("" when none is).
    """
    F = fisher_matrix(L, J, noise)
    if not np.all(np.isfinite(F)):
        return np.full(F.shape[0], -np.inf), "infinite Fisher information (Poisson pixel with L = 0 that changes)"
    c = crlb(F)
    with np.errstate(divide="ignore"):
        return np.log10(c.component), (c.reason if c.singular else "")


def crlb_from_hcr_limit(L0, L_alt, deltas, noise: NoiseModel, n_points: int = 3,
                        degree: int = 2) -> CRLBResult:
    """CRLB of a scalar θ as the Δ → 0 limit of Δ²/λ(Δ), from images at θ* + Δ_k (no derivative).

    Method: the information per unit offset λ(Δ)/Δ² = F + aΔ + bΔ² + … is smooth in the signed Δ;
    a polynomial of `degree` is fitted by least squares to the `n_points` smallest |Δ| (with finite
    λ) and evaluated at Δ = 0 (Richardson extrapolation when n_points = degree + 1), giving F̂ and
    CRLB = 1/F̂.

    Parameters
    ----------
    L0 : torch.Tensor or array_like of shape (*S)
        The noise-free image at θ*.
    L_alt : torch.Tensor or array_like of shape (K, *S)
        The images at θ* + Δ_k.
    deltas : array_like of shape (K,)
        Offsets Δ_k in parameter units (scalar θ only).
    noise : NoiseModel
        The observation model.
    n_points : int, optional
        How many of the smallest |Δ| enter the fit.
    degree : int, optional
        Degree of the polynomial in Δ (lowered to n_points − 1 when fewer points are usable).

    Returns
    -------
    CRLBResult
        The CRLB 1/F̂ (units²); unresolved (+inf, with a reason) when the extrapolated F̂ ≤ 0.
    """
    d = as_numpy(deltas)
    if d.ndim != 1:
        raise ValueError(f"crlb_from_hcr_limit needs scalar θ: deltas of shape (K,), got {d.shape}")
    lam = as_numpy(noise.chi2_exponent(L0, L_alt)).reshape(-1)
    ok = np.flatnonzero((d != 0) & np.isfinite(lam))
    if ok.size == 0:
        raise ValueError("no Δ ≠ 0 with finite λ")
    pick = ok[np.argsort(np.abs(d[ok]), kind="stable")[:n_points]]
    x = d[pick] / np.abs(d[pick]).max()
    coef = np.polynomial.polynomial.polyfit(x, lam[pick] / d[pick] ** 2, min(degree, pick.size - 1))
    F_hat = float(coef[0])
    if F_hat > 0:
        return crlb([[F_hat]])
    return replace(crlb([[0.0]]), reason=f"extrapolated information λ/Δ² at Δ → 0 is {F_hat:.3g} "
                                        "≤ 0: CRLB unresolved")
