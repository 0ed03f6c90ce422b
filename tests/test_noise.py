"""Noise models: registry, validation, χ² exponents (closed forms, exactness, precision, Poisson
zeros), Gram exponents, Fisher information, sampling and likelihood."""
import math
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from scipy import integrate, stats

from nlosbench import noise
from nlosbench.noise import AWGN, Poisson


def test_registry_builtins_and_plugin(monkeypatch):
    assert {"awgn", "poisson"} <= set(noise.available())
    assert noise.get("awgn", sigma=0.2) == AWGN(0.2)
    assert noise.get("poisson", scale=3.0) == Poisson(3.0)
    with pytest.raises(ValueError, match="unknown noise model"):
        noise.get("nope")

    monkeypatch.setattr(noise, "_REGISTRY", dict(noise._REGISTRY))

    @noise.register("poisson-read")
    @dataclass(frozen=True)
    class PoissonRead(noise.QuadraticNoise):  # Gaussian approximation of Poisson + read noise
        scale: float
        read: float

        def weight(self, L0):
            return self.scale / (L0 + self.scale * self.read**2)

        def sample(self, L, generator):
            raise NotImplementedError

        def nll(self, y, L):
            raise NotImplementedError

    m = noise.get("poisson-read", scale=2.0, read=0.5)
    assert "poisson-read" in noise.available() and m.name == "poisson-read"
    L0, L1 = torch.tensor([1.0, 2.0]), torch.tensor([1.5, 2.0])
    assert float(m.chi2_exponent(L0, L1)) == pytest.approx(2.0 * 0.25 / 1.5, rel=1e-15)
    with pytest.raises(TypeError):
        noise.register("bad")(int)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_parameter_validation(bad):
    with pytest.raises(ValueError, match="sigma"):
        AWGN(bad)
    with pytest.raises(ValueError, match="scale"):
        Poisson(bad)


def test_chi2_closed_forms_and_batch():
    g = torch.Generator().manual_seed(0)
    L0 = torch.rand(4, 6, 3, generator=g) + 0.1
    L1 = L0 + 0.05 * torch.randn(5, 2, 4, 6, 3, generator=g)
    L1 = L1.clamp_min(0.0)
    d = (L1.double() - L0.double()).reshape(10, -1)
    lam = AWGN(0.3).chi2_exponent(L0, L1)
    assert lam.shape == (5, 2) and lam.dtype == torch.float64
    torch.testing.assert_close(lam.reshape(-1), (d**2).sum(1) / 0.09, rtol=1e-14, atol=0)
    lam = Poisson(7.0).chi2_exponent(L0, L1)
    torch.testing.assert_close(lam.reshape(-1), 7.0 * (d**2 / L0.double().reshape(-1)).sum(1),
                               rtol=1e-14, atol=0)
    assert AWGN(1.0).chi2_exponent(L0, L0).shape == ()  # no batch dims → 0-dim
    assert float(AWGN(1.0).chi2_exponent(L0, L0)) == 0.0
    with pytest.raises(ValueError, match="L1 must have shape"):
        AWGN(1.0).chi2_exponent(L0, L0[:2])


@pytest.mark.parametrize("mu0,mu1,scale", [(3.0, 4.5, 1.0), (0.4, 0.1, 2.5), (10.0, 13.0, 0.5)])
def test_poisson_chi2_is_exact(mu0, mu1, scale):
    """χ²(p1‖p0) = Σ_k p1(k)²/p0(k) − 1 summed over counts equals exp(λ) − 1 (rel 1e-12)."""
    k = np.arange(400)
    lp0, lp1 = stats.poisson.logpmf(k, scale * mu0), stats.poisson.logpmf(k, scale * mu1)
    chi2 = math.fsum(np.exp(2 * lp1 - lp0)) - 1.0
    t = lambda v: torch.tensor([v], dtype=torch.float64)
    lam = float(Poisson(scale).chi2_exponent(t(mu0), t(mu1)))
    assert math.expm1(lam) == pytest.approx(chi2, rel=1e-12)


def test_awgn_chi2_is_exact():
    """χ² between N(1.3, σ²) and N(1, σ²) by quadrature equals exp(λ) − 1 (rel 1e-9)."""
    s = 0.7
    p0, p1 = stats.norm(1.0, s).pdf, stats.norm(1.3, s).pdf
    chi2 = integrate.quad(lambda y: p1(y) ** 2 / p0(y), -10, 12, epsabs=0, epsrel=1e-12)[0] - 1
    t = lambda v: torch.tensor([v], dtype=torch.float64)
    lam = float(AWGN(s).chi2_exponent(t(1.0), t(1.3)))
    assert math.expm1(lam) == pytest.approx(chi2, rel=1e-9)


@pytest.mark.parametrize("model", [AWGN(0.1), Poisson(50.0)])
def test_precision_1e6_relative_on_full_size_image(model):
    """Renders 256×512×3 float32 in [1, 2) differing by k ulps (~1e-6 relative): λ from the
    analytic construction to 1e-6 relative (asserted 1e-10; float64 direct differences)."""
    rng = np.random.default_rng(1)
    ulp = 2.0**-23
    L0 = (1.0 + rng.integers(0, 2**22, size=(256, 512, 3)) * ulp).astype(np.float32)
    k = rng.integers(1, 16, size=L0.shape)
    L1 = (L0.astype(np.float64) + k * ulp).astype(np.float32)
    assert np.array_equal(L1.astype(np.float64) - L0, k * ulp)  # construction is exact
    assert 1e-7 < np.abs(L1 / L0 - 1).mean() < 2e-6
    w = np.broadcast_to(np.asarray(model.weight(torch.from_numpy(L0.astype(np.float64)))), L0.shape)
    exact = math.fsum(((k * ulp) ** 2 * w).ravel())
    lam = float(model.chi2_exponent(torch.from_numpy(L0), torch.from_numpy(L1)))
    assert lam == pytest.approx(exact, rel=1e-10)


def test_poisson_zero_mean_pixels():
    m = Poisson(2.0)
    L0 = torch.tensor([0.0, 1.0, 0.0])
    same_zero = torch.tensor([0.0, 1.5, 0.0])
    lit_zero = torch.tensor([0.0, 1.5, 0.2])
    lam = m.chi2_exponent(L0, torch.stack([same_zero, lit_zero, L0]))
    assert lam[0] == pytest.approx(2.0 * 0.25)  # the L0 = 0, L1 = 0 pixels add 0
    assert lam[1] == math.inf and lam[2] == 0.0
    g = m.gram_exponent(L0, torch.stack([same_zero, lit_zero]), torch.stack([same_zero, lit_zero]))
    assert g[0, 0] == pytest.approx(0.5) and g[0, 1] == pytest.approx(0.5)
    assert g[1, 1] == math.inf
    F = m.fisher(L0, torch.tensor([[0.0, 2.0, 1.0], [0.0, 1.0, 0.0]]))
    assert F.shape == (2, 2, 3)
    assert F[0, 0].tolist() == [0.0, 8.0, math.inf] and F[1, 1].tolist() == [0.0, 2.0, 0.0]
    assert F[0, 1].tolist() == [0.0, 4.0, 0.0]
    for t in (lam, g, F):
        assert not torch.isnan(t).any()


@pytest.mark.parametrize("model", [AWGN(0.1), Poisson(1.0)])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_inputs_raise(model, bad):
    L = torch.ones(3, 4)
    B = L.clone()
    B[1, 2] = bad
    with pytest.raises(ValueError, match="L1 contains"):
        model.chi2_exponent(L, torch.stack([L, B]))
    with pytest.raises(ValueError, match="L0 contains"):
        model.chi2_exponent(B, L)
    with pytest.raises(ValueError, match="dL contains"):
        model.fisher(L, B)
    with pytest.raises(ValueError, match="Lj contains"):
        model.gram_exponent(L, L, B)
    with pytest.raises(ValueError, match="L contains"):
        model.sample(B, torch.Generator())


def test_poisson_negative_mean_raises():
    with pytest.raises(ValueError, match="negative"):
        Poisson(1.0).chi2_exponent(torch.ones(3), -torch.ones(3))


def test_gram_exponent_equals_direct_summation_over_poisson_counts():
    """log E_L0[ℓ_i ℓ_j] by brute force: each pixel's Σ_k p_i(k) p_j(k) / p_0(k) over counts k = 0 … 120
    (scale 2, means 0.4–3 photons: the tail beyond 120 is < 1e-80), multiplied over 3 pixels, against
    `gram_exponent` (a closed form) — rel 1e-12."""
    from scipy.stats import poisson

    scale = 2.0
    L0 = torch.tensor([0.2, 1.0, 1.5], dtype=torch.float64)
    Li = torch.tensor([0.5, 0.7, 1.4], dtype=torch.float64)
    Lj = torch.tensor([0.3, 1.2, 1.1], dtype=torch.float64)
    k = np.arange(121)
    brute = 0.0
    for a, b, c in zip((scale * L0).tolist(), (scale * Li).tolist(), (scale * Lj).tolist(), strict=True):
        brute += math.log((poisson.pmf(k, b) * poisson.pmf(k, c) / poisson.pmf(k, a)).sum())
    got = float(Poisson(scale).gram_exponent(L0, Li, Lj))
    assert got == pytest.approx(brute, rel=1e-12)
    assert float(Poisson(scale).gram_exponent(L0, Li, Li)) == pytest.approx(
        float(Poisson(scale).chi2_exponent(L0, Li)), rel=1e-14)


def test_gram_exponent_equals_quadrature_for_awgn():
    """log E_L0[ℓ_i ℓ_j] for AWGN by Gauss–Hermite quadrature over each pixel's y (80 nodes), 2 pixels."""
    sigma = 0.5
    L0, Li, Lj = (torch.tensor(v, dtype=torch.float64) for v in ([0.1, 0.4], [0.3, 0.2], [0.6, 0.5]))
    x, w = np.polynomial.hermite_e.hermegauss(80)  # ∫ f(x) e^{−x²/2} dx
    brute = 0.0
    for a, b, c in zip(L0.tolist(), Li.tolist(), Lj.tolist(), strict=True):
        y = a + sigma * x  # y ~ N(a, σ²)
        li = np.exp(((y - a) ** 2 - (y - b) ** 2) / (2 * sigma**2))
        lj = np.exp(((y - a) ** 2 - (y - c) ** 2) / (2 * sigma**2))
        brute += math.log((w * li * lj).sum() / math.sqrt(2 * math.pi))
    assert float(AWGN(sigma).gram_exponent(L0, Li, Lj)) == pytest.approx(brute, rel=1e-10)


@pytest.mark.parametrize("model", [AWGN(0.2), Poisson(3.0)])
def test_fisher_per_pixel_and_matrix_shapes(model):
    L = torch.rand(5, 4, 3, dtype=torch.float64) + 0.2
    J = torch.randn(2, 5, 4, 3, dtype=torch.float64)
    w = model.weight(L)
    torch.testing.assert_close(model.fisher(L, J[0]), w * J[0] ** 2, rtol=1e-15, atol=0)
    F = model.fisher(L, J)
    assert F.shape == (2, 2, 5, 4, 3)
    torch.testing.assert_close(F[0, 1], w * J[0] * J[1], rtol=1e-15, atol=0)
    with pytest.raises(ValueError, match="dL must have shape"):
        model.fisher(L, J[:, :2])


def test_fisher_is_limit_of_lambda_over_delta2():
    """Δ²/λ → 1/F for a smooth curve L(θ) (rel 1e-6 at Δ = 1e-7)."""
    x = torch.linspace(0, 1, 50, dtype=torch.float64)
    L = lambda t: 1.0 + torch.exp(-((x - t) ** 2) / 0.02)
    dL = lambda t: torch.exp(-((x - t) ** 2) / 0.02) * 2 * (x - t) / 0.02
    for m in (AWGN(0.1), Poisson(5.0)):
        F = float(m.fisher(L(0.4), dL(0.4)).sum())
        h = 1e-7
        lam = float(m.chi2_exponent(L(0.4 - h / 2), L(0.4 + h / 2)))
        assert lam / h**2 == pytest.approx(F, rel=1e-6)


def test_awgn_sample_and_nll():
    m = AWGN(0.5)
    L = torch.full((400, 500), 2.0)
    y = m.sample(L, torch.Generator().manual_seed(3))
    assert y.shape == L.shape and y.dtype == L.dtype
    assert torch.equal(y, m.sample(L, torch.Generator().manual_seed(3)))  # same seed → same draw
    n = y.numel()  # mean within 5 standard errors, variance within 5 standard errors
    assert abs(float(y.mean()) - 2.0) < 5 * 0.5 / math.sqrt(n)
    assert abs(float(y.var()) - 0.25) < 5 * 0.25 * math.sqrt(2 / n)
    Lv = torch.tensor([1.0, 2.0, 3.0], requires_grad=True)
    yv = torch.tensor([1.5, 2.0, 2.0])
    v = m.nll(yv, Lv)
    v.backward()
    assert v.item() == pytest.approx((0.25 + 0 + 1) / (2 * 0.25))
    torch.testing.assert_close(Lv.grad, -(yv - Lv.detach()) / 0.25)


def test_poisson_sample_and_nll():
    m = Poisson(4.0)
    L = torch.full((400, 500), 1.5)
    y = m.sample(L, torch.Generator().manual_seed(4))
    assert torch.equal(y * 4.0, torch.round(y * 4.0))  # radiance units: counts / scale
    n = y.numel()  # E[y] = L, Var[y] = L / scale, within 5 standard errors
    assert abs(float(y.mean()) - 1.5) < 5 * math.sqrt(1.5 / 4 / n)
    assert abs(float(y.var()) - 1.5 / 4) < 5 * (1.5 / 4) * math.sqrt(2 / n + 1 / (6 * n))
    # nll differences equal −log-pmf differences (the dropped constant is θ-independent)
    yv = torch.tensor([0.0, 0.5, 2.25])
    k = (yv * 4).numpy()
    La, Lb = torch.tensor([0.3, 0.7, 2.0]), torch.tensor([0.1, 0.9, 2.5])
    ref = -stats.poisson.logpmf(k, 4 * La.numpy()).sum() + stats.poisson.logpmf(k, 4 * Lb.numpy()).sum()
    assert float(m.nll(yv, La) - m.nll(yv, Lb)) == pytest.approx(ref, rel=1e-12)
    # safe at L = 0: y = 0 gives finite value and gradient, y > 0 gives +inf
    Lz = torch.tensor([0.0, 1.0], requires_grad=True)
    v = m.nll(torch.tensor([0.0, 1.0]), Lz)
    v.backward()
    assert math.isfinite(v.item()) and torch.isfinite(Lz.grad).all()
    assert float(m.nll(torch.tensor([0.25]), torch.tensor([0.0]))) == math.inf
