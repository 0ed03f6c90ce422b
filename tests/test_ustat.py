"""The standard error of a pixel-group U-statistic (`bounds.ustat`) against its exact variance by enumeration."""
import itertools

import numpy as np
import pytest

from nlosbench.bounds.ustat import group_variances, grouped, pair_squares, pixel_terms, pixel_ustat, sum_terms

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
