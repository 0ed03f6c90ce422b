"""Unbiased squared means from independent replicates: the order-2 U-statistic and its jackknife.

For R independent replicates D_1..D_R of a quantity with mean d (a rendered difference image
L̃_r(θ*+Δ) − L̃_r(θ*), or an FD Jacobian J̃_r) and a weight w that does not depend on them, the Gram
G_rs = Σ_ω w D_r D_s has E G_rs = Σ_ω w d² for r ≠ s: the noise × noise terms vanish between independent
replicates. So

    est = Σ_{r≠s} G_rs / (R(R−1))

is unbiased for Σ_ω w d² (λ(Δ) = ‖L(θ*+Δ) − L(θ*)‖²_w, or the Fisher information F = ‖J‖²_w), while the
plug-in from the replicate mean, 1ᵀG1/R², carries the rendering noise tr(G)/R²-type term (λ̃ = λ + C/N).
`est` can be ≤ 0 where the signal is below the rendering noise: that is reported, never clipped.

Standard error: the delete-one jackknife over replicates (R ≥ 3; NaN for R = 2). Measured on toys (see
`unbiased_fisher`): right where the signal dominates, conservative (SE² up to ~2× the variance) where
the noise × noise part dominates. With R − 1 degrees of freedom, confidence limits use Student's t.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class UStat:
    """est (*T): the U-statistic; se (*T): its jackknife standard error (NaN for R = 2); loo (R, *T):
    the estimate without replicate k (empty for R = 2); replicates: R."""

    est: np.ndarray
    se: np.ndarray
    loo: np.ndarray
    replicates: int


def u_statistic(G: np.ndarray) -> UStat:
    """The U-statistic and its jackknife from Grams G (R, R, *T) (G_rs = Σ_ω w D_r D_s, any trailing
    shape *T, e.g. (K,) offsets or (P, P) parameter pairs), float64."""
    G = np.asarray(G, dtype=np.float64)
    R = G.shape[0]
    if G.ndim < 2 or G.shape[1] != R or R < 2:
        raise ValueError(f"need Grams (R, R, ...) over R >= 2 independent replicates, got shape {G.shape}")
    diag = np.einsum("rr...->r...", G)
    cross = G.sum(axis=(0, 1)) - diag.sum(axis=0)
    est = cross / (R * (R - 1))
    if R < 3:
        return UStat(est, np.full(est.shape, math.nan), np.empty((0,) + est.shape), R)
    # leave replicate k out: drop the pairs (k, s) and (r, k) from the sum over r ≠ s
    row, col = G.sum(axis=1), G.sum(axis=0)
    loo = (cross[None] - (row - diag) - (col - diag)) / ((R - 1) * (R - 2))
    se = np.sqrt((R - 1) / R * ((loo - loo.mean(axis=0)) ** 2).sum(axis=0))
    return UStat(est, se, loo, R)


def t_quantile(level: float, replicates: int, tests: int = 1) -> float:
    """One-sided Student-t quantile (R − 1 degrees of freedom) for confidence `level` shared by `tests`
    limits (Bonferroni: each at 1 − (1 − level)/tests). NaN for fewer than 3 replicates (no SE)."""
    if not 0 < level < 1:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    if replicates < 3:
        return math.nan
    from scipy import stats

    return float(stats.t.ppf(1.0 - (1.0 - level) / max(int(tests), 1), replicates - 1))


def pairwise_ustat(X, weights, chunk_bytes: int = 256 * 2**20) -> UStat:
    """U-statistics of Σ_ω w_i (X_r[j] − X_r[i])² over R replicates for every pair of G points: est (G, G)
    (symmetric in (i, j) when the weights are), se (G, G), loo (R, G, G); diagonal 0.

    X: (R, G, N) float (replicate r of point i, pixels flattened); weights: a scalar, an (N,) array, or
    (G, N) (row i weights the pairs (i, j), e.g. scale / L_i for Poisson). Differences are direct (float64,
    column chunks of at most `chunk_bytes`)."""
    X = np.asarray(X)
    R, G, N = X.shape
    W = np.broadcast_to(np.asarray(weights, dtype=np.float64), (G, N)) if np.ndim(weights) else None
    w0 = float(weights) if W is None else None
    grams = np.zeros((R, R, G, G))
    step = max(1, chunk_bytes // (8 * R * N))
    for i in range(G):
        xi = X[:, i].astype(np.float64)
        wi = w0 if W is None else W[i]
        for j0 in range(0, G, step):
            j1 = min(G, j0 + step)
            D = X[:, j0:j1].astype(np.float64) - xi[:, None]  # (R, J, N)
            grams[:, :, i, j0:j1] = np.einsum("rjn,sjn->rsj", D * wi, D)
    return u_statistic(grams)
