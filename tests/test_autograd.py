"""nb.render as a torch autograd Function: FD and AD backward passes inside an optimisation loop."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.forward import GradientSettings, fd_jacobian, jacobian, vjp


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


# -- grad="auto": the gradient diagnostics' verdicts pick the backend --------------------------------

@pytest.fixture(scope="module")
def small_box():
    """The paper's Cornell box at 16×16: θ = (red_x, red_radius, red_color)."""
    return nb.scenes.get("cornell_paper", defines={"res": 16})


@pytest.fixture
def verdicts_file(tmp_path):
    """Recorded verdicts: position artifact-prone (→ FD), colour clean with `prb` (→ AD); radius has none."""
    from nlosbench.diagnostics import Verdict, save_verdicts
    from nlosbench.diagnostics.verdict import STATUS_TEXT

    fd = {"method": "fd", "step": 0.01, "rounds": 1, "crn": True}
    return save_verdicts(tmp_path / "verdicts.json", {
        "red_x": Verdict("red_x", "ad-artifact-prone", STATUS_TEXT["ad-artifact-prone"], fd),
        "red_color": Verdict("red_color", "ad-clean", STATUS_TEXT["ad-clean"], {"method": "ad", "integrator": "prb"})})


def test_auto_gives_fd_to_the_artifact_prone_parameter_and_ad_to_the_clean_one(small_box, verdicts_file):
    """Backward through nb.render(grad="auto", verdicts=...) is FD for red_x (its verdict; bit for bit)
    and red_radius (the prior: geometry) and one AD `prb` pass for red_color: 1 + 2·2 renders, 1 AD pass."""
    m = small_box
    theta = torch.tensor(m.params.default, dtype=torch.float64, requires_grad=True)
    before = m.stats.snapshot()
    img = nb.render(m, theta, 16, 7, grad="auto", verdicts=verdicts_file)
    w = torch.linspace(-1, 1, img.numel()).reshape(img.shape)
    (img * w).sum().backward()
    used = m.stats.since(before)
    assert (used.renders, used.grad_passes) == (1 + 2 * 2, 1)
    fd = vjp(m, m.params.default, w, 16, 7, GradientSettings("fd"))
    ad = vjp(m, m.params.default, w, 16, 7, GradientSettings("ad", ad={"type": "prb"}))
    assert theta.grad[:2].tolist() == [fd[0], fd[1]]
    # reverse-mode AD accumulates with atomics: repeat passes agree to ~1e-6 relative, not bit for bit
    tol = 1e-5 * abs(ad[2])
    assert abs(float(theta.grad[2]) - ad[2]) < tol
    assert abs(fd[2] - ad[2]) > 100 * tol, (fd[2], ad[2])  # so the colour component came from AD, not FD


def test_auto_is_resolved_once_and_says_what_it_chose(small_box, verdicts_file, monkeypatch, caplog):
    """Three optimisation steps (settings object and string form alike) consult the verdicts once;
    the choice is logged once and stored on the resolved settings."""
    import logging

    from nlosbench.diagnostics import verdict

    calls = []
    real = verdict.choose_backend
    monkeypatch.setattr(verdict, "choose_backend", lambda *a, **k: calls.append(1) or real(*a, **k))
    m, settings = small_box, GradientSettings("auto", step=0.02, verdicts=str(verdicts_file))
    theta = torch.tensor(m.params.default, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.SGD([theta], lr=1e-6)
    with caplog.at_level(logging.INFO, logger="nlosbench.gradients"):
        for it in range(3):
            opt.zero_grad()
            grad = settings if it < 2 else "auto"
            opts = {} if it < 2 else {"step": 0.02, "verdicts": str(verdicts_file)}
            nb.render(m, theta, 4, it, grad=grad, **opts).sum().backward()
            opt.step()
    assert len(calls) == 1
    assert len([r for r in caplog.records if r.name == "nlosbench.gradients"]) == 1
    chosen = nb.resolve_gradient(m, settings)
    assert (chosen.method, chosen.ad_params, chosen.step) == ("mixed", (2,), 0.02)
    assert "red_x → fd(ξ=0.02" in chosen.chosen and "verdict: AD artifact-prone" in chosen.chosen
    assert "red_radius → fd" in chosen.chosen and "prior: radius" in chosen.chosen
    assert "red_color → ad:prb (verdict: AD clean)" in chosen.chosen
    assert chosen.chosen in caplog.text


def test_auto_without_verdicts_and_inside_an_estimator():
    """No verdicts: the prior (an exact toy → AD). Problem(gradient=GradientSettings("auto")) works in
    an estimator unchanged: Gauss–Newton on noise-free blob2d recovers θ."""
    from nlosbench import estimators
    from nlosbench.estimators.base import Problem

    m = nb.scenes.get("blob2d", width=0.15)
    assert nb.resolve_gradient(m, GradientSettings("auto")) == GradientSettings("ad")
    y = m.render([0.45, 0.6], 1, 0)
    problem = Problem(m, nb.noise.AWGN(0.02), GradientSettings("auto"), seed=1)
    est = estimators.get("gauss-newton", spp=1).fit(problem, y, [0.5, 0.5], np.random.default_rng(0))
    assert np.allclose(est.theta, [0.45, 0.6], atol=1e-4)


def test_mixed_jacobian_takes_each_component_from_its_backend():
    m = nb.scenes.get("blob2d")
    s = GradientSettings("mixed", step=1e-3, ad_params=(1,))
    J = jacobian(m, [0.5, 0.4], 1, 0, s)
    assert torch.equal(J[0], fd_jacobian(m, [0.5, 0.4], 1, 0, s, [0])[0])
    assert torch.equal(J[1], nb.forward.ad_jacobian(m, [0.5, 0.4], 1, 0, s, [1])[0])
    assert torch.equal(jacobian(m, [0.5, 0.4], 1, 0, s, [1])[0], J[1])


def test_mixed_vjp_picks_the_ad_integrator_for_its_ad_parameters_only(small_box):
    """Mixed with no AD `type`: the AD part (red_color) gets `prb` although red_x / red_radius move
    geometry (they go by FD), also through a restriction; its value matches a plain `prb` reverse pass."""
    m, w = small_box, torch.ones(16, 16, 3)
    m._ad_cache.clear()
    g = vjp(m, m.params.default, w, 16, 7, GradientSettings("mixed", ad_params=(2,)))
    r = m.restrict(["red_x", "red_color"])
    g_r = vjp(r, [m.params.default[0], m.params.default[2]], w, 16, 7, GradientSettings("mixed", ad_params=(1,)))
    assert [dict(k)["type"] for k in m._ad_cache] == ["prb"]
    ad = vjp(m, m.params.default, w, 16, 7, GradientSettings("ad", ad={"type": "prb"}))
    assert abs(g[2] - ad[2]) < 1e-5 * abs(ad[2]) and abs(g_r[1] - ad[2]) < 1e-5 * abs(ad[2])


def test_bad_auto_and_mixed_settings(tmp_path):
    m = nb.scenes.get("blob2d")
    with pytest.raises(ValueError, match="method 'mixed'"):
        GradientSettings("mixed")
    with pytest.raises(ValueError, match="method 'mixed'"):
        GradientSettings("ad", ad_params=(1,))
    with pytest.raises(ValueError, match="index past"):
        jacobian(m, [0.5, 0.5], 1, 0, GradientSettings("mixed", ad_params=(2,)))
    with pytest.raises(ValueError, match="verdicts are read by method 'auto'"):
        GradientSettings("fd", verdicts="x.json")
    with pytest.raises(ValueError, match="path or a mapping"):
        GradientSettings("auto", verdicts=3)
    with pytest.raises(FileNotFoundError, match="gradients"):
        nb.render(m, torch.tensor([0.5, 0.5], dtype=torch.float64), 1, 0, grad="auto", verdicts=tmp_path / "none")
    with pytest.raises(ValueError, match="string `grad`"):
        nb.render(m, [0.5, 0.5], 1, 0, grad=GradientSettings("fd"), step=0.1)
