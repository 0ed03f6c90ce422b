"""`mle-adam`: maximum likelihood with torch.optim.Adam on θ through the differentiable renderer.

The loss is the noise model's negative log-likelihood of y at L_θ = nb.render(model, θ, ...) (L2 for
AWGN, Poisson NLL for photon counts); its gradient comes from FD (central, common random numbers) or
AD, as the problem's GradientSettings say. Adam works on u = (θ − lower)/(upper − lower) ∈ [0, 1]^P and
after each step u is clipped to the box (Θ's bounds are respected; FD stencils turn one-sided at the box).
Every iteration renders with a fresh seed (stochastic gradients).

Two step rules. `lr="auto"` (the default) needs no tuning per scene: each iteration renders L and its image
Jacobian J (with FD the very renders a vector-Jacobian product makes), forms the plug-in Fisher matrix
F̂ = `bounds.fisher_matrix(L, J, noise)`, the gradient g = ∇_θ NLL = Jᵀ ∂NLL/∂L, the Gauss–Newton step
d = F̂⁻¹ g and the CRLB scale σ̂_j = √(F̂⁻¹)_jj (θ units), and sets the step scale

    a_j = AUTO_FRACTION · max(σ̂_j, |d_j|)

Adam is fed the whitened gradient d_j / max(σ̂_j, |d_j|) ∈ [−1, 1] (so its second moment stays of order 1
wherever the iterate is, and does not freeze the steps once the gradient has shrunk), and its unit-normalised
step m̂_j / (√v̂_j + ε) moves θ_j by that many a_j: far from θ̂ a fraction of the Gauss–Newton step, near θ̂ a
fraction of the CRLB's standard deviation. It stops on the signal-to-noise of d over a window (`stopping`) and
returns the window's mean iterate (Polyak) less the window's mean d (`average`). A number for `lr` keeps the
0.1 rule: a fixed step in units of Θ's width with a decaying schedule, stopped when θ stops moving.

Predicted variance (`fit_cov`), for a numeric `lr`. Linearised at ê (the score's fixed point on y,
`predict.target`), the NLL's gradient at θ_k is F d_k + ξ_k, d_k = θ_k − ê, with ξ_k the noise of iteration
k's render and Jacobian at its spp s_k, Cov ξ_k = JᵀW Σ_render(s_k) WJ + Σ_ω w² (Σ_obs + Σ_truth + Σ_render)
Cov δJ (`predict.score_noise`), plus the Jacobian's noise against the model's change, δJᵀ W J d
(`Linearisation.drift_noise`). Adam on u = θ/width then is a linear stochastic recursion with momentum,

    g_k = width·(F d_k + ξ_k),   m_{k+1} = β₁ m_k + (1 − β₁) g_k,   d_{k+1} = d_k − width·η_k m_{k+1} / (1 − β₁^{k+1}),

with the per-component step η_k = lr_k / √v̂_k, where v̂_k (Adam's second moment, bias-corrected) is taken at
its expectation E[g²] over the trials (the start's spread early, the gradient noise late) — so the step
size and the schedule (lr_k, s_k) set how much of the noise the last iterates average. The covariance of
(d, m) is propagated through every iteration from the start's second moment about ê (`predict.start_moment`) and
read at the fits' iteration counts; with a constant η it tends to the stationary η Q / (F (2 − η F)) (no
momentum). Not modelled: Θ's box (clipping), a v̂ that differs from fit to fit, and anything nonlinear far
from θ* (a start outside the basin is a local minimum, not this recursion). With `lr="auto"` the returned
θ̂ is the window's mean iterate less its mean Gauss–Newton step d = F̂⁻¹ g, F̂ the plug-in F of each
iteration's render and Jacobian (F plus the Jacobian's noise, `Linearisation.jacobian_excess`: ≈ 20 F in NLOS
at 128 spp with 3-cm FD, ≈ F in LOS). Far from θ̂ a step is AUTO_FRACTION of d, so the iterates' error about ê
contracts by I − AUTO_FRACTION·F̂⁻¹G per iteration (G = JᵀW J₀, `Linearisation.G`) from the start's
(`predict.start_moment`), to the window's middle (k − window/2 steps); θ̄ − d̄ leaves (I − F̂⁻¹G) of it, plus
the score noise of one iterate at its spp averaged over the window: F̂⁻¹ Q F̂⁻¹ / window (Q =
`predict.score_noise`). Steps that |d| < σ̂ rescales (near θ̂) are taken as the same fraction of d.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from ..bounds.crlb import crlb, fisher_matrix
from ..forward.autograd import render
from ..forward.gradients import jacobian
from ..seeds import derive
from .base import (
    Budget,
    Estimator,
    Outcome,
    Problem,
    Tracker,
    check_start,
    finite_or_raise,
    floored,
    nll_gradient,
    render_seed,
)
from .predict import Linearisation, score_noise, start_moment

LR_SCHEDULES = ("constant", "cosine", "exponential")
AVERAGES = ("polyak-newton", "polyak", "last")
#: steps that stop moving once the schedule has cut the learning rate below this fraction have stalled
STALL = 0.1
#: lr="auto": a unit-normalised Adam step moves θ_j by this fraction of max(CRLB scale, |Gauss–Newton step|)
AUTO_FRACTION = 0.5
#: lr="auto": the spp schedule when `spp` is not given (numeric lr: ((0, 512), (0.5, 1024)), the paper's)
AUTO_SPP = 128
#: lr="auto": the window's mean Gauss–Newton step below this many CRLB standard deviations is negligible
NEGLIGIBLE = 0.1
#: lr="auto": a window whose iterates all moved less than this many CRLB standard deviations per step has stopped
TINY = 0.01
#: lr="auto": the iterations a fit is planned at in cost estimates (`AdamMLE.expected_iterations`): the stopping
#: rule needs `window` iterations at least; on the Π hallway at 40 × 30 (profile start, 128 spp, FD ξ = 3 cm, θ* =
#: 1.2 m, 4 fits) they stopped after 10, 10, 14 and 17 ("converged")
AUTO_ITERATIONS = 15


def spp_schedule(spp) -> tuple[tuple[float, int], ...]:
    """An spp schedule as ((start fraction of the iterations, spp), ...) sorted, the first at 0.
    `spp` is an int (constant) or pairs [[0, 512], [0.5, 1024]]."""
    pairs = [(0.0, spp)] if isinstance(spp, (int, np.integer)) else [tuple(p) for p in spp]
    out = []
    for p in pairs:
        if len(p) != 2:
            raise ValueError(f"spp schedule entries are [fraction, spp] pairs, got {p!r}")
        frac, n = float(p[0]), p[1]
        if not 0.0 <= frac < 1.0 or isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"spp schedule entry {list(p)}: need 0 <= fraction < 1 and a positive integer spp")
        out.append((frac, int(n)))
    out.sort()
    if not out or out[0][0] != 0.0:
        raise ValueError(f"the spp schedule must start at fraction 0, got {spp!r}")
    return tuple(out)


def stopping(d: np.ndarray, theta: np.ndarray, sigma: np.ndarray, moves: np.ndarray) -> tuple[str, str] | None:
    """The lr="auto" stopping rule on a window of k iterations: (status, reason), or None to go on.

    With d_i = F̂⁻¹ g_i the Gauss–Newton step at iterate i (θ units; ≈ θ_i − θ̂ plus rendering noise), its
    window mean d̄ ≈ θ̄ − θ̂ and SE_j = SD_j(d) / √k: "converged" when every |d̄_j| ≤ 2 SE_j (the gradient is
    not distinguishable from zero given its scatter) or ≤ NEGLIGIBLE · σ̂_j (θ̄ lies within a tenth of the
    CRLB's standard deviation of θ̂, e.g. noise-free data), and the means of the window's two halves of
    iterates differ by at most 2 SE (their SDs over √(k/2)) or NEGLIGIBLE · σ̂_j (the iterates have stopped
    drifting: a window that still holds the approach, whose scattered d can pass the first test, does not);
    "stalled" when the iterates stopped (every step below TINY · σ̂_j) while d̄ is still significantly non-zero.

    Parameters
    ----------
    d : numpy.ndarray
        The window's Gauss–Newton steps (k, P), θ units (components held at Θ's bounds set to 0).
    theta : numpy.ndarray
        The window's iterates (k, P), θ units.
    sigma : numpy.ndarray
        The CRLB scale σ̂ = √diag F̂⁻¹ (P,), θ units, averaged over the window.
    moves : numpy.ndarray
        |θ_i − θ_(i−1)| over the window (k, P), θ units.

    Returns
    -------
    tuple of (str, str) or None
        ("converged" or "stalled", the reason), or None while neither holds.
    """
    k = len(d)
    mean, se = d.mean(axis=0), d.std(axis=0, ddof=1) / math.sqrt(k)
    t = np.abs(mean) / np.where(se > 0, se, np.inf)
    a, b = theta[: k // 2], theta[k // 2:]
    drift = np.abs(a.mean(axis=0) - b.mean(axis=0))
    drift_se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b))
    settled = np.all((drift <= 2 * drift_se) | (drift <= NEGLIGIBLE * sigma))
    if settled and np.all((np.abs(mean) <= 2 * se) | (np.abs(mean) <= NEGLIGIBLE * sigma)):
        return "converged", (f"the mean Gauss–Newton step over the last {k} iterations is not distinguishable from "
                             f"0 (|mean|/SE ≤ {t.max():.2g}) or below {NEGLIGIBLE:g} × the CRLB's SD "
                             f"(|mean|/σ̂ ≤ {np.max(np.abs(mean) / sigma):.2g}), and the iterates stopped drifting")
    if np.all(moves <= TINY * sigma):
        return "stalled", (f"θ moved < {TINY:g} × the CRLB's SD per step for {k} iterations while the mean "
                           f"Gauss–Newton step is {t.max():.2g} SE from 0")
    return None


class AdamMLE(Estimator):
    """Maximum likelihood by Adam on θ through nb.render (FD or AD gradients of the NLL).

    Parameters
    ----------
    lr : "auto" or float, default "auto"
        "auto": each Adam step (unit-normalised, |m̂/√v̂| ≲ 1, on the whitened gradient) is scaled per parameter
        to AUTO_FRACTION × max(√(F̂⁻¹)_jj, |(F̂⁻¹ g)_j|) in θ units — a fraction of the CRLB's standard deviation
        near θ̂ and of the Gauss–Newton step far from it, from the plug-in Fisher matrix F̂ of each iteration's
        render and Jacobian (module docstring; with AD gradients this costs P forward passes per iteration
        instead of one reverse pass); stopped by the gradient's signal-to-noise (`stopping`). A number: the
        0.1 rule, a fixed step in units of Θ's width (0.05: about 5 % of the range per step at first) with
        `lr_schedule`, stopped by `tol` / `patience`.
    iterations : int, default 200
        Maximum iterations.
    spp : int or sequence of [fraction, spp], optional
        Samples per pixel, constant or a schedule [[fraction of the iterations, spp], ...] starting at
        fraction 0. Default: AUTO_SPP (128) with lr "auto", ((0.0, 512), (0.5, 1024)) (the paper's) with a
        numeric lr.
    lr_schedule : {"constant", "cosine", "exponential"}, optional
        The step's decay, to lr_final × the start at the last iteration. Default: "constant" with lr "auto"
        (the step follows F̂ instead), "cosine" with a numeric lr.
    lr_final : float, default 1e-3
        The final step as a fraction of the first, in (0, 1].
    tol : float, default 1e-4
        Numeric lr only: converged when every component of u moved less than tol (fraction of Θ's width) for
        `patience` consecutive iterations while the learning rate is still at least STALL of its start
        (later, the schedule made the steps small: status "stalled").
    patience : int, default 3
        Numeric lr: the consecutive iterations of `tol`.
    betas : tuple of float, default (0.5, 0.99)
        Adam's moment decay rates. Not torch's (0.9, 0.999): the NLL's gradient shrinks by orders of
        magnitude between a far start and θ̂, and a long second-moment memory then freezes the steps near
        θ̂ while heavy momentum overshoots (on blob2d at high SNR, (0.9, 0.999) ends at ≈ 5 × CRLB after
        100 iterations, (0.5, 0.99) at the CRLB after ≈ 30).
    start : {"given", "profile"}, default "given"
        Start at `init` (or a uniform random point), or at the profile-likelihood minimum over the
        problem's bank grid.
    window : int, default 10
        lr "auto": the iterations k the stopping rule looks back over, and whose iterates are averaged into θ̂.
    average : {"polyak-newton", "polyak", "last"}, default "polyak-newton"
        lr "auto": θ̂ is the mean θ̄ of the window's iterates minus the window's mean Gauss–Newton step d̄
        (≈ θ̄ − θ̂), θ̄ alone, or the last iterate. Measured on blob2d (AWGN σ = 0.05, FD, 128 spp, 96 trials):
        MSE / CRLB = 1.16 (last), 1.11 (θ̄), 1.04 (θ̄ − d̄) at rendering noise 0.5 (a render's variance up to
        0.9 σ², at the peak), 2.85, 2.43, 1.97 at rendering noise 2 (up to 14 σ²); no difference without
        rendering noise. A numeric lr returns the last iterate.

    Examples
    --------
    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.5], spp=64, seed=0)
    >>> fit = nb.estimators.AdamMLE(spp=16, iterations=40).fit(problem, y, init=[0.4], rng=np.random.default_rng(0))
    >>> fit.theta.round(4), fit.status, fit.iterations < 40
    (array([0.5]), 'converged', True)
    """

    name = "mle-adam"
    valid_when = ("The NLL is smooth near θ̂ and the start lies in the basin of the global optimum (a "
                  "unimodal likelihood, or a start close enough); then it is the efficient MLE at high SNR. "
                  "Across visibility changes use FD or projective AD gradients; for multimodal likelihoods "
                  "(hard edges, NLOS) wrap it in multi-start or use grid-search.")

    def __init__(self, lr: float | str = "auto", iterations: int = 200, spp=None, lr_schedule: str | None = None,
                 lr_final: float = 1e-3, tol: float = 1e-4, patience: int = 3,
                 betas: tuple[float, float] = (0.5, 0.99), start: str = "given", window: int = 10,
                 average: str = "polyak-newton"):
        auto = isinstance(lr, str)
        if auto and lr != "auto" or not auto and not lr > 0:
            raise ValueError(f"mle-adam: lr must be > 0 (or 'auto'), got {lr!r}")
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise ValueError(f"mle-adam: iterations must be a positive integer, got {iterations!r}")
        lr_schedule = lr_schedule or ("constant" if auto else "cosine")
        if lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"mle-adam: lr_schedule must be one of {list(LR_SCHEDULES)}, got {lr_schedule!r}")
        if not 0 < lr_final <= 1:
            raise ValueError(f"mle-adam: lr_final (fraction of lr at the end) must lie in (0, 1], got {lr_final}")
        if tol < 0 or int(patience) != patience or patience < 1:
            raise ValueError(f"mle-adam: need tol >= 0 and patience >= 1, got tol={tol}, patience={patience}")
        if isinstance(window, bool) or int(window) != window or window < 3:
            raise ValueError(f"mle-adam: window must be an integer >= 3, got {window!r}")
        if average not in AVERAGES:
            raise ValueError(f"mle-adam: average must be one of {list(AVERAGES)}, got {average!r}")
        if spp is None:
            spp = AUTO_SPP if auto else ((0.0, 512), (0.5, 1024))
        self.lr = "auto" if auto else float(lr)
        self.iterations, self.spp = int(iterations), spp_schedule(spp)
        self.lr_schedule, self.lr_final, self.tol, self.patience = (
            lr_schedule,
            float(lr_final),
            float(tol),
            int(patience),
        )
        self.betas = (float(betas[0]), float(betas[1]))
        self.start = check_start(self.name, start)
        self.window, self.average = int(window), average

    def expected_iterations(self) -> int:
        """The iterations a fit is planned at for a cost estimate: with lr "auto" max(AUTO_ITERATIONS, window)
        (the stopping rule ends fits long before the cap), capped by `iterations`; with a numeric lr, `iterations`
        (its schedule runs to the end unless θ stops moving).

        Returns
        -------
        int
            Iterations per fit.
        """
        if self.lr == "auto":
            return min(self.iterations, max(AUTO_ITERATIONS, self.window))
        return self.iterations

    def lr_factor(self, k: int, n: int) -> float:
        """Learning-rate multiplier at iteration k of n (1 at the start, lr_final at the end).

        Parameters
        ----------
        k : int
            The iteration, 0 to n − 1.
        n : int
            The number of iterations.

        Returns
        -------
        float
            The factor applied to `lr`.
        """
        x = k / max(n - 1, 1)
        if self.lr_schedule == "constant":
            return 1.0
        if self.lr_schedule == "cosine":
            return self.lr_final + (1.0 - self.lr_final) * 0.5 * (1.0 + math.cos(math.pi * x))
        return self.lr_final**x

    def spp_at(self, k: int, n: int) -> int:
        """spp of iteration k of n under the schedule.

        Parameters
        ----------
        k : int
            The iteration, 0 to n − 1.
        n : int
            The number of iterations.

        Returns
        -------
        int
            Samples per pixel of that iteration's render.
        """
        return [s for frac, s in self.spp if k >= frac * n][-1]

    def _average(self, problem: Problem, thetas: list[np.ndarray], steps: list[np.ndarray]) -> np.ndarray:
        """θ̂ from the last `window` iterates θ_i and their Gauss–Newton steps d_i (θ units): their mean θ̄
        ("polyak"), or θ̄ − d̄ ("polyak-newton": d̄ ≈ θ̄ − θ̂ by linearisation, so the correction removes what of
        the approach the window still holds and averages the renders' noise over k iterations), in Θ."""
        w = self.window
        theta = np.mean(thetas[-w:], axis=0)
        if self.average == "polyak-newton":
            theta = theta - np.mean(steps[-w:], axis=0)
        return np.clip(theta, problem.params.lower, problem.params.upper)

    def _fit(
        self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator, tracker: Tracker
    ) -> Outcome:
        n = tracker.budget.cap(self.iterations)
        base = render_seed(rng)
        auto = self.lr == "auto"
        lo, hi = torch.as_tensor(problem.params.lower), torch.as_tensor(problem.params.upper)
        width = hi - lo
        u = torch.tensor(problem.to_unit(theta0), dtype=torch.float64, requires_grad=True)
        # lr "auto": Adam's step at lr 1 is the unit-normalised direction m̂/(√v̂ + ε), scaled per θ_j below
        opt = torch.optim.Adam([u], lr=1.0 if auto else self.lr, betas=self.betas)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: 1.0 if auto else self.lr_factor(k, n))
        still, done, loss = 0, 0, math.nan
        thetas, steps, sigmas, moves = [], [], [], []  # lr "auto": θ_i, F̂⁻¹g_i, σ̂_i, |θ_(i+1) − θ_i|
        reason, status = f"reached max iterations ({n})", "max-iterations"
        while done < n:
            stop = tracker.exhausted()
            if stop:
                reason, status = stop, "budget"
                break
            theta = torch.clamp(lo + u * width, lo, hi)  # rounding may step past `upper`
            seed, spp = derive(base, "mle-adam", done), self.spp_at(done, n)
            if auto:
                t = theta.detach().numpy()
                L = problem.model.render(t, spp, seed)
                J = jacobian(problem.model, t, spp, seed, problem.gradient)  # FD: the renders a vjp would make
                loss = finite_or_raise(float(problem.nll(y, L)), f"NLL at iteration {done}")
                tracker.record(done, loss, t)
                g = nll_gradient(problem, y, L, J)
                bound = crlb(fisher_matrix(floored(problem, L), J, problem.noise))
                if bound.singular:
                    status, reason = "stalled", f"singular Fisher matrix at θ = {t.tolist()}: {bound.reason}"
                    break
                held = ((u.detach().numpy() <= 0) & (g > 0)) | ((u.detach().numpy() >= 1) & (g < 0))
                free = ~held  # the Gauss–Newton step of the components that Θ's bounds do not hold (0 for those)
                d = np.zeros_like(g)
                d[free] = np.linalg.solve(bound.F[np.ix_(free, free)], g[free]) if free.any() else 0.0
                sigma = np.sqrt(bound.component)
                thetas.append(t)
                steps.append(d)
                sigmas.append(sigma)
                reach = np.maximum(sigma, np.abs(d))  # the step scale is AUTO_FRACTION × this, θ units
                u.grad = torch.as_tensor(d / reach)  # the whitened gradient, |·| ≤ 1
                scale = torch.as_tensor(AUTO_FRACTION * reach) / width
            else:
                L = render(problem.model, theta, spp, seed, grad=problem.gradient)
                loss_t = problem.nll(y, L)
                loss = finite_or_raise(float(loss_t.detach()), f"NLL at iteration {done}")
                tracker.record(done, loss, theta.detach().numpy())
                opt.zero_grad()
                loss_t.backward()
            before = u.detach().clone()
            opt.step()
            sched.step()
            with torch.no_grad():
                if auto:
                    u.copy_(before + (u - before) * scale * self.lr_factor(done, n))
                u.clamp_(0.0, 1.0)
            done += 1
            if auto:
                moves.append(np.abs((u.detach() - before).numpy() * width.numpy()))
                if done >= self.window:
                    w = self.window
                    verdict = stopping(np.array(steps[-w:]), np.array(thetas[-w:]), np.mean(sigmas[-w:], axis=0),
                                       np.array(moves[-w:]))
                    if verdict:
                        status, reason = verdict
                        break
                continue
            still = still + 1 if float((u.detach() - before).abs().max()) < self.tol else 0
            if still >= self.patience:
                factor = self.lr_factor(done - 1, n)
                status = "converged" if factor >= STALL else "stalled"
                reason = (f"θ moved < {self.tol:g} of Θ's width for {self.patience} iterations at "
                          f"{factor:.3g} × the initial learning rate")
                break
        if auto and thetas and self.average != "last":
            return Outcome(self._average(problem, thetas, steps), done, status, reason, loss)
        return Outcome(problem.from_unit(u.detach().numpy()), done, status, reason, loss)

    def fit_cov(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None,
                budget: Budget, statuses: Sequence[str] | None = None) -> tuple[np.ndarray, str]:
        """Covariance of θ̂ − ê after the fits' iterations from the linear recursion of the module docstring
        (covariance of the state (d, m), 2P × 2P, propagated through the schedule).

        Parameters
        ----------
        problem : Problem
            The estimation problem (its gradient settings and Θ).
        lin : Linearisation
            The linearisation at θ*: Jacobian, weight, Fisher matrix and the variances of the observation, the
            clean image, the fit renders and the Jacobian noise (`estimators.predict`).
        iterations : sequence of int, optional
            The fits' iteration counts (None: the estimator's maximum, capped by `budget`).
        budget : Budget
            The fits' budget.
        statuses : sequence of str, optional
            How each fit stopped (`Estimate.status`).

        Returns
        -------
        tuple of (numpy.ndarray, str)
            The covariance (P, P) in parameter units² and a note of what was assumed.
        """
        F, g = lin.F, problem.gradient
        if self.lr == "auto":  # the window's mean iterate less its mean GN step (module docstring)
            s = self.spp_at(0, 1)
            Fh = F + lin.jacobian_excess(s, g, lin.w)  # the plug-in F̂ each iteration divides by, in expectation
            Fhi = np.linalg.inv(Fh)
            step = np.eye(len(F)) - AUTO_FRACTION * Fhi @ lin.G  # one step of AUTO_FRACTION × the GN step
            ks = [int(budget.cap(self.iterations))] if iterations is None else [int(k) for k in iterations]
            V0 = start_moment(lin)
            V = np.zeros_like(F)
            for k in ks:  # the window's mean iterate sits window/2 steps before the end
                A = np.linalg.matrix_power(step, max(k - self.window // 2, 0))
                V += A @ V0 @ A.T / len(ks)
            B = np.eye(len(F)) - Fhi @ lin.G  # what θ̄ − d̄ leaves of θ̄'s error
            ratio = float(np.trace(Fh) / np.trace(F))
            return (B @ V @ B.T + Fhi @ score_noise(lin, s, g) @ Fhi.T / self.window,
                    f"lr auto: the mean of {self.window} iterates at {s} spp less their mean Gauss–Newton step; "
                    f"plug-in F̂ / F = {ratio:.3g}, {np.mean(ks):.3g} iterations on average")
        n = budget.cap(self.iterations)
        P = len(F)
        wd = problem.params.upper - problem.params.lower
        Wu = np.diag(wd)
        b1, b2 = self.betas
        X = np.zeros((2 * P, 2 * P))
        X[:P, :P] = start_moment(lin)
        v = np.zeros(P)
        eye = np.eye(P)
        noise = {}
        Vd = [X[:P, :P].copy()]
        for k in range(n):
            s = self.spp_at(k, n)
            if s not in noise:
                noise[s] = score_noise(lin, s, g)
            Q = noise[s] + lin.drift_noise(s, g, X[:P, :P])  # + the Jacobian's noise against J d
            G = np.hstack([Wu @ F, np.zeros((P, P))])  # g = G (d, m) + width·ξ
            v = b2 * v + (1 - b2) * np.diag(G @ X @ G.T + Wu @ Q @ Wu)
            t = k + 1
            eta = self.lr * self.lr_factor(k, n) / (np.sqrt(v / (1 - b2**t)) + 1e-8) / (1 - b1**t)
            S = np.diag(wd * eta)
            Mm = np.hstack([(1 - b1) * Wu @ F, b1 * eye])
            Md = np.hstack([eye, np.zeros((P, P))]) - S @ Mm
            M = np.vstack([Md, Mm])
            N = np.vstack([-S @ ((1 - b1) * Wu), (1 - b1) * Wu])
            X = M @ X @ M.T + N @ Q @ N.T
            Vd.append(X[:P, :P].copy())
        ks = list(iterations) if iterations is not None else [n]
        V = sum(Vd[min(int(k), n)] for k in ks) / len(ks)
        return V, (f"Adam as a linear recursion with momentum β₁ = {b1:g}, step lr/√E[g²] under the "
                   f"{self.lr_schedule} schedule, {np.mean(ks):.3g} iterations on average")
