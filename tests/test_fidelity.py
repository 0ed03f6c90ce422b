"""Fidelity sweeps: the recommendation logic, pixel binning at a fixed photon budget, scene pruning, and
the `fidelity` study end to end (analytic toy with a known cost curve; real cornell_ball renders)."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

import nlosbench as nb
from nlosbench import bounds
from nlosbench.binning import bin_image
from nlosbench.bounds import crlb_log10
from nlosbench.bounds.service import Bound
from nlosbench.cli import main
from nlosbench.experiment import config
from nlosbench.forward.gradients import GradientSettings, fd_jacobian
from nlosbench.io import read_csv
from nlosbench.schema import grid_values
from nlosbench.studies import fidelity as study
from nlosbench.studies.context import RunContext
from nlosbench.tradeoff import (
    Point,
    aggregate,
    error_limits,
    jackknife_noise,
    pareto_front,
    recommend,
    relative_error,
    settled,
)

NOISES = [nb.noise.AWGN(sigma=0.3), nb.noise.Poisson(scale=5.0)]


# -- pure logic --------------------------------------------------------------------------------
def test_relative_error_is_exact_and_handles_infinities():
    assert relative_error(math.log10(1.03), 0.0) == pytest.approx(0.03, rel=1e-12)
    assert relative_error(-5.0, -5.0 + math.log10(2.0)) == pytest.approx(0.5, rel=1e-12)  # b = b_ref / 2
    d = 1e-15  # expm1 keeps full relative accuracy for tiny differences
    assert relative_error(d, 0.0) == pytest.approx(d * math.log(10.0), rel=1e-9)
    got = relative_error([np.inf, -np.inf, np.inf, -np.inf, 3.0], [np.inf, -np.inf, 1.0, 1.0, np.inf])
    assert got.tolist() == [0.0, 0.0, np.inf, np.inf, np.inf]
    assert relative_error(-1e4, -1.1e4) == np.inf  # 10^1000 overflows: honestly infinite, not NaN
    with pytest.raises(ValueError, match="NaN"):
        relative_error([np.nan], [0.0])
    assert aggregate([0.1, 0.3, 0.2]) == 0.3 and aggregate([0.1, 0.3, 0.2], "median") == 0.2
    with pytest.raises(ValueError, match="aggregate"):
        aggregate([0.1], "mean")


def test_recommendation_on_a_known_cost_accuracy_curve():
    """Error halves as cost doubles (e_k = 0.4/2^k, cost 2^k): with 5 % the first setting within is k = 3;
    its speed-up over the reference k = 5 is 2^5/2^3 = 4."""
    pts = [Point(k, 2.0 ** k, 0.4 / 2 ** k if k < 5 else 0.0) for k in range(6)]
    r = recommend("spp", pts, reference=5, tolerance=0.05)
    assert (r.value, r.speedup, r.error) == (3, 4.0, 0.05)
    assert recommend("spp", pts, 5, 0.049).value == 4  # 0.05 > 0.049: one step costlier
    assert recommend("spp", pts, 5, 1.0).value == 0
    # cost need not follow the value order; ∞ errors never qualify; equal costs keep the first listed
    pts = [Point("a", 5.0, 0.0), Point("b", 1.0, math.inf), Point("c", 2.0, 0.01), Point("d", 2.0, 0.02)]
    r = recommend("gradient", pts, "a", 0.05)
    assert (r.value, r.speedup) == ("c", 2.5)
    assert recommend("gradient", pts, "a", 0.001).value == "a"  # nothing cheaper qualifies: the reference


def test_a_point_resolved_within_tolerance_is_recommended_over_a_cheaper_unresolved_one():
    """With confidence limits the upper limit decides: error 2 % but upper limit 12 % does not qualify at
    10 %; upper limit 8 % does; without limits (None or NaN) the error itself decides."""
    pts = [Point(64, 1.0, 0.02, 0.12), Point(128, 2.0, 0.03, 0.08), Point(512, 8.0, 0.0, 0.0)]
    r = recommend("spp", pts, 512, 0.1)
    assert (r.value, r.upper, r.speedup) == (128, 0.08, 4.0)
    assert recommend("spp", [Point(64, 1.0, 0.02), Point(512, 8.0, 0.0)], 512, 0.1).value == 64
    assert recommend("spp", [Point(64, 1.0, 0.02, math.nan), Point(512, 8.0, 0.0)], 512, 0.1).value == 64


def _paired_bounds(g, trials, R, ratios, rho):
    """Synthetic bounds over `trials` data sets: M = len(ratios) pairs of CRLB-like bounds b = 1/mean(F_r)
    from R replicate sets, F_ref,r = 1 + 0.2 z_r and F_r = (1 + 0.2 (ρ z_r + √(1 − ρ²) z'_r)) / ratio, so
    b/b_ref → ratio; returns log10 points and leave-one-outs ((T, M), (T, M, R)) of both."""
    M = len(ratios)
    z = g.normal(size=(trials, M, R))
    zs = rho * z + math.sqrt(1 - rho * rho) * g.normal(size=(trials, M, R))
    Fr, Fs = 1 + 0.2 * z, (1 + 0.2 * zs) / np.asarray(ratios)[None, :, None]
    pt = lambda F: -np.log10(F.mean(axis=2))  # noqa: E731
    loo = lambda F: -np.log10((F.sum(axis=2, keepdims=True) - F) / (R - 1))  # noqa: E731
    return pt(Fs), pt(Fr), loo(Fs), loo(Fr)


def test_error_limits_cover_every_true_error_jointly_at_their_level(rng):
    """2000 synthetic data sets of M = 4 paired bounds from R = 8 replicate sets (true errors 0, 5, 10,
    30 %): all four true errors lie inside their limits together in ≥ 95 % − 3 SE (≈ 93.5 %) of them
    (Bonferroni: measured 96.3 %); correlated pairs (ρ = 0.9) give limits about √(1 − ρ) ≈ 0.32× as wide as
    independent ones (pairing cancels the common noise; measured 0.34–0.35 on the 30 % pair), and below 3
    replicates or with an infinite bound nothing is resolved: (0, ∞)."""
    ratios = np.array([1.0, 1.05, 1.1, 1.3])
    truth = np.abs(ratios - 1)
    widths = {}
    for rho in (0.9, 0.0):
        b, ref, lb, lr = _paired_bounds(rng, 2000, 8, ratios, rho)
        cover, width = [], []
        for t in range(2000):
            lo, hi = error_limits(b[t], ref[t], lb[t], lr[t], level=0.95)
            cover.append(np.all((lo <= truth + 1e-12) & (truth <= hi + 1e-12)))
            width.append(hi[3] - lo[3])
        assert np.mean(cover) >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / 2000), (rho, np.mean(cover))
        widths[rho] = np.median(width)
    assert 0.25 < widths[0.9] / widths[0.0] < 0.45, widths
    lo, hi = error_limits([0.0, math.inf], [0.01, 0.0], np.zeros((2, 2)), np.zeros((2, 2)))
    assert lo.tolist() == [0.0, 0.0] and hi.tolist() == [math.inf, math.inf]
    lo, hi = error_limits([0.0, math.inf], [0.01, 0.0], np.zeros((2, 4)), np.zeros((2, 4)))
    assert hi[1] == math.inf and 0 < lo[0] == hi[0] == pytest.approx(1 - 10 ** -0.01)  # exact pairs: no spread
    with pytest.raises(ValueError, match="leave-one-outs"):
        error_limits([0.0], [0.0], np.zeros((2, 3)), np.zeros((2, 3)))
    # an exact repeat (an HCR set by its Δ → 0 term is the CRLB) is one event: it does not widen the family,
    # a distinct comparison does
    b, ref, lb, lr = (x[0] for x in _paired_bounds(rng, 1, 8, ratios, 0.5))
    one = error_limits(b[:1], ref[:1], lb[:1], lr[:1])
    twice = error_limits(np.repeat(b[:1], 2), np.repeat(ref[:1], 2), np.repeat(lb[:1], 2, 0), np.repeat(lr[:1], 2, 0))
    two = error_limits(b[:2], ref[:2], lb[:2], lr[:2])
    assert np.allclose(twice[1], one[1][0]) and two[1][0] > one[1][0]


def test_pareto_front_keeps_exactly_the_undominated_points(rng):
    """Against a brute-force dominance check on random clouds (ties included), and a hand-made case."""
    assert pareto_front([4, 1, 2, 3, 2, math.nan], [1, 5, 3, 4, 2, 0]) == [1, 4, 0]
    for _ in range(200):
        c, e = rng.integers(0, 6, 12).astype(float), rng.integers(0, 6, 12).astype(float)
        undominated = {i for i in range(12) if not any(c[k] <= c[i] and e[k] <= e[i] and (c[k], e[k]) != (c[i], e[i])
                                                        for k in range(12))}
        front = pareto_front(c, e)
        # one representative per undominated (cost, error) pair, ordered by cost
        assert {(c[i], e[i]) for i in front} == {(c[i], e[i]) for i in undominated} and len(front) == len(
            {(c[i], e[i]) for i in undominated})
        assert list(c[front]) == sorted(c[front])
    with pytest.raises(ValueError, match="one length"):
        pareto_front([1, 2], [1])


def test_depth_settles_where_every_later_change_is_within_tolerance():
    depths = [1, 2, 3, 4, 5, 6]
    assert settled(depths, [math.inf, 0.5, 0.04, 0.06, 0.01, 0.0], 0.05) == 5  # 4 still changes by 6 %
    assert settled(depths, [math.inf, 0.5, 0.04, 0.03, 0.01, 0.0], 0.05) == 3
    assert settled(depths, [0.0] * 6, 0.05) == 1


@pytest.mark.parametrize("tol", [0.0, -0.1, math.nan, math.inf, True])
def test_bad_tolerance_is_refused(tol):
    with pytest.raises(ValueError, match="tolerance"):
        recommend("spp", [Point(1, 1.0, 0.0)], 1, tol)


def test_bad_tables_are_refused():
    with pytest.raises(ValueError, match="reference 7 is not among"):
        recommend("spp", [Point(1, 1.0, 0.0)], 7, 0.05)
    with pytest.raises(ValueError, match="cost"):
        recommend("spp", [Point(1, 0.0, 0.0)], 1, 0.05)
    with pytest.raises(ValueError, match="as many errors"):
        settled([1, 2], [0.0], 0.05)


# -- binning -----------------------------------------------------------------------------------
def _bound_set(R, J, noise, thetas):
    """log10 HCR (G,), with its Δ → 0 term, and log10 CRLB (G,) from exact renders (G, H, W, C) and
    Jacobians (G, 1, H, W, C): the HCR is the larger of the grid curve's sup and the CRLB term."""
    crlb = np.array([crlb_log10(R[g], J[g], noise)[0][0] for g in range(len(thetas))])
    return np.maximum(bounds.hcr_curve(R, thetas, noise).log10, crlb), crlb


@pytest.mark.parametrize("noise", NOISES, ids=str)
def test_binning_an_image_constant_within_bins_keeps_every_bound(noise, rng):
    """Image and derivative constant in each b×b block: the block means with σ/b (AWGN) or summed counts
    (Poisson) are sufficient statistics, so HCR and CRLB are unchanged (to rounding)."""
    b, G = 3, 5
    thetas = np.linspace(0.0, 0.4, G)
    coarse = rng.uniform(0.5, 2.0, (G, 4, 5, 3)) + thetas[:, None, None, None] * rng.uniform(0, 1, (4, 5, 3))
    up = lambda x: x.repeat(b, axis=-3).repeat(b, axis=-2)  # noqa: E731
    R, J = up(coarse), up(rng.normal(0, 1, (G, 1, 4, 5, 3)))
    full = _bound_set(R, J, noise, thetas)
    binned = _bound_set(bin_image(R, b), bin_image(J, b), noise.binned(b), thetas)
    for f, g in zip(full, binned, strict=True):
        np.testing.assert_allclose(g, f, rtol=1e-12)


@pytest.mark.parametrize("noise", NOISES, ids=str)
def test_binning_a_generic_image_never_lowers_a_bound(noise, rng):
    """Data processing: binning loses information, so every λ shrinks and every bound grows (or stays)."""
    b, G = 2, 6
    thetas = np.linspace(0.0, 0.5, G)
    R = rng.uniform(0.2, 2.0, (G, 8, 6, 3))
    J = rng.normal(0, 1, (G, 1, 8, 6, 3))
    lam, lam_b = (bounds.pairwise_lambda(x, n) for x, n in ((R, noise), (bin_image(R, b), noise.binned(b))))
    assert np.all(lam_b <= lam * (1 + 1e-12)) and np.any(lam_b < 0.9 * lam)
    full = _bound_set(R, J, noise, thetas)
    binned = _bound_set(bin_image(R, b), bin_image(J, b), noise.binned(b), thetas)
    for f, g in zip(full, binned, strict=True):
        assert np.all(g >= f - 1e-12)


def test_binned_noise_models_and_bad_factors():
    assert nb.noise.AWGN(sigma=0.4).binned(2) == nb.noise.AWGN(sigma=0.2)
    assert nb.noise.Poisson(scale=3.0).binned(3) == nb.noise.Poisson(scale=27.0)
    assert bin_image(np.ones((4, 6, 3)), 1).shape == (4, 6, 3)
    for b in (0, 1.5, True, "2", float("inf"), float("nan")):
        with pytest.raises(ValueError, match="binning factor"):
            bin_image(np.ones((4, 4, 3)), b)
    with pytest.raises(ValueError, match="cannot bin a 4×6 image by b = 4"):
        bin_image(np.ones((4, 6, 3)), 4)


# -- scene pruning -------------------------------------------------------------------------------
def test_scene_elements_can_be_removed_before_loading(cornell):
    theta = [0.0, 0.3, 0.8]
    dark = nb.scenes.get("cornell_ball", remove=["light"])
    assert float(dark.render(theta, 4, 0).abs().max()) == 0.0  # the only emitter is gone
    assert dark.content_key() != cornell.content_key()  # cached renders cannot mix
    with pytest.raises(ValueError, match=r"no element with id \['lamp'\].*ids: back, ball"):
        nb.scenes.get("cornell_ball", remove=["lamp"])


# -- the study end to end --------------------------------------------------------------------------
def _run(tmp_path: Path, raw: dict) -> tuple[Path, dict]:
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    return out, json.loads((out / "results.json").read_text())["studies"]["00-fidelity"]["results"]


TOY = {"name": "toy", "seed": 5, "executor": {"type": "serial"},
       "scene": {"name": "blob2d", "options": {"width": 0.2}, "params": ["x"]},
       "noise": [{"model": "awgn", "sigma": 2.0}],
       "studies": [{"type": "fidelity", "grid": {"start": 0.35, "stop": 0.65, "num": 7}, "spp": [36, 144],
                    "bins": [1, 2, 3, 4, 6], "gradient": ["fd", "ad"], "cost": "samples", "fd_step": 0.01}]}


def test_toy_study_picks_the_settings_of_its_known_cost_curve(tmp_path):
    """blob2d is exact (no rendering noise), cost counted in pixel-samples, so the curve is known:
    spp changes nothing (error 0, cost ∝ spp: 144/36 = 4×); bin b costs 1/b² and its error equals an
    independent computation on block sums with AWGN σ·b; AD (exact) differs from FD (ξ = 0.01) by the FD
    truncation error only, at 2 passes per point against 3 (1.5×)."""
    out, res = _run(tmp_path, TOY)
    k = res["knobs"]
    assert [p["error"] for p in k["spp"]["points"]] == [0.0, 0.0]
    assert k["spp"]["recommendation"] == {"value": 36, "error": 0.0, "upper": 0.0,
                                          "cost": k["spp"]["points"][0]["cost"], "speedup": 4.0}

    model = nb.scenes.get("blob2d", width=0.2).restrict(["x"])
    thetas = np.linspace(0.35, 0.65, 7)
    R = np.stack([model.render([t], 1, 0).numpy() for t in thetas]).astype(np.float64)
    J = np.stack([fd_jacobian(model, [t], 1, 0, GradientSettings(step=0.01)).numpy() for t in thetas]).astype(
        np.float64
    )
    sums = lambda x, b: x.reshape(*x.shape[:-3], 24 // b, b, 24 // b, b, 1).sum(axis=(-4, -2))  # noqa: E731
    ref = _bound_set(R, J, nb.noise.AWGN(2.0), thetas)
    expected = {}
    for b in (2, 3, 4, 6):
        got = _bound_set(sums(R, b), sums(J, b), nb.noise.AWGN(2.0 * b), thetas)
        expected[b] = max(relative_error(g, r).max() for g, r in zip(got, ref, strict=True))
    points = {p["value"]: p for p in k["bin"]["points"]}
    for b, e in expected.items():
        # the study's binned sensor returns float32 images (every model does): its block means and FD
        # differences are rounded where this reference keeps float64, which moves the error ~1e-6 relative
        assert points[b]["error"] == pytest.approx(e, rel=1e-5)
        assert points[1]["cost"] / points[b]["cost"] == b * b
    assert expected[2] < 0.05 < expected[3]  # so the right pick is b = 2, neither end of the list
    assert (k["bin"]["recommendation"]["value"], k["bin"]["recommendation"]["speedup"]) == (2, 4.0)

    ad = next(p for p in k["gradient"]["points"] if p["value"] == "ad")
    # AD changes only F: the HCR moves through its Δ → 0 term, at most as much as the CRLB (a max is 1-Lipschitz)
    assert 0 < ad["error"] < 0.05 and ad["error_hcr"] <= ad["error_crlb"] * (1 + 1e-9)
    assert (k["gradient"]["recommendation"]["value"], k["gradient"]["recommendation"]["speedup"]) == ("ad", 1.5)
    o = res["overall"]
    assert o["setting"] == {"spp": 36, "bin": 2, "max_depth": None, "gradient": "ad", "prune": []}
    assert o["verified"] and o["speedup"] == pytest.approx(4 * 4 * 1.5, rel=1e-12) == o["predicted_speedup"]
    report = (out / "report.md").read_text()
    # exact renders: every replicate set is the same, so the limits collapse onto the error
    e2 = study._pct(expected[2])
    assert f"| bin | 2 | 1 | {e2} | [{e2}, {e2}] | 4× |" in report and "**Caution:**" not in report


CORNELL = {
    "name": "cornell-fidelity",
    "seed": 2,
    "executor": {"type": "serial"},
    "scene": {"name": "cornell_ball", "options": {"defines": {"res": 16}}, "params": ["ball_x"]},
    "noise": [{"model": "awgn", "sigma": 1.0}, {"model": "poisson", "scale": 10.0}],
    "studies": [
        {
            "type": "fidelity",
            "grid": {"start": -0.06, "stop": 0.06, "num": 4},
            "spp": [4, 16],
            "bins": [1, 2],
            "max_depth": [2, 3],
            "fd_step": 0.02,
            "los_until": 0.0,
            "prune": ["green_wall"],
        }
    ],
}


def test_jackknife_noise_ends_miss_the_true_bound_at_their_level(rng):
    """20 000 synthetic CRLB-like bounds b = 1/mean(F_r) from R = 8 replicate sets (F_r = 1 + 0.05 z_r, true
    b = 1: a reference known to a few per cent, as the committed ones): the one-sided ends b·(1 + n) and
    b/(1 + n) of the points' Monte Carlo noise n each miss the true b in 5 % ± (0.25 % + 3 SE; SE = 0.15 %) of
    them: the t limits of a jackknife are exact for a mean, close for 1/mean (measured on 2·10⁶ sets: 5.19 % and
    4.81 %; at F_r = 1 + 0.2 z_r the skew of 1/mean parts them further).
    An infinite point is +inf noise, fewer than 3 sets NaN."""
    T, R = 20000, 8
    F = 1.0 + 0.05 * rng.standard_normal((T, R))
    point = -np.log10(F.mean(axis=1))
    loo = -np.log10((F.sum(axis=1, keepdims=True) - F) / (R - 1))
    n = jackknife_noise(point, loo, level=0.95)
    b = 10.0 ** point
    tol = 0.0025 + 3 * math.sqrt(0.05 * 0.95 / T)
    assert abs(np.mean(b * (1 + n) < 1.0) - 0.05) < tol and abs(np.mean(b / (1 + n) > 1.0) - 0.05) < tol
    assert jackknife_noise([math.inf, 0.0], np.zeros((2, 4)))[0] == math.inf
    assert np.isnan(jackknife_noise([0.0], np.zeros((1, 2)))).all()


def test_reference_convergence_is_its_points_noise_and_names_the_fd_variants_spread():
    """The reference converges on its points' Monte Carlo noise; an interval widened by the FD variants' spread
    (±78 % against ±2 %: the committed LOS light run's case) is said to be that, and no number of replicates is
    advised for it; a noise above tolerance / 2 gets R·(noise / (tol / 2))² replicates."""
    res = {"tolerance": 0.1, "reference_noise": 0.02, "reference_interval": 0.783, "replicates": 40,
           "level": 0.95, "reference_converged": True}
    text = study._convergence(res)
    assert "±2 %" in text and "converged" in text and "±78.3 %" in text and "do not shrink it" in text
    assert "replicates would" not in text and "**Caution:**" not in text
    text = study._convergence({**res, "reference_noise": 0.1, "reference_converged": False})
    assert "about 160 replicates" in text and "**Caution:**" in text and "±78.3 %" in text
    assert "do not shrink" not in study._convergence({**res, "reference_interval": 0.03})


def test_bound_noise_is_the_relative_half_width_of_the_interval():
    """noise = max(10^(upper − point) − 1, 1 − 10^(lower − point)); 0 for an exact bound, ∞ for an open upper
    end, NaN without limits (fewer than 3 replicates)."""
    lg = math.log10
    assert study.bound_noise(Bound("crlb", lg(0.8), lower=lg(0.8), upper=lg(1.5), point=lg(1.0))) == pytest.approx(0.5)
    assert study.bound_noise(Bound("crlb", lg(0.4), lower=lg(0.4), upper=lg(1.1), point=lg(1.0))) == pytest.approx(0.6)
    assert study.bound_noise(Bound("hcr", -2.0, lower=-2.0, upper=-2.0, point=-2.0)) == 0.0
    assert study.bound_noise(Bound("hcr", -2.0, lower=-2.0, upper=math.inf, point=-1.9)) == math.inf
    assert study.bound_noise(Bound("hcr", -2.0, lower=-math.inf, upper=-1.8, point=-1.9)) == 1.0
    assert math.isnan(study.bound_noise(Bound("crlb", -2.0, flags=("estimate-only",), lower=-2.0, upper=-2.0,
                                              point=-2.0)))


def test_cornell_study_runs_end_to_end_and_its_report_reproduces(tmp_path):
    """Real renders through the runner: every knob point, depth sufficiency and pruning, then `report`
    re-makes report.md and the plots from the saved files alone."""
    out, res = _run(tmp_path, CORNELL)
    d = out / "00-fidelity"
    rows = read_csv(d / "fidelity.csv")
    n_points = sum(len(s["points"]) for s in res["knobs"].values())
    assert n_points == 2 + 2 + 2 + 2 and len(rows) == n_points * 2 * 4
    assert all(float(r["err_hcr"]) == float(r["err_crlb"]) == 0.0 for r in rows if r["reference"] == "True")
    k = res["knobs"]
    # three replicate render sets: the 4 grid points and, with independent seeds, an FD pair (θ ± 0.02, one seed
    # per stencil: common random numbers inside it) at each of them — no render shared with the grid; and, for the
    # Poisson model, one weight render per grid point, independent of the replicates
    assert all(p["renders"] == 3 * (4 + 2 * 4) + 4 and p["cost"] > 0 for s in k.values() for p in s["points"])
    # the run's count is every setting's (each pruned or deeper scene is a model of its own), as the report says
    settings = {json.dumps(p["setting"], sort_keys=True) for s in k.values() for p in s["points"]}
    settings |= {json.dumps(res["overall"]["setting"], sort_keys=True)} if res["overall"]["verified"] else set()
    assert res["renders"] == (3 * (4 + 2 * 4) + 4) * len(settings)
    assert f"; {res['renders']} renders (" in (out / "report.md").read_text()
    spp4, bin2 = k["spp"]["points"][0], next(p for p in k["bin"]["points"] if p["value"] == 2)
    # bin 2 at 16 spp renders 16/4 per fine pixel: the pixel-samples of the spp-4 setting (each from its own set)
    assert bin2["samples"] == spp4["samples"] and bin2["renders"] == spp4["renders"]
    depth2 = next(p for p in k["max_depth"]["points"] if p["value"] == 2)
    assert depth2["error"] > 0  # a Cornell box without indirect light is another image
    assert res["depth"]["settled"] in (2, 3) and res["depth"]["nlos_points"] == 2
    assert next(p for p in k["prune"]["points"] if p["value"] == "green_wall")["error"] > 0
    report = (out / "report.md").read_text()
    assert "**Depth sufficiency**" in report and "| green_wall |" in report and "**Overall:**" in report
    assert ("still changes up to the deepest path tried" in report) == (res["depth"]["settled"] == 3)
    # 3 replicate sets give confidence limits: every other setting's error has a spread (real renders), the
    # reference's against itself none; the report cautions exactly when the reference's own noise exceeds
    # tolerance / 2
    assert all(p["upper"] > p["lower"] for s in k.values() for p in s["points"] if p["setting"] != res["reference"])
    assert (k["spp"]["points"][1]["lower"], k["spp"]["points"][1]["upper"]) == (0.0, 0.0)
    assert ("**Caution:**" in report) == (res["reference_noise"] > 0.05 / 2) == (not res["reference_converged"])
    for f in ("fidelity.png", "depth.png"):
        (d / f).unlink()
    (out / "report.md").unlink()
    assert main(["report", str(out)]) == 0
    assert (out / "report.md").read_text() == report
    assert (d / "fidelity.png").stat().st_size > 0 and (d / "depth.png").stat().st_size > 0


def _ctx(tmp_path, raw):
    cfg = config.resolve(raw)
    return RunContext.create(cfg, tmp_path, quiet=True), cfg["studies"][0]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"tolerance": 0.0}, "tolerance must be a finite number > 0"),
        ({"bins": [1, 5], "spp": [25]}, r"b = 5 does not divide the 24×24 image"),
        ({"bins": [1, 4], "spp": [8]}, r"reference spp 8 is not a multiple of b² = 16"),
        ({"bins": [0]}, "binning factor must be an integer >= 1"),
        ({"max_depth": [2, 4]}, "max_depth and prune need a Mitsuba scene"),
    ],
)
def test_bad_toy_settings_are_refused_before_any_work(tmp_path, change, message):
    ctx, block = _ctx(tmp_path, {**TOY, "studies": [{**TOY["studies"][0], **change}]})
    with pytest.raises(ValueError, match=message):
        study.run(ctx, block)
    assert ctx.model.stats.renders <= 1  # at most the 1-spp probe of the image size


def test_bad_mitsuba_settings_are_refused(tmp_path):
    base = CORNELL["studies"][0]
    ctx, block = _ctx(tmp_path, {**CORNELL, "studies": [{**base, "prune": ["green_wall", "lamp"]}]})
    with pytest.raises(ValueError, match=r"no element with id \['lamp'\]"):
        study.run(ctx, block)
    for change, message in (({"prune": ["ball"]}, "'ball' carries θ"), ({"max_depth": [0, 3]}, "depths must be >= 1")):
        with pytest.raises(ValueError, match=message):
            study.run(ctx, {**block, **change})


def test_smoke_shrinks_the_paper_config_and_stays_valid():
    cfg = config.load(Path(__file__).parents[1] / "configs" / "paper_fidelity.yaml", smoke=True)
    s = cfg["studies"][0]
    assert s["spp"] == [4, 16] and s["bins"] == [1, 2] and len(s["max_depth"]) == 2 and len(s["prune"]) <= 1
    assert len(grid_values(s["grid"])) <= 3


def test_the_overall_model_drops_every_element_resolved_as_unneeded():
    """The combination takes each knob's recommendation and removes the elements whose removal is resolved
    within tolerance (upper limit ≤ 10 %), not those merely estimated within it; its predicted speed-up is
    the product of the knobs' and the removals' (here 2 × 1.25)."""
    ref = study.Setting(512, 1, 8, "fd")
    summary = {
        "spp": {"recommendation": {"value": 256, "speedup": 2.0}},
        "prune": {"points": [{"value": "none", "cost": 10.0, "error": 0.0, "upper": 0.0},
                             {"value": "lamp", "cost": 8.0, "error": 0.02, "upper": 0.06},
                             {"value": "wall", "cost": 5.0, "error": 0.02, "upper": 0.3},
                             {"value": "box", "cost": 9.0, "error": 0.5, "upper": 0.9}]},
    }
    o = study._overall(None, summary, ref, {"tolerance": 0.1, "verify": False})
    assert o["setting"] == {"spp": 256, "bin": 1, "max_depth": 8, "gradient": "fd", "prune": ("lamp",)}
    assert o["predicted_speedup"] == pytest.approx(2.0 * 10 / 8) and not o["verified"]


def test_a_pruning_only_study_reports_no_empty_knob_tables(tmp_path):
    """With no knob swept (one spp, no binning, the scene's own depth) the report has the pruning table and
    the overall model, and no knob table left with a header and no rows."""
    study_cfg = {**CORNELL["studies"][0], "spp": [16], "bins": [1], "max_depth": [], "los_until": None}
    out, res = _run(tmp_path, {**CORNELL, "noise": CORNELL["noise"][:1], "studies": [study_cfg]})
    report = (out / "report.md").read_text()
    assert set(res["knobs"]) == {"prune"} and res["depth"] is None
    assert "| knob | value" not in report and "| knob | recommended" not in report
    assert "**Scene pruning:**" in report and "**Overall:**" in report
