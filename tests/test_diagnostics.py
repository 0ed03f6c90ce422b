"""AD-vs-FD gradient diagnostics: metrics on synthetic images with known answers, the verdict logic on
recorded metrics, remedies, cost measurement, and real Mitsuba gradients on the paper's Cornell box."""
import json
import math

import numpy as np
import pytest

import nlosbench as nb
from nlosbench import diagnostics as D
from nlosbench.diagnostics import metrics as M
from nlosbench.diagnostics.verdict import prior_settings
from nlosbench.forward import GradientSettings

SHAPE = (48, 48, 3)


def _noise_stack(rng, seeds: int, sigma: np.ndarray) -> np.ndarray:
    return rng.normal(size=(seeds, *SHAPE)) * sigma


def _hetero_sigma() -> np.ndarray:
    """Per-pixel noise level: 1 in the background, 10 on a one-pixel ring (a silhouette) and a block."""
    s = np.ones(SHAPE)
    y, x = np.mgrid[:SHAPE[0], :SHAPE[1]]
    ring = np.abs(np.hypot(y - 24, x - 24) - 12) < 0.6
    s[ring] = 10.0
    s[4:12, 30:44] = 10.0
    return s


def _reference(rng, sigma) -> M.Reference:
    return M.Reference.from_stack(rng.normal(size=(8, *SHAPE)) * sigma * 0.25)


# -- metrics on synthetic images -----------------------------------------------------------------

def test_clean_heteroscedastic_noise_flags_nothing():
    """40 trials × 8 seeds × 48² pixels of Gaussian noise whose σ jumps 10× on a ring and a block:
    no pixel crosses the threshold (measured false-positive rate 0 of 737,280 pixel-scores; a
    Gaussian tail alone would give ~1e-15 at z = 8, the rest is the per-pixel σ estimate's error)."""
    rng = np.random.default_rng(1)
    sigma = _hetero_sigma()
    flagged = total = 0
    for _ in range(40):
        z = M.outlier_scores(_noise_stack(rng, 8, sigma), _reference(rng, sigma))
        flagged += int((z > M.THRESHOLD).sum())
        total += z.size
    assert total == 40 * 8 * 48 * 48
    assert flagged == 0, f"false-positive rate {flagged / total:.2e}"


def test_planted_clusters_are_found_with_count_and_area():
    rng = np.random.default_rng(2)
    sigma = _hetero_sigma()
    imgs = _noise_stack(rng, 6, sigma)
    # seed 0: a 3×4 block and a 1-pixel spike; seed 3: an L-shaped cluster of 5 pixels on the noisy ring
    imgs[0, 30:33, 5:9, 0] += 60.0
    imgs[0, 44, 44, 1] -= 40.0
    for r, c in [(12, 22), (12, 23), (12, 24), (13, 24), (14, 24)]:
        imgs[3, r, c, 2] += 400.0
    z = M.outlier_scores(imgs, _reference(rng, sigma))
    found = {s: M.clusters(z[s]) for s in range(6)}
    assert [c.area for c in found[0]] == [12, 1]
    assert found[0][0].bbox == (30, 33, 5, 9)
    assert [c.area for c in found[3]] == [5]
    assert all(not found[s] for s in (1, 2, 4, 5))
    assert [c.area for c in M.clusters(z[0], min_area=2)] == [12]
    rows = M.image_metrics(imgs, _reference(rng, sigma))
    assert (rows[0]["clusters"], rows[0]["outlier_pixels"], rows[0]["max_cluster_area"]) == (2, 13, 12)
    # clusters at different places in different seeds do not persist; the same place does
    masks = M.outlier_mask(z)
    assert M.persistence(masks) == 0.0
    assert M.persistence(np.stack([masks[0]] * 3)) == 1.0


def test_persistent_bias_is_flagged_even_though_every_seed_agrees():
    """A bias present in every seed keeps the per-seed spread small; the reference exposes it."""
    rng = np.random.default_rng(3)
    sigma = np.ones(SHAPE)
    imgs = _noise_stack(rng, 4, sigma)
    imgs[:, 20:23, 20:23, :] += 30.0
    z = M.outlier_scores(imgs, _reference(rng, sigma))
    assert all([c.area for c in M.clusters(zs)] == [9] for zs in z)
    assert M.persistence(M.outlier_mask(z)) == 1.0


def test_total_agreement_interval_covers_at_its_level():
    """400 trials of 6 seeds vs a 4-round reference, same mean: the 95 % CI of the difference covers 0
    in 95 % ± 3.3 % (3 binomial standard errors) of trials; a shift of 6 SE is detected in all."""
    rng = np.random.default_rng(4)
    covered, detected = 0, 0
    for _ in range(400):
        ref = M.Reference.from_stack(1.0 + rng.normal(size=(4, 4, 4, 1)) * 0.5)
        imgs = 1.0 + rng.normal(size=(6, 4, 4, 1))
        covered += M.total_agreement(imgs, ref).agrees
        detected += not M.total_agreement(imgs + 6 * np.sqrt(16 / 6 + 16 * 0.25 / 4) / 16, ref).agrees
    assert abs(covered / 400 - 0.95) < 3 * math.sqrt(0.95 * 0.05 / 400)
    assert detected >= 390
    with pytest.raises(ValueError, match="at least 2 seeds"):
        M.total_agreement(np.zeros((1, 2, 2, 1)), ref)


def test_spp_trend_and_input_errors():
    assert [M.spp_trend(a, b) for a, b in [(0, 0), (10, 2), (5, 5), (2, 10)]] == ["none", "fade", "steady", "grow"]
    with pytest.raises(ValueError, match="shape"):
        M.as_stack(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        M.as_stack(np.full((2, 2, 1), np.nan))
    with pytest.raises(ValueError, match="center"):
        M.Reference.from_stack(np.zeros((2, 2, 2, 1)), center="mode")


# -- remedies ----------------------------------------------------------------------------------------

def test_median_of_k_removes_planted_heavy_tailed_error_mean_does_not():
    """20 trials of K = 5 passes: Gaussian noise (σ = 0.1) plus, in each pass, 2 % of pixels hit by a
    spike of ±50 (a heavy tail). The median's RMSE stays near the Gaussian level; the mean's is
    dominated by spikes (measured ratio ≈ 25, asserted > 10)."""
    rng = np.random.default_rng(5)
    truth = rng.normal(size=SHAPE)
    err_mean, err_median = [], []
    for _ in range(20):
        passes = truth + 0.1 * rng.normal(size=(5, *SHAPE))
        hit = rng.random(passes.shape) < 0.02
        passes[hit] += rng.choice([-50.0, 50.0], size=int(hit.sum()))
        err_mean.append(np.sqrt(np.mean((D.mean_of_k(passes) - truth) ** 2)))
        err_median.append(np.sqrt(np.mean((D.median_of_k(passes) - truth) ** 2)))
    assert np.mean(err_median) < 0.15
    assert np.mean(err_mean) > 10 * np.mean(err_median)


# -- verdict logic on recorded metrics -------------------------------------------------------------------

FD_SPEC = json.dumps({"method": "fd", "step": 0.01, "rounds": 1, "crn": True})
PP_SPEC = json.dumps({"method": "ad", "integrator": "prb_projective", "guiding": "none"})


def _row(label, method, spp, outliers, agrees=True, remedy="", spec=PP_SPEC, cost=1.0, **kw):
    return {"param": "p", "label": label + (f" + {remedy}" if remedy else ""), "method": method, "remedy": remedy,
            "spp": spp, "crn": True if method == "fd" else "", "applicable": "", "spec": spec,
            "outlier_pixels_per_image": outliers, "agrees": agrees, "total": 1.0, "ref_total": 1.0, "ci_low": -1,
            "ci_high": 1, "cost_to_target": cost if agrees else float("inf"), **kw}


def _fd(spp, outliers, cost=2.0):
    return _row("fd", "fd", spp, outliers, spec=FD_SPEC, cost=cost)


def test_verdict_clean_when_ad_has_no_more_outliers_than_fd():
    v = D.judge([_fd(64, 5), _fd(256, 1), _row("pp", "ad", 64, 2), _row("pp", "ad", 256, 0.5)], "p")
    assert v.status == "ad-clean" and v.text == "AD clean"
    assert v.settings() == GradientSettings("ad", ad={"type": "prb_projective", "guiding": "none"})
    assert v.cheapest == "pp"
    # of two clean integrators, grad="auto" gets the one that reaches the target soonest at any spp
    prb = json.dumps({"method": "ad", "integrator": "prb"})
    two = D.judge([_fd(64, 5), _fd(256, 1), _row("pp", "ad", 64, 2, cost=0.5), _row("pp", "ad", 256, 0, cost=0.3),
                   _row("prb", "ad", 64, 2, spec=prb, cost=0.1), _row("prb", "ad", 256, 0, spec=prb, cost=0.4)], "p")
    assert two.settings() == GradientSettings("ad", ad={"type": "prb"}) and two.cheapest == "prb"


def test_verdict_artifact_prone_on_excess_or_non_fading_outliers():
    rows = [_fd(256, 1), _row("pp", "ad", 256, 9, cost=5.0), _row("pp", "ad", 256, 0, remedy="median", cost=3.0)]
    excess = D.judge(rows, "p")
    assert excess.status == "ad-artifact-prone" and "median-of-K" in excess.text
    assert excess.settings().method == "fd" and excess.cheapest == "fd"
    # paper: AD outliers stay from 4096 to 16384 spp while FD's fade away
    steady = D.judge([_fd(4096, 8), _fd(16384, 2), _row("pp", "ad", 4096, 3), _row("pp", "ad", 16384, 2.5)], "p")
    assert steady.status == "ad-artifact-prone"
    assert any("steady" in r for r in steady.reasons)


def test_verdict_biased_and_undetermined():
    v = D.judge([_fd(256, 1), _row("pp", "ad", 256, 0, agrees=False)], "p")
    assert v.status == "ad-biased" and v.settings().method == "fd" and "biased" in v.reasons[0]
    # an integrator marked not applicable does not count
    na = _row("prb", "ad", 256, 0, applicable="ignores visibility changes")
    assert D.judge([_fd(256, 1), na], "p").status == "undetermined"
    # clean-looking AD on 2 seeds is not enough to switch grad="auto" to AD
    few = D.judge([_fd(256, 1), _row("pp", "ad", 256, 0, seeds=2)], "p")
    assert few.status == "undetermined" and few.settings().method == "fd" and "power" in few.reasons[-1]
    with pytest.raises(ValueError, match="no gradient metrics"):
        D.judge([_fd(256, 1)], "q")


def test_verdicts_round_trip_and_choose_backend(tmp_path, cornell):
    clean = D.judge([_fd(256, 1), _row("pp", "ad", 256, 0)], "p")
    prone = D.judge([_fd(256, 1), _row("pp", "ad", 256, 9)], "p")
    D.save_verdicts(tmp_path / "verdicts.json", {"ball_x": clean, "ball_red": clean})
    loaded = D.load_verdicts(tmp_path)
    assert loaded["ball_x"] == clean
    # measured verdicts: one AD pass for the clean parameters, with the most general integrator
    both = cornell.restrict(["ball_x", "ball_red"])
    assert D.choose_backend(both, loaded).ad["type"] == "prb_projective"
    assert D.choose_backend(both, tmp_path) == D.choose_backend(both, loaded)  # a saved file works as well
    # an artifact-prone parameter gets FD, the clean one AD: a "mixed" backend, and it says why
    mixed = D.choose_backend(both, {"ball_x": prone, "ball_red": clean})
    assert (mixed.method, mixed.ad_params, mixed.ad["type"]) == ("mixed", (1,), "prb_projective")
    assert "ball_x → fd" in mixed.chosen and "AD artifact-prone" in mixed.chosen and "ball_red → ad:" in mixed.chosen
    # the "auto" settings' FD options, spp and AD overrides are kept
    base = GradientSettings("auto", step=0.02, rounds=3, spp=8, ad={"sppi": 0})
    kept = D.choose_backend(both, {"ball_x": prone, "ball_red": clean}, base=base)
    assert (kept.step, kept.rounds, kept.spp, kept.ad["sppi"], kept.ad["type"]) == (0.02, 3, 8, 0, "prb_projective")
    # no measurements: the paper's finding (geometry → FD, colour → AD prb); exact toys → AD
    assert prior_settings(cornell, cornell.params.index("ball_red")) == GradientSettings("ad", ad={"type": "prb"})
    prior = D.choose_backend(cornell)
    assert (prior.method, prior.ad_params, prior.ad) == ("mixed", (2,), {"type": "prb"})
    assert "ball_x → fd" in prior.chosen and "prior: translate" in prior.chosen
    assert D.choose_backend(cornell.restrict(["ball_x", "ball_radius"])) == GradientSettings("fd")
    assert D.choose_backend(cornell.restrict(["ball_red"])) == GradientSettings("ad", ad={"type": "prb"})
    assert D.choose_backend(nb.scenes.get("blob2d")) == GradientSettings("ad")
    # verdicts of other parameters too (a study over all of θ, used on a restriction) are fine; of none, an error
    assert D.choose_backend(cornell.restrict(["ball_red"]), {"ball_x": prone, "ball_red": clean}).method == "ad"
    with pytest.raises(ValueError, match="name no parameter"):
        D.choose_backend(cornell.restrict(["ball_red"]), {"red_x": clean})
    with pytest.raises(FileNotFoundError, match="gradients"):
        D.load_verdicts(tmp_path / "nothing")


# -- backends, applicability, cost ------------------------------------------------------------------


def test_backend_specs_round_trip_and_errors(cornell):
    for spec in (
        {"method": "fd", "step": 0.02, "rounds": 3, "crn": False},
        {"method": "ad", "integrator": "prb_projective", "sppi": 0, "guiding": "none"},
    ):
        assert D.spec_of(D.backend(spec)) == spec
    assert D.label(D.backend({"method": "fd", "step": 0.01})) == "fd(ξ=0.01,R=1,crn)"
    assert D.label(D.backend({"method": "ad", "integrator": "prb"})) == "ad:prb"
    with pytest.raises(ValueError, match="integrator must be one of"):
        D.backend({"method": "ad", "integrator": "path"})
    with pytest.raises(ValueError, match="unknown option"):
        D.backend({"method": "ad", "integrator": "prb", "spp": 4})
    with pytest.raises(ValueError, match="method"):
        D.backend({"step": 0.01})
    why = D.applicable_integrators(cornell, cornell.params.index("ball_radius"))
    assert why["prb_projective"] == "" and "visibility" in why["prb"] and "direct" in why["direct_projective"]
    assert D.applicable_integrators(cornell.restrict(["ball_red"]), 0)["prb"] == ""
    assert D.param_kind(cornell.restrict(["ball_radius"]), 0) == "radius"


def test_measure_sees_memory_outside_python_objects():
    """A 160 MiB buffer written by numpy (as Dr.Jit's would be, outside Python's object heap) and freed
    within the block. On Linux (the kernel's peak RSS, reset per block): a 40 MiB spike inside a
    nested block counts for the inner block and, with the 10 MiB held around it, for the outer one, each
    within a tolerance that holds on any machine (page rounding, a baseline that shrinks a little)."""
    import sys

    with D.measure() as c:
        a = np.ones(20 * (1 << 20), dtype=np.float64)
        a.sum()
        del a
    assert c.seconds > 0
    assert c.peak_bytes > 100 * (1 << 20), (c.method, c.peak_bytes)
    if sys.platform.startswith("linux"):
        assert c.method == "vmhwm"
        with D.measure() as outer:
            a = np.full(10 * (1 << 17), 2.0)  # 10 MiB, kept
            with D.measure() as inner:
                b = np.full(40 * (1 << 17), 1.0)  # 40 MiB, freed at once
                del b
            del a
        # ±10 % / +15 %: the baseline RSS can shrink by a few pages while the block runs (the GPU
        # machine measured 40.77 MB = 38.9 MiB for this 40 MiB spike), and the allocator rounds up
        mib = 1 << 20
        assert 0.9 * 40 * mib < inner.peak_bytes < 1.15 * 40 * mib, inner
        assert 0.9 * 50 * mib < outer.peak_bytes < 1.15 * 50 * mib, outer
        assert outer.peak_bytes - inner.peak_bytes > 5 * mib, (outer, inner)  # the 10 MiB held around it


# -- real renders on the paper's Cornell box -------------------------------------------------------


@pytest.fixture(scope="module")
def paper_box():
    return nb.scenes.get("cornell_paper")


def test_paper_box_is_the_papers_scene_and_the_red_ball_stays_free(paper_box):
    """Materials as in the paper's caption; over the corners of Θ the red ball touches neither the
    floor, the right wall nor the green ball (bounding boxes of the moved, resized sphere)."""
    import itertools

    import mitsuba as mi

    p = mi.traverse(paper_box.scene)
    assert [float(p[f"{k}.alpha"][0]) for k in ("wall", "green_ball.bsdf", "red_ball.bsdf")] == pytest.approx(
        [0.1, 0.05, 0.4862]
    )
    rad = np.array(p["light.emitter.radiance.value"], dtype=np.float64).ravel()
    assert len(paper_box.scene.emitters()) == 1 and np.ptp(rad) == 0 and rad[0] > 0
    shapes = {s.id(): s for s in paper_box.scene.shapes()}

    def box(name):
        b = shapes[name].bbox()
        return np.array(b.min, dtype=np.float64).ravel(), np.array(b.max, dtype=np.float64).ravel()

    g_lo, g_hi = box("green_ball")
    g_c, g_r = (g_lo + g_hi) / 2, (g_hi - g_lo)[0] / 2
    P = paper_box.params
    for x, r in itertools.product(*[(P.lower[P.index(n)], P.upper[P.index(n)]) for n in ("red_x", "red_radius")]):
        paper_box._apply(P.validate([x, r, 0.8]))
        lo, hi = box("red_ball")
        assert lo[1] > -1.0 and hi[0] < 1.0 and hi[1] < 1.0
        assert np.linalg.norm((lo + hi) / 2 - g_c) > g_r + (hi - lo)[0] / 2
    paper_box._apply(P.default)


def test_paper_box_colour_gradient_ad_agrees_with_fd_and_is_clean(paper_box):
    """The paper: colour gradients are clean under AD and FD. 4 seeds of AD (prb) and of FD (CRN,
    ξ = 0.01) at 256 spp on the 32×32 box: totals agree within the 95 % CI, no outlier clusters."""
    m, theta, j = paper_box, paper_box.params.default, paper_box.params.index("red_color")
    fd = D.gradient_images(m, theta, j, GradientSettings("fd", step=0.01), 256, range(100, 104))
    ad = D.gradient_images(m, theta, j, D.backend({"method": "ad", "integrator": "prb"}), 256, range(4))
    ref = D.Reference.from_stack(fd.images)
    s = D.summarize(ad.images, ref)
    assert s["agrees"], s
    assert s["clusters_per_image"] == 0 and s["outlier_pixels_per_image"] == 0, s
    # the gradient is a real signal: the reference total is many standard errors from 0
    assert abs(ref.total) > 10 * ref.total_se
    assert ad.renders == 0 and ad.grad_passes == 4 and fd.renders == 8


def test_visibility_boost_with_boost_1_is_the_plain_pass(paper_box):
    """The remedy splits prb_projective into its continuous term (sppp = sppi = 0) and its visibility
    terms (sppc = 0) at the pass's seed: on real renders (16×16 box, d/d red_x, 16 spp, 2 seeds) the
    two parts sum to the plain pass to float rounding, so no term is lost or counted twice, and a
    boost only adds visibility samples. (Measured the same for d/d red_radius.)"""
    m = nb.scenes.get("cornell_paper", defines={"res": 16})
    pp = D.backend({"method": "ad", "integrator": "prb_projective", "guiding": "none"})
    j = m.params.index("red_x")
    plain = D.gradient_images(m, m.params.default, j, pp, 16, [5, 6])
    split = D.remedy_run(m, m.params.default, j, pp, 16, [5, 6], "visibility-boost", boost=1)
    assert np.abs(plain.images).max() > 1.0  # the silhouette derivative is there
    np.testing.assert_allclose(split.images, plain.images, rtol=0, atol=2e-6 * np.abs(plain.images).max())
    assert split.grad_passes == 2 * plain.grad_passes
    with pytest.raises(ValueError, match="projective"):
        D.remedy_run(
            m, m.params.default, 0, D.backend({"method": "ad", "integrator": "prb"}), 16, [1], "visibility-boost"
        )
    with pytest.raises(ValueError, match="median of 2"):
        D.remedy_run(m, m.params.default, 0, pp, 16, [1], "median", k=2)


def _paper_block(**kw) -> dict:
    """A paper-scale `gradients` block (the paper: 4096 and 16384 spp; FD averaged over 16 rounds)."""
    from nlosbench.experiment.config import study_schema
    from nlosbench.schema import validate_block
    from nlosbench.studies import gradients as study

    return validate_block(
        {
            "id": "grad",
            "spp": [4096, 16384],
            "seeds": 8,
            "ad_options": {},
            "reference": {"spp": 65536, "rounds": 16},
            **kw,
        },
        study_schema(study),
    )


def test_smoke_shrinks_a_paper_scale_block():
    from nlosbench.experiment.config import study_schema
    from nlosbench.schema import validate_block
    from nlosbench.studies import gradients as study

    big = _paper_block(
        backends=[
            {"method": "fd", "step": 0.01, "rounds": 16},
            {"method": "ad", "integrator": "prb_projective", "sppi": 0},
        ]
    )
    tiny = validate_block(study.smoke(big), study_schema(study))  # still a valid block
    assert (tiny["spp"], tiny["seeds"], tiny["reference"]) == ([4, 8], 2, {"spp": 32, "rounds": 2})
    assert tiny["remedies"]["k"] == 4 and tiny["remedies"]["boost"] == 2
    assert tiny["backends"][0] == big["backends"][0]
    assert tiny["backends"][1] == {"method": "ad", "integrator": "prb_projective", "sppi": 0, "guiding": "none"}
    assert tiny["ad_options"] == {"guiding": "none"}
    assert study.smoke(_paper_block(spp=[1024], reference=None))["spp"] == [8]
    assert study.smoke(_paper_block(spp=[1024], reference=None))["reference"] is None


def test_gradients_study_end_to_end(tmp_path, paper_box):
    """The smoke copy of a paper-scale `gradients` study on the 16×16 box (2 spp levels, 2 seeds,
    median reference, two remedies): files, a verdict per parameter that `choose_backend` accepts,
    and the report's tables."""
    from nlosbench.studies import gradients as study
    from nlosbench.studies.context import RunContext

    model = nb.scenes.get("cornell_paper", defines={"res": 16})
    big = _paper_block(
        params=["red_color", "red_x"],
        reference=None,
        backends=[{"method": "fd", "step": 0.02}, {"method": "ad", "integrator": "prb_projective", "sppi": 0}],
        remedies={"names": ["median", "visibility-boost"], "k": 3, "boost": 4},
    )
    cfg = {"type": "gradients", **study.smoke(big)}
    ctx = RunContext(dir=tmp_path, config={}, model_spec={}, model=model, noises=[], seed=3, quiet=True)
    res = study.run(ctx, cfg)
    out = tmp_path / "grad"
    assert {"summary.csv", "seeds.csv", "verdicts.json", "gradient_grid.png"} <= {p.name for p in out.iterdir()}
    assert len(list((out / "images").glob("*.exr"))) == 2 * (1 + 2 * 2)
    rows = list(__import__("csv").DictReader(open(out / "summary.csv")))
    assert len(rows) == 2 * (2 * 2 + 2)  # per parameter: 2 backends × 2 spp + 2 remedies
    assert {r["remedy"] for r in rows} == {"", "median", "visibility-boost"}
    assert all(float(r["seconds"]) > 0 and float(r["time_ratio"]) > 0 for r in rows)
    assert {r["spp_trend"] for r in rows if not r["remedy"]} <= {"none", "fade", "steady", "grow"}
    verdicts = D.load_verdicts(out)
    assert set(verdicts) == set(res["verdicts"]) == {"red_color", "red_x"}
    assert all(v.status != "ad-clean" for v in verdicts.values())  # 2 seeds: too few to call AD clean
    assert D.choose_backend(model.restrict(["red_color", "red_x"]), out).method == "fd"
    md = study.report(out, res)
    assert "| red_x |" in md and "gradient_grid.png" in md and "time to target" in md and "× fwd memory" in md
