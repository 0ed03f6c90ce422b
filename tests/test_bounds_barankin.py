"""Barankin bound: equals HCR with one point, never below HCR, matches the linear-domain formula,
stays below the CRLB where an efficient estimator exists, and Barankin ≥ HCR > CRLB on a hard-edge
model; huge and infinite exponents are handled."""
import math

import numpy as np
import pytest
import torch

from nlosbench import bounds as B
from nlosbench.noise import AWGN, Poisson


def edge1d(theta, n: int = 200, base: float = 1.0, amp: float = 0.1) -> torch.Tensor:
    """Hard-edge 1-D toy: pixel i covers [i/n, (i+1)/n]; L_i = base + amp · (covered fraction of
    the pixel by the lit region x > θ). Piecewise linear in θ: ∂L/∂θ = −amp·n in θ's pixel only."""
    t = torch.as_tensor(theta, dtype=torch.float64).reshape(-1, 1)
    right = torch.arange(1, n + 1, dtype=torch.float64) / n
    return (base + amp * ((right - t) * n).clamp(0.0, 1.0)).squeeze(0)


def test_edge_model_barankin_above_hcr_above_crlb():
    n, amp, sigma = 200, 0.1, 0.45  # low SNR: amp²/σ² ≈ 0.05 per fully switched pixel
    t0 = 100.5 / n  # middle of a pixel
    thetas = np.arange(0.05, 0.95, 0.25 / n)
    thetas = thetas[np.abs(thetas - t0) > 1e-9]  # drop θ*'s own render
    deltas = thetas - t0
    L0, L_alt, noise = edge1d(t0, n, amp=amp), edge1d(thetas, n, amp=amp), AWGN(sigma)
    crlb = sigma**2 / (amp * n) ** 2
    h = B.hcr(L0, L_alt, deltas, noise)
    b = B.barankin(L0, L_alt, deltas, noise)
    assert h.at_edge is None and h.reason == ""  # the sup is at a finite Δ inside the grid
    assert abs(h.delta) > 10 / n
    assert h.value > 5 * crlb  # strictly above the CRLB (it is ≈ 15×)
    assert b.value >= h.value and b.tightening >= 1.0 and b.points[0] == h.index
    assert b.hcr_log10 == h.log10
    # the derivative-free Δ → 0 limit recovers the CRLB inside the pixel
    assert B.crlb_from_hcr_limit(L0, L_alt, deltas, noise).component[0] == pytest.approx(crlb, rel=1e-6)


def test_one_point_is_hcr_exactly():
    g = torch.Generator().manual_seed(0)
    L0 = torch.rand(40, generator=g, dtype=torch.float64)
    deltas = np.linspace(-1, 1, 21)
    L_alt = L0 + torch.sin(torch.as_tensor(deltas)[:, None] * torch.randn(40, generator=g, dtype=torch.float64))
    h = B.hcr(L0, L_alt, deltas, AWGN(0.5))
    b = B.barankin(L0, L_alt, deltas, AWGN(0.5), max_points=1)
    assert b.value == h.value and b.log10 == h.log10 and b.tightening == 1.0
    assert b.points.tolist() == [h.index] and b.deltas.tolist() == [h.delta]


@pytest.mark.parametrize("seed", range(4))
def test_never_below_hcr_and_matches_linear_domain_formula(seed):
    g = torch.Generator().manual_seed(seed)
    L0 = 0.5 + torch.rand(30, generator=g, dtype=torch.float64)
    deltas = np.linspace(-0.6, 0.6, 25)
    L_alt = (L0 + torch.tanh(3 * torch.as_tensor(deltas)[:, None] * torch.randn(30, generator=g,
                                                                                   dtype=torch.float64))).clamp_min(0.0)
    for noise in (AWGN(0.8), Poisson(2.0)):
        h = B.hcr(L0, L_alt, deltas, noise)
        b = B.barankin(L0, L_alt, deltas, noise, max_points=6)
        assert b.tightening == pytest.approx(b.value / h.value, rel=1e-12)
        # McAulay–Seidman directly: δᵀ (expm1(G))⁻¹ δ over the chosen points (rel 1e-8)
        p = b.points
        M = np.expm1(noise.gram_exponent(L0, L_alt[p], L_alt[p]).numpy())
        assert b.value == pytest.approx(deltas[p] @ np.linalg.solve(M, deltas[p]), rel=1e-8)
        assert b.cond < 1e10 and len(set(p.tolist())) == len(p)


def test_linear_gaussian_not_above_crlb():
    """An efficient estimator exists, so every valid bound is ≤ CRLB = σ²/‖a‖² (rel 1e-6)."""
    g = torch.Generator().manual_seed(7)
    L0 = torch.rand(50, generator=g, dtype=torch.float64)
    a = torch.randn(50, generator=g, dtype=torch.float64)
    sigma = 2.0
    h_ = np.logspace(-3, 0.5, 20)
    deltas = np.concatenate([-h_, h_])
    L_alt = L0 + torch.as_tensor(deltas)[:, None] * a
    crlb = sigma**2 / float((a**2).sum())
    h = B.hcr(L0, L_alt, deltas, AWGN(sigma))
    b = B.barankin(L0, L_alt, deltas, AWGN(sigma))
    assert h.value <= b.value <= crlb * (1 + 1e-6)


def test_huge_and_infinite_exponents():
    """λ from 1e3 to 1e7 and λ = +inf (Poisson pixel dark at θ*, lit at θ*+Δ): finite log10,
    inf points never chosen, result ≥ HCR."""
    L0 = torch.tensor([0.0, 1.0, 2.0, 1.0], dtype=torch.float64)
    deltas = np.array([-1.0, -0.5, -0.1, 0.1, 0.5, 1.0, 2.0])
    L_alt = torch.stack([L0 + torch.tensor([0.0, 1.0, 0.0, 0.0]) * 1e3 * d**2 for d in deltas])
    L_alt[[0, 6], 0] = 5.0  # λ = +inf for these two
    noise = Poisson(10.0)
    h = B.hcr(L0, L_alt, deltas, noise)
    assert np.isinf(h.lam[[0, 6]]).all() and h.lam.max() == np.inf and h.lam[1:6].max() > 1e5
    b = B.barankin(L0, L_alt, deltas, noise)
    assert np.isfinite(b.log10) and b.log10 >= h.log10 and not set(b.points) & {0, 6}
    tiny = B.barankin(L0, L_alt[[1, 5]], deltas[[1, 5]], noise)  # only λ ≥ 6e5: value underflows
    assert tiny.value == 0.0 and np.isfinite(tiny.log10) and tiny.log10 < -1e5


def test_vector_theta_per_component():
    rng = np.random.default_rng(8)
    L0 = torch.as_tensor(0.5 + rng.random(20))
    A = torch.as_tensor(rng.normal(size=(2, 20)))
    deltas = rng.normal(scale=0.3, size=(30, 2))
    L_alt = L0 + torch.sin(torch.as_tensor(deltas) @ A)
    h = B.hcr(L0, L_alt, deltas, AWGN(0.7))
    with pytest.raises(ValueError, match="component"):
        B.barankin(L0, L_alt, deltas, AWGN(0.7))
    for j in range(2):
        b = B.barankin(L0, L_alt, deltas, AWGN(0.7), component=j)
        assert b.hcr_log10 == h.component_log10[j] and b.log10 >= b.hcr_log10
        assert b.points[0] == h.component_index[j]
        np.testing.assert_array_equal(b.deltas, deltas[b.points, j])


def test_barankin_is_the_variance_of_the_best_unbiased_estimator_on_its_points():
    """Brute force on a nonlinear AWGN toy (L_i(θ) = tanh(3θ a_i), 6 test points): the Barankin bound over
    all test points is the variance at θ* of T = θ* + Σ c_k (ℓ_k − 1), c = (B − 11ᵀ)⁻¹ δ, the unbiased
    estimator (at the test points) of least variance. Simulated with 200 000 draws of y ~ p_θ*: T is
    unbiased at every test point (importance-weighted means, within 6 SE) and its variance matches the
    bound (within 3 %: the ℓ's are heavy-tailed, SE ≈ 1 %). The greedy bound, a subset, is not above it."""
    g = np.random.default_rng(11)
    sigma, n = 0.6, 12
    a = g.normal(size=n)
    deltas = np.array([-0.3, -0.15, -0.05, 0.05, 0.15, 0.3])

    def L(t):
        return np.tanh(3 * t * a) + 1.0

    theta0 = 0.1
    L0, Lk = L(theta0), np.stack([L(theta0 + d) for d in deltas])
    noise = AWGN(sigma)
    G = noise.gram_exponent(torch.as_tensor(L0), torch.as_tensor(Lk), torch.as_tensor(Lk)).numpy()
    M = np.expm1(G)
    c = np.linalg.solve(M, deltas)
    full = float(deltas @ c)
    greedy = B.barankin(torch.as_tensor(L0), torch.as_tensor(Lk), deltas, noise, max_points=6)
    assert greedy.value <= full * (1 + 1e-9)
    y = L0 + sigma * g.normal(size=(200_000, n))
    logl = ((y - L0) ** 2).sum(1)[:, None] - ((y[:, None, :] - Lk[None]) ** 2).sum(2)
    ell = np.exp(logl / (2 * sigma**2))  # (draws, K): p_θk(y) / p_θ*(y)
    T = theta0 + (ell - 1.0) @ c
    assert T.var() == pytest.approx(full, rel=0.03)
    for k, d in enumerate(deltas):  # E_θk[T] = E_θ*[ℓ_k T]
        est = ell[:, k] * T
        assert abs(est.mean() - (theta0 + d)) < 6 * est.std() / math.sqrt(len(est)), (k, est.mean())
