"""nb.render as a torch autograd Function: FD and AD backward passes inside an optimisation loop."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.forward import GradientSettings, fd_jacobian


@pytest.mark.parametrize("grad", ["fd", "ad"])
def test_loss_gradient_matches_exact_on_blob2d(grad):
    m = nb.scenes.get("blob2d")
    y = m.render([0.45, 0.55], 1, 0)
    theta = torch.tensor([0.5, 0.5], dtype=torch.float64, requires_grad=True)
    loss = ((nb.render(m, theta, 1, 0, grad=grad, step=1e-4) - y) ** 2).sum()
    loss.backward()
    # exact: d/dθ Σ (L(θ) − y)² through torch autograd on the closed form
    t = torch.tensor([0.5, 0.5], dtype=torch.float64, requires_grad=True)
    ((m.clean(t).float() - y) ** 2).sum().backward()
    assert torch.allclose(theta.grad, t.grad, rtol=1e-3, atol=1e-6)


def test_adam_loop_on_blob2d_recovers_theta():
    m = nb.scenes.get("blob2d")
    y = m.render([0.42, 0.58], 1, 0)
    theta = torch.tensor([0.5, 0.5], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([theta], lr=0.01)
    for _ in range(150):
        opt.zero_grad()
        loss = ((nb.render(m, theta, 1, 0, grad="fd", step=1e-3) - y) ** 2).sum()
        loss.backward()
        opt.step()
    assert np.allclose(theta.detach().numpy(), [0.42, 0.58], atol=2e-3)


def test_fd_backward_on_mitsuba_contracts_the_fd_jacobian(cornell):
    theta = torch.tensor([0.0, 0.3, 0.8], dtype=torch.float64, requires_grad=True)
    settings = GradientSettings(step=0.02, rounds=2)
    img = nb.render(cornell, theta, 32, 3, grad=settings)
    w = torch.linspace(0, 1, img.numel()).reshape(img.shape)
    (img * w).sum().backward()
    J = fd_jacobian(cornell, [0.0, 0.3, 0.8], 32, 3, settings).double()
    expect = torch.einsum("phwc,hwc->p", J, w.double())
    assert torch.allclose(theta.grad, expect, rtol=1e-6)


def test_fd_rounds_and_crn_seeds():
    """CRN uses one seed per stencil, so the rendering noise cancels up to its (small) θ-dependence;
    independent seeds leave noise/ξ in the derivative."""
    m = nb.scenes.get("blob2d", render_noise=0.5)
    crn = fd_jacobian(m, [0.5, 0.5], 16, 0, GradientSettings(step=1e-3)).double()
    ind = fd_jacobian(m, [0.5, 0.5], 16, 0, GradientSettings(step=1e-3, crn=False)).double()
    clean = nb.forward.ad_jacobian(nb.scenes.get("blob2d"), [0.5, 0.5], 1, 0).double()
    assert (crn - clean).norm() < 0.3 * clean.norm()
    assert (ind - clean).norm() > 10 * clean.norm()
    four = fd_jacobian(m, [0.5, 0.5], 16, 0, GradientSettings(step=1e-3, rounds=4)).double()
    assert (four - clean).norm() < (crn - clean).norm()  # rounds average independent seeds


def test_fd_at_the_edge_of_theta_is_one_sided():
    m = nb.scenes.get("blob2d")
    J = fd_jacobian(m, [0.8, 0.5], 1, 0, GradientSettings(step=1e-4)).double()
    exact = nb.forward.ad_jacobian(m, [0.8, 0.5], 1, 0).double()
    assert (J - exact).norm() < 2e-3 * exact.norm()  # one-sided: O(ξ) error


def test_bad_gradient_settings():
    with pytest.raises(ValueError, match="gradient method"):
        GradientSettings(method="magic")
    with pytest.raises(ValueError, match="rounds"):
        GradientSettings(rounds=0)
    with pytest.raises(ValueError, match="step"):
        GradientSettings(step=0.0)
