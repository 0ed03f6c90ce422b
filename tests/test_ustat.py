"""The standard error of a pixel-group U-statistic (`bounds.ustat`) against its exact variance by enumeration."""
import itertools

import numpy as np
import pytest

from nlosbench.bounds.ustat import (
    group_variances,
    grouped,
    limits,
    pair_squares,
    pixel_terms,
    pixel_ustat,
    sum_terms,
    t_quantile,
)

#: a replicate's values (two channels of one pixel) for two statistics A and B on the same paths, and their odds
SUPPORT_A = np.array([[0.3, 1.0], [-0.5, 0.4], [1.2, -0.2]])
SUPPORT_B = np.array([[0.1, 1.4], [-0.9, 0.2], [0.8, 0.3]])
PROB = np.array([0.5, 0.3, 0.2])
W = np.array([1.0, 2.5])


def _kernel(xa, xb, c):
    """The contrast's kernel h(r, s) = Σ_c w_c (b_r,c b_s,c − c·a_r,c a_s,c), written out."""
    return (W * (xb[:, None] * xb[None] - c * xa[:, None] * xa[None])).sum(axis=-1)


@pytest.mark.parametrize("R", [4, 5])
@pytest.mark.parametrize("c", [0.0, 1.1])
def test_the_group_variance_is_unbiased_over_every_draw(R, c):
    """Every draw of R replicates from a three-point law (two channels of one pixel, two statistics paired on the
    same replicates), enumerated with its probability: the mean of the per-group variance estimate equals the
    exact variance of the U-statistic Σ_{r≠s} h(r, s)/(R(R − 1)) of the contrast B − c·A (both from the
    enumeration, the U-statistic from its kernel written out); the delete-one jackknife's mean exceeds it."""
    mean_u = mean_u2 = mean_v = mean_jack = 0.0
    for draw in itertools.product(range(3), repeat=R):
        p = float(np.prod(PROB[list(draw)]))
        xa, xb = SUPPORT_A[list(draw)], SUPPORT_B[list(draw)]
        h = _kernel(xa, xb, c)
        u = (h.sum() - np.trace(h)) / (R * (R - 1))
        A, B = xa.reshape(R, 1, 2), xb.reshape(R, 1, 2)
        pa, la = pixel_terms(A, W[None])
        pb, lb = pixel_terms(B, W[None])
        q = pair_squares([A, B], [-c, 1.0], W[None], 2)
        lo = grouped(lb - c * la, 2)
        v = group_variances(grouped(pb - c * pa, 2), lo, q, R)
        assert float(grouped(pb - c * pa, 2)[0, 0]) == pytest.approx(u, abs=1e-12)
        mean_u, mean_u2, mean_v = mean_u + p * u, mean_u2 + p * u * u, mean_v + p * float(v[0, 0])
        mean_jack += p * float(sum_terms(pb - c * pa, lb - c * la, R, 2)[2][0] ** 2)
    var = mean_u2 - mean_u**2
    assert mean_v == pytest.approx(var, rel=1e-9)
    assert mean_jack > 1.05 * var


def test_the_unbiased_standard_error_matches_the_spread_of_a_noise_dominated_statistic():
    """Pure noise (mean 0) in 300 pixels of three correlated channels, R = 4: Var U = 2ζ₂/(R(R − 1)) with
    ζ₂ = Σ_m tr((W Σ)²), Σ the channels' covariance; over 4000 draws the mean SE² is within 5 % of that closed form
    (the jackknife's counts ζ₂ 2(R − 1)/(R − 2) = 3 times: its mean SE² is ≈ 3× it)."""
    rng = np.random.default_rng(1)
    R, M, C = 4, 300, 3
    cov = np.array([[1.0, 0.8, 0.6], [0.8, 1.0, 0.8], [0.6, 0.8, 1.0]])
    w = np.array([1.0, 2.0, 0.5])
    L = np.linalg.cholesky(cov)
    ws = np.diag(w) @ cov
    exact = 2 * M * np.trace(ws @ ws) / (R * (R - 1))
    x = (rng.standard_normal((R, 4000, M, C)) @ L.T).reshape(R, 4000, M * C)  # 4000 draws, one statistic each
    u = pixel_ustat(x, np.tile(w, M), group=C)
    assert np.var(u.est) == pytest.approx(exact, rel=0.05)
    assert np.mean(u.se**2) == pytest.approx(exact, rel=0.05)


def _signal_and_noise(rng, R: int, draws: int, M: int, scale: float):
    """R replicates of `draws` statistics: M pixels of three correlated channels, mean d (the signal, times `scale`)
    plus Gaussian noise of covariance Σ; weights w. Returns (x (R, draws, M·3), d (M, 3), Σ, w)."""
    cov = np.array([[1.0, 0.8, 0.6], [0.8, 1.0, 0.8], [0.6, 0.8, 1.0]])
    w = np.array([1.0, 2.0, 0.5])
    d = scale * np.random.default_rng(7).normal(size=(M, 3))
    x = (rng.standard_normal((R, draws, M, 3)) @ np.linalg.cholesky(cov).T + d).reshape(R, draws, M * 3)
    return x, d, cov, w


def test_the_noise_part_of_the_variance_matches_its_closed_form():
    """Signal and noise of comparable size (200 pixels of three correlated channels, R = 5, 4000 draws): Var U =
    a/R + b/(R(R − 1)) with a = 4 Σ_m (w∘d)ᵀΣ(w∘d) (signal × noise) and b = 2 Σ_m tr((WΣ)²) (noise × noise); the
    mean reported noise part is within 5 % of b/(R(R − 1)) and the mean of the rest (se² − noise) within 5 % of a/R."""
    R, M = 5, 200
    x, d, cov, w = _signal_and_noise(np.random.default_rng(2), R, 4000, M, 0.6)
    ws = np.diag(w) @ cov
    a = 4 * sum(float((w * dm) @ cov @ (w * dm)) for dm in d)
    b = 2 * M * np.trace(ws @ ws)
    u = pixel_ustat(x, np.tile(w, M), group=3)
    assert np.mean(u.noise) == pytest.approx(b / (R * (R - 1)), rel=0.05)
    assert np.mean(u.se**2 - u.noise) == pytest.approx(a / R, rel=0.05)


def test_score_limits_miss_at_their_level_on_either_side_where_wald_limits_tilt():
    """A signal-dominated statistic (relative SE ≈ 8 %, R = 8, 4000 draws): each one-sided 95 % score limit
    (`limits`) misses the true Σ w d² a number of times inside the binomial 99.9 % band for 5 % (155–245 of 4000;
    measured 210 and 195); the Wald limits est ∓ t·se, whose SE is taken at the estimate, tilt: their upper limit
    misses more than 1.3× as often as their lower one (256 and 152: a low estimate carries a small SE). At R = 4
    and a relative SE of 12 % the score limits remove most of the tilt, not all (269 and 213; Wald 298 and 173)."""
    R, M = 8, 60
    x, d, cov, w = _signal_and_noise(np.random.default_rng(3), R, 4000, M, 0.9)
    truth = float((np.tile(w, M) * d.reshape(-1) ** 2).sum())
    u = pixel_ustat(x, np.tile(w, M), group=3)
    assert 0.05 < np.median(u.se) / truth < 0.12
    t = t_quantile(0.95, u.dof)
    lo, hi = limits(u.est, u.se, t, u.noise)
    assert 155 <= int((hi < truth).sum()) <= 245 and 155 <= int((lo > truth).sum()) <= 245
    wald_hi, wald_lo = int((u.est + t * u.se < truth).sum()), int((u.est - t * u.se > truth).sum())
    assert wald_hi > 1.3 * wald_lo


@pytest.mark.parametrize("R, C, J", [(4, 3, 1), (5, 2, 2), (6, 400, 1), (3, 5, 2)])
def test_pair_squares_equals_the_kernel_written_out_on_either_route(R, C, J):
    """Q_m = Σ_{r≠s} H_rs² per group from `pair_squares` against H_rs = Σ_a ω_a y_ra y_sa written out: both routes
    (the (J·C)² moments where R ≥ J·C, the R × R kernel where R < J·C, a transient scan point's 400 bins) to 1e-12."""
    rng = np.random.default_rng(R * 100 + C)
    xs = [rng.normal(size=(R, 2, 7 * C)) for _ in range(J)]
    w, coefs = rng.uniform(0.5, 2.0, size=(2, 7 * C)), list(rng.normal(size=J))
    y = np.concatenate([x.reshape(R, 2, 7, C) for x in xs], axis=-1)
    om = np.concatenate([c * w.reshape(2, 7, C) for c in coefs], axis=-1)
    H = np.einsum("rkma,skma,kma->kmrs", y, y, om)
    exact = sum(H[..., r, s] ** 2 for r in range(R) for s in range(R) if r != s)
    assert np.allclose(pair_squares(xs, coefs, w, C), exact, rtol=1e-12, atol=0)
