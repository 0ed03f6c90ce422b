"""HCR intervals from inexact (Monte Carlo) renders: multi-spp λ estimation, HCR_Neff vs HCR-hat,
and bootstrap confidence intervals.

A render at N spp is L̃ = L + E, E unbiased with Σ_ω w·Var E ∝ N^(−p) (p = 1 for a path tracer).
For a quadratic noise model (λ = Σ_ω w(L0)(L1 − L0)²: AWGN, Poisson) and independent renders of θ*
and θ*+Δ, E[λ̃^(N)] = λ + C/N^p with C = N^p Σ_ω w (Var E0 + Var E1) ≥ 0: rendering noise inflates λ
and biases the HCR low, most where the sup sits at small Δ (NLOS). The paper's remedy:

* render θ* and every θ*+Δ at k spp levels N_1..N_k and fit λ̃^(N_i) = λ + C/N_i^p by weighted
  least squares (weights N_i^p, the inverse of Var λ̃ = O(N^−p)) → λ̂ (`fit_lambda`);
* HCR-hat = HCR from λ̂ is an upper bound *in expectation* (Jensen) on the HCR restricted to the tested Δ
  — not on the HCR over every Δ, which a sup over more Δ (or Δ → 0) can raise; HCR_Neff, from one render
  set at N_eff ≈ Σ N_i (equal budget), is typically a lower one (`inexact_hcr`).

Replicates. Each level (and the N_eff set) is rendered as R independent replicates of N/R spp; their
mean is statistically a render at N spp (`RenderBank.replicates`). A (θ*, Δ) pair reduces to the R×R Gram
matrix G_rs = Σ_ω w D_r D_s of replicate differences D_r = L̃_r(θ*+Δ) − L̃_r(θ*) (`replicate_grams`):
λ̃ of the replicate means is 1ᵀG1/R², and λ̃ of the mean over any subset of replicates follows from
G too, so resampling costs no renders.

Bootstrap. Resamples are *half-samples* (⌊R/2⌋ replicates drawn without replacement, independently
per level and for the N_eff set), not draws with replacement: a duplicated replicate multiplies its
rendering noise, so the C/N^p term would vary with the multiplicity pattern and swamp the spread
(tried: 90 % intervals 2–3× too wide on the toy). Each half-sample λ̃_S is centred on its exact mean
over all subsets and scaled by the delete-d jackknife factor √(m/(R−m)) (`half_sample_lambda`).
The spread is right where λ is resolved and conservative (up to √3 in standard deviation) where
rendering noise dominates λ: the noise×noise part of a quadratic statistic scales as 1/m², not 1/m.
Measured on blob2d (60 runs, R = 4 and 8): bootstrap / true standard deviation of λ̃_Neff and λ̂
0.88–1.27 where λ ≫ C/N, 0.9–1.8 where λ ≲ C/N. Intervals are reported in log10 around the observed
value (`_spread_interval`).

Poisson weights. λ_P weighs by scale/L0 and L0 is itself a noisy render. The levels use one weight
image for all of them: the spp-weighted mean of every θ* replicate at every level (the best L0 the
budget gives). Its error is common to all levels, so it cannot mimic the C/N^p term; it changes λ by
a relative O(Var/(L0² N_total)) amount. HCR_Neff weighs by the N_eff set's own θ* image, exactly as
`noise.chi2_exponent` does (the direct method). Weights stay fixed under the bootstrap.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from nlosbench.bank import check_spp
from nlosbench.bounds.hcr import HCRResult, as_numpy, hcr_from_lambda
from nlosbench.noise import NoiseModel, QuadraticNoise, check_finite, to_float64


def check_levels(levels: Sequence[int], replicates: int = 1) -> np.ndarray:
    """`check_spp`, and at least 2 distinct values: the line λ + C/N^p needs two.

    Parameters
    ----------
    levels : sequence of int
        spp levels N_i.
    replicates : int, optional
        R: each level must split into R replicates of N_i/R spp.

    Returns
    -------
    ndarray of int, shape (k,)
        The levels, checked.
    """
    lv = check_spp(levels, replicates)
    if np.unique(lv).size < 2:
        raise ValueError(f"levels {lv.tolist()}: the fit λ̃ = λ + C/N^p needs at least 2 distinct spp levels "
                         f"(got k = {lv.size} level(s), {np.unique(lv).size} distinct)")
    return lv


def quadratic(noise: NoiseModel) -> QuadraticNoise:
    """`noise` if its λ is Σ w(L0)(L1 − L0)² (the form the C/N^p analysis rests on), else TypeError."""
    if not isinstance(noise, QuadraticNoise):
        raise TypeError(f"inexact-rendering analysis needs a noise model with λ = Σ w(L0)(L1 − L0)² "
                        f"(a QuadraticNoise such as awgn or poisson), got {type(noise).__name__}")
    return noise


def replicate_grams(X0, XD, weight_image, noise: NoiseModel) -> np.ndarray:
    """Gram matrices (K, R, R) float64 of replicate differences, G_rs = Σ_ω w D_r D_s.

    D_r = XD[r, k] − X0[r] (direct differences in float64, XD taken to float64 one Δ at a time) and
    w = noise.weight(weight_image). A Δ whose difference is non-zero at a pixel of infinite weight
    (Poisson, L0 = 0) gets G = +inf (λ = +inf: that Δ gives no bound), as in `noise.chi2_exponent`.

    Parameters
    ----------
    X0 : torch.Tensor or array_like of shape (R, *S)
        Replicates at θ*.
    XD : torch.Tensor or array_like of shape (R, K, *S)
        Replicates at θ*+Δ_k.
    weight_image : torch.Tensor or array_like of shape (*S)
        The image the noise weight is taken at (the θ* render).
    noise : NoiseModel
        A quadratic noise model (λ = Σ_ω w(L0)(L1 − L0)²: AWGN, Poisson); others raise TypeError.

    Returns
    -------
    ndarray of shape (K, R, R)
        The Gram matrix of each Δ, float64.
    """
    noise = quadratic(noise)
    X0, Lw = to_float64(X0, "X0"), to_float64(weight_image, "weight_image")
    XD = XD if isinstance(XD, torch.Tensor) else torch.as_tensor(np.asarray(XD))
    R, S = X0.shape[0], tuple(X0.shape[1:])
    if tuple(XD.shape[:1]) != (R,) or tuple(XD.shape[2:]) != S or tuple(Lw.shape) != S:
        raise ValueError(f"expected X0 (R, *S), XD (R, K, *S), weight_image (*S); got {tuple(X0.shape)}, "
                         f"{tuple(XD.shape)}, {tuple(Lw.shape)}")
    check_finite(X0, "X0")
    check_finite(XD, "XD")
    noise.validate(Lw, "weight image (θ* render)")
    w = noise.weight(Lw).expand(S).reshape(-1)
    inf = torch.isinf(w)
    wf = torch.where(inf, torch.zeros_like(w), w)
    any_inf = bool(inf.any())
    K = XD.shape[1]
    G = np.empty((K, R, R))
    for k in range(K):
        D = (to_float64(XD[:, k], "XD") - X0).reshape(R, -1)
        G[k] = as_numpy((D * wf) @ D.T)
        if any_inf and bool((D[:, inf] != 0).any()):
            G[k] = np.inf
    return G


def lambda_from_grams(G: np.ndarray) -> np.ndarray:
    """λ̃ of the replicate-mean images, 1ᵀG1/R², from Grams (…, R, R) → (…)."""
    R = G.shape[-1]
    return G.sum(axis=(-1, -2)) / R**2


@dataclass
class LambdaFit:
    """Weighted least-squares fit of λ̃^(N_i) = λ + C/N_i^p over the levels, per Δ.

    The `fit` of an `InexactHCR`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    lam : ndarray of shape (…)
        λ̂ — ≤ 0 is *unresolved* (kept, never clipped), +inf where some level has λ̃ = +inf.
    C : ndarray of shape (…)
        The bias coefficient (λ units × spp^p); NaN where λ̂ = +inf.
    se : ndarray of shape (…)
        Standard error of λ̂ from the weighted residuals (NaN for k = 2 levels, where the line passes
        through both points).
    power : float
        The decay rate p used.
    noise_dominated : ndarray of bool, shape (…)
        C/N_max^p > λ̂ — even at the highest level rendering noise outweighs the signal.

    Examples
    --------
    λ̃ = 1 + 8/N exactly at three levels: the fit recovers λ = 1 and C = 8:

    >>> import numpy as np
    >>> levels = [8, 16, 32]
    >>> fit = nb.bounds.inexact.fit_lambda(np.array([[1 + 8 / n] for n in levels]), levels)
    >>> fit.lam.round(9).tolist(), fit.C.round(9).tolist(), fit.noise_dominated.tolist()
    ([1.0], [8.0], [False])
    """

    lam: np.ndarray
    C: np.ndarray
    se: np.ndarray
    power: float
    noise_dominated: np.ndarray


def fit_lambda(lam_levels, levels: Sequence[int], power: float = 1.0) -> LambdaFit:
    """Fit λ̃ = λ + C/N^p by weighted least squares with weights N_i^p (the inverse of the O(N^−p)
    variance of λ̃).

    Parameters
    ----------
    lam_levels : array_like of shape (k, …)
        λ̃ at each level (extra dims: Δ, resamples, …); +inf allowed, NaN and −inf are errors.
    levels : sequence of int
        The spp levels (k,), at least 2 distinct.
    power : float, optional
        p > 0 (1 for a path tracer, or `decay_check(...).p`).

    Returns
    -------
    LambdaFit
        λ̂, C, the standard error of λ̂ and the noise-dominated flags, each of shape (…).
    """
    lv = check_levels(levels).astype(np.float64)
    if not (np.isfinite(power) and power > 0):
        raise ValueError(f"power p must be finite and > 0, got {power}")
    y = as_numpy(lam_levels)
    if y.shape[:1] != lv.shape:
        raise ValueError(f"lam_levels must have shape ({lv.size}, ...), got {y.shape}")
    if np.isnan(y).any() or (y == -np.inf).any():
        raise ValueError("lam_levels contains NaN or -inf")
    k = lv.size
    x = lv ** -power
    om = (lv / lv.max()) ** power  # weights ∝ N^p, scaled to ≤ 1
    ex = (slice(None),) + (None,) * (y.ndim - 1)
    inf = np.isinf(y).any(axis=0)
    yf = np.where(np.isinf(y), 0.0, y)
    s0, s1, s2 = om.sum(), (om * x).sum(), (om * x * x).sum()
    sy, sxy = (om[ex] * yf).sum(axis=0), (om[ex] * x[ex] * yf).sum(axis=0)
    det = s0 * s2 - s1 * s1
    lam = (s2 * sy - s1 * sxy) / det
    C = (s0 * sxy - s1 * sy) / det
    if k > 2:
        resid = yf - lam[None] - C[None] * x[ex]
        s2r = (om[ex] * resid**2).sum(axis=0) / (k - 2)
        se = np.sqrt(s2r * s2 / det)
    else:
        se = np.full(lam.shape, np.nan)
    lam, C, se = np.where(inf, np.inf, lam), np.where(inf, np.nan, C), np.where(inf, np.nan, se)
    with np.errstate(invalid="ignore"):
        dominated = ~inf & (C * lv.max() ** -power > lam)
    return LambdaFit(lam=lam, C=C, se=se, power=float(power), noise_dominated=dominated)


@dataclass
class InexactHCR:
    """HCR at one θ* from inexact renders: HCR_Neff (direct, one render set at N_eff) and HCR-hat
    (from λ̂) over the same Δ set; the interval [HCR_Neff, HCR-hat] in log10 (units²).

    Returned by `inexact_hcr`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    levels : ndarray of int, shape (k,)
        Total spp per level.
    n_eff : int
        N_eff, the spp of the direct render set.
    deltas : ndarray of shape (K,) or (K, P)
        The offsets Δ, parameter units.
    lam_levels : ndarray of shape (k, K)
        λ̃ per level and Δ.
    lam_eff : ndarray of shape (K,)
        λ̃ at N_eff.
    fit : LambdaFit
        The λ̂ fit over the levels.
    hcr_neff : HCRResult
        HCR_Neff, from `lam_eff`.
    hcr_hat : HCRResult
        HCR-hat, from the fitted λ̂ (`hcr_hat.unresolved` when some λ̂ ≤ 0).
    width : float
        log10 HCR-hat − log10 HCR_Neff, in decades (negative: the ends crossed).
    inverted : bool
        width < 0.
    confidence : float
        The level of the bootstrap intervals.
    ci_neff, ci_hat : ndarray of shape (2,)
        Bootstrap intervals (log10) at `confidence` — the observed value plus the resamples' spread
        around their median (`_spread_interval`), NaN without bootstrap.
    n_boot : int
        The number of bootstrap resamples (0: none).
    boot_unresolved : float
        Fraction of resamples whose HCR-hat was unresolved (NaN without bootstrap).
    samples_levels, samples_eff : int
        spp spent per image by each method (Σ N_i, N_eff).

    Examples
    --------
    Renders without rendering noise at two levels: no bias to remove, and the interval closes:

    >>> import numpy as np
    >>> g, deltas = np.array([1.0, 2.0, 2.0]), np.array([0.5, 1.0])
    >>> X0, XD = np.tile(g, (2, 1, 1)), np.tile((1 + deltas)[:, None] * g, (2, 1, 1, 1))  # (k, R = 1, ...)
    >>> r = nb.bounds.inexact_hcr(X0, XD, deltas, [8, 16], nb.noise.AWGN(3.0), X0[0], XD[0], 24)
    >>> r.width, r.fit.C.tolist(), r.inverted
    (0.0, [0.0, 0.0], False)
    """

    levels: np.ndarray
    n_eff: int
    deltas: np.ndarray
    lam_levels: np.ndarray
    lam_eff: np.ndarray
    fit: LambdaFit
    hcr_neff: HCRResult
    hcr_hat: HCRResult
    width: float
    inverted: bool
    confidence: float
    ci_neff: np.ndarray
    ci_hat: np.ndarray
    n_boot: int
    boot_unresolved: float
    samples_levels: int
    samples_eff: int


def inexact_hcr(X0, XD, deltas, levels: Sequence[int], noise: NoiseModel, X0_eff, XD_eff, n_eff: int,
                lower=None, upper=None, power: float = 1.0, bootstrap: int = 0, confidence: float = 0.9,
                seed: int = 0) -> InexactHCR:
    """HCR_Neff, HCR-hat and their bootstrap intervals at one θ* (see the module docstring).

    Parameters
    ----------
    X0 : torch.Tensor or array_like of shape (k, R, *S)
        θ* replicates per level (R replicates of N_i/R spp each).
    XD : torch.Tensor or array_like of shape (k, R, K, *S)
        θ*+Δ_k replicates per level.
    deltas : array_like of shape (K,) or (K, P)
        Offsets Δ_k, parameter units.
    levels : sequence of int
        Total spp per level (k,), at least 2 distinct, each divisible into the R replicates.
    noise : NoiseModel
        A quadratic noise model (AWGN, Poisson).
    X0_eff : torch.Tensor or array_like of shape (R, *S)
        The N_eff set at θ* (R replicates of n_eff/R spp).
    XD_eff : torch.Tensor or array_like of shape (R, K, *S)
        The N_eff set at θ*+Δ_k.
    n_eff : int
        N_eff, the spp of the N_eff set (recorded; equal budget: N_eff ≈ Σ N_i).
    lower, upper : float or array_like of shape (P,), optional
        Limits on Δ as in `hcr`. None: no limit.
    power : float, optional
        Decay rate p of the fit λ̃ = λ + C/N^p (1 for a path tracer, or `decay_check(...).p`).
    bootstrap : int, optional
        Half-sample resamples over the replicates (0: none; needs R ≥ 2).
    confidence : float, optional
        Level of the bootstrap intervals, in (0, 1).
    seed : int, optional
        The bootstrap's random stream (derive it).

    Returns
    -------
    InexactHCR
        HCR_Neff and HCR-hat (parameter units²), the λ̂ fit, and the bootstrap intervals (log10).

    Examples
    --------
    A linear toy (L = θ·g, θ* = 1) with rendering noise of variance 1/N per pixel, R = 2 replicates: the
    direct N_eff set's λ̃ carries the noise's bias, so HCR_Neff sits below HCR-hat:

    >>> import numpy as np
    >>> g, deltas, levels, rng = np.array([1.0, 2.0, 2.0]), np.array([0.5, 1.0]), [8, 16], np.random.default_rng(0)
    >>> def sets(n):  # R = 2 replicates of n/2 spp: noise variance 2/n
    ...     return (1 + np.concatenate([[0.0], deltas]))[:, None] * g + rng.standard_normal((2, 3, 3)) / np.sqrt(n / 2)
    >>> X = np.stack([sets(n) for n in levels])  # (k, R, 1 + K, S): θ* first, then θ* + Δ
    >>> eff = sets(24)
    >>> r = nb.bounds.inexact_hcr(X[:, :, 0], X[:, :, 1:], deltas, levels, nb.noise.AWGN(3.0),
    ...                           eff[:, 0], eff[:, 1:], n_eff=24)
    >>> r.width > 0, r.hcr_neff.log10 < r.hcr_hat.log10, r.samples_levels == r.samples_eff
    (True, True, True)
    """
    X0, X0_eff = to_float64(X0, "X0"), to_float64(X0_eff, "X0_eff")
    # the Δ renders stay in their dtype: `replicate_grams` takes them to float64 one Δ at a time
    XD, XD_eff = (x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x)) for x in (XD, XD_eff))
    k, R = X0.shape[:2]
    lv = check_levels(levels, R)
    if lv.size != k or XD.shape[:2] != (k, R) or X0_eff.shape[0] != R or XD_eff.shape[0] != R:
        raise ValueError(f"expected X0 (k={lv.size}, R, *S), XD (k, R, K, *S), X0_eff (R, *S), XD_eff (R, K, *S); "
                         f"got {tuple(X0.shape)}, {tuple(XD.shape)}, {tuple(X0_eff.shape)}, {tuple(XD_eff.shape)}")
    if not (0 < confidence < 1):
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if bootstrap and R < 2:
        raise ValueError("a bootstrap over render replicates needs replicates >= 2 (or bootstrap = 0)")
    d = as_numpy(deltas)
    pooled = torch.einsum("i,ir...->...", torch.as_tensor(lv / lv.sum(), dtype=torch.float64, device=X0.device), X0) / R
    G = np.stack([replicate_grams(X0[i], XD[i], pooled, noise) for i in range(k)])  # (k, K, R, R)
    G_eff = replicate_grams(X0_eff, XD_eff, X0_eff.mean(dim=0), noise)  # (K, R, R)
    lam_levels, lam_eff = lambda_from_grams(G), lambda_from_grams(G_eff)
    fit = fit_lambda(lam_levels, lv, power)
    h_eff = hcr_from_lambda(lam_eff, d, lower, upper)
    h_hat = hcr_from_lambda(fit.lam, d, lower, upper)
    ci_eff = ci_hat = np.full(2, np.nan)
    unres = np.nan
    if bootstrap:
        b_eff, b_hat, b_unres = _bootstrap(G, G_eff, lv, power, d, lower, upper, int(bootstrap),
                                           np.random.default_rng(seed))
        ci_eff = _spread_interval(h_eff.log10, b_eff, confidence)
        ci_hat = _spread_interval(h_hat.log10, b_hat, confidence)
        unres = float(b_unres.mean())
    width = h_hat.log10 - h_eff.log10
    return InexactHCR(
        levels=lv,
        n_eff=int(n_eff),
        deltas=d,
        lam_levels=lam_levels,
        lam_eff=lam_eff,
        fit=fit,
        hcr_neff=h_eff,
        hcr_hat=h_hat,
        width=float(width),
        inverted=bool(width < 0),
        confidence=float(confidence),
        ci_neff=ci_eff,
        ci_hat=ci_hat,
        n_boot=int(bootstrap),
        boot_unresolved=unres,
        samples_levels=int(lv.sum()),
        samples_eff=int(n_eff),
    )


def half_sample_lambda(G: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Resampled λ̃* (B, …) from Grams G (…, R, R) and half-sample subset masks.

    λ̃_S = 1_SᵀG1_S/m² is λ̃ of the mean of the replicates in S. Its deviation from its exact mean over
    all subsets, E_S λ̃_S = [(m/R) tr G + m(m−1)/(R(R−1)) (1ᵀG1 − tr G)]/m², scaled by √(m/(R−m))
    (the delete-d jackknife factor), is added to the observed λ̃ = 1ᵀG1/R²: E*[λ̃*] = λ̃ exactly, and
    Var*(λ̃*) ≈ Var(λ̃) for the mean-linear part.

    Parameters
    ----------
    G : ndarray of shape (…, R, R)
        Gram matrices of replicate differences (`replicate_grams`).
    masks : ndarray of bool, shape (B, …', R)
        Subset masks with m ones each (half-samples: m = ⌊R/2⌋; …' = the leading dims of G without the
        Δ axis, broadcast over Δ).

    Returns
    -------
    ndarray of shape (B, …)
        The resampled λ̃* (+inf where G is).
    """
    R = G.shape[-1]
    m = int(masks.sum(axis=-1).flat[0])
    if R < 2 or not np.all(masks.sum(axis=-1) == m) or not 0 < m < R:
        raise ValueError(f"half-sample masks need 0 < m < R = {R} ones each")
    inf = np.isinf(G).any(axis=(-1, -2))
    Gf = np.where(np.isinf(G), 0.0, G)
    s = masks[..., None, :].astype(np.float64)  # (B, …', 1, R): broadcast over the Δ axis
    quad = np.einsum("...r,...rs,...s->...", s, Gf, s) / m**2
    tr, tot = np.trace(Gf, axis1=-2, axis2=-1), Gf.sum(axis=(-1, -2))
    mean = ((m / R) * tr + m * (m - 1) / (R * (R - 1)) * (tot - tr)) / m**2
    return np.where(inf, np.inf, tot / R**2 + np.sqrt(m / (R - m)) * (quad - mean))


def _half_masks(rng: np.random.Generator, shape: tuple, R: int) -> np.ndarray:
    """Random half-sample masks (*shape, R) with ⌊R/2⌋ ones each (subsets without replacement)."""
    order = rng.random((*shape, R)).argsort(axis=-1)
    return order < R // 2


def _bootstrap(G, G_eff, levels, power, deltas, lower, upper, n: int, rng: np.random.Generator):
    """log10 HCR_Neff* (n,), log10 HCR-hat* (n,) and HCR-hat* unresolved flags (n,) over n half-sample
    resamples of the replicates (independently per level and for the N_eff set)."""
    k, K, R, _ = G.shape
    lam_lv = half_sample_lambda(G, _half_masks(rng, (n, k), R))  # (n, k, K)
    lam_eff = half_sample_lambda(G_eff, _half_masks(rng, (n,), R))  # (n, K)
    lam_hat = fit_lambda(np.moveaxis(lam_lv, 1, 0), levels, power).lam  # (n, K)
    out = np.empty((3, n))
    for b in range(n):
        he, hh = hcr_from_lambda(lam_eff[b], deltas, lower, upper), hcr_from_lambda(lam_hat[b], deltas, lower, upper)
        out[:, b] = he.log10, hh.log10, hh.unresolved
    return out[0], out[1], out[2].astype(bool)


def _spread_interval(observed: float, boot: np.ndarray, confidence: float) -> np.ndarray:
    """[lo, hi] = observed + (bootstrap quantiles − bootstrap median), in log10: the run-to-run spread
    the resamples show, placed around the observed value. Recentring matters because a resample of a
    sup over Δ is itself shifted up (the sup of noisier functionals); quantiles are taken without
    interpolation, so ±inf (resamples with no usable Δ) pass through as unbounded ends."""
    a = (1.0 - confidence) / 2
    q = np.array([np.quantile(boot, a, method="lower"), np.quantile(boot, 1 - a, method="higher")])
    with np.errstate(invalid="ignore"):
        return observed + q - np.quantile(boot, 0.5, method="lower")
