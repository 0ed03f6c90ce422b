"""The detector model (`forward.detector`): a Gaussian jitter composes with the toy's own response as Gaussians
do (closed form), the CRLB through the detector and the bound service matches the toy's closed form, the
adjoint passes the dot-product test, gating and the time sum count what they should, the photon budget is met,
a measured response file reproduces the Gaussian, and bad input fails with one line."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService
from nlosbench.forward.analytic import TransientPoint
from nlosbench.forward.detector import Detected, Detector, ps_to_m

W = 0.006  # the toy's bin width, m
SA, SB = 30.0, 40.0  # toy jitter, detector jitter (ps)


def _combined_ps():
    """σ of toy ⊛ detector: σa² + σb² + w²/12 (a binned image convolved with a bin-integrated kernel adds one box)."""
    s2 = ps_to_m(SA) ** 2 + ps_to_m(SB) ** 2 + W**2 / 12
    return np.sqrt(s2) / ps_to_m(1.0)


def _pair():
    """(toy at σa seen by a detector of σb, toy at the combined σ): a window wide enough that no return is cut."""
    window = {"start": 1.15, "bins": 144}
    base = TransientPoint(jitter_ps=SA, background=1e-9, **window)
    det = Detected(base, Detector(bin_width=W, start=base.start, jitter_ps=SB, dark=0.5))
    ref = TransientPoint(jitter_ps=_combined_ps(), background=0.5, **window)
    return det, ref


def test_gaussian_jitter_composes_in_closed_form():
    det, ref = _pair()
    for theta in (ref.params.default, np.array([-0.1, 0.15, 0.62])):
        a, b = det.render(theta, 1, 0).double(), ref.render(theta, 1, 0).double()
        assert float((a - b).abs().max() / b.max()) < 5e-3
        assert float(a.sum()) == pytest.approx(float(b.sum()), rel=1e-3)


def test_crlb_through_the_detector_matches_the_closed_form():
    """Exact renders; the service's FD Jacobians pass through the detector (the same response, no background)."""
    det, ref = _pair()
    t = ref.params.default
    (pt,) = BoundService(RenderBank(det, seed=0), [nb.noise.Poisson(1.0)]).at([t], 16, ("crlb",), replicates=3,
                                                                               fd_step=1e-3)
    assert 10 ** pt.bounds["crlb"].point == pytest.approx(ref.crlb(t), rel=0.01)
    assert det.channels == ref.bins


def test_jacobians_go_through_the_linear_part_and_the_adjoint_is_exact():
    base = TransientPoint()
    rng = np.random.default_rng(0)
    for d in (Detector(bin_width=W, start=base.start, jitter_ps=25.0, gate=(1.5, 1.8), dark=0.1, gain=3.0),
              Detector(bin_width=W, response=(0.1, 0.6, 0.2, 0.1), response_shift=-1, ambient=1.0),
              Detector(bin_width=W, start=base.start, jitter_ps=25.0, timing=False, dark=0.1)):
        m = Detected(base, d)
        t = base.params.default
        h = 1e-4
        tp, tm = t.copy(), t.copy()
        tp[2] += h
        tm[2] -= h
        fd = (m.render(tp, 1, 0).double() - m.render(tm, 1, 0).double()) / (2 * h)
        assert torch.allclose(m.jvp(t, 2, 1, 0).double(), fd, rtol=1e-3, atol=1e-3 * float(fd.abs().max()))
        x = rng.normal(size=(base.scan, base.scan, base.bins, 1))
        G = rng.normal(size=d.apply_linear(x).shape)
        assert np.vdot(G, d.apply_linear(x)) == pytest.approx(np.vdot(d.adjoint(G, base.bins), x), rel=1e-10)
        g = m.vjp(t, torch.from_numpy(G.astype(np.float32)), 1, 0)
        assert g[2] == pytest.approx(float((torch.from_numpy(G) * m.jvp(t, 2, 1, 0).double()).sum()), rel=1e-4)


def test_gate_time_sum_and_wall_return():
    L = np.random.default_rng(1).uniform(size=(2, 3, 40, 1))
    d = Detector(bin_width=0.01, start=-0.1, gate=(0.2, 0.3), dark=0.5, wall_return=100.0)
    out = d.apply(L)
    centres = -0.1 + (np.arange(40) + 0.5) * 0.01
    off = (centres < 0.2) | (centres >= 0.3)
    assert np.all(out[:, :, off] == 0) and np.all(out[:, :, ~off] >= 0.5)  # gated off: no counts, no wall return
    ungated = Detector(bin_width=0.01, start=-0.1, dark=0.5, wall_return=100.0)
    assert np.allclose(ungated.apply(L)[:, :, 10] - L[:, :, 10, :] - 0.5, 100.0)  # bin 10 holds optical path 0
    summed = Detector(bin_width=0.01, start=-0.1, dark=0.5, wall_return=100.0, timing=False).apply(L)
    assert summed.shape == (2, 3, 1, 1)
    assert np.allclose(summed[:, :, 0], L.sum(axis=2) + 0.5 * 40 + 100.0)
    gated = Detector(bin_width=0.01, start=-0.1, gate=(0.2, 0.3), dark=0.5, wall_return=100.0, timing=False)
    assert np.allclose(gated.apply(L)[:, :, 0], out.sum(axis=2))


def test_photon_budget_and_zero_mean_bins():
    base = TransientPoint()
    ref = base.render(base.params.default, 1, 0).numpy() - base.background
    d = Detector.for_budget(1e6, ref, bin_width=W, start=base.start, jitter_ps=20.0, gate=(1.5, 1.9), dark=0.01)
    assert d.apply_linear(ref).sum() == pytest.approx(1e6, rel=1e-9)
    mean, deriv = np.zeros((1, 1, 4, 1)), np.zeros((1, 1, 4, 1))
    mean[..., 1, 0], deriv[..., 2, 0] = 1.0, 3.0
    with pytest.raises(ValueError, match=r"1 bins have zero mean but a non-zero derivative.*\(0, 0, 2, 0\)"):
        d.check(mean, deriv)
    d.check(mean + 0.01, deriv)


def test_a_measured_response_file_reproduces_the_gaussian(tmp_path):
    t = np.linspace(-200, 200, 801)
    f = tmp_path / "irf.txt"
    np.savetxt(f, np.c_[t, np.exp(-0.5 * (t / SB) ** 2)])
    h_file, first_file = Detector.from_file(f, bin_width=W).kernel()
    h_g, first_g = Detector(bin_width=W, jitter_ps=SB).kernel()
    # sampled (file) against bin-integrated (jitter): the same Gaussian up to the box, < 3 % of the peak
    a = dict(zip(range(first_file, first_file + len(h_file)), h_file, strict=True))
    diff = max(abs(a.get(first_g + i, 0.0) - v) for i, v in enumerate(h_g))
    assert diff < 0.03 * h_g.max()


@pytest.mark.parametrize("bad, match", [({"bin_width": 0.0}, "bin_width"), ({"jitter_ps": -1.0}, "jitter_ps"),
                                        ({"gate": (0.3, 0.2)}, "gate"), ({"gain": 0.0}, "gain"),
                                        ({"dark": float("nan")}, "dark"), ({"response": (0.0, 0.0)}, "response"),
                                        ({"jitter_ps": 10.0, "response": (1.0,)}, "not both")])
def test_bad_detectors_fail_in_one_line(bad, match):
    with pytest.raises(ValueError, match=match):
        Detector(**{"bin_width": 0.01, **bad})
