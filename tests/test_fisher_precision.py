"""Precision on request in the Fisher maps (`BoundService.fisher(precision=p, budget=B, looks=K)`): fresh FD
rounds only at the θ whose CRLB interval is wider than asked, limits that keep their coverage whatever the
stopping (checked against the exact CRLB of blob2d from its noiseless autograd Jacobian, never against what the
code computes), and the fisher-maps study's keys."""
import math

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.bank import RenderBank, Request
from nlosbench.bounds import BoundService

SIGMA, FD = 0.3, dict(fd_step=0.01, rounds=3, max_halvings=1)


def _blob(render_noise: float):
    return nb.scenes.get("blob2d", width=0.15, render_noise=render_noise).restrict(["x"])


def _exact_crlb(x: float) -> float:
    """σ² / Σ (∂L/∂x)² of blob2d (width 0.15, y = 0.5) from the noiseless model."""
    m0 = nb.scenes.get("blob2d", width=0.15)
    J = torch.func.jacrev(m0.clean)(torch.tensor([x, 0.5], dtype=torch.float64))[..., 0]
    return SIGMA**2 / float((J**2).sum())


@pytest.mark.slow
def test_both_ends_cover_the_exact_crlb_whatever_the_stopping():
    """blob2d's x (rendering noise 4 at 16 spp, AWGN σ = 0.3), θ = 0.45 and 0.75 per run, precision 0.25 (K = 2
    looks: the pilot's ends at one-sided 1 − 0.05/20, the fresh look's at 1 − 0.95·0.05), 100 seeds: 200 (θ, seed)
    intervals, independent (the bank derives each θ's FD seeds from θ). The lower end lies at or below the exact
    CRLB, and the upper end at or above it, each in ≥ 0.95 − 3·√(0.95·0.05/200) = 0.904 of them, and most runs make
    the fresh look (the rule is exercised). The FD step (1 cm, halved once) smooths blob2d's Gaussian (width 15 cm)
    by ≈ (ξ/w)²/6 < 0.1 % of F. Measured (seeds 0–99): lower 0.95, upper 0.965; every run made the fresh look (with
    3 looks each at 1 − 0.05/3 and nested rounds before: 1.00, 0.99). The guarantee is the proof in
    `bounds.precision`."""
    thetas = [0.45, 0.75]
    exact = np.array([_exact_crlb(x) for x in thetas])
    low, up, looks = [], [], []
    for seed in range(100):
        fps = BoundService(RenderBank(_blob(4.0), seed=seed), [nb.noise.AWGN(SIGMA)]).fisher(
            [[x] for x in thetas], 16, precision=0.25, **FD)
        for fp, e in zip(fps, exact, strict=True):
            b = fp.precise[0].bounds["crlb"]
            low.append(10**b.lower <= e * (1 + 1e-9))
            up.append(10**b.upper >= e * (1 - 1e-9))
            looks.append(fp.precise[0].precision.looks)
    need = 0.95 - 3 * math.sqrt(0.95 * 0.05 / len(low))
    assert np.mean(low) >= need and np.mean(up) >= need, (np.mean(low), np.mean(up))
    assert set(looks) <= {1, 2} and np.mean(np.array(looks) == 2) > 0.5, np.bincount(looks)


def _central(bank: RenderBank, theta: np.ndarray, step: float, r: int) -> torch.Tensor:
    """Round r's central FD Jacobian (1, H, W, C) float64 at θ from the bank's stencil renders (θ ± ξ, one seed)."""
    seed = bank.seed("fisher-stencil", 16, theta, r)
    X = bank.images([Request.of(theta + step, 16, seed), Request.of(theta - step, 16, seed)]).double()
    return ((X[0] - X[1]) / float(((theta + step) - (theta - step))[0]))[None]


def test_fresh_rounds_go_only_where_the_target_is_unmet_and_the_maps_are_the_reported_looks():
    """blob2d's x (rendering noise 2), seed 2, precision 0.145 (the pilot, its ends at 1 − α/20, reaches 0.134 at
    0.35 and 0.156 at 0.75): the θ that meets it at the pilot gets no FD round
    beyond the pilot's R0 = 3 and keeps them; the other is reported from fresh rounds R0 … R0 + R − 1 only, and its
    rounds, maps and CRLB of θ are those rounds' (the same stencil renders read back from the bank, no render; the map
    sums to the unbiased F of its finest step: Σ_r≠s ⟨J_r, J_s⟩ / (R(R − 1)σ²))."""
    bank = RenderBank(_blob(2.0), seed=2)
    svc = BoundService(bank, [nb.noise.AWGN(SIGMA)])
    fps = svc.fisher([[0.35], [0.75]], 16, precision=0.145, **FD)
    met = [fp for fp in fps if fp.precise[0].precision.looks == 1]
    fresh = [fp for fp in fps if fp.precise[0].precision.looks > 1]
    assert met and fresh, [fp.precise[0].precision for fp in fps]
    R0 = 3
    for fp in met:
        assert fp.rounds.shape[0] == R0 and fp.precise[0].precision.met
        seeds = {k.seed for k in bank._memo if np.allclose(k.theta, fp.theta)} - {bank.seed("fisher", 16, fp.theta)}
        assert seeds == {bank.seed("fisher-stencil", 16, fp.theta, r) for r in range(R0)}, seeds
    for fp in fresh:
        R = fp.precise[0].precision.fresh_sets
        assert fp.rounds.shape[0] == R >= 4
        before = bank.renders
        J = torch.stack([_central(bank, fp.theta, fp.step, r) for r in range(R0, R0 + R)])
        assert bank.renders == before
        torch.testing.assert_close(fp.rounds, J, rtol=0, atol=0)
        flat = J.reshape(R, -1)
        G = flat @ flat.T
        F = float((G.sum() - G.diagonal().sum()) / (R * (R - 1))) / SIGMA**2
        assert math.isclose(float(fp.maps[0].sum()), F, rel_tol=1e-9)
        assert math.isclose(fp.precise[0].bounds["crlb"].point, -math.log10(F), rel_tol=1e-9)


def test_one_look_renders_the_pilot_alone_and_quotes_it_at_the_full_level():
    """`looks=1` with a target the pilot cannot meet (blob2d's x, rendering noise 2, seed 2, ±1 %): the same renders
    as the call without a target (the pilot's 3 rounds, no fresh one), the CRLB's point its unbiased F from those
    rounds, its ends at the full level 0.95, and the record says it was not met and what one fresh look would cost."""
    def call(**kw):
        bank = RenderBank(_blob(2.0), seed=2)
        (fp,) = BoundService(bank, [nb.noise.AWGN(SIGMA)]).fisher([[0.35]], 16, **FD, **kw)
        return fp, bank.renders

    (plain, n_plain), (one, n_one) = call(), call(precision=0.01, looks=1)
    pt = one.precise[0]
    assert n_one == n_plain and one.rounds.shape[0] == 3
    torch.testing.assert_close(one.rounds, plain.rounds, rtol=0, atol=0)
    flat = one.rounds.reshape(3, -1)
    G = flat @ flat.T
    F = float((G.sum() - G.diagonal().sum()) / 6) / SIGMA**2
    assert math.isclose(pt.bounds["crlb"].point, -math.log10(F), rel_tol=1e-9)
    assert pt.bounds["crlb"].level == 0.95 and pt.precision.level == 0.95 and pt.precision.looks == 1
    assert not pt.precision.met and 0 < pt.precision.extra_pixel_samples < math.inf


@pytest.mark.parametrize("bad, match", [
    (dict(precision=0.2, rounds=2), "needs replicates >= 3"),
    (dict(budget=10**6), "a budget needs a precision target"),
    (dict(precision=-1.0), "precision must be a finite number > 0"),
    (dict(precision=0.2, looks=0), "looks must be an integer >= 1"),
])
def test_bad_targets_raise_before_any_render(bad, match):
    bank = RenderBank(_blob(2.0))
    with pytest.raises(ValueError, match=match):
        BoundService(bank, [nb.noise.AWGN(SIGMA)]).fisher([[0.5]], 16, **{**FD, **bad})
    assert bank.renders == 0


def test_the_study_reports_the_precision_and_names_the_key_of_a_bad_one(tmp_path):
    """The fisher-maps study on blob2d's x with `precision`: results.json keeps each θ's record (target, reached,
    looks), fisher.csv says how many rounds each map used, the report has the precision table; `precision` with
    `fd_rounds: 2` is refused before anything runs, naming fd_rounds."""
    import csv
    import json

    import yaml

    from nlosbench.cli import main

    raw = {"name": "p", "scene": {"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]},
           "executor": {"type": "serial"}, "seed": 2, "noise": [{"model": "awgn", "sigma": SIGMA}],
           "studies": [{"type": "fisher-maps", "at": [0.35, 0.75], "labels": ["a", "b"], "spp": 16, "fd_rounds": 3,
                        "max_halvings": 1, "precision": 0.1}]}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    assert main(["run", str(cfg), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    study = tmp_path / "run" / "00-fisher-maps"
    res = json.loads((tmp_path / "run" / "results.json").read_text())["studies"]["00-fisher-maps"]["results"]
    recs = res["precision"]
    assert [r["theta_index"] for r in recs] == [0, 1] and all(r["target"] == 0.1 for r in recs)
    rows = list(csv.DictReader((study / "fisher.csv").open()))
    assert [int(r["fd_rounds"]) for r in rows] == [3 if r["looks"] == 1 else r["fresh_sets"] for r in recs]
    assert "Precision of the CRLB of θ" in (tmp_path / "run" / "report.md").read_text()
    raw["studies"][0]["fd_rounds"] = 2
    cfg.write_text(yaml.safe_dump(raw))
    assert main(["run", str(cfg), "--out", str(tmp_path / "bad"), "--quiet"]) == 2
    assert not (tmp_path / "bad").exists()


def test_the_estimate_before_a_run_gives_the_range_a_precision_budget_allows(tmp_path):
    """With `precision` and `precision_budget`, the plan line says the least (pilot: at each of 2 θ a render and 3
    rounds of θ and 2 stencils × 2 steps, 32 renders of 16 spp × 24 × 24 px, what the pilot is charged) and the most
    (the budget, which caps the call, pilot included) it may spend, before anything renders; without a budget the
    most is the default ceiling, CEILING pilots, and the line says so."""
    import yaml

    from nlosbench.bounds.precision import CEILING
    from nlosbench.experiment.runner import prepare

    block = {"type": "fisher-maps", "at": [0.35, 0.75], "spp": 16, "fd_rounds": 3, "max_halvings": 1,
             "precision": 0.1, "precision_budget": 10**6}
    raw = {"name": "p", "scene": {"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]},
           "executor": {"type": "serial"}, "noise": [{"model": "awgn", "sigma": SIGMA}], "studies": [block]}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    run = prepare(cfg, out=tmp_path / "run", quiet=True)
    (e,) = run.estimates.values()
    pilot = 2 * (1 + 3 * (1 + 2 * 2)) * 16 * 24 * 24
    assert (e.floor, e.samples) == (pilot, 10**6)
    assert f"{pilot:.3g} to {10**6:.3g} pixel-samples" in run.notes[0], run.notes
    assert run.ctx.bank.renders == 0
    block.pop("precision_budget")
    cfg.write_text(yaml.safe_dump(raw))
    run = prepare(cfg, out=tmp_path / "run2", quiet=True)
    (e,) = run.estimates.values()
    assert (e.floor, e.samples) == (pilot, CEILING * pilot)
    assert f"the default ceiling, {CEILING} × the pilot's pixel-samples (≈ {pilot:.3g}): ≈ {CEILING * pilot:.3g}" in (
        run.notes[0]), run.notes
