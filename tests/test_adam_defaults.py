"""mle-adam with its defaults (lr "auto", spp AUTO_SPP, no iterations given) against gauss-newton on the same
unimodal problems: the same observations, the same starts near θ*, the same FD gradient settings and the same
spp per render (gauss-newton at spp = AUTO_SPP; its other options default). Pixel-samples are Σ spp × H × W over
a fit's renders (`Estimate.samples`, from the model's counters)."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench import estimators
from nlosbench.bounds import crlb, fisher_matrix
from nlosbench.estimators import Problem
from nlosbench.estimators.mle_adam import AUTO_SPP, stopping
from nlosbench.forward import GradientSettings, ad_jacobian
from nlosbench.seeds import derive


def _compare(model, noise, truth, trials: int, spread: float, gradient: GradientSettings, clean_spp: int, seed: int):
    """Per trial i: y = noise(L_θ*, rendered at clean_spp with seed derive(seed, "clean", i)), a start uniform in
    θ* ± spread × Θ's width (clipped to Θ), both estimators fitted from it. Returns {name: (squared errors (n,),
    pixel-samples (n,), statuses)}."""
    p = model.params
    out = {"mle-adam": ([], [], []), "gauss-newton": ([], [], [])}
    for i in range(trials):
        clean = model.render(truth, clean_spp, derive(seed, "clean", i))
        y = noise.sample(clean, torch.Generator().manual_seed(derive(seed, "noise", i)))
        rng = np.random.default_rng(derive(seed, "start", i))
        start = np.clip(truth + rng.uniform(-spread, spread, p.dim) * (p.upper - p.lower), p.lower, p.upper)
        problem = Problem(model, noise, gradient, seed=derive(seed, "problem", i))
        for name, est in (("mle-adam", estimators.get("mle-adam")),
                          ("gauss-newton", estimators.get("gauss-newton", spp=AUTO_SPP))):
            e = est.fit(problem, y, start, np.random.default_rng(derive(seed, "fit", i)))
            err, samples, status = out[name]
            err.append(float(np.sum((e.theta - truth) ** 2)))
            samples.append(e.samples)
            status.append(e.status)
    return {k: (np.array(a), np.array(b), c) for k, (a, b, c) in out.items()}


def _ratios(res) -> tuple[float, float, list[str]]:
    """(MSE(mle-adam) / MSE(gauss-newton), pixel-samples(mle-adam) / pixel-samples(gauss-newton), mle-adam's
    fit statuses)."""
    adam, gn = res["mle-adam"], res["gauss-newton"]
    return float(adam[0].mean() / gn[0].mean()), float(adam[1].sum() / gn[1].sum()), list(adam[2])


@pytest.mark.slow
def test_adam_defaults_match_gauss_newton_on_blob2d_with_rendering_noise():
    """blob2d (width 0.15, synthetic rendering noise 0.5: per-pixel render variance 0.25·L/spp, at 128 spp up to 0.9
    × the AWGN variance, at the peak), AWGN σ = 0.05, θ* = (0.45, 0.58), 24 trials (seed 31), starts within ±5 % of
    Θ's width, FD step 0.005. Measured: MSE(mle-adam) = 1.12 × MSE(gauss-newton) (6.4e-6 against 5.7e-6; 0.53–0.94
    with seeds 1–8), 1.15 × the CRLB (exact AD Fisher information of the clean image), at 0.42 × its pixel-samples
    (≈ 74 renders a fit against ≈ 174, every fit "converged"; gauss-newton runs to its 30 iterations in 20 of 24
    fits: with fresh rendering noise each iteration its steps never fall below its tol). Asserted: ≤ 1.5 × the MSE
    at ≤ 3 × the pixel-samples, every fit "converged", and MSE ≤ 1.6 × CRLB (24 trials: the mean of ‖e‖²/CRLB has a
    relative SE of about 0.2)."""
    model = nb.scenes.get("blob2d", width=0.15, render_noise=0.5)
    noise = nb.noise.AWGN(0.05)
    truth = np.array([0.45, 0.58])
    res = _compare(model, noise, truth, 24, 0.05, GradientSettings("fd", step=0.005), clean_spp=4096, seed=31)
    mse, samples, statuses = _ratios(res)
    assert mse <= 1.5 and samples <= 3.0 and set(statuses) == {"converged"}, (mse, samples, statuses)
    exact = nb.scenes.get("blob2d", width=0.15)
    bound = crlb(fisher_matrix(exact.render(truth, 1, 0), ad_jacobian(exact, truth, 1, 0), noise)).trace
    assert res["mle-adam"][0].mean() <= 1.6 * bound, (res["mle-adam"][0].mean(), bound)


@pytest.mark.slow
def test_adam_defaults_match_gauss_newton_on_cornell_ball():
    """The Mitsuba scene cornell_ball at 16 × 16 px (max_depth 3), θ = (ball_x, ball_red) at (0.1, 0.6), AWGN
    σ = 0.05, observations from 1024-spp renders, 8 trials (seed 37), starts within ±5 % of Θ's width, FD step
    0.02. Measured: MSE(mle-adam) = 1.07 × MSE(gauss-newton) (1.02e-3 against 9.5e-4; 0.51–0.83 with seeds
    1–3), at 0.63 × its pixel-samples (≈ 68 renders a fit against ≈ 108, every fit "converged"; 25 s on 2
    shared CPU cores). Asserted: ≤ 1.5 × the MSE at ≤ 3 × the pixel-samples, every fit "converged"."""
    model = nb.scenes.get("cornell_ball", defines={"res": 16, "max_depth": 3}).restrict(["ball_x", "ball_red"])
    res = _compare(model, nb.noise.AWGN(0.05), np.array([0.1, 0.6]), 8, 0.05, GradientSettings("fd", step=0.02),
                   clean_spp=1024, seed=37)
    mse, samples, statuses = _ratios(res)
    assert mse <= 1.5 and samples <= 3.0 and set(statuses) == {"converged"}, (mse, samples, statuses)


def test_stopping_rule_tells_converged_from_still_moving_and_stalled():
    """`stopping` on synthetic windows of k = 10 iterations, P = 1, σ̂ = 1: steps d scattered about 0 by
    rendering noise with settled iterates → converged; d consistently 5 SD from 0 while θ drifts → go on;
    the same d with θ frozen (steps < TINY σ̂) → stalled; noise-free d below NEGLIGIBLE σ̂ → converged."""
    rng = np.random.default_rng(41)
    sigma = np.ones(1)
    settled = 0.3 * rng.standard_normal((10, 1))
    noisy = rng.standard_normal((10, 1))
    assert stopping(noisy, settled, sigma, np.abs(np.diff(settled, axis=0, prepend=0)))[0] == "converged"
    drifting = np.linspace(5, 1, 10)[:, None]
    assert stopping(drifting + 0.1 * noisy, drifting, sigma, np.full((10, 1), 0.4)) is None
    frozen = np.full((10, 1), 3.0)
    status, reason = stopping(3.0 + 0.1 * noisy, frozen, sigma, np.zeros((10, 1)))
    assert status == "stalled" and "SE from 0" in reason
    tiny = np.geomspace(0.05, 1e-4, 10)[:, None]
    assert stopping(tiny, tiny, sigma, tiny)[0] == "converged"


def test_the_trials_cost_estimate_reads_the_spp_that_the_estimator_resolves():
    """mle-adam's spp default follows its lr (AUTO_SPP with "auto", 512 then 1024 with a number): the trials
    study's plan counts that, × (1 + 2P) FD renders per iteration at the largest spp, for the iterations it plans:
    with lr "auto" what its stopping rule typically takes (AUTO_ITERATIONS, not the cap of 200), with a numeric lr
    its cap (an upper bound), and never more than a budget allows."""
    from nlosbench.estimators import Budget
    from nlosbench.estimators.mle_adam import AUTO_ITERATIONS
    from nlosbench.studies.trials import _fit_cost

    k = AUTO_ITERATIONS * 5
    assert _fit_cost("mle-adam", {}, GradientSettings(), 2, Budget()) == (k, k * AUTO_SPP)
    assert _fit_cost("mle-adam", {"iterations": 12}, GradientSettings(), 2, Budget()) == (60, 60 * AUTO_SPP)
    assert _fit_cost("mle-adam", {}, GradientSettings(), 2, Budget(iterations=11)) == (55, 55 * AUTO_SPP)
    assert _fit_cost("mle-adam", {"lr": 0.05}, GradientSettings(), 2, Budget()) == (1000, 1000 * 1024)
