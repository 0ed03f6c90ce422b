"""HCR bound: log-domain extremes, exclusions, closed forms (linear Gaussian and Poisson), vector θ,
and the grid path (pairwise λ, HCR curve) against per-θ* hcr()."""
import math

import numpy as np
import pytest
import torch

from nlosbench import bounds as B
from nlosbench.bounds.hcr import hcr_from_lambda, log_expm1
from nlosbench.noise import AWGN, Poisson


def test_log_domain_extremes():
    r = hcr_from_lambda([1e6], [0.3])
    assert r.value == 0.0  # underflows, the log does not
    assert r.log10 == pytest.approx(math.log10(0.09) - 1e6 / math.log(10), rel=1e-14)
    assert math.isfinite(r.log10) and r.log10 == pytest.approx(-4.3429e5, rel=1e-4)
    r = hcr_from_lambda([1e-14], [0.3])
    assert r.value == pytest.approx(0.09 / 1e-14, rel=1e-10)
    assert r.log10 == pytest.approx(math.log10(0.09 / 1e-14), rel=1e-12)
    lam = np.array([1e-300, 1e-8, 0.5, 1.0, 2.0, 700.0, 710.0, 1e300])
    le = log_expm1(lam)
    assert np.isfinite(le).all()
    np.testing.assert_allclose(le[1:6], np.log(np.expm1(lam[1:6])), rtol=1e-14)
    assert le[-1] == 1e300 and le[0] == pytest.approx(math.log(1e-300))
    assert log_expm1(np.array([np.inf]))[0] == np.inf


def test_exclusions_unresolved_and_bounds():
    lam = [np.inf, 0.0, 0.5, 0.2, 0.1]
    deltas = [1.0, 0.5, 0.0, -0.3, 2.0]
    r = hcr_from_lambda(lam, deltas, lower=-1.0, upper=1.5)
    # λ = inf → no bound; λ = 0 with Δ ≠ 0 → +inf (unresolved); Δ = 0 → no bound; Δ = 2 outside
    assert r.functional[[0, 2, 4]].tolist() == [-np.inf] * 3 and r.functional[1] == np.inf
    assert r.unresolved and "λ ≤ 0" in r.reason
    assert r.index == 3 and r.delta == -0.3
    assert r.value == pytest.approx(0.09 / math.expm1(0.2), rel=1e-14)
    assert r.usable.tolist() == [False, False, False, True, False]
    none = hcr_from_lambda([np.inf, np.inf], [0.1, -0.1])
    assert none.value == 0.0 and none.log10 == -np.inf and none.delta is None and none.index == -1
    assert "no usable" in none.reason and not np.isnan(none.functional).any()
    for bad_lam, bad_d in [([np.nan], [1.0]), ([-np.inf], [1.0]), ([1.0], [np.nan])]:
        with pytest.raises(ValueError):
            hcr_from_lambda(bad_lam, bad_d)
    with pytest.raises(ValueError, match="deltas must have shape"):
        hcr_from_lambda([1.0, 2.0], [1.0])


def test_at_edge_flags():
    # f = Δ²/expm1(λ): sup at the largest Δ > 0, in the interior, or at the smallest on its side
    assert hcr_from_lambda([0.01, 0.02, 0.04, 1.0], [0.1, 0.2, 0.3, -0.5]).at_edge == "largest"
    r = hcr_from_lambda([0.01, 0.02, 0.1, 1.0], [0.1, 0.2, 0.3, -0.5])
    assert r.index == 1 and r.at_edge is None and r.reason == ""
    assert hcr_from_lambda([0.01, 0.1, 0.001], [0.1, 0.2, -0.01]).at_edge == "smallest"


def _linear_renders(L0, a, deltas):
    return L0 + torch.as_tensor(deltas, dtype=torch.float64).reshape(-1, *[1] * L0.ndim) * a


def test_linear_gaussian_sup_at_small_delta_equals_crlb():
    g = torch.Generator().manual_seed(0)
    L0 = torch.rand(16, 16, 3, generator=g, dtype=torch.float64)
    a = torch.randn(16, 16, 3, generator=g, dtype=torch.float64)
    sigma = 0.5
    crlb = sigma**2 / float((a**2).sum())
    h = np.logspace(-5, 0, 40)
    deltas = np.concatenate([-h, h])
    r = B.hcr(L0, _linear_renders(L0, a, deltas), deltas, AWGN(sigma))
    assert r.at_edge == "smallest" and abs(r.delta) == h[0] and "smallest" in r.reason
    assert r.value <= crlb and r.value == pytest.approx(crlb, rel=1e-5)
    # every Δ's functional is below the CRLB (the linear Gaussian model is efficient)
    assert (r.functional <= math.log10(crlb) + 1e-12).all()


def test_linear_poisson_closed_form():
    g = torch.Generator().manual_seed(1)
    L0 = 1e4 * (1 + torch.rand(8, 8, 3, generator=g, dtype=torch.float64))
    a = 10 * torch.randn(8, 8, 3, generator=g, dtype=torch.float64)
    scale = 2.0
    deltas = np.concatenate([-np.logspace(-4, 1, 30), np.logspace(-4, 1, 30)])
    r = B.hcr(L0, _linear_renders(L0, a, deltas), deltas, Poisson(scale))
    closed = scale * deltas**2 * float((a**2 / L0).sum())
    np.testing.assert_allclose(r.lam, closed, rtol=1e-9)
    assert r.at_edge == "smallest"
    assert r.value == pytest.approx(1 / float((scale * a**2 / L0).sum()), rel=1e-5)


def _blob(theta: np.ndarray, n: int = 16) -> torch.Tensor:
    """Images (K, n, n) of a Gaussian blob at θ = (x, y) on a constant floor."""
    x = torch.linspace(0, 1, n, dtype=torch.float64)
    t = torch.as_tensor(theta, dtype=torch.float64).reshape(-1, 2)
    r2 = (x[None, None, :] - t[:, 0, None, None]) ** 2 + (x[None, :, None] - t[:, 1, None, None]) ** 2
    return 0.2 + torch.exp(-r2 / 0.02)


def test_vector_mse_bound_below_sum_of_components():
    rng = np.random.default_rng(2)
    t0 = np.array([0.45, 0.55])
    deltas = rng.normal(scale=0.05, size=(200, 2))
    r = B.hcr(_blob(t0)[0], _blob(t0 + deltas), deltas, AWGN(0.3))
    assert r.component_value.shape == (2,) and isinstance(r.delta, np.ndarray)
    assert r.value <= r.component_value.sum() * (1 + 1e-12)
    assert r.value >= r.component_value.max() * (1 - 1e-12)  # ‖Δ‖² ≥ Δ_j² at each component's argmax
    for j in range(2):  # each component bound is the sup of its own functional
        k = r.component_index[j]
        assert r.component_value[j] == pytest.approx(deltas[k, j] ** 2 / math.expm1(r.lam[k]), rel=1e-12)


def test_vector_linear_gaussian_limits():
    """Δ = r·(cos φ, sin φ) over 3600 directions, λ ≤ 1e-8: per-component HCR → (F⁻¹)_jj and the
    MSE bound → λ_max(F⁻¹) (rel 1e-4, the angular grid's resolution)."""
    g = torch.Generator().manual_seed(3)
    L0 = torch.rand(64, generator=g, dtype=torch.float64)
    A = torch.randn(2, 64, generator=g, dtype=torch.float64)
    A[1] += 0.8 * A[0]  # correlated parameters
    sigma = 1.0
    F = (A @ A.T).numpy() / sigma**2
    Finv = np.linalg.inv(F)
    phi = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    deltas = np.concatenate([r * np.stack([np.cos(phi), np.sin(phi)], 1) for r in (1e-5, 2e-5)])
    L_alt = L0 + torch.as_tensor(deltas) @ A
    r = B.hcr(L0, L_alt, deltas, AWGN(sigma))
    np.testing.assert_allclose(r.component_value, np.diag(Finv), rtol=1e-4)
    assert r.value == pytest.approx(np.linalg.eigvalsh(Finv).max(), rel=1e-4)


def test_pairwise_lambda_chunked_equals_unchunked_and_direct(tmp_path):
    rng = np.random.default_rng(4)
    R = (rng.random((7, 5, 6, 3)) + 0.1).astype(np.float32)
    R[2, 0, 0, 0] = 0.0  # a zero-mean pixel: Poisson λ[2, j] = inf for renders lit there
    for model in (AWGN(0.2), Poisson(3.0)):
        full = B.pairwise_lambda(torch.from_numpy(R), model)
        tiny = B.pairwise_lambda(torch.from_numpy(R), model, chunk_bytes=16 * 7)  # 7 px, 1 render
        mm = np.lib.format.open_memmap(tmp_path / "r.npy", mode="w+", dtype=np.float32, shape=R.shape)
        mm[:] = R
        from_mm = B.pairwise_lambda(mm, model, chunk_bytes=16 * 40)
        direct = np.array([[float(model.chi2_exponent(R[i], R[j])) for j in range(7)] for i in range(7)])
        assert full.shape == (7, 7) and full.dtype == np.float64
        np.testing.assert_allclose(tiny, full, rtol=1e-13)
        np.testing.assert_allclose(from_mm, full, rtol=1e-13)
        np.testing.assert_allclose(full, direct, rtol=1e-13)
        assert (np.diag(full) == 0).all() and not np.isnan(full).any()
    assert np.isinf(full[2, [0, 1, 3]]).all() and np.isfinite(full[:, 2]).all()


def test_pairwise_lambda_names_bad_render():
    R = torch.rand(5, 4, 4)
    R[3, 1, 2] = np.nan
    with pytest.raises(ValueError, match=r"renders\[3\] contains 1 NaN"):
        B.pairwise_lambda(R, AWGN(0.1), chunk_bytes=16 * 8)


@pytest.mark.parametrize("vector", [False, True])
def test_hcr_curve_equals_per_theta_hcr(vector):
    rng = np.random.default_rng(5 + vector)
    G = 15
    thetas = rng.uniform(0, 1, size=(G, 2) if vector else G)
    R = torch.from_numpy(rng.random((G, 6, 5, 3)) + 0.05)
    lower, upper = (np.array([0.1, 0.0]), np.array([0.9, 1.0])) if vector else (0.1, 0.9)
    model = Poisson(2.0)
    curve = B.hcr_curve(R, thetas, model, lower=lower, upper=upper, chunk_bytes=16 * 20)
    T = thetas.reshape(G, -1)
    for i in range(G):
        o = np.flatnonzero(np.arange(G) != i)
        d = thetas[o] - thetas[i]
        r = B.hcr(R[i], R[o], d, model, lower=lower - T[i], upper=upper - T[i])
        assert curve.log10[i] == pytest.approx(r.log10, rel=1e-12)
        assert curve.value[i] == pytest.approx(r.value, rel=1e-12)
        assert curve.index[i] == o[r.index] and curve.at_edge[i] == r.at_edge
        np.testing.assert_allclose(curve.delta[i], r.delta, rtol=1e-15)
        np.testing.assert_allclose(curve.component_log10[i], r.component_log10, rtol=1e-12)
        assert curve.reason[i] == r.reason and curve.unresolved[i] == r.unresolved
        inside = ((thetas[curve.index[i]] >= lower) & (thetas[curve.index[i]] <= upper)).all()
        assert inside


def test_benchmark_reduced_agrees():
    from nlosbench.benchmarks import bounds as bench

    rows = bench.run(reduced=True)
    names = {r["bench"] for r in rows}
    assert {"hcr_curve", "pairwise_lambda"} <= names
    curve = next(r for r in rows if r["bench"] == "hcr_curve")
    assert curve["max_abs_log10_diff"] <= 1e-9 and curve["ratio"] > 0


def test_all_unresolved_deltas_say_there_is_no_finite_bound():
    """Identical images at every Δ (λ = 0): the functional is infinite there, so the −inf log10 must
    not read as a bound of 0; the result says so and is flagged unresolved."""
    r = B.hcr_from_lambda(np.zeros(3), np.array([-0.1, 0.1, 0.2]))
    assert r.unresolved and r.index == -1 and r.log10 == -np.inf
    assert "no finite bound" in r.reason and "infinite functional" in r.reason
