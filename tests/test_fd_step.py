"""Every printed limit is a limit: the FD step of the CRLB and of the HCR's Δ → 0 term is shown converged
(bounds.fd_step), open and unresolved ends are honest, a curve and a point give the same interval from the
same renders, and the Poisson ZZB stays a lower bound. Limits are checked against exact bounds of toys, never
against what the code itself computes."""
import math

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService, hcr_interval, pairwise_ustat, ziv_zakai, zzb_interval
from nlosbench.bounds.ustat import UStat, pixel_ustat
from nlosbench.bounds.zzb import bhattacharyya_ustat
from nlosbench.forward.analytic import AnalyticModel
from nlosbench.params import Param, ParamSpace

SIGMA = 0.05
EDGE_EXACT = SIGMA**2 / 64**2  # edge1d (64 px, amplitude 1): F = (64 / σ)² in one pixel, HCR = CRLB = σ²/64²


def _edge_lower_ends(theta: float, runs: int, **at) -> tuple[np.ndarray, np.ndarray]:
    """(HCR lower ends, CRLB lower ends) / the exact bound over `runs` runs (seeds 0 …) of the bound service on
    edge1d with synthetic rendering noise (0.3 at 16 spp: per-pixel SD ≈ 0.075·√L; common random numbers unless
    `at` says otherwise)."""
    m = nb.scenes.get("edge1d", render_noise=0.3)
    h, c = [], []
    for seed in range(runs):
        (pt,) = BoundService(RenderBank(m, seed=seed), [nb.noise.AWGN(SIGMA)]).at([[theta]], 16, test_grid=7,
                                                                                   offsets=2, **at)
        h.append(10 ** pt.bounds["hcr"].lower / EDGE_EXACT)
        c.append(10 ** pt.bounds["crlb"].lower / EDGE_EXACT)
    return np.array(h), np.array(c)


@pytest.mark.parametrize("theta, seeds", [(0.507, "common"), (0.5 + 5e-5, "common"), (0.501, "independent")],
                         ids=["mid-pixel", "1e-4-from-a-pixel-boundary", "independent-seeds-1mm-from-a-boundary"])
def test_lower_ends_cover_the_exact_edge_bound(theta, seeds):
    """edge1d, AWGN σ = 0.05, exact HCR = CRLB = σ²/64² = 6.10e-7. Over 200 seeds the one-sided 95 % lower
    ends of the HCR and the CRLB lie at or below it in ≥ 0.95 − 0.046 of runs (three binomial SDs at n = 200).
    Mid-pixel the edge crosses the next pixel inside θ ± 1 cm, so F at ξ = 1 cm is 0.64× the truth and the
    step must be halved; 5e-5 from a boundary every central difference wider than 1e-4 averages the two
    pixels' derivatives (F halved at every step), and only the one-sided differences see the truth. Without
    refinement (max_halvings 0, the old rule) the mid-pixel coverage is < 0.5: the test can fail. With independent
    seeds 1 mm from a boundary, θ* is rendered under each stencil's seed, so the one-sided differences exist there
    too (with the central difference alone the CRLB's lower end was 1.90× the exact bound in every run)."""
    hcr, crlb = _edge_lower_ends(theta, 200, seeds=seeds)
    tol = 3 * math.sqrt(0.95 * 0.05 / 200)
    assert np.mean(hcr <= 1) >= 0.95 - tol, np.mean(hcr <= 1)
    assert np.mean(crlb <= 1) >= 0.95 - tol, np.mean(crlb <= 1)
    if theta == 0.507:
        _, before = _edge_lower_ends(theta, 20, max_halvings=0)
        assert np.mean(before <= 1) < 0.5


def test_an_unconverged_step_labels_the_delta_to_zero_lower_ends_and_prints_the_rising_ratio():
    """edge1d without rendering noise at θ = 0.507 with one halving allowed: the central F(ξ/2)/F(ξ) = 1.57 (its
    window [0.497, 0.517] covers three pixels at ξ = 1 cm, one at 5 mm; exact, with 64 px per unit: the edge
    moves 0.192, 1 and 0.09 of pixels 31, 32, 33 over 2 cm, F ∝ 50² + 9.6² + 4.5² = 2613 → 64² = 4096). The
    CRLB's and the HCR's lower ends (set by Δ → 0) say they are not confidence limits, with the ratio > 1 (F
    rose), in the CSV columns too; the upper ends stay limits."""
    m = nb.scenes.get("edge1d")
    (pt,) = BoundService(RenderBank(m), [nb.noise.AWGN(SIGMA)]).at([[0.507]], 16, max_halvings=1)
    c, h = pt.bounds["crlb"], pt.bounds["hcr"]
    for b in (c, h):
        assert b.lower_note.startswith("not a confidence limit: FD step not converged (F ×1.57")
        assert "fd-step-not-converged" in b.flags and b.upper_note == ""
        cols = b.columns()
        assert cols[f"{b.kind}_lower_note"] == b.lower_note and cols[f"{b.kind}_upper_note"] == ""
    assert "F(ξ/2)/F(ξ) = 1.57" in c.reason and "try ξ = 0.0025" in c.reason  # what would settle it
    (ok,) = BoundService(RenderBank(m), [nb.noise.AWGN(SIGMA)]).at([[0.507]], 16)
    assert ok.bounds["crlb"].lower_note == "" and ok.bounds["crlb"].point == pytest.approx(math.log10(EDGE_EXACT))


class _Cusp(AnalyticModel):
    """One pixel L = 0.2 + √|θ − 0.5|: its derivative diverges at θ = 0.5."""

    def __init__(self):
        super().__init__("cusp", ParamSpace([Param("t", 0.0, 1.0, 0.5, "m", "cusp position")]))

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        return (0.2 + torch.sqrt(torch.abs(theta[0] - 0.5)))[None, None, None]


def test_a_diverging_derivative_gets_a_zero_lower_end_and_the_not_converged_label():
    """L ∝ √|θ − θ₀| at θ* = θ₀ + 1e-7: F rises at every halving (×2 one-sided, ×8 central), so the CRLB's
    lower end is 0 (log10 −inf), flagged as diverging and not converged, and the reason says why."""
    (pt,) = BoundService(RenderBank(_Cusp()), [nb.noise.AWGN(0.01)]).at([[0.5 + 1e-7]], 16, ("crlb",))
    c = pt.bounds["crlb"]
    assert c.lower == -math.inf and {"fd-step-diverging", "fd-step-not-converged"} <= set(c.flags)
    assert "not converged" in c.reason and "may diverge" in c.reason


def test_curve_and_at_give_the_same_interval_from_the_same_renders():
    """blob2d's x with synthetic rendering noise, 9 grid points spanning Θ, R = 3, common seeds, explicit FD
    step ξ checked against ξ/2: the curve and `at` (its test grid the same 9 points, no offsets, one halving)
    use the same renders and must give the same HCR and CRLB ends (the curve used to drop λ's Satterthwaite
    degrees of freedom: 5× wider)."""
    m = nb.scenes.get("blob2d", width=0.15, render_noise=0.3).restrict(["x"])
    T = np.linspace(m.params.lower[0], m.params.upper[0], 9)
    svc = BoundService(RenderBank(m, seed=3), [nb.noise.AWGN(0.3)])
    curve = svc.curve(T, 16, "common", 3, fd_step=0.01, zzb=False)
    for g in (2, 4, 5):
        (pt,) = svc.at([[T[g]]], 16, ("hcr", "crlb"), "common", 3, test_grid=9, offsets=0, fd_step=0.01,
                       max_halvings=1)
        for kind in ("hcr", "crlb"):
            a, b = curve.points[g].bounds[kind], pt.bounds[kind]
            assert (a.lower, a.point, a.upper) == pytest.approx((b.lower, b.point, b.upper), rel=1e-9, abs=1e-12)


def test_vector_hcr_delta_to_zero_term_is_the_crlb_trace():
    """blob2d (x, y) without rendering noise, AWGN σ = 0.05: the HCR's Δ → 0 term is trace F⁻¹ from the exact
    Jacobian (torch autograd; symmetric spot: twice 1/λ_min(F), the direction-wise limit it used to be), so the
    HCR at θ* is never below the CRLB."""
    m = nb.scenes.get("blob2d")
    t = torch.tensor([0.45, 0.5], dtype=torch.float64)
    J = torch.func.jacrev(m.clean)(t).reshape(-1, 2)
    F = (J.T @ J).numpy() / SIGMA**2
    (pt,) = BoundService(RenderBank(m), [nb.noise.AWGN(SIGMA)]).at([t.numpy()], 1, ("hcr", "crlb"), test_grid=5)
    h, c = pt.bounds["hcr"], pt.bounds["crlb"]
    exact = np.trace(np.linalg.inv(F))
    assert 10 ** h.point == pytest.approx(exact, rel=2e-3)
    assert h.terms.endswith("point: Δ → 0")
    # the FD-smoothed F at the finest step is still 0.3 % low here (smooth curvature): the central Richardson
    # extrapolation to ξ → 0 removes the ξ² error and leaves the ξ⁴ one, ~(0.3 %)² (measured 1.0e-5 above), so
    # both lower ends lie at the exact CRLB within 1e-4 — without it they would be 0.3 % above
    assert 10 ** c.lower <= exact * (1 + 1e-4) and 10 ** h.lower <= exact * (1 + 1e-4)
    assert 10 ** c.point > exact * (1 + 1e-3)  # the finest step's own F: the smoothing the extrapolation removes


def test_the_upper_end_is_open_whenever_a_tested_delta_is_unresolved():
    """A near-ambiguity: 5 tested Δ, one with true λ = 0.02 (a θ* + Δ that looks almost like θ*), the others
    resolved, and F known. The true HCR is set by the ambiguous Δ (Δ²/(e^0.02 − 1) ≈ 50 Δ²). Over 300 runs of
    R = 4 replicates the upper end is ≥ the true HCR in ≥ 0.95 − 0.038 (the old rule, dropping unresolved Δ,
    was below it in every run): it is open (+inf) wherever that Δ is unresolved."""
    g = np.random.default_rng(0)
    deltas = np.array([-0.2, -0.1, 0.1, 0.2, 0.3])
    lam_true = np.array([30.0, 8.0, 8.0, 30.0, 0.02])
    N, R = 200, 4
    d = np.sqrt(lam_true / N)[:, None] * np.ones(N)  # (K, N) per-pixel differences with Σ d² = λ (σ = 1)
    F = UStat(np.array([[900.0]]), np.array([[1e-9]]), np.full((R, 1, 1), 900.0), R, np.array([[1e6]]))
    true = max(np.max(deltas**2 / np.expm1(lam_true)), 1 / 900.0)
    above = []
    for _ in range(300):
        D = d[None] + 0.1 * g.normal(size=(R, len(deltas), N))
        iv = hcr_interval(pixel_ustat(D, 1.0), deltas, F)
        above.append(10**iv.upper >= true)
    assert np.mean(above) >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / 300)


def _rare_path_renders(L: np.ndarray, spp: int, reps: int, g) -> np.ndarray:
    """Monte Carlo renders of means L (G, N) where light arrives on rare paths: each sample finds a path of
    radiance 200 with probability L/200, else 0 (E X = L; at 16 spp almost every pixel is 0)."""
    return 200.0 * g.binomial(spp, L / 200.0, size=(reps,) + L.shape) / spp


def test_poisson_zzb_from_rare_path_renders_stays_below_the_exact_zzb():
    """A Poisson toy (G = 9 θ on [0, 1], 400 pixels, L = 0.3 + 0.5·θ·c_ω, 1 photon per unit radiance) rendered
    with rare paths at 16 spp, R = 4. The U-statistic on √X (the old estimator) is unbiased for
    Σ(E√X_j − E√X_i)², and rare paths make E√X ∝ L rather than √L: its distance is several times too small, so
    its ZZB point is ≈ 10× the exact ZZB and its "95 %" lower end lies above the exact ZZB in > 12 % of 100
    runs (measured 28 %). The upper-biased distance (weights 1/(√Y_i + √Y_j)² from an independent render, the
    zero-pixel bound X̄_i + X̄_j) keeps the lower end at or below the exact ZZB in ≥ 0.95 − 0.066 of runs, and
    its point at or below it in most."""
    g = np.random.default_rng(1)
    T = np.linspace(0.0, 1.0, 9)
    L = 0.3 + 0.5 * T[:, None] * g.uniform(0.0, 1.0, 400)[None]
    noise = nb.noise.Poisson(scale=1.0)
    exact = ziv_zakai(torch.from_numpy(L), T, noise).log10
    new, old = [], []
    for _ in range(100):
        X = _rare_path_renders(L, 16, 4, g)
        Y = _rare_path_renders(L, 16, 1, g)[0]
        new.append(zzb_interval(bhattacharyya_ustat(X, Y, noise.scale), T, "bhattacharyya"))
        old.append(zzb_interval(pairwise_ustat(np.sqrt(X), 0.5 * noise.scale), T, "bhattacharyya"))
    assert np.mean([z.lower <= exact for z in new]) >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / 100)
    assert np.mean([z.point <= exact for z in new]) > 0.5
    assert np.mean([z.lower > exact for z in old]) > 0.12 and np.median([z.point for z in old]) > exact + 0.5


def test_an_unresolved_halving_is_named_unresolved_not_a_nan_ratio():
    """Where F̂ ≤ 0 at a step (rendering noise above the signal) the halving has no ratio: the lower end's note
    says "F unresolved", never "F ×nan ± nan" (as a 512-spp NLOS table printed it)."""
    from nlosbench.bounds.fd_step import Halving, StepFisher, crlb_term

    F = UStat(np.array([[4.0]]), np.array([[1.0]]), np.empty((0, 1, 1)), 4, np.array([[30.0]]))
    noisy = UStat(np.array([[-1.0]]), np.array([[3.0]]), np.empty((0, 1, 1)), 4, np.array([[30.0]]))
    sf = StepFisher([{"central": F}, {"central": noisy}], [0.02, 0.01],
                    [Halving(0.02, math.nan, math.nan, False, False)])
    note = crlb_term(sf, 0.95).lower_note
    assert "F unresolved from ξ = 0.02" in note and "nan" not in note, note


def test_a_stage_shown_biased_low_does_not_hold_the_upper_end():
    """Three FD stages of a scalar F with SE 0.01 (df 30): 1.0 at ξ, 2.0 at ξ/2, 2.02 at ξ/4. The first halving
    is shown to rise (F ×2: ξ's F is biased low by the FD smoothing), so the CRLB's upper end is 1/(the
    smallest lower limit of F over ξ/2 and ξ/4) ≈ 0.5, not 1/(1.0 − t·0.01) ≈ 1.02, which no number of
    replicates could lower. Without a rise (1.0, 1.02, 1.0) every stage counts."""
    from nlosbench.bounds.fd_step import StepFisher, crlb_term, settled_from

    def sf(values, halvings):
        stats = [{"central": UStat(np.array([[v]]), np.array([[0.01]]), np.empty((0, 1, 1)), 8, np.array([[30.0]]))}
                 for v in values]
        return StepFisher(stats, [0.04, 0.02, 0.01][:len(values)], halvings)

    from nlosbench.bounds.fd_step import Halving
    rose = sf([1.0, 2.0, 2.02], [Halving(0.04, 2.0, 0.01, False, True), Halving(0.02, 1.01, 0.01, True, False)])
    assert settled_from(rose) == 1
    upper = 10 ** crlb_term(rose, 0.95).upper
    t = float(nb.bounds.ustat.t_quantile(0.95, 30.0))
    assert upper == pytest.approx(1 / (2.0 - t * 0.01), rel=1e-12)
    flat = sf([1.0, 1.02, 1.0], [Halving(0.04, 1.02, 0.01, False, False), Halving(0.02, 0.98, 0.01, True, False)])
    assert settled_from(flat) == 0
    assert 10 ** crlb_term(flat, 0.95).upper == pytest.approx(1 / (1.0 - t * 0.01), rel=1e-12)


def test_a_first_step_per_theta_gives_what_each_theta_gets_alone():
    """`at` with one first FD step per θ* (edge1d, rendering noise 0.3, common seeds, seed 3): θ* = 0.507 from
    ξ = 8 mm and θ* = 0.3 from ξ = 32 mm, in one call, give bit for bit the bounds and the FD stages (their steps
    included) of two calls with one θ* and one step each; the stages start at each θ*'s own step. A step per θ* of
    the wrong length, or one not positive, is refused before any render. Measured ratios in the reasons: 0.507 F ×1.13
    from 8 to 4 mm, then settled; 0.3 F rising ×1.87, ×1.41, ×1.4, ×1.24 down to 2 mm."""
    kw = dict(test_grid=7, offsets=2, max_halvings=4)

    def service(seed=3):
        bank = RenderBank(nb.scenes.get("edge1d", render_noise=0.3), seed=seed)
        return BoundService(bank, [nb.noise.AWGN(SIGMA)]), bank

    both = service()[0].at([[0.507], [0.3]], 16, fd_step=[0.008, 0.032], **kw)
    for pt, (theta, xi) in zip(both, [(0.507, 0.008), (0.3, 0.032)], strict=True):
        (alone,) = service()[0].at([[theta]], 16, fd_step=xi, **kw)
        for kind in ("hcr", "crlb"):
            a, b = alone.bounds[kind], pt.bounds[kind]
            assert (a.lower, a.point, a.upper, a.reason) == (b.lower, b.point, b.upper, b.reason), kind
    # the stages start at each θ*'s step: 0.507 checks 8 → 4 mm first; 0.3 (F rising at every halving) stops after
    # 4 halvings of 32 mm, at 2 mm, and names the next, 1 mm (from 8 mm it would be 0.25 mm)
    assert "= 1.13 ± 0.0017 at ξ = 0.008;" in both[0].bounds["crlb"].reason
    assert "try ξ = 0.001 (one more halving)" in both[1].bounds["crlb"].reason
    for bad, match in (([0.008, 0.016, 0.032], "one step or one per θ"), ([0.008, -0.01], "positive number")):
        svc, bank = service()
        with pytest.raises(ValueError, match=match):
            svc.at([[0.507], [0.3]], 16, fd_step=bad, **kw)
        assert bank.renders == 0


def test_a_step_tolerance_per_theta_gives_what_each_theta_gets_alone():
    """`at` with one step tolerance per θ* (edge1d, rendering noise 0.3, common seeds, seed 3, first steps 8 and 32
    mm): tolerances [0.1, 0.5] for θ* = 0.507 and 0.3 in one call give bit for bit the bounds of two calls with one
    θ* and its tolerance each, and each check stops where its own tolerance says: 0.507 (F ×1.13 from 8 to 4 mm)
    halves once more at 0.1, to 2 mm; 0.3 (F ×1.87, then ×1.41 ± 0.027) is shown ≤ 1.5 at its second halving, where
    at 0.1 it rises at every halving (lower end 0). Tolerances of the wrong length or not positive are refused before
    any render."""
    kw = dict(test_grid=7, offsets=2, max_halvings=4)

    def service(seed=3):
        bank = RenderBank(nb.scenes.get("edge1d", render_noise=0.3), seed=seed)
        return BoundService(bank, [nb.noise.AWGN(SIGMA)]), bank

    both = service()[0].at([[0.507], [0.3]], 16, fd_step=[0.008, 0.032], step_tol=[0.1, 0.5], **kw)
    for pt, (theta, xi, tol) in zip(both, [(0.507, 0.008, 0.1), (0.3, 0.032, 0.5)], strict=True):
        (alone,) = service()[0].at([[theta]], 16, fd_step=xi, step_tol=tol, **kw)
        for kind in ("hcr", "crlb"):
            a, b = alone.bounds[kind], pt.bounds[kind]
            assert (a.lower, a.point, a.upper, a.reason) == (b.lower, b.point, b.upper, b.reason), kind
    assert "= 1.13 ± 0.0017 at ξ = 0.008; F(ξ/2)/F(ξ) = 0.999" in both[0].bounds["crlb"].reason
    assert both[1].bounds["crlb"].reason.endswith("FD step converged: F(ξ/2)/F(ξ) = 1.87 ± 0.075 at ξ = 0.032; "
                                                  "F(ξ/2)/F(ξ) = 1.41 ± 0.027 at ξ = 0.016")
    (strict,) = service()[0].at([[0.3]], 16, fd_step=0.032, step_tol=0.1, **kw)
    assert strict.bounds["crlb"].lower == -math.inf and "may diverge" in strict.bounds["crlb"].reason
    for bad, match in (([0.1, 0.2, 0.3], "one tolerance or one per θ"), ([0.1, 0.0], "step_tol must be a positive")):
        svc, bank = service()
        with pytest.raises(ValueError, match=match):
            svc.at([[0.507], [0.3]], 16, fd_step=[0.008, 0.032], step_tol=bad, **kw)
        assert bank.renders == 0
    svc, bank = service()  # `fisher` and a curve's own check take one tolerance (`curve`'s quoted bounds one each)
    for call in (lambda: svc.fisher([[0.5]], 16, fd_step=0.01, step_tol=[0.1]),
                 lambda: svc.curve([0.2, 0.5, 0.8], 16, step_tol=[0.1, 0.1, 0.1])):
        with pytest.raises(ValueError, match=r"step_tol must be a positive number \(e.g. 0.1: F within 10 %\), got"):
            call()
    assert bank.renders == 0


class _Exit(AnalyticModel):
    """Two pixels: 0.2 + 40·max(0.5 − θ, 0)² (an object that leaves the view at θ₀ = 0.5: no derivative beyond)
    and 0.3 + 0.5·θ (light that stays). Beyond θ₀ the exact F is 0.5²/σ²; a central FD stencil reaching back
    past θ₀ sees the first pixel change, so F at a step wider than θ* − θ₀ is biased high and falls as ξ halves."""

    def __init__(self, render_noise: float = 0.01):
        super().__init__("exit", ParamSpace([Param("t", 0.0, 1.0, 0.5, "m", "exit position")]),
                         render_noise=render_noise)

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        t = theta[0]
        return torch.stack([0.2 + 40 * torch.clamp(0.5 - t, min=0.0) ** 2, 0.3 + 0.5 * t])[None, :, None]


def test_a_step_that_reaches_where_the_object_was_visible_is_halved_until_f_stops_falling():
    """_Exit at θ* = 0.505, ξ = 4 cm, AWGN σ = 0.05, 3 sets with common seeds (exact CRLB σ²/0.25 = 0.01): the
    central F is 0.625, 0.30, 0.2525 and 0.25 (/σ²) at ξ = 4, 2, 1, 0.5 cm: it falls ×0.48 and ×0.84 before it
    settles. The rule before stopped at the first halving (F not shown to rise), and the 4 cm stage, biased high,
    held the CRLB's lower end at 0.55 × the exact bound at any number of sets (measured over these 20 seeds: 0.548 –
    0.553). Now the step halves on while F is shown to fall and stages shown biased high set no lower end: over 20
    seeds both ends are unlabelled one-sided limits (at most 3 misses each) within 5 % of the exact bound (measured:
    lower 0.952 – 0.964, upper 0.998 – 1.010). Where the halvings run out while F still falls (max_halvings = 1) the
    upper ends of the CRLB and of the HCR are labelled "not a confidence limit: F still falls" (the forward difference
    happens to cover it here; with independent seeds there is none), the lower ends stay limits."""
    exact = SIGMA**2 / 0.25
    ends = []
    for seed in range(20):
        (pt,) = BoundService(RenderBank(_Exit(), seed=seed), [nb.noise.AWGN(SIGMA)]).at(
            [[0.505]], 16, test_grid=5, offsets=1, fd_step=0.04, max_halvings=4)
        c = pt.bounds["crlb"]
        assert not c.lower_note and not c.upper_note, c.reason
        assert c.reason.count("F(ξ/2)/F(ξ)") == 3, c.reason  # 4 → 2 → 1 → 0.5 cm
        ends.append((10 ** c.lower / exact, 10 ** c.upper / exact))
    lo, up = np.array(ends).T
    # each end a one-sided 95 % limit: at most 3 misses of 20 (P ≈ 0.016 at a 5 % miss rate)
    assert (lo > 1).sum() <= 3 and (up < 1).sum() <= 3, ends
    assert lo.min() > 1 / 1.05 and up.max() < 1.05, ends
    (pt,) = BoundService(RenderBank(_Exit(), seed=0), [nb.noise.AWGN(SIGMA)]).at(
        [[0.505]], 16, test_grid=5, offsets=1, fd_step=0.04, max_halvings=1)
    for kind in ("crlb", "hcr"):
        b = pt.bounds[kind]
        assert b.upper_note.startswith("not a confidence limit: F still falls (F ×0.48"), (kind, b.upper_note)
        assert not b.lower_note and 10 ** b.lower <= exact


def test_the_step_is_not_halved_past_a_check_no_finer_step_resolves(cornell):
    """cornell_ball's ball_x at 0.1 (AWGN σ = 0.1, 3 rounds, ξ = 4 cm, up to 4 halvings). At 2 spp the first check's
    SE is above HOPELESS_SE (F ×1.54 ± 0.74): the service stops there (15 renders, not 33), and its note asks for more
    spp; the halvings it did not make, rendered here on the same seeds, are no better resolved (every SE above
    HOPELESS_SE: this renderer's FD noise does not shrink with the step). At 64 spp the same call halves 4 times."""
    from nlosbench.bounds.fd_step import HOPELESS_SE, halving

    model = cornell.restrict(["ball_x"])
    reasons = {}
    for spp in (2, 64):
        bank = RenderBank(model, seed=3)
        svc = BoundService(bank, [nb.noise.AWGN(0.1)])
        (pt,) = svc.at([[0.1]], spp, ("crlb",), test_grid=3, offsets=0, fd_step=0.04, max_halvings=4)
        reasons[spp] = (bank.renders, pt.bounds["crlb"].reason)
    renders, reason = reasons[2]
    assert renders == 15 and reason.count("F(ξ/2)/F(ξ) =") == 1 and reason.endswith("more spp per round)"), reason
    stages = [svc._stages(np.array([[0.1]]), None, 2, "common", 3, xi)[0] for xi in (0.02, 0.01, 0.005, 0.0025)]
    ses = [halving(a, b, 100.0, 0.95, 0.1).se for a, b in zip(stages, stages[1:], strict=False)]
    assert min(ses) > HOPELESS_SE, ses
    assert reasons[64][0] == 33 and reasons[64][1].count("F(ξ/2)/F(ξ) =") == 4, reasons[64]


class _Brightening(AnalyticModel):
    """A smooth spot on a 64-pixel strip over [0, 1] m whose brightness grows along its track:
    L_i = 0.2 + exp(k(θ − 0.5))·exp(−(x_i − θ)²/(2w²)), k = 10 /m, w = 6 cm. No kink anywhere, and F(θ) grows
    ≈ e^{2kθ}: a one-sided difference at step ξ is biased by ≈ ±(ξ/2)·F'/F (±10 % at 1 cm, ±20 % at 2 cm)."""

    def __init__(self):
        super().__init__("brightening", ParamSpace([Param("t", 0.2, 0.8, 0.5, "m", "spot position")]),
                         render_noise=0.3)
        self._x = (torch.arange(64, dtype=torch.float64) + 0.5) / 64

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        t = theta[0]
        return (0.2 + torch.exp(10 * (t - 0.5)) * torch.exp(-(self._x - t) ** 2 / (2 * 0.06**2)))[None, :, None]

    def exact_crlb(self) -> float:
        """σ²/Σ(∂L/∂θ)² at θ = 0.5 for AWGN σ = SIGMA (autograd of the clean image), m²."""
        J = torch.autograd.functional.jacobian(self.clean, torch.tensor([0.5], dtype=torch.float64)).reshape(-1)
        return SIGMA**2 / float((J**2).sum())


def test_a_smooth_slope_does_not_widen_the_ends_by_a_coarse_one_sided_difference():
    """_Brightening at θ* = 0.5, AWGN σ = 0.05, 8 sets with common seeds, ξ = 2 cm halved once. The exact CRLB is
    σ²/Σ(∂L/∂θ)² (autograd of the clean image). A one-sided difference guards a kink on θ*'s side, and the finest
    stage's does that at least as well as a coarser one (on θ*'s side it is exact at every step; on the other side
    the finer one reaches less far), while on a smooth slope the coarse one is biased twice as much (±20 % here
    against ±10 %). The ends use the finest stage's one-sided differences only: over 20 seeds each end is a one-sided
    95 % limit (at most 3 misses of 20; measured: none) and the interval's relative half-width stays below the coarse
    stage's bias (median < 16 %; measured 12.9 %, where the 2 cm one-sided differences among the candidates made it
    24.4 %, ≥ 23.6 % in every seed)."""
    m = _Brightening()
    exact = m.exact_crlb()
    ends = []
    for seed in range(20):
        (pt,) = BoundService(RenderBank(m, seed=seed), [nb.noise.AWGN(SIGMA)]).at(
            [[0.5]], 16, ("crlb",), replicates=8, fd_step=0.02, max_halvings=1)
        c = pt.bounds["crlb"]
        assert not c.lower_note and not c.upper_note, c.reason
        ends.append((10 ** c.lower / exact, 10 ** c.point / exact, 10 ** c.upper / exact))
    lo, point, up = np.array(ends).T
    assert (lo > 1).sum() <= 3 and (up < 1).sum() <= 3, ends  # P ≈ 0.016 each at a 5 % miss rate
    assert np.median(np.maximum(point / lo, up / point)) < 1.16, ends


def test_a_target_that_the_one_sided_bias_keeps_out_of_reach_names_a_finer_step():
    """_Brightening at θ* = 0.5, AWGN σ = 0.05, 8 sets, a ±10 % target. From ξ = 2 cm halved once, the finest
    stage (1 cm) has one-sided differences biased by ≈ ±(ξ/2)·F′/F = ±10 % (F ∝ e^{2kθ}, k = 10 /m), which the ends
    take: no number of sets is predicted to meet the target, and the note says that the step's bias, not noise,
    sets the width, with its size (8–14 %), and that a finer step narrows it. From ξ = 4 mm (bias ±2 % at the
    finest stage) the same target is met by the pilot, and no such note is made. Where up to 3 halvings are allowed
    but the budget leaves no fresh look, the plan (4 sets at a finer step) is finite and the note names the bias all
    the same."""
    import re

    def quote(step: float, halvings: int = 1, budget: int = 2_000_000):
        (pt,) = BoundService(RenderBank(_Brightening(), seed=0), [nb.noise.AWGN(SIGMA)]).at(
            [[0.5]], 16, ("crlb",), replicates=8, fd_step=step, max_halvings=halvings, precision=0.1, budget=budget)
        return pt.precision

    coarse, fine, poor = quote(0.02), quote(0.004), quote(0.02, 3, 1)
    assert not coarse.met and coarse.extra_sets == float("inf"), coarse
    assert not poor.met and math.isfinite(poor.extra_sets), poor
    for p in (coarse, poor):
        gap = re.search(r"one-sided F lie up to ±([\d.]+) % from the central one, beyond their noise", p.note)
        assert gap and 8 <= float(gap.group(1)) <= 14 and "a finer step narrows them" in p.note, p.note
    assert fine.met and "finer step" not in fine.note, fine


def test_a_look_halves_past_the_pilots_finest_step_where_the_one_sided_bias_sets_the_width():
    """_Brightening at θ* = 0.5, AWGN σ = 0.05, 8 sets, a ±10 % target, ξ = 2 cm with up to 3 halvings: the pilot's
    check passes at 1 cm, where the one-sided differences are biased ≈ ±10 % (the test above: out of reach at the
    pilot's steps; there the look was exploratory, 32 sets at 2 → 1 cm, and ended at ±11–12 %, unmet in 3 of 3 seeds).
    The plan now offers windows past the pilot's finest step and predicts their one-sided bias halved per halving:
    over 20 seeds every look renders a finer finest step (5 or 2.5 mm) and meets the target (measured: 20 of 20 at
    4 sets, ±4.7–8.9 %: this toy's rendering noise is smooth in θ and cancels between θ ± ξ, so F's noise does not
    grow as the step shrinks, which the plan reads from the pilot's own halving), and each end is a one-sided 95 %
    limit of the exact CRLB σ²/Σ(∂L/∂θ)² (at most 3 misses of 20 per side; measured: none)."""
    m = _Brightening()
    exact = m.exact_crlb()
    met, ends = 0, []
    for seed in range(20):
        (pt,) = BoundService(RenderBank(m, seed=seed), [nb.noise.AWGN(SIGMA)]).at(
            [[0.5]], 16, ("crlb",), replicates=8, fd_step=0.02, max_halvings=3, precision=0.1, budget=2_000_000)
        c = pt.bounds["crlb"]
        last = float(c.reason.rsplit("at ξ = ", 1)[1])  # the last halving's coarser step: the finest is half of it
        assert pt.precision.fresh_sets > 0 and last <= 0.01 and not c.lower_note and not c.upper_note, c.reason
        met += pt.precision.met
        ends.append((10 ** c.lower / exact, 10 ** c.upper / exact))
    lo, up = np.array(ends).T
    assert met >= 18, ends
    assert (lo > 1).sum() <= 3 and (up < 1).sum() <= 3, ends  # P ≈ 0.016 each at a 5 % miss rate


def test_a_second_look_is_planned_from_the_first_and_takes_the_finer_step_it_showed_was_needed():
    """_Brightening with rendering noise 2 (F's one-sided bias ≈ ±10 % at 1 cm hidden in a 4-set pilot's noise),
    AWGN σ = 0.05, ±10 %, three looks: the pilot plans a look at its own steps (2 → 1 cm), which shows the bias; the
    second look is planned from the first look's data alone, past the pilot's finest step. Over 12 seeds, 6 looks
    met the target at the second look (measured: 6, each with a finest step of 2.5 mm; a second look at the first
    one's steps, as before, can meet it in none: the bias alone is ±10 %); the others' first looks did not show the
    bias either. Each end is a one-sided 95 % limit of the exact CRLB (at most 3 misses of 12 per side; measured:
    none)."""
    m = _Brightening()
    m.render_noise = 2.0
    exact = m.exact_crlb()
    finer, ends = 0, []
    for seed in range(12):
        (pt,) = BoundService(RenderBank(m, seed=seed), [nb.noise.AWGN(SIGMA)]).at(
            [[0.5]], 16, ("crlb",), replicates=4, fd_step=0.02, max_halvings=3, precision=0.1, budget=20_000_000,
            looks=3)
        c, p = pt.bounds["crlb"], pt.precision
        finer += p.met and p.looks == 3 and float(c.reason.rsplit("at ξ = ", 1)[1]) < 0.01
        ends.append((10 ** c.lower / exact, 10 ** c.upper / exact))
    lo, up = np.array(ends).T
    assert finer >= 4, ends
    assert (lo > 1).sum() <= 3 and (up < 1).sum() <= 3, ends  # P ≈ 0.02 each at a 5 % miss rate


def test_a_check_that_passes_while_its_estimate_says_f_falls_halves_on():
    """_Exit with rendering noise 1.5 at θ* = 0.505, ξ = 2 cm, AWGN σ = 0.05, 3 sets: F falls ×0.84 from 2 to 1 cm
    (exact), which these 3 sets do not show (seeds 0 and 2: ×0.81 ± 0.06, ×0.80 ± 0.08; upper limits above 1/1.1).
    The check passes, but a look with more sets would show the fall, and then no look at those two steps could quote
    an upper end: the step halves on (the rule before stopped at 1 cm), and the next check, ×0.99, stops it. Where
    the estimate is above 1/1.1 (seed 5: ×0.915 ± 0.016) it stops at the first check, as before."""
    for seed, halvings in ((0, 2), (2, 2), (5, 1)):
        (pt,) = BoundService(RenderBank(_Exit(render_noise=1.5), seed=seed), [nb.noise.AWGN(SIGMA)]).at(
            [[0.505]], 16, ("crlb",), fd_step=0.02, max_halvings=3)
        c = pt.bounds["crlb"]
        assert c.reason.count("F(ξ/2)/F(ξ)") == halvings, (seed, c.reason)
        assert "FD step converged" in c.reason and not c.lower_note and not c.upper_note, (seed, c.reason)


class _MixedKinks(AnalyticModel):
    """Two pixels with kinks 1e-4 either side of θ* = 0.5: L₁ = min(θ, 0.5 + 1e-4) (slope 1 up to its kink, just
    beyond θ*) and L₂ = max(θ, 0.5 − 1e-4) (slope 1 from its kink, just before θ*). At θ* both slopes are 1: exact
    F = 2/σ²."""

    def __init__(self):
        super().__init__("mixed-kinks", ParamSpace([Param("t", 0.0, 1.0, 0.5, "m", "position")]))

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        t = theta[0]
        return torch.stack([torch.clamp(t, max=0.5 + 1e-4), torch.clamp(t, min=0.5 - 1e-4)])[None, :, None]


@pytest.mark.xfail(strict=True, reason="known gap: the one-sided variants guard kinks on one side of θ* only")
def test_kinks_on_both_sides_of_theta_in_different_pixels_are_bracketed():
    """_MixedKinks, AWGN σ = 0.05, 4 sets, ξ = 2 cm halved up to 3 times (every step ≫ the kinks' 1e-4): the central
    F is (½² + ½²)/σ² at every step (the check passes at ×1.0), and the whole-image forward and backward F are 1/σ²
    each (one pixel's slope 1, the other's ≈ 0), so the largest candidate is half the exact F and the CRLB's lower
    end is 2.0 × the exact bound σ²/2, unlabelled (measured: 2.0). The truth per pixel lies between its forward and
    backward derivative, but on different sides in different pixels, which no whole-image variant sees. A bound that
    holds for every pattern is (√F_c + √Q/2)², Q = 2(F_fwd + F_bwd) − 4F_c the information of J_fwd − J_bwd
    (Cauchy–Schwarz), but its limits take a square root of Q's noise. With a box pixel filter only an edge parallel
    to a pixel side makes a kink."""
    (pt,) = BoundService(RenderBank(_MixedKinks()), [nb.noise.AWGN(SIGMA)]).at(
        [[0.5]], 16, ("crlb",), replicates=4, fd_step=0.02, max_halvings=3)
    c = pt.bounds["crlb"]
    assert not c.lower_note, c.reason
    assert 10 ** c.lower <= SIGMA**2 / 2 * (1 + 1e-6), (10 ** c.lower, SIGMA**2 / 2)
