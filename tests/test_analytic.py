"""Analytic toys: FD against exact gradients, synthetic rendering noise statistics, determinism."""
import pytest
import torch

import nlosbench as nb
from nlosbench.forward import GradientSettings, ad_jacobian, fd_jacobian


@pytest.mark.parametrize("theta", [[0.5, 0.5], [0.37, 0.61]])
def test_blob2d_fd_matches_exact_gradient(theta):
    m = nb.scenes.get("blob2d")
    J_fd = fd_jacobian(m, theta, 1, 0, GradientSettings(step=1e-4)).double()
    J_ex = ad_jacobian(m, theta, 1, 0).double()
    rel = (J_fd - J_ex).norm() / J_ex.norm()
    assert rel < 1e-3, rel


def test_edge1d_fd_matches_exact_away_from_kinks():
    m = nb.scenes.get("edge1d", pixels=64)
    theta = (20 + 0.4) / 64  # inside pixel 20, 0.4 px from its left boundary: the stencil crosses no kink
    J_fd = fd_jacobian(m, [theta], 1, 0, GradientSettings(step=1e-3)).double()
    J_ex = ad_jacobian(m, [theta], 1, 0).double()
    assert J_ex.abs().sum() == pytest.approx(64.0)  # d coverage/dθ = −pixels in one pixel, amplitude 1
    assert ((J_fd - J_ex).norm() / J_ex.norm()) < 1e-3


def test_edge1d_is_not_smooth_at_pixel_boundary():
    m = nb.scenes.get("edge1d", pixels=64)
    kink = 20 / 64
    J_fd = fd_jacobian(m, [kink], 1, 0, GradientSettings(step=0.25 / 64)).double()
    # a central stencil straddling a pixel boundary spreads the derivative over two pixels
    assert (J_fd[0, 0, :, 0] != 0).sum() == 2


@pytest.mark.parametrize("power", [1.0, 0.8])
def test_synthetic_render_noise_variance_falls_as_n_to_minus_p(power):
    m = nb.scenes.get("blob2d", render_noise=0.3, render_noise_power=power)
    clean = m.clean(torch.tensor([0.5, 0.5], dtype=torch.float64))
    for n in (4, 64):
        reps = torch.stack([m.render([0.5, 0.5], n, s).double() for s in range(200)])
        ratio = reps.var(0).sum() / m.noise_variance(clean, n).sum()
        # 200 replicates: the summed-variance ratio has relative sd ≈ sqrt(2/199)/sqrt(#pixels) ≪ 5 %
        assert abs(float(ratio) - 1) < 0.05, (n, float(ratio))
        assert abs(float((reps.mean(0) - clean).mean())) < 3e-3  # unbiased


def test_same_seed_same_image_different_seed_independent():
    m = nb.scenes.get("blob2d", render_noise=0.2)
    a, b, c = m.render([0.5, 0.4], 16, 7), m.render([0.5, 0.4], 16, 7), m.render([0.5, 0.4], 16, 8)
    assert torch.equal(a, b)
    clean = m.clean(torch.tensor([0.5, 0.4], dtype=torch.float64)).float()
    corr = torch.corrcoef(torch.stack([(a - clean).flatten(), (c - clean).flatten()]))[0, 1]
    assert abs(float(corr)) < 0.15  # 576 pixels: |corr| of independent noise has sd ≈ 0.04


def test_exact_model_ignores_spp_and_seed():
    m = nb.scenes.get("edge1d")
    assert m.exact and torch.equal(m.render([0.5], 1, 0), m.render([0.5], 999, 3))
