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


@pytest.mark.parametrize("theta", [None, [-0.12, 0.2, 0.6], [-0.12, 0.2, 0.6, 0.4]])
def test_closed_form_fisher_matches_the_autograd_jacobian(theta):
    m = TransientPoint(free_albedo=theta is not None and len(theta) == 4)
    t = m.params.default if theta is None else np.array(theta)
    P = m.params.dim
    J = torch.stack([m.jvp(t, j) for j in range(P)]).double()[..., 0]  # (P, scan, scan, T), counts per unit
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


def test_depth_crlb_with_the_albedo_unknown_is_the_closed_form_two_by_two():
    """θ = (depth, albedo), x and y known: the service's "crlb_each" gives each parameter's CRLB from the full
    Fisher matrix, (F⁻¹)_jj, against the closed form 1 / (F_dd − F_da² / F_aa) (depth) within 0.1 % (exact renders:
    FD truncation only); its ends bracket it; the known-albedo 1 / F_dd is below it."""
    m = TransientPoint(free_albedo=True, albedo=0.8)
    sub = m.restrict(["depth", "albedo"], {"x": 0.05, "y": -0.03})
    t = np.array([0.75, 0.8])
    F = m.fisher([0.05, -0.03, 0.75, 0.8])[np.ix_([2, 3], [2, 3])]
    nuisance = 1.0 / (F[0, 0] - F[0, 1] ** 2 / F[1, 1])
    (pt,) = BoundService(RenderBank(sub, seed=0), [nb.noise.Poisson(1.0)]).at([t], 1, ("crlb", "crlb_each"),
                                                                               replicates=3, fd_step=1e-3)
    d, a = pt.bounds["crlb_depth"], pt.bounds["crlb_albedo"]
    assert 10 ** d.point == pytest.approx(nuisance, rel=1e-3)
    assert 10 ** a.point == pytest.approx(1.0 / (F[1, 1] - F[0, 1] ** 2 / F[0, 0]), rel=1e-3)
    assert d.lower <= d.point <= d.upper and "the others unknown" in d.reason
    assert 10 ** pt.bounds["crlb"].point == pytest.approx(10 ** d.point + 10 ** a.point, rel=1e-9)  # the trace
    assert nuisance > 1.0 / F[0, 0]
    with pytest.raises(ValueError, match="albedo must be in"):
        TransientPoint(free_albedo=True, albedo=20.0)


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
