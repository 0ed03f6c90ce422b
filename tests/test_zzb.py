"""The Ziv–Zakai bound (nlosbench.bounds.zzb) against closed forms and an exact MMSE by quadrature, its
valley filling, its interval from replicated renders, and the Bayesian MSE of a real MLE against it."""
import math

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.bounds.ustat import pairwise_ustat
from nlosbench.bounds.zzb import a_of_h, integrate, pe_from_bhattacharyya, pe_from_lambda, zzb_from_errors, zzb_interval

T_GRID = np.linspace(0.0, 1.0, 201)  # a uniform prior on [0, 1]: T²/12 = 0.0833


def _linear_gaussian_errors(snr: float, t=T_GRID) -> np.ndarray:
    """y = θ·√snr + N(0, 1): λ(θ_i, θ_j) = snr (θ_i − θ_j)²; the CRLB is 1/snr."""
    return pe_from_lambda(snr * (t[:, None] - t[None, :]) ** 2)


def _exact_mmse(snr: float) -> float:
    """The MMSE of θ ~ U[0, 1] from y = θ + N(0, 1/snr), by quadrature over θ (2001 points) and y (4001)."""
    s = 1 / math.sqrt(snr)
    th = np.linspace(0.0, 1.0, 2001)
    ys = np.linspace(-6 * s, 1 + 6 * s, 4001)
    like = np.exp(-((ys[:, None] - th[None, :]) ** 2) / (2 * s * s))
    post = like / like.sum(axis=1, keepdims=True)
    mean = post @ th
    var = post @ th**2 - mean**2
    py = like.mean(axis=1)
    return float((py * var).sum() / py.sum())


@pytest.mark.parametrize("snr", [10.0, 100.0, 1e3, 1e4])
def test_linear_gaussian_zzb_is_below_the_exact_mmse_and_close_to_it(snr):
    """A valid bound: ZZB ≤ MMSE (quadrature) at every SNR; and not loose: ≥ 0.75 × MMSE (measured
    0.84, 0.94, 0.93, 0.82 at SNR 10 … 10⁴ on this 201-point grid)."""
    z = zzb_from_errors(_linear_gaussian_errors(snr), T_GRID).value
    mmse = _exact_mmse(snr)
    assert z <= mmse and z >= 0.75 * mmse, (z, mmse)


def test_limits_prior_variance_at_low_snr_and_crlb_at_high_snr():
    """SNR → 0: the ZZB tends to the prior variance T²/12 from below (a 401-point grid: within 2 %; the
    lower sum loses ≈ 0.4 % at this spacing and SNR 10⁻³ still carries a little information); high SNR
    (error scale 0.01): the ZZB approaches the CRLB 1/snr from below as the grid refines (measured 0.885,
    0.931, 0.954 × CRLB at 401, 801, 1601 points); on 1601 points within [0.9, 1.0] × CRLB, and halving
    the spacing moves it by < 3 % (the reported `halved`)."""
    t = np.linspace(0, 1, 401)
    low = zzb_from_errors(_linear_gaussian_errors(1e-3, t), t)
    assert 0.98 / 12 < low.value < 1 / 12 and low.prior_variance == pytest.approx(1 / 12, rel=1e-3)
    t = np.linspace(0, 1, 1601)
    high = zzb_from_errors(_linear_gaussian_errors(1e4, t), t)
    assert 0.9 <= high.value * 1e4 <= 1.0 and abs(high.halved) < math.log10(1.03)


def test_valley_filling_on_a_periodic_toy():
    """L(θ) = cos(2π·4θ): images repeat every quarter of Θ, so P_e(h) (and A(h)) rises again near
    h = 1/4, 1/2, 3/4. Valley filling makes A non-increasing and ≥ A; the filled bound is larger than
    one without filling and never above the prior variance."""
    t = np.linspace(0, 1, 161)
    L = np.stack([np.cos(2 * np.pi * 4 * t), np.sin(2 * np.pi * 4 * t)], axis=1) * 6.0
    lam = ((L[:, None] - L[None]) ** 2).sum(-1)
    Pe = pe_from_lambda(lam)
    A = a_of_h(Pe, t)
    V = np.maximum.accumulate(A[::-1])[::-1]
    assert np.all(np.diff(V) <= 1e-15) and np.all(V >= A)
    k = round(0.25 / (t[1] - t[0]))
    assert A[k] > 3 * A[k // 2]  # the revival at one period
    delta = t[1] - t[0]
    unfilled = 0.5 * float(((np.arange(len(A))[:-1] * delta + delta / 2) * A[1:]).sum() * delta)
    filled = integrate(A, delta)
    assert unfilled < filled <= 1 / 12


def test_poisson_error_from_bhattacharyya_is_a_lower_bound_on_the_exact_error():
    """Two Poisson pixels (means 2 vs 5 photons): the exact equal-prior error ½ Σ_k min(p0, p1) is above
    ½(1 − √(1 − ρ²)) with ρ the Bhattacharyya coefficient."""
    from scipy.stats import poisson

    k = np.arange(200)
    mu0, mu1 = np.array([2.0, 0.5]), np.array([5.0, 0.8])
    p0 = np.outer(poisson.pmf(k, mu0[0]), poisson.pmf(k, mu0[1]))
    p1 = np.outer(poisson.pmf(k, mu1[0]), poisson.pmf(k, mu1[1]))
    exact = 0.5 * np.minimum(p0, p1).sum()
    b = 0.5 * ((np.sqrt(mu1) - np.sqrt(mu0)) ** 2).sum()
    assert pe_from_bhattacharyya(b) <= exact <= 0.5
    assert pe_from_bhattacharyya(b) > 0.5 * exact  # and not vacuous here


def test_a_non_uniform_grid_is_refused():
    with pytest.raises(ValueError, match="uniform θ grid"):
        zzb_from_errors(np.full((3, 3), 0.5), [0.0, 0.1, 0.5])


def test_interval_from_replicates_covers_the_exact_zzb():
    """120 runs of R = 5 replicates of a smooth 1-D toy (40 pixels, synthetic rendering noise 0.15 per
    pixel, independent across replicates): the interval's lower end is below the exact ZZB in ≥ 90 %
    of runs (stated level 95 %) and the upper end above it in
    ≥ 90 %; the point estimate is within 10 % of it on average."""
    t = np.linspace(0, 1, 41)
    x = np.linspace(0, 1, 40)
    L = 3.0 * np.exp(-((x[None] - t[:, None]) ** 2) / 0.02)  # (G, N), AWGN σ = 1
    exact = integrate(a_of_h(pe_from_lambda(((L[:, None] - L[None]) ** 2).sum(-1)), t), t[1] - t[0])
    g = np.random.default_rng(5)
    low, high, points = [], [], []
    for _ in range(120):
        X = L[None] + 0.15 * g.normal(size=(5,) + L.shape)
        z = zzb_interval(pairwise_ustat(X, 1.0), t, "lambda")
        low.append(10**z.lower <= exact)
        high.append(10**z.upper >= exact)
        points.append(10**z.point / exact)
    assert np.mean(low) >= 0.9 and np.mean(high) >= 0.9, (np.mean(low), np.mean(high))
    assert abs(np.mean(points) - 1) < 0.1


def test_bayesian_mse_of_the_mle_is_above_the_zzb():
    """The Bayesian protocol on an exact toy (blob2d's x, y fixed, AWGN σ = 0.3: an ambiguous spot):
    240 trials, θ* ~ U[0.2, 0.8], a grid-search MLE from a uniform start; its Bayesian MSE + 2 SE is
    above the ZZB computed from the same grid renders (a bound for every estimator)."""
    from nlosbench.executors import SerialExecutor
    from nlosbench.montecarlo import Setting, make_bayes_trials, run_trials, summarize_bayes

    model = nb.scenes.get("blob2d", width=0.1).restrict(["x"])
    noise = nb.noise.AWGN(0.3)
    grid = np.linspace(0.2, 0.8, 121)
    renders = torch.stack([model.render([v], 1, 0) for v in grid])
    z = nb.bounds.ziv_zakai(renders, grid, noise)
    rng = np.random.default_rng(8)
    thetas = rng.uniform(0.2, 0.8, size=(240, 1))
    cleans = [model.render(t, 1, 0) for t in thetas]
    trials = make_bayes_trials(thetas, [Setting("grid-search", {"num": 121, "spp": 1, "refine_evals": 30})],
                               {0: noise}, cleans, seed=3)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        records = run_trials(SerialExecutor(model), trials, Path(d) / "t.jsonl")
    (row,) = summarize_bayes(records, {0: {"log10": z.log10}})
    assert row["n"] == 240 and row["n_failed"] == 0
    assert row["bayes_mse"] + 2 * row["bayes_mse_se"] >= z.value, (row["bayes_mse"], z.value)
    assert row["vs_zzb"] != "below"
    assert z.value < z.prior_variance  # the data say something: not the vacuous bound


def test_an_upper_end_never_passes_the_no_information_value():
    """Rendering noise far above the signal (a toy 3-point grid, 3 replicates, noise 30× the signal): the jackknife's
    upper end would run off to metres², but the ZZB's lower sum can never exceed its value at P_e = ½ (no
    information), which on a uniform prior is T²/12 less the sum's grid error; the upper end stops there, and the
    exact ZZB (P_e from the noise-free λ) lies below it."""
    t = np.linspace(0, 1, 3)
    x = np.linspace(0, 1, 40)
    L = 0.1 * np.exp(-((x[None] - t[:, None]) ** 2) / 0.02)
    cap = integrate(a_of_h(np.full((3, 3), 0.5), t), 0.5)
    assert 0 < cap <= 1 / 12
    exact = integrate(a_of_h(pe_from_lambda(((L[:, None] - L[None]) ** 2).sum(-1)), t), 0.5)
    g = np.random.default_rng(0)
    uppers = [zzb_interval(pairwise_ustat(L[None] + 3.0 * g.normal(size=(3,) + L.shape), 1.0), t, "lambda").upper
              for _ in range(50)]
    assert max(uppers) <= math.log10(cap) + 1e-12 and exact <= cap
    assert sum(u == pytest.approx(math.log10(cap)) for u in uppers) >= 10  # the cap is reached, not just respected
