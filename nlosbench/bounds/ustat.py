"""Unbiased squared means from independent replicates: the order-2 U-statistic and its standard error.

For R independent replicates D_1..D_R of a quantity with mean d (a rendered difference image
L̃_r(θ*+Δ) − L̃_r(θ*), or an FD Jacobian J̃_r) and a weight w that does not depend on them, the Gram
G_rs = Σ_ω w D_r D_s has E G_rs = Σ_ω w d² for r ≠ s: the noise × noise terms vanish between independent
replicates. So

    est = Σ_{r≠s} G_rs / (R(R−1))

is unbiased for Σ_ω w d² (λ(Δ) = ‖L(θ*+Δ) − L(θ*)‖²_w, or the Fisher information F = ‖J‖²_w), while the
plug-in from the replicate mean, 1ᵀG1/R², carries the rendering noise tr(G)/R²-type term (λ̃ = λ + C/N).
`est` can be ≤ 0 where the signal is below the rendering noise: that is reported, never clipped.

Standard error. `u_statistic` (any Grams): the delete-one jackknife over replicates (R ≥ 3; NaN for
R = 2), with R − 1 degrees of freedom. In terms of the Hoeffding parts (ζ₁ signal × noise, ζ₂ noise × noise) the
jackknife's expectation is 4ζ₁/R + 4ζ₂/(R(R − 2)) against the variance 4ζ₁/R + 2ζ₂/(R(R − 1)): ζ₂ counts
2(R − 1)/(R − 2) times, 4× at R = 3 (spot_rgb's F̂ at R = 3: SE 1.08× its SD, so its one-sided 95 % ends missed
3.6 %): right where the signal dominates, conservative where the noise × noise part does.
`pixel_ustat` (sums over pixels): a path tracer's Monte Carlo errors are independent across pixels (each
pixel's samples are its own; common random numbers couple θ within a pixel, never two pixels), so the
U-statistic is a sum of independent per-pixel-group terms U_m and its variance is the sum of theirs. For R ≥ 4
each Var U_m has a distribution-free unbiased estimate: with the group's kernel H_rs = Σ_{ω∈m} w X_r X_s (r ≠ s),
S = Σ_{r≠s} H_rs, a_r = Σ_{s≠r} H_rs and Q = Σ_{r≠s} H_rs², U_m = S/(R(R − 1)) and

    θ̂²_m = (S² − 4 Σ_r a_r² + 2Q) / (R(R − 1)(R − 2)(R − 3))

is the degree-4 U-statistic of θ_m² (the mean of H_rs·H_tu over distinct r, s, t, u: S² less the products that
share one index, 4 Σ a_r² − 4Q, and those that share both, 2Q), so v_m = U_m² − θ̂²_m is unbiased for Var U_m
(E U² = Var U + θ²) and Σ_m v_m for the variance of the sum (`group_variances`, `pair_squares`; checked by exact
enumeration in the tests). A v_m may be < 0; the total is used where it is > 0, the jackknife total where it is
not. R = 3 has no such estimate (θ² needs four distinct replicates): there the per-group jackknife, conservative.
The degrees of freedom are Satterthwaite's from the per-group jackknife variances, (Σ v)² / Σ v²/(R − 1) — many
more than R − 1 — so the confidence limits are far tighter at equal renders. Confidence limits use Student's t
with those degrees of freedom (`t_quantile`). A contrast of two statistics over the same replicates (the FD step
check, the Richardson extrapolation) has the kernel H_b − c·H_a: its Q comes from both (`pair_squares`).
Covariances between statistics (`covariance`, the HCR lower end's joint level) use only their correlations, from
the per-group jackknife: its ζ₂ inflation is a common factor of statistics of the same replicates, and the
variances themselves are the unbiased ones above.

Groups. The values of one pixel are *not* independent: its C colour channels (and a transient scan point's
time bins) come from the same light paths, so their errors are correlated (0.76–0.998 in the Π hallway's FD
Jacobians). The unit of independence is the group of `group` consecutive values (N = M·group, flattened from
(…, C) images with C last): each group's terms are summed before the leave-one-out variance, so
v_m = Var(Σ_c term_mc) carries the channels' covariances. Treating the C values as independent instead
under-states the SE by up to √C (×1.55 measured on the Π hallway's F). The group size comes from the model
(`ForwardModel.channels`), never from a guess at an array's shape.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass
class UStat:
    """A U-statistic over R independent replicates, with its standard error and leave-one-out values.

    Returned by `u_statistic` and `pairwise_ustat`, read by `hcr_interval` and `zzb_interval`; each
    parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    est : ndarray of shape (*T)
        The U-statistic (unbiased; may be ≤ 0 where the signal is below the rendering noise).
    se : ndarray of shape (*T)
        Its standard error (NaN for R = 2).
    loo : ndarray of shape (R, *T)
        The estimate without replicate k (empty for R = 2).
    replicates : int
        R.
    df : ndarray of shape (*T) or None, optional
        Degrees of freedom of the SE (None: R − 1, the replicate jackknife's).
    terms : ndarray of shape (R, *T, M) or None, optional
        Per-pixel-group leave-one-outs, the M summands of `loo` (`pixel_ustat`): two statistics over the same
        replicates and pixels get their covariance from them (`covariance`); None where not kept.
    noise : ndarray of shape (*T) or None, optional
        The part of se² that does not scale with the signal (all but the signal × noise term 4ζ₁/R; `sum_terms`),
        for score-type limits (`limits`); None (or NaN) where unknown: the limits are est ∓ t·se there.

    Examples
    --------
    >>> import numpy as np
    >>> u = nb.bounds.UStat(est=np.array([2.0]), se=np.array([0.5]), loo=np.empty((0, 1)), replicates=5)
    >>> u.dof  # the replicate jackknife's R − 1
    array([4.])
    """

    est: np.ndarray
    se: np.ndarray
    loo: np.ndarray
    replicates: int
    df: np.ndarray | None = None
    terms: np.ndarray | None = None
    noise: np.ndarray | None = None

    @property
    def dof(self) -> np.ndarray:
        """Degrees of freedom of `se`, broadcast to est's shape."""
        return np.broadcast_to(np.asarray(self.replicates - 1.0 if self.df is None else self.df, dtype=np.float64),
                               np.shape(self.est))


def u_statistic(G: np.ndarray) -> UStat:
    """The U-statistic and its jackknife from Grams G (R, R, *T).

    est = Σ_{r≠s} G_rs / (R(R−1)), unbiased for Σ_ω w d²; the SE is the delete-one jackknife over
    replicates, with R − 1 degrees of freedom.

    Parameters
    ----------
    G : array_like of shape (R, R, *T)
        G_rs = Σ_ω w D_r D_s over R ≥ 2 replicates, with any trailing shape (*T), e.g. (K,) offsets or
        (P, P) parameter pairs; taken to float64.

    Returns
    -------
    UStat
        est (*T), se (*T) (NaN for R = 2), loo (R, *T) (empty for R = 2), replicates R.

    See Also
    --------
    nlosbench.bounds.hcr : The HCR at θ* from one set of renders (a plug-in: rendering noise biases it low).
    nlosbench.bounds.crlb : The CRLB, the HCR's Δ → 0 limit, from a Fisher matrix.
    nlosbench.bounds.hcr_interval : The HCR and CRLB with one-sided confidence ends from replicate render sets.
    nlosbench.bounds.ziv_zakai : The Ziv–Zakai bound on the Bayesian MSE over a prior on Θ (any estimator).
    nlosbench.bounds.zzb_interval : The Ziv–Zakai bound with confidence ends from replicate render sets.
    nlosbench.bounds.pairwise_ustat : Unbiased λ for every pair of grid points from replicate renders.

    Examples
    --------
    Four replicates of a scalar D_r with mean 1: est is unbiased for d² = 1, the plug-in D̄² carries
    the noise.

    >>> import numpy as np
    >>> D = np.array([1.1, 0.9, 1.2, 0.8])
    >>> u = nb.bounds.u_statistic(np.outer(D, D))
    >>> round(float(u.est), 4), round(float(u.se), 4)
    (0.9917, 0.1828)
    """
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


def covariance(terms: np.ndarray) -> np.ndarray:
    """The covariance (J, J) of J statistics from their per-group leave-one-outs `terms` (J, R, M) (`UStat.terms`,
    the same R replicates and M pixel groups): Σ_m (R − 1)/R Σ_r (t_jrm − t̄_jm)(t_irm − t̄_im), the grouped jackknife
    (independent groups, so no cross-group terms); its diagonal is each statistic's jackknife SE², which for R ≥ 4
    overstates the noise × noise part, so callers take only its correlations (module docstring)."""
    dev = terms - terms.mean(axis=1, keepdims=True)
    R = terms.shape[1]
    return (R - 1) / R * np.einsum("arm,brm->ab", dev, dev)


def t_quantile(level: float, dof, tests: int = 1):
    """One-sided Student-t quantile with `dof` degrees of freedom (a number or an array) for confidence
    `level` shared by `tests` limits (Bonferroni: each at 1 − (1 − level)/tests); NaN where dof < 2 (fewer
    than 3 replicates: no SE)."""
    if not 0 < level < 1:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    from scipy.special import stdtrit  # the t quantile as a ufunc: stats.t.ppf's checks cost ~100× more

    d = np.asarray(dof, dtype=np.float64)
    q = np.where(d >= 2, stdtrit(np.maximum(d, 2), 1.0 - (1.0 - level) / max(int(tests), 1)), np.nan)
    return float(q) if q.ndim == 0 else q


def pixel_terms(x: np.ndarray, w) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel U-statistics of Σ_ω w X_r X_s (x (R, k, N) float64, w scalar or (k, N)): (per (k, N), the
    estimate of each pixel; lo (R, k, N), each pixel's estimate without replicate r; empty for R < 3)."""
    R = x.shape[0]
    S, Q = x.sum(axis=0), (x * x).sum(axis=0)  # (k, N)
    per = w * (S * S - Q) / (R * (R - 1))
    if R < 3:
        return per, np.empty((0,) + per.shape)
    return per, w * ((S[None] - x) ** 2 - (Q[None] - x * x)) / ((R - 1) * (R - 2))


def pair_squares(xs: Sequence[np.ndarray], coefs: Sequence[float], w, group: int = 1) -> np.ndarray:
    """Q_m = Σ_{r≠s} H_rs² per group (k, M) of the kernel H_rs = Σ_j coef_j Σ_{ω∈m} w_ω x_j,r,ω x_j,s,ω: a linear
    combination of per-value statistics over the same R replicates (xs: arrays (R, k, N); w scalar or (k, N)), each
    group the `group` consecutive values that share path samples. With y_r the group's J·C values of replicate r and
    ω their weights coef_j·w_c, H_rs = Σ_a ω_a y_ra y_sa, so Σ_{r,s} H_rs² = Σ_ab ω_a ω_b (Σ_r y_ra y_rb)² and Q is
    that less Σ_r H_rr² (memory (J·C)² per group, whatever R). Where R < J·C (a transient scan point's hundreds of
    time bins) the R × R kernel itself is cheaper: Q = Σ_{r≠s} H_rs² directly (memory R² per group). The square part
    of `sum_terms`' unbiased variance."""
    R, k, N = xs[0].shape
    C = check_group(group, N)
    y = np.concatenate([x.reshape(R, k, N // C, C) for x in xs], axis=-1)  # (R, k, M, J·C)
    wv = np.broadcast_to(np.asarray(w, dtype=np.float64), (k, N)).reshape(k, N // C, C)
    om = np.concatenate([c * wv for c in coefs], axis=-1)  # (k, M, J·C)
    if R < y.shape[-1]:
        H = np.einsum("rkma,skma->kmrs", y * om, y)  # (k, M, R, R)
        off = ~np.eye(R, dtype=bool)
        return (H * H)[..., off].sum(axis=-1)
    P = np.einsum("rkma,rkmb->kmab", y, y)
    diag = np.einsum("rkma,kma->rkm", y * y, om)  # H_rr
    return np.einsum("kmab,kma,kmb->km", P * P, om, om) - (diag * diag).sum(axis=0)


def sum_terms(per: np.ndarray, lo: np.ndarray, R: int, group: int = 1, q: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(est (k,), loo (R, k), se (k,), df (k,), noise (k,)) of a sum over independent groups of values of per-value
    statistics per (k, N) with leave-one-out values lo (R, k, N): each group of `group` consecutive values
    (a pixel's channels, N = M·group) summed first, se² the sum over the M groups of each group's variance estimate
    v_m, Satterthwaite's degrees of freedom from the per-group jackknife variances; NaN se for R < 3. Linear in
    (per, lo, the kernel), so a contrast of two statistics over the same replicates (paired) is
    `sum_terms(per_b − c·per_a, lo_b − c·lo_a, R, group, pair_squares([xa, xb], [−c, 1], w, group))`.

    v_m: with q (the group's Q = Σ_{r≠s} H_rs², `pair_squares`) and R ≥ 4, the unbiased estimate of Var U_m
    (module docstring: U_m² less the degree-4 U-statistic of θ_m²); else (R = 3, or no q) the delete-one jackknife,
    conservative where the noise × noise part dominates. The per-group v_m may be < 0; their total is used where
    it is > 0, and where it is not (rare: signal and noise both tiny beside the spread of the estimate) the
    jackknife total is.

    noise: the part of se² that is not the signal × noise term, from the same v_m and Q_m (`noise_part`); NaN where
    it is not known (R < 4, no q, or the jackknife total in use)."""
    est = per.sum(axis=1)
    nan = np.full(est.shape, math.nan)
    if R < 3:
        return est, np.empty((0,) + est.shape), nan, nan, nan
    lo = grouped(lo, group)
    jack = (R - 1) / R * ((lo - lo.mean(axis=0)) ** 2).sum(axis=0)  # per-group jackknife variances (k, M)
    tot = jack.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        df = np.where(tot > 0, tot**2 / ((jack * jack).sum(axis=1) / (R - 1)), R - 1.0)
    noise = nan
    if q is not None and R >= 4:
        u = grouped(per, group)
        v = group_variances(u, lo, q, R)
        unbiased = v.sum(axis=1)
        tot = np.where(unbiased > 0, unbiased, tot)
        noise = np.where(unbiased > 0, noise_part(u, v, q, R), math.nan)
    return est, lo.sum(axis=2), np.sqrt(tot), df, noise


def noise_part(u: np.ndarray, v: np.ndarray, q: np.ndarray, R: int) -> np.ndarray:
    """The part (k,) of V = Σ_m v_m that does not scale with the signal, from per-group U-statistics u (k, M), their
    unbiased variances v (k, M) and Q_m (k, M) over R ≥ 4 replicates. Hoeffding: Var U_m = (4(R − 2)ζ₁ + 2ζ₂)/(R(R − 1))
    with ζ₂ = Var H_rs = E H_rs² − θ_m², estimated by Q_m/(R(R − 1)) − (U_m² − v_m) (the degree-4 U-statistic of θ_m²
    is U_m² − v_m); so Σ ζ₁ = (V·R(R − 1) − 2 Σ ζ₂)/(4(R − 2)) and the rest of V, V − 4Σζ₁/R = (2Σζ₂ − R·V)/(R(R − 2)),
    is the noise × noise term (ζ₁ = the signal × noise covariance dᵀWSWd: it scales with the signal, ζ₂ − 2ζ₁ does
    not). Clipped to [0, V]. Pure noise gives V, noise-free replicates 0."""
    z2 = (q / (R * (R - 1.0)) - u * u + v).sum(axis=1)
    V = v.sum(axis=1)
    return np.clip((2.0 * z2 - R * V) / (R * (R - 2.0)), 0.0, np.maximum(V, 0.0))


def limits(est, se, t, noise=None) -> tuple[np.ndarray, np.ndarray]:
    """One-sided limits (lower, upper) of a U-statistic of a squared mean (λ, F) at Student-t quantile(s) t.

    With its variance modelled as A·θ + B, θ the true value (the signal × noise term scales with the signal, the
    noise × noise term B = `noise` does not; A·est = se² − B), each limit is the θ whose own SE puts est at t SEs,
    (est − θ)² = t²(se² + c·(θ − est)) with c = (se² − B)/est: a score-type (Wilson) interval,

        upper = est + (t²c + √(t⁴c² + 4t²se²))/2,    lower = est − (√(t⁴c² + 4t²se²) − t²c)/2.

    The Wald ends est ∓ t·se hold the SE at the estimate's own value, so a low estimate gets a small SE: on a
    signal-dominated statistic the upper limit of θ then misses twice as often as the lower one (spot_rgb's F at
    ±25 %: 6 % and 3 % at a nominal 5 %; `tests/test_channel_groups.py`). Where `noise` is None or NaN, est ≤ 0, se
    ≤ 0 or t is not finite: est ∓ t·se. Arrays broadcast (est, se, t, noise)."""
    est, se, t = (np.asarray(x, dtype=np.float64) for x in (est, se, t))
    with np.errstate(invalid="ignore"):
        lo, hi = est - t * se, est + t * se
        if noise is None:
            return lo, hi
        noise = np.asarray(noise, dtype=np.float64)
        score = (est > 0) & (se > 0) & np.isfinite(t) & np.isfinite(noise)
        c = np.where(score, np.clip(se * se - noise, 0.0, None) / np.where(score, est, 1.0), 0.0)
        tc = np.where(score, t * t * c, 0.0)
        root = np.sqrt(tc * tc + 4.0 * np.where(score, t * t * se * se, 0.0))
        return np.where(score, est - (root - tc) / 2.0, lo), np.where(score, est + (root + tc) / 2.0, hi)


def group_variances(u: np.ndarray, lo: np.ndarray, q: np.ndarray, R: int) -> np.ndarray:
    """Unbiased estimates v_m (k, M) of Var U_m for per-group U-statistics u (k, M) over R ≥ 4 replicates, from their
    leave-one-outs lo (R, k, M) and Q_m = Σ_{r≠s} H_rs² (`pair_squares`): v = U² − (S² − 4 Σ_r a_r² + 2Q)/D with
    D = R(R − 1)(R − 2)(R − 3) (module docstring), computed centred: with S = R(R − 1)·U, a_r = Σ_{s≠r} H_rs =
    (S − (R − 1)(R − 2)·lo_r)/2 and a'_r = a_r − (R − 1)U = (R − 1)(R − 2)(U − lo_r)/2 (Σ a'_r = 0),

        v = (4 Σ_r a'_r² − 2 (Q − R(R − 1) U²)) / D,

    so no U² of the signal is subtracted from itself (U² less an estimate of θ² would lose the variance to rounding
    where the signal dominates). May be < 0."""
    dev = lo - u[None]
    return ((R - 1) ** 2 * (R - 2) ** 2 * (dev * dev).sum(axis=0) - 2.0 * (q - R * (R - 1) * u * u)) / (
        R * (R - 1) * (R - 2) * (R - 3))


def grouped(x: np.ndarray, group: int) -> np.ndarray:
    """x (..., N) with each group of `group` consecutive values along the last axis summed: (..., N / group).
    ValueError when N is not a multiple of the group."""
    N = x.shape[-1]
    group = check_group(group, N)
    if group == 1:
        return x
    return x.reshape(x.shape[:-1] + (N // group, group)).sum(axis=-1)


def check_group(group, values: int | None = None) -> int:
    """The group size as an int ≥ 1 that divides `values` (when given); ValueError otherwise."""
    if isinstance(group, bool) or not isinstance(group, (int, np.integer)) or group < 1:
        raise ValueError(f"group must be a positive integer (the values per pixel that share path samples), "
                         f"got {group!r}")
    if values is not None and values % group:
        raise ValueError(f"{values} values do not split into groups of {group} (a pixel's channels)")
    return int(group)


def pixel_ustat(X, weights, group: int = 1, chunk_bytes: int = 256 * 2**20) -> UStat:
    """U-statistics of Σ_ω w_ω X_r,k,ω X_s,k,ω over R replicates for each of K quantities (X (R, K, N):
    replicate differences or FD Jacobians, pixels flattened with each pixel's `group` values (its channels)
    consecutive; weights scalar, (N,) or (K, N)): est (K,), loo (R, K) (the estimate without replicate r, for
    downstream jackknifes), se (K,) from the per-group variances summed over groups (independent pixels,
    correlated channels; unbiased for R ≥ 4, the jackknife at R = 3: see the module docstring), df (K,)
    Satterthwaite's, terms (R, K, M) the per-group leave-one-outs (M = N / group), noise (K,) the part of se²
    that does not scale with the signal (`sum_terms`, for `limits`). float64, in chunks of K."""
    X = np.asarray(X)
    R, K, N = X.shape
    if R < 2:
        raise ValueError(f"need R >= 2 independent replicates, got {R}")
    check_group(group, N)
    W = np.broadcast_to(np.asarray(weights, dtype=np.float64), (K, N)) if np.ndim(weights) else None
    est, se, df, noise = np.empty(K), np.full(K, math.nan), np.full(K, math.nan), np.full(K, math.nan)
    loo = np.empty((R, K)) if R >= 3 else np.empty((0, K))
    terms = np.empty((R, K, N // group)) if R >= 3 else None
    step = max(1, chunk_bytes // (8 * R * N * 3))
    for k0 in range(0, K, step):
        k1 = min(K, k0 + step)
        x, w = X[:, k0:k1].astype(np.float64), float(weights) if W is None else W[k0:k1]
        per, lo = pixel_terms(x, w)
        e, left, s, d, nz = sum_terms(per, lo, R, group, pair_squares([x], [1.0], w, group) if R >= 4 else None)
        est[k0:k1], se[k0:k1], df[k0:k1], noise[k0:k1] = e, s, d, nz
        if R >= 3:
            loo[:, k0:k1], terms[:, k0:k1] = left, grouped(lo, group)
    return UStat(est, se, loo, R, df, terms, noise)


def pairwise_ustat(X, weights, group: int = 1, chunk_bytes: int = 256 * 2**20) -> UStat:
    """U-statistics of Σ_ω w_i (X_r[j] − X_r[i])² over R replicates for every pair of G points.

    est (G, G) (diagonal 0), se and df (G, G) as in `pixel_ustat` (independent pixels: per-pixel-group variances,
    unbiased for R ≥ 4, the jackknife at R = 3, each pixel's `group` channels together, summed over pixels;
    Satterthwaite's degrees of freedom), loo (R, G, G). Differences are direct (float64).

    Parameters
    ----------
    X : array_like of shape (R, G, N)
        Replicate r of point i, pixels flattened (any float dtype).
    weights : float or array_like of shape (N,) or (G, N)
        The per-pixel weight: a scalar (AWGN 1/σ²), an (N,) array, or (G, N) where row i weights the pairs
        (i, j) (e.g. scale / L_i for Poisson).
    group : int, optional
        The values per pixel that share path samples (`ForwardModel.channels`; consecutive in N).
    chunk_bytes : int, optional
        float64 working memory per block, in bytes.

    Returns
    -------
    UStat
        est, se, df (G, G) and loo (R, G, G) (empty for R = 2): for weights 1/σ², λ[i, j] with θ* = θ_i.

    See Also
    --------
    nlosbench.bounds.hcr : The HCR at θ* from one set of renders (a plug-in: rendering noise biases it low).
    nlosbench.bounds.crlb : The CRLB, the HCR's Δ → 0 limit, from a Fisher matrix.
    nlosbench.bounds.hcr_interval : The HCR and CRLB with one-sided confidence ends from replicate render sets.
    nlosbench.bounds.ziv_zakai : The Ziv–Zakai bound on the Bayesian MSE over a prior on Θ (any estimator).
    nlosbench.bounds.zzb_interval : The Ziv–Zakai bound with confidence ends from replicate render sets.
    nlosbench.bounds.u_statistic : The unbiased estimate and its jackknife from a replicate Gram array.

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(5, 3, 100)) + np.array([0.0, 0.1, 0.2])[:, None]
    >>> u = nb.bounds.pairwise_ustat(X, 1.0)
    >>> u.est.shape, u.loo.shape, float(u.est[0, 0])
    ((3, 3), (5, 3, 3), 0.0)
    """
    X = np.asarray(X)
    R, G, N = X.shape
    W = np.broadcast_to(np.asarray(weights, dtype=np.float64), (G, N)) if np.ndim(weights) else None
    est, se, df = np.zeros((G, G)), np.zeros((G, G)), np.full((G, G), np.inf)
    loo = np.zeros((R, G, G)) if R >= 3 else np.empty((0, G, G))
    for i in range(G):
        D = X.astype(np.float64) - X[:, i : i + 1].astype(np.float64)  # (R, G, N)
        u = pixel_ustat(D, float(weights) if W is None else W[i][None], group, chunk_bytes)
        est[i], se[i], df[i] = u.est, u.se, u.df
        if R >= 3:
            loo[:, i] = u.loo
    return UStat(est, se, loo, R, df)
