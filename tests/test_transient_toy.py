"""The analytic transient toy (`forward.analytic.TransientPoint`): its closed-form Fisher information against the
autograd Jacobian, and the pipeline's CRLB (render bank + bound service, FD from renders) against that closed form
within the service's confidence limits, over independent runs."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService
from nlosbench.forward.analytic import TransientPoint


@pytest.mark.parametrize("theta", [None, [-0.12, 0.2, 0.6]])
def test_closed_form_fisher_matches_the_autograd_jacobian(theta):
    m = TransientPoint()
    t = m.params.default if theta is None else np.array(theta)
    J = torch.stack([m.jvp(t, j) for j in range(3)]).double()[..., 0]  # (3, scan, scan, T), counts per metre
    mu = m.clean(torch.as_tensor(t))[..., 0]
    F_auto = torch.einsum("aijk,bijk->ab", J / mu, J).numpy()
    F = m.fisher(t)
    assert np.allclose(F, F_auto, rtol=1e-5, atol=0), F / F_auto
    assert np.all(np.linalg.eigvalsh(F) > 0)


def test_image_is_counts_with_the_stated_budget_and_shape():
    m = TransientPoint()
    L = m.render(m.params.default, 1, 0)
    assert L.shape == (m.scan, m.scan, m.bins, 1) and m.channels == m.bins
    # the window holds the whole return: photons + background per bin over every bin, within 0.1 %
    assert float(L.double().sum()) == pytest.approx(m.photons + m.background * m.scan**2 * m.bins, rel=1e-3)
    assert float(L.min()) >= m.background


def test_exact_renders_give_the_closed_form_crlb():
    """No rendering noise: the service's FD Fisher information is the closed form up to FD truncation (ξ = 1 mm
    against σ = 9 mm of optical path): within 0.1 %."""
    m = TransientPoint()
    t = m.params.default
    (pt,) = BoundService(RenderBank(m, seed=0), [nb.noise.Poisson(1.0)]).at([t], 16, ("crlb",), replicates=3,
                                                                             fd_step=1e-3)
    assert 10 ** pt.bounds["crlb"].point == pytest.approx(m.crlb(t), rel=1e-3)


def test_noisy_renders_bracket_the_closed_form_crlb():
    """Rendering noise (render_noise 0.3, 256 spp, 4 replicate sets): 12 independent runs of the service (a bank
    seed each); each end is a one-sided 95 % limit, so the closed form falls outside [lower, upper] with
    probability ≤ 10 % per run: more than 5 misses of 12 has probability < 0.5 % (binomial). The point estimates
    agree with it within 1 %."""
    m = TransientPoint(render_noise=0.3)
    t = m.params.default
    exact = np.log10(m.crlb(t))
    miss, points = 0, []
    for seed in range(12):
        (pt,) = BoundService(RenderBank(m, seed=seed), [nb.noise.Poisson(1.0)]).at([t], 256, ("crlb",), replicates=4,
                                                                                  fd_step=1e-3)
        b = pt.bounds["crlb"]
        miss += not (b.lower <= exact <= b.upper)
        points.append(b.point)
    assert miss <= 5, miss
    assert np.allclose(10 ** (np.array(points) - exact), 1.0, atol=0.01)


def test_bad_options_fail_before_anything_renders():
    for bad in ({"background": 0.0}, {"scan": 0}, {"jitter_ps": -1.0}, {"bins": 2.5}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            TransientPoint(**bad)
