"""Fisher matrix and CRLB: closed forms, singular (non-identifiable) parameters, and the CRLB as the
Δ → 0 limit of the HCR functional."""
import numpy as np
import pytest
import torch

from nlosbench import bounds as B
from nlosbench.noise import AWGN, Poisson


def _linear(P=2, shape=(6, 5, 3), seed=0):
    g = torch.Generator().manual_seed(seed)
    L = 1.0 + torch.rand(shape, generator=g, dtype=torch.float64)
    J = torch.randn(P, *shape, generator=g, dtype=torch.float64)
    return L, J


def test_fisher_matrix_closed_forms():
    L, J = _linear(P=3)
    A = J.reshape(3, -1)
    np.testing.assert_allclose(B.fisher_matrix(L, J, AWGN(0.4)), (A @ A.T).numpy() / 0.16, rtol=1e-13)
    np.testing.assert_allclose(B.fisher_matrix(L, J, Poisson(5.0)),
                               (5.0 * (A / L.reshape(-1)) @ A.T).numpy(), rtol=1e-13)
    F1 = B.fisher_matrix(L, J[0], AWGN(0.4))  # scalar θ: J with the image's shape
    assert F1.shape == (1, 1) and F1[0, 0] == pytest.approx(float((J[0] ** 2).sum()) / 0.16, rel=1e-13)


def test_crlb_regular():
    L, J = _linear(P=2)
    F = B.fisher_matrix(L, J, AWGN(0.4))
    r = B.crlb(F)
    Finv = np.linalg.inv(F)
    np.testing.assert_allclose(r.F_inv, Finv, rtol=1e-12)
    np.testing.assert_allclose(r.component, np.diag(Finv), rtol=1e-12)
    assert r.trace == pytest.approx(np.trace(Finv), rel=1e-12)
    s = np.sqrt(np.diag(F))
    assert r.cond == pytest.approx(np.linalg.cond(F / np.outer(s, s)), rel=1e-8)
    assert not r.singular and r.reason == ""
    assert B.crlb(4.0).component.tolist() == [0.25]  # scalar F


def test_crlb_parameter_without_effect_is_flagged():
    L, J = _linear(P=3)
    J[1] = 0.0  # θ1 does not change the image
    r = B.crlb(B.fisher_matrix(L, J, AWGN(0.4)))
    assert r.singular and "θ[1] has no effect" in r.reason
    assert r.component[1] == np.inf and r.trace == np.inf and r.cond == np.inf
    F02 = B.fisher_matrix(L, J[[0, 2]], AWGN(0.4))  # the others keep their CRLB
    np.testing.assert_allclose(r.component[[0, 2]], np.diag(np.linalg.inv(F02)), rtol=1e-12)
    assert np.isfinite(r.F_inv).all() and (r.F_inv[1] == 0).all()


def test_crlb_confounded_parameters_are_flagged():
    L, J = _linear(P=3)
    J[2] = -2.0 * J[0]  # θ0 and θ2 act identically (up to scale): only θ0 − 2θ2 is visible
    r = B.crlb(B.fisher_matrix(L, J, AWGN(0.4)))
    assert r.singular and "rank-deficient" in r.reason and "[0, 2]" in r.reason
    assert r.component[0] == np.inf and r.component[2] == np.inf
    assert r.component[1] == pytest.approx(
        1 / float(B.fisher_matrix(L, J[1], AWGN(0.4))[0, 0]) / (1 - _corr2(J[0], J[1])), rel=1e-8)
    assert B.crlb(np.zeros((2, 2))).component.tolist() == [np.inf, np.inf]


def _corr2(a, b):
    """Squared correlation coefficient (uncentred) of two Jacobian images."""
    return float((a * b).sum() ** 2 / ((a * a).sum() * (b * b).sum()))


def test_crlb_rejects_bad_matrices():
    for F in ([[1.0, 0.5], [0.0, 1.0]], [[-1.0]], [[np.nan]], np.ones((2, 3))):
        with pytest.raises(ValueError):
            B.crlb(F)


@pytest.mark.parametrize("model", [AWGN(0.3), Poisson(4.0)])
def test_crlb_from_hcr_limit_matches_fisher(model):
    """L(θ) = L0 + θ a + θ² b: Richardson over the 3 smallest |Δ| recovers F exactly (rel 1e-7)."""
    L0, (a, b) = _linear(P=2, seed=1)
    L0 = L0 + 5.0  # keeps Poisson means positive
    deltas = np.array([-4e-2, -2e-2, -1e-2, 1e-2, 3e-2, 0.1])
    t = torch.as_tensor(deltas)[:, None, None, None]
    L_alt = L0 + t * a + t**2 * b
    r = B.crlb_from_hcr_limit(L0, L_alt, deltas, model)
    F = B.fisher_matrix(L0, a, model)[0, 0]
    assert not r.singular and r.component[0] == pytest.approx(1 / F, rel=1e-7)
    naive = deltas[2] ** 2 / float(model.chi2_exponent(L0, L_alt[2]))  # smallest Δ alone: O(Δ) off
    assert abs(naive * F - 1) > 10 * abs(r.component[0] * F - 1)


def test_crlb_from_hcr_limit_unresolved_and_vector():
    L0 = torch.ones(4, dtype=torch.float64)
    r = B.crlb_from_hcr_limit(L0, torch.stack([L0, L0]), np.array([0.1, 0.2]), AWGN(1.0))
    assert r.singular and r.component[0] == np.inf and "unresolved" in r.reason
    with pytest.raises(ValueError, match="scalar"):
        B.crlb_from_hcr_limit(L0, torch.stack([L0, L0]), np.ones((2, 2)), AWGN(1.0))
