"""Check of the rendering-noise decay rate (the paper's appendix): does Σ_ω W_ω Var L̃^(N)(ω) fall as
N^(−p) with p = 1?

From repeated independent renders at several spp N, the per-pixel variances Var_N(ω) are weighted
by random W_ω ~ U[0, L_max] into γ(N) = Σ_ω W_ω Var_N(ω); for each weighting the model
γ(N) = C_p N^(−p) is fitted by least squares over a grid of p and p_opt is the best p. The
distribution of p_opt (over many weightings) says which rate the renderer follows; the inexact-HCR
fit λ̃ = λ + C/N^p can then use the measured p instead of assuming 1. Scaling W (L_max) scales γ
and C_p only, so p_opt does not depend on L_max.

Few repeats bias p_opt low on a renderer with fireflies: a heavy-tailed pixel's sample variance is
usually below its mean, more so at low N. Pool pixels (several θ) or repeats. Measured on
cornell_ball (8…64 spp): one θ × 4 repeats gave p = 0.78; one θ × 16 repeats 1.00–1.05; four θ × 8
repeats 0.96–0.99.
"""
from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nlosbench.bounds.hcr import as_numpy
from nlosbench.bounds.inexact import check_levels


def pixel_variances(renders) -> np.ndarray:
    """Unbiased per-pixel variance (ddof = 1) over repeats → (k, *S) float64.

    Parameters
    ----------
    renders : torch.Tensor or array_like of shape (k, R, *S)
        R ≥ 2 independent renders (distinct seeds) at each of k spp levels.

    Returns
    -------
    ndarray of shape (k, *S)
        The per-pixel variance at each level, float64 (radiance units²): the input of `decay_check`.
    """
    X = as_numpy(renders)
    if X.ndim < 3 or X.shape[1] < 2:
        raise ValueError(f"need renders (k, R, *S) with R >= 2 repeats per level, got shape {X.shape}")
    return X.var(axis=1, ddof=1)


@dataclass
class DecayResult:
    """Distribution of the fitted decay rate over random weightings.

    Returned by `decay_check`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    levels : ndarray of int, shape (k,)
        The spp levels N.
    p : float
        Median p_opt: the measured rate.
    p_opt : ndarray of shape (n_weights,)
        The best p of each weighting.
    p_grid : ndarray of shape (G,)
        The grid of p searched.
    fit_error : ndarray of shape (G,)
        Mean over weightings of the relative squared error ‖γ − C_p N^−p‖² / ‖γ‖² at each grid p.
    mean, std : float
        Mean and standard deviation of p_opt.
    mode : float
        The most frequent grid value of p_opt.
    q05, q95 : float
        The 5 % and 95 % quantiles of p_opt.
    at_edge : float
        Fraction of p_opt on the ends of p_grid (widen it when large).
    gamma_example : ndarray of shape (k,)
        γ(N) of the first weighting.
    c_example : float
        Its least-squares C at p.
    far_from_one : bool
        |p − 1| > tolerance.
    warning : str
        The message warned ("" if none).

    Examples
    --------
    >>> import numpy as np
    >>> levels = np.array([8, 16, 32, 64])
    >>> V = np.random.default_rng(1).uniform(0.5, 2.0, 50) / levels[:, None]  # variances falling as 1/N
    >>> r = nb.bounds.decay_check(V, levels, n_weights=100)
    >>> r.levels.tolist(), r.q05 <= r.p <= r.q95, r.far_from_one
    ([8, 16, 32, 64], True, False)
    """

    levels: np.ndarray
    p: float
    p_opt: np.ndarray
    p_grid: np.ndarray
    fit_error: np.ndarray
    mean: float
    std: float
    mode: float
    q05: float
    q95: float
    at_edge: float
    gamma_example: np.ndarray
    c_example: float
    far_from_one: bool
    warning: str


def decay_check(variances, levels: Sequence[int], n_weights: int = 10_000, l_max: float = 1.0,
                p_grid: tuple[float, float, float] = (0.5, 1.5, 0.001), seed: int = 0,
                tolerance: float = 0.1) -> DecayResult:
    """Fit γ(N) = C_p N^(−p) for `n_weights` random weightings W ~ U[0, l_max] of the per-pixel
    variances, and return the distribution of the best p.

    Warns (RuntimeWarning) when the median p_opt is farther than `tolerance` from 1 or more than 5 % of
    the p_opt sit on the grid ends.

    Parameters
    ----------
    variances : array_like of shape (k, *S)
        Per-pixel variances at each spp level (finite, ≥ 0), e.g. the variance over R ≥ 2 repeats,
        renders.var(axis=1, ddof=1) for renders (k, R, *S).
    levels : sequence of int
        The spp levels N (k,), at least 2 distinct.
    n_weights : int, optional
        The number of random weightings.
    l_max : float, optional
        The weights' upper end (> 0); it scales γ and C_p only, not p_opt.
    p_grid : (float, float, float), optional
        (start, stop, step) of the grid of p searched (the paper: (0.85, 1.15, 0.001); the default is
        wider so that p = 0.8 is found).
    seed : int, optional
        Drives the random weights (derive it).
    tolerance : float, optional
        How far from 1 the median p may be before a warning.

    Returns
    -------
    DecayResult
        The measured rate p (median p_opt) and the distribution of p_opt; `p` can be passed as the
        `power` of `inexact_hcr`.

    Examples
    --------
    Variances that fall exactly as 1/N give p = 1:

    >>> import numpy as np
    >>> levels = np.array([8, 16, 32, 64])
    >>> V = np.random.default_rng(0).uniform(0.5, 2.0, 100) / levels[:, None]
    >>> r = nb.bounds.decay_check(V, levels, n_weights=200)
    >>> r.p, r.warning
    (1.0, '')
    """
    lv = check_levels(levels).astype(np.float64)
    V = as_numpy(variances)
    if V.shape[:1] != lv.shape or V.ndim < 2:
        raise ValueError(f"variances must have shape ({lv.size}, *S), got {V.shape}")
    V = V.reshape(lv.size, -1)
    if not np.all(np.isfinite(V)) or np.any(V < 0):
        raise ValueError("variances must be finite and >= 0")
    if not (np.isfinite(l_max) and l_max > 0) or n_weights < 1:
        raise ValueError(f"need l_max > 0 and n_weights >= 1, got {l_max}, {n_weights}")
    start, stop, step = p_grid
    if not (0 < start < stop and step > 0):
        raise ValueError(f"p_grid must be (start, stop, step) with 0 < start < stop and step > 0, got {p_grid}")
    grid = np.round(np.arange(start, stop + step / 2, step), 12)
    X = lv[None, :] ** -grid[:, None]  # (G, k): N^−p
    xx = (X * X).sum(axis=1)  # (G,)
    rng = np.random.default_rng(seed)
    chunk = max(1, 2**24 // V.shape[1])  # weightings per block: ≤ 128 MB of float64 weights
    p_opt = np.empty(n_weights)
    err_sum = np.zeros(grid.size)
    gamma0 = None
    for s in range(0, n_weights, chunk):
        W = rng.uniform(0.0, l_max, size=(min(chunk, n_weights - s), V.shape[1]))
        gam = W @ V.T  # (B, k)
        if gamma0 is None:
            gamma0 = gam[0].copy()
        gg = (gam * gam).sum(axis=1, keepdims=True)
        gx = gam @ X.T  # (B, G)
        err = np.maximum(gg - gx * gx / xx, 0.0) / np.where(gg > 0, gg, 1.0)  # relative squared error
        p_opt[s:s + gam.shape[0]] = grid[np.argmin(err, axis=1)]
        err_sum += err.sum(axis=0)
    p = float(np.median(p_opt))
    ip = int(np.argmin(np.abs(grid - p)))
    vals, counts = np.unique(p_opt, return_counts=True)
    at_edge = float(np.mean((p_opt <= grid[0]) | (p_opt >= grid[-1])))
    msgs = []
    far = abs(p - 1.0) > tolerance
    if far:
        msgs.append(f"measured rendering-noise decay rate p = {p:.3f} is far from 1 (tolerance {tolerance}); "
                    "fit λ̃ = λ + C/N^p with the measured p")
    if at_edge > 0.05:
        msgs.append(f"{at_edge:.0%} of p_opt sit on the ends of the p grid [{grid[0]}, {grid[-1]}]: widen it")
    warning = "; ".join(msgs)
    if warning:
        warnings.warn(warning, RuntimeWarning, stacklevel=2)
    return DecayResult(levels=lv.astype(np.int64), p=p, p_opt=p_opt, p_grid=grid, fit_error=err_sum / n_weights,
                       mean=float(p_opt.mean()), std=float(p_opt.std()), mode=float(vals[np.argmax(counts)]),
                       q05=float(np.quantile(p_opt, 0.05)), q95=float(np.quantile(p_opt, 0.95)), at_edge=at_edge,
                       gamma_example=gamma0, c_example=float(gamma0 @ X[ip] / xx[ip]), far_from_one=far,
                       warning=warning)
