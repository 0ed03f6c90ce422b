"""Per-pixel Fisher information maps: consistency with the Fisher matrix, shapes, files."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench import bounds as B
from nlosbench.noise import AWGN, Poisson


@pytest.mark.parametrize("model", [AWGN(0.2), Poisson(30.0)])
def test_maps_sum_to_fisher_diagonal(model):
    g = torch.Generator().manual_seed(0)
    L = 0.1 + torch.rand(12, 16, 3, generator=g)
    J = torch.randn(2, 12, 16, 3, generator=g)
    J[1, :6] = 0.0  # θ1 only informs the bottom half
    maps = B.fisher_maps(L, J, model)
    F = B.fisher_matrix(L, J, model)
    assert maps.shape == (2, 12, 16) and maps.dtype == np.float64 and (maps >= 0).all()
    np.testing.assert_allclose(maps.sum(axis=(1, 2)), np.diag(F), rtol=1e-12)
    assert (maps[1, :6] == 0).all() and (maps[1, 6:] > 0).any()
    np.testing.assert_allclose(B.fisher_maps(L, J, model, reduce="mean"), maps / 3, rtol=1e-15)
    one = B.fisher_maps(L, J[0], model)  # scalar θ
    np.testing.assert_array_equal(one, maps[:1])
    gray = B.fisher_maps(L[..., 0], J[:, ..., 0], model)  # (H, W) images
    np.testing.assert_allclose(gray.sum(axis=(1, 2)), np.diag(B.fisher_matrix(L[..., 0], J[:, ..., 0], model)),
                               rtol=1e-12)
    with pytest.raises(ValueError, match="reduce"):
        B.fisher_maps(L, J, model, reduce="max")


def test_save_fisher_maps(tmp_path):
    from nlosbench.io import read_exr

    L = 0.5 + torch.rand(8, 10, 3)
    J = torch.randn(2, 8, 10, 3)
    maps = B.fisher_maps(L, J, AWGN(0.1))
    paths = B.save_fisher_maps(maps, ["x", "radius"], tmp_path / "fi", prefix="ball")
    names = sorted(p.name for p in paths)
    assert names == ["ball_radius.exr", "ball_radius.png", "ball_x.exr", "ball_x.png"]
    assert all(p.stat().st_size > 0 for p in paths)
    back = read_exr(tmp_path / "fi" / "ball_radius.exr")
    np.testing.assert_allclose(back[..., 0], maps[1], rtol=1e-6)  # float32 storage
    with pytest.raises(ValueError):
        B.save_fisher_maps(maps, ["x"], tmp_path)


def test_the_study_takes_ad_passes_and_an_exact_toy_gets_its_closed_form_crlb(tmp_path):
    """The fisher-maps study with `gradient: {method: ad}` on blob2d (no rendering noise: torch's exact Jacobian in
    every pass), 4 passes, AWGN σ = 0.3: each parameter's CRLB is (F⁻¹)_jj of F = JᵀJ/σ² from torch's Jacobian of the
    clean image (an independent route) to float32 rounding; no FD step is recorded or checked, and the report says
    the maps come from AD passes."""
    import csv

    import torch
    import yaml

    from nlosbench.cli import main

    raw = {"name": "ad", "scene": {"name": "blob2d"}, "executor": {"type": "serial"},
           "noise": [{"model": "awgn", "sigma": 0.3}],
           "studies": [{"type": "fisher-maps", "at": [[0.4, 0.6]], "labels": ["mid"], "spp": 8, "fd_rounds": 4,
                        "gradient": {"method": "ad"}}]}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    assert main(["run", str(cfg), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    rows = list(csv.DictReader((tmp_path / "run" / "00-fisher-maps" / "fisher.csv").open()))
    m = nb.scenes.get("blob2d")
    J = torch.autograd.functional.jacobian(m.clean, torch.tensor([0.4, 0.6], dtype=torch.float64))
    exact = np.diag(np.linalg.inv(torch.einsum("hwcp,hwcq->pq", J, J).numpy() / 0.3**2))
    assert [r["param"] for r in rows] == ["x", "y"]
    for r, want in zip(rows, exact, strict=True):
        assert 10 ** float(r["log10_crlb"]) == pytest.approx(want, rel=1e-5) and not r["crlb_lower_note"], r
        assert r["fd_step"] == "nan" and "without an FD step" in r["flag"]
    assert "4 independent AD passes" in (tmp_path / "run" / "report.md").read_text()


def test_ad_and_fd_information_agree_for_a_colour():
    """cornell_ball's ball_red at 0.8 (a colour: `prb` differentiates it without visibility terms), AWGN σ = 0.05,
    64 spp, 8 independent AD passes against 8 FD rounds (ξ = 0.05, the step check converged): two routes to F from
    disjoint renders. Their log10 CRLBs agree by a two-sided test at 3 standard errors (each SE from its 95 % ends;
    measured: −4.038 and −4.033, each ±0.012)."""
    m = nb.scenes.get("cornell_ball").restrict(["ball_red"])
    svc = nb.bounds.BoundService(nb.RenderBank(m, seed=0), [nb.noise.AWGN(0.05)])
    [ad] = svc.fisher([0.8], 64, rounds=8, gradient="ad", ad={"type": "prb"})
    [fd] = svc.fisher([0.8], 64, fd_step=0.05, rounds=8)
    a, f = ad.crlb[0][0], fd.crlb[0][0]
    assert not a.lower_note and not f.lower_note, (a.reason, f.reason)
    se = [(b.upper - b.lower) / (2 * 1.6449) for b in (a, f)]
    assert abs(a.log10 - f.log10) < 3 * np.hypot(*se), (a.log10, f.log10, se)


def test_an_ad_jacobian_is_one_request_whatever_fd_step_a_caller_passes():
    """The bank keys an AD Jacobian without the FD step it ignores: `fisher(gradient="ad")` at two `fd_step` values
    (blob2d with rendering noise, 3 passes) renders its passes once and gives the same CRLB bit for bit."""
    m = nb.scenes.get("blob2d", render_noise=2.0)
    bank = nb.RenderBank(m, seed=0)
    svc = nb.bounds.BoundService(bank, [nb.noise.AWGN(0.3)])
    [a] = svc.fisher([[0.4, 0.6]], 8, fd_step=0.01, rounds=3, gradient="ad")
    made = bank.renders
    [b] = svc.fisher([[0.4, 0.6]], 8, fd_step=0.03, rounds=3, gradient="ad")
    assert bank.renders == made and [c.log10 for c in a.crlb[0]] == [c.log10 for c in b.crlb[0]]
