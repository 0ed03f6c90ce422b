"""The FD step of a transient bound against the temporal response and the bins (`forward.detector.max_fd_step`):
on the analytic toy's exact renders, the central-difference Fisher information at the rule's largest step is
within 1 % of the closed form for bins up to 2σ wide, while a step that shifts the arrival by 2σ overestimates it
2-4× — which the service's halving rule (it halves only while F rises) does not catch; the study refuses such a
step before rendering, with the largest step that fits."""
import numpy as np
import pytest
import torch
import yaml

import nlosbench as nb
from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService
from nlosbench.cli import main
from nlosbench.forward.analytic import TransientPoint
from nlosbench.forward.detector import STEP_FRACTION, max_fd_step, ps_to_m


def fd_ratio(m: TransientPoint, xi: float) -> float:
    """F_ξ / F of the depth from a central difference of exact renders over ±ξ (Poisson weight at θ*)."""
    t = m.params.default
    mu = m.clean(torch.as_tensor(t)).numpy()
    tp, tm = t.copy(), t.copy()
    tp[2] += xi
    tm[2] -= xi
    J = (m.clean(torch.as_tensor(tp)).numpy() - m.clean(torch.as_tensor(tm)).numpy()) / (2 * xi)
    return float((J**2 / mu).sum() / m.fisher(t)[2, 2])


@pytest.mark.parametrize("jitter_ps, bin_width, background", [(30.0, 0.006, 0.5), (30.0, 0.006, 1e-6),
                                                               (10.0, 0.006, 0.5), (100.0, 0.006, 0.5),
                                                               (30.0, 0.018, 0.5)])
def test_the_rule_step_resolves_the_response_and_a_wide_one_does_not(jitter_ps, bin_width, background):
    """Bins from σ/1.5 to 2σ wide: at ξ_max (shift σ/2) |F_ξ/F − 1| ≤ 1 %; at 4ξ_max (shift 2σ) F_ξ > 2F."""
    m = TransientPoint(jitter_ps=jitter_ps, bin_width=bin_width, bins=int(round(0.576 / bin_width)),
                       background=background)
    xi = max_fd_step(m.sigma)
    assert xi == pytest.approx(STEP_FRACTION * ps_to_m(jitter_ps) / 2)
    assert abs(fd_ratio(m, xi) - 1) <= 0.01
    assert fd_ratio(m, 4 * xi) > 2.0


def test_the_halving_rule_alone_accepts_a_step_four_times_too_wide():
    """Exact renders, ξ = 4ξ_max, one halving allowed: F falls (2.6× → 1.09× the closed form) as ξ halves, so the
    rule, which halves only while F rises, settles there and the CRLB is 1.09× too low — the step rule is needed."""
    m = TransientPoint()
    t = m.params.default
    (pt,) = BoundService(RenderBank(m.restrict(["depth"], {"x": t[0], "y": t[1]}), seed=0),
                         [nb.noise.Poisson(1.0)]).at([t[[2]]], 1, ("crlb",), replicates=3,
                                                     fd_step=4 * max_fd_step(m.sigma), max_halvings=1)
    exact = 1.0 / m.fisher(t)[2, 2]
    assert 10 ** pt.bounds["crlb"].point < 0.95 * exact


def test_the_study_refuses_a_step_that_does_not_resolve_the_jitter(tmp_path, capsys):
    cfg = {"name": "tof-step", "seed": 0, "scene": {"name": "transient_point", "options": {"jitter_ps": 5.0}},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "time-of-flight", "jitters_ps": [5.0], "fd_step": 0.01, "trials": 0}]}
    path = tmp_path / "tof.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) != 0
    err = capsys.readouterr().err
    limit = max_fd_step(np.hypot(ps_to_m(5.0), ps_to_m(5.0)))
    assert "fd_step" in err and f"use fd_step <= {limit:.3g}" in err, err
    with pytest.raises(ValueError, match="no temporal response"):
        max_fd_step(0.0)
