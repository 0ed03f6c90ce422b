"""Barankin bound (McAulay–Seidman form) with several test points chosen from the same renders.

For test offsets Δ_1..Δ_m and B_ab = E_θ*[ℓ_a ℓ_b] (ℓ = p_θ*+Δ / p_θ*),
Var(θ̂) ≥ δᵀ (B − 11ᵀ)⁻¹ δ with δ_a = Δ_a (the component of interest) and
(B − 11ᵀ)_ab = expm1(g_ab), g = noise.gram_exponent. The matrix is scaled to the correlation matrix
C_ab = expm1(g_ab) / sqrt(expm1(λ_a) expm1(λ_b)) (|C_ab| ≤ 1) in the log domain, so huge exponents
neither overflow nor need to be dropped. Points are added greedily, starting from the HCR maximiser
(the one-point bound *is* the HCR bound), only while the bound rises and C stays well conditioned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nlosbench.bounds.hcr import LN10, as_numpy, hcr, log_expm1
from nlosbench.noise import NoiseModel


@dataclass
class BarankinResult:
    """Barankin bound on Var(θ̂_j) (parameter units²).

    Returned by `barankin`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    value : float
        The bound on Var(θ̂_j), parameter units² (may underflow to 0).
    log10 : float
        Its log10, exact; −inf when no test point is usable.
    points : ndarray of int, shape (m,)
        Indices of the chosen test points into the K test images, the HCR maximiser first.
    deltas : ndarray of shape (m,)
        Their Δ_j, parameter units.
    hcr_log10 : float
        log10 of the (one-point) HCR bound on the same component.
    tightening : float
        value / HCR ≥ 1.
    cond : float
        Condition number of the chosen points' correlation matrix C.
    unresolved : bool
        As for HCR: some Δ has λ ≤ 0.
    reason : str
        The HCR's reason plus why the point selection stopped.

    Examples
    --------
    Test points of a model quadratic in θ (θ* = 1): more points than the HCR's one tighten the bound:

    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> deltas = np.array([-0.5, 0.5, 1.0, 2.0])
    >>> r = nb.bounds.barankin(g, torch.stack([(1.0 + d) ** 2 * g for d in deltas]), deltas, nb.noise.AWGN(3.0))
    >>> len(r.points), r.tightening >= 1, r.log10 >= r.hcr_log10
    (3, True, True)
    """

    value: float
    log10: float
    points: np.ndarray
    deltas: np.ndarray
    hcr_log10: float
    tightening: float
    cond: float
    unresolved: bool
    reason: str


def barankin(L0, L_alt, deltas, noise: NoiseModel, component: int | None = None, lower=None,
             upper=None, max_points: int = 8, cond_max: float = 1e10, rtol: float = 1e-9,
             chunk_bytes: int = 256 * 2**20) -> BarankinResult:
    """Barankin bound at θ* from L0 (*S) and test images L_alt (K, *S) at θ* + Δ_k.

    Points are added greedily, starting from the HCR maximiser: a point is added only if it raises the
    bound by more than `rtol` (relative) and keeps cond(C) ≤ `cond_max`; at most `max_points` points.
    Never below the HCR bound.

    Parameters
    ----------
    L0 : torch.Tensor or array_like of shape (*S)
        The noise-free image at θ*.
    L_alt : torch.Tensor or array_like of shape (K, *S)
        The test images at θ* + Δ_k.
    deltas : array_like of shape (K,) or (K, P)
        Offsets Δ_k in parameter units.
    noise : NoiseModel
        The observation model (its `gram_exponent` gives B − 11ᵀ).
    component : int, optional
        For vector θ ((K, P) deltas), the component j whose variance is bounded (required when P > 1).
    lower, upper : float or array_like of shape (P,), optional
        Limits on Δ as in `hcr` (e.g. Θ − θ*). None: no limit.
    max_points : int, optional
        The most test points used.
    cond_max : float, optional
        The largest condition number of C allowed.
    rtol : float, optional
        The relative rise a new point must bring.
    chunk_bytes : int, optional
        float64 working memory per block of test images, in bytes.

    Returns
    -------
    BarankinResult
        The bound on Var(θ̂_j) (parameter units²), the chosen points and the tightening over the HCR.

    Examples
    --------
    L(θ) = θ·g under AWGN with F = 1 (CRLB = 1): the HCR is 0.88, several points lift it near the CRLB.

    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> deltas = np.array([-1.0, -0.5, 0.5, 1.0, 2.0])
    >>> L_alt = torch.stack([(1.0 + d) * g for d in deltas])
    >>> r = nb.bounds.barankin(g, L_alt, deltas, nb.noise.AWGN(3.0))
    >>> round(10**r.hcr_log10, 4), round(r.value, 4), len(r.points)
    (0.8802, 0.9997, 5)
    """
    d = as_numpy(deltas)
    if d.ndim == 2 and d.shape[1] > 1 and component is None:
        raise ValueError("vector θ: pass component=j to bound Var(θ̂_j)")
    j = component or 0
    delta = d.reshape(d.shape[0], -1)[:, j]
    h = hcr(L0, L_alt, deltas, noise, lower, upper)
    k0 = int(h.component_index[j])
    logb = float(h.component_log10[j]) * LN10
    notes = [f"HCR: {h.reason}"] if h.reason else []
    if k0 < 0:
        return BarankinResult(0.0, -np.inf, np.array([], int), np.array([]), -np.inf, 1.0, 1.0,
                              h.unresolved, "; ".join(notes + ["no usable test point"]))

    cand = np.flatnonzero(h.usable)
    le = log_expm1(h.lam[cand])
    with np.errstate(divide="ignore"):
        logu = np.log(np.abs(delta[cand])) - 0.5 * le  # u = δ / sqrt(expm1 λ), kept as log|u|, sign
    sgn = np.sign(delta[cand])
    sel = [int(np.flatnonzero(cand == k0)[0])]
    cols = [_corr_column(L0, L_alt, cand, sel[0], le, noise, chunk_bytes)]
    cond, why = 1.0, f"reached max_points = {max_points}"
    while len(sel) < max_points:
        rest = np.setdiff1d(np.arange(cand.size), sel)
        if rest.size == 0:
            why = "all test points used"
            break
        m = len(sel)
        Cs = np.stack(cols)  # (m, C): correlation of each chosen point with every candidate
        Cb = np.empty((rest.size, m + 1, m + 1))
        Cb[:, :m, :m] = Cs[:, sel]
        Cb[:, m, :m] = Cb[:, :m, m] = Cs[:, rest].T
        Cb[:, m, m] = 1.0
        lu = np.concatenate([np.broadcast_to(logu[sel], (rest.size, m)), logu[rest, None]], axis=1)
        sg = np.concatenate([np.broadcast_to(sgn[sel], (rest.size, m)), sgn[rest, None]], axis=1)
        top = lu.max(axis=1, keepdims=True)
        v = sg * np.exp(lu - top)
        e, V = np.linalg.eigh(Cb)
        ok = e[:, 0] > e[:, -1] / cond_max
        q = (np.einsum("rij,ri->rj", V, v) ** 2 / np.where(ok[:, None], e, 1.0)).sum(axis=1)
        with np.errstate(divide="ignore"):
            cand_logb = np.where(ok & (q > 0), 2.0 * top[:, 0] + np.log(np.where(q > 0, q, 1.0)),
                                 -np.inf)
        r = int(np.argmax(cand_logb))
        if not cand_logb[r] > logb + np.log1p(rtol):
            why = "no further test point raises the bound with cond(C) <= cond_max"
            break
        sel.append(int(rest[r]))
        cols.append(_corr_column(L0, L_alt, cand, sel[-1], le, noise, chunk_bytes))
        logb, cond = float(cand_logb[r]), float(e[r, -1] / e[r, 0])
    hcr_log10 = float(h.component_log10[j])
    return BarankinResult(value=float(np.exp(logb)), log10=logb / LN10, points=cand[sel],
                          deltas=delta[cand[sel]], hcr_log10=hcr_log10,
                          tightening=float(np.exp(logb - hcr_log10 * LN10)), cond=cond,
                          unresolved=h.unresolved, reason="; ".join(notes + [why]))


def _corr_column(L0, L_alt, cand: np.ndarray, a: int, le: np.ndarray, noise: NoiseModel,
                 chunk_bytes: int) -> np.ndarray:
    """Correlation C_{c,a} between every candidate c and candidate a → (C,), with C_aa = 1."""
    per = max(1, chunk_bytes // (16 * max(1, math.prod(np.shape(L0)))))
    g = np.concatenate([as_numpy(noise.gram_exponent(L0, L_alt[cand[s:s + per]], L_alt[cand[a]]))
                        for s in range(0, cand.size, per)])
    with np.errstate(divide="ignore"):
        mag = np.where(g > 0, log_expm1(np.where(g > 0, g, 1.0)), np.log(-np.expm1(np.minimum(g, 0))))
    c = np.sign(g) * np.exp(mag - 0.5 * (le + le[a]))
    c[a] = 1.0
    return c
