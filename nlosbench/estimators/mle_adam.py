"""`mle-adam`: maximum likelihood with torch.optim.Adam on θ through the differentiable renderer.

The loss is the noise model's negative log-likelihood of y at L_θ = nb.render(model, θ, ...) (L2 for
AWGN, Poisson NLL for photon counts); its gradient comes from FD (central, common random numbers) or
AD, as the problem's GradientSettings say. Adam works on u = (θ − lower)/(upper − lower) ∈ [0, 1]^P,
so one learning rate suits parameters of any unit, and after each step u is clipped to the box
(Θ's bounds are respected; FD stencils turn one-sided at the box). Every iteration renders with a
fresh seed (stochastic gradients), the spp follows a schedule (the paper: 512 then 1024) and the
learning rate decays (cosine or exponential) so the last iterates settle.

Predicted variance (`fit_cov`). Linearised at ê (the score's fixed point on y, `predict.target`), the NLL's
gradient at θ_k is F d_k + ξ_k, d_k = θ_k − ê, with ξ_k the noise of iteration k's render and Jacobian at
its spp s_k, Cov ξ_k = JᵀW Σ_render(s_k) WJ + Σ_ω w² (Σ_obs + Σ_truth + Σ_render) Cov δJ (`predict.
score_noise`), plus the Jacobian's noise against the model's change, δJᵀ W J d (`Linearisation.drift_noise`).
Adam on u = θ/width then is a linear stochastic recursion with momentum,

    g_k = width·(F d_k + ξ_k),   m_{k+1} = β₁ m_k + (1 − β₁) g_k,   d_{k+1} = d_k − width·η_k m_{k+1} / (1 − β₁^{k+1}),

with the per-component step η_k = lr_k / √v̂_k, where v̂_k (Adam's second moment, bias-corrected) is taken at
its expectation E[g²] over the trials (the start's spread early, the gradient noise late) — so the step
size and the schedule (lr_k, s_k) set how much of the noise the last iterates average. The covariance of
(d, m) is propagated through every iteration from the start's second moment about ê (`predict.start_moment`) and
read at the fits' iteration counts; with a constant η it tends to the stationary η Q / (F (2 − η F)) (no
momentum). Not modelled: Θ's box (clipping), a v̂ that differs from fit to fit, and anything nonlinear far
from θ* (a start outside the basin is a local minimum, not this recursion).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from ..forward.autograd import render
from ..seeds import derive
from .base import Budget, Estimator, Outcome, Problem, Tracker, check_start, finite_or_raise, render_seed
from .predict import Linearisation, score_noise, start_moment

LR_SCHEDULES = ("constant", "cosine", "exponential")
#: steps that stop moving once the schedule has cut the learning rate below this fraction have stalled
STALL = 0.1


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


class AdamMLE(Estimator):
    """Maximum likelihood by Adam on θ through nb.render (FD or AD gradients of the NLL).

    Parameters
    ----------
    lr : float, default 0.05
        Adam step size in units of Θ's width (0.05: about 5 % of the range per step at first).
    iterations : int, default 200
        Maximum iterations.
    spp : int or sequence of [fraction, spp], default ((0.0, 512), (0.5, 1024))
        Samples per pixel, constant or a schedule [[fraction of the iterations, spp], ...] starting at
        fraction 0 (paper: 512 then 1024).
    lr_schedule : {"constant", "cosine", "exponential"}, default "cosine"
        The learning rate's decay, to lr·lr_final at the last iteration.
    lr_final : float, default 1e-3
        The final learning rate as a fraction of `lr`, in (0, 1].
    tol : float, default 1e-4
        Converged when every component of u moved less than tol (fraction of Θ's width) for `patience`
        consecutive iterations while the learning rate is still at least STALL of its start (later, the
        schedule made the steps small: status "stalled").
    patience : int, default 3
        The consecutive iterations of `tol`.
    betas : tuple of float, default (0.5, 0.99)
        Adam's moment decay rates. Not torch's (0.9, 0.999): the NLL's gradient shrinks by orders of
        magnitude between a far start and θ̂, and a long second-moment memory then freezes the steps near
        θ̂ while heavy momentum overshoots (on blob2d at high SNR, (0.9, 0.999) ends at ≈ 5 × CRLB after
        100 iterations, (0.5, 0.99) at the CRLB after ≈ 30).
    start : {"given", "profile"}, default "given"
        Start at `init` (or a uniform random point), or at the profile-likelihood minimum over the
        problem's bank grid.
    """

    name = "mle-adam"
    valid_when = ("The NLL is smooth near θ̂ and the start lies in the basin of the global optimum (a "
                  "unimodal likelihood, or a start close enough); then it is the efficient MLE at high SNR. "
                  "Across visibility changes use FD or projective AD gradients; for multimodal likelihoods "
                  "(hard edges, NLOS) wrap it in multi-start or use grid-search.")

    def __init__(self, lr: float = 0.05, iterations: int = 200, spp=((0.0, 512), (0.5, 1024)),
                 lr_schedule: str = "cosine", lr_final: float = 1e-3, tol: float = 1e-4, patience: int = 3,
                 betas: tuple[float, float] = (0.5, 0.99), start: str = "given"):
        if not lr > 0:
            raise ValueError(f"mle-adam: lr must be > 0, got {lr}")
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise ValueError(f"mle-adam: iterations must be a positive integer, got {iterations!r}")
        if lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"mle-adam: lr_schedule must be one of {list(LR_SCHEDULES)}, got {lr_schedule!r}")
        if not 0 < lr_final <= 1:
            raise ValueError(f"mle-adam: lr_final (fraction of lr at the end) must lie in (0, 1], got {lr_final}")
        if tol < 0 or int(patience) != patience or patience < 1:
            raise ValueError(f"mle-adam: need tol >= 0 and patience >= 1, got tol={tol}, patience={patience}")
        self.lr, self.iterations, self.spp = float(lr), int(iterations), spp_schedule(spp)
        self.lr_schedule, self.lr_final, self.tol, self.patience = (
            lr_schedule,
            float(lr_final),
            float(tol),
            int(patience),
        )
        self.betas = (float(betas[0]), float(betas[1]))
        self.start = check_start(self.name, start)

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

    def _fit(
        self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator, tracker: Tracker
    ) -> Outcome:
        n = tracker.budget.cap(self.iterations)
        base = render_seed(rng)
        lo, hi = torch.as_tensor(problem.params.lower), torch.as_tensor(problem.params.upper)
        width = hi - lo
        u = torch.tensor(problem.to_unit(theta0), dtype=torch.float64, requires_grad=True)
        opt = torch.optim.Adam([u], lr=self.lr, betas=self.betas)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: self.lr_factor(k, n))
        still, done, loss = 0, 0, math.nan
        reason, status = f"reached max iterations ({n})", "max-iterations"
        while done < n:
            stop = tracker.exhausted()
            if stop:
                reason, status = stop, "budget"
                break
            theta = torch.clamp(lo + u * width, lo, hi)  # rounding may step past `upper`
            L = render(
                problem.model, theta, self.spp_at(done, n), derive(base, "mle-adam", done), grad=problem.gradient
            )
            loss_t = problem.nll(y, L)
            loss = finite_or_raise(float(loss_t.detach()), f"NLL at iteration {done}")
            tracker.record(done, loss, theta.detach().numpy())
            opt.zero_grad()
            loss_t.backward()
            before = u.detach().clone()
            opt.step()
            sched.step()
            with torch.no_grad():
                u.clamp_(0.0, 1.0)
            done += 1
            still = still + 1 if float((u.detach() - before).abs().max()) < self.tol else 0
            if still >= self.patience:
                factor = self.lr_factor(done - 1, n)
                status = "converged" if factor >= STALL else "stalled"
                reason = (f"θ moved < {self.tol:g} of Θ's width for {self.patience} iterations at "
                          f"{factor:.3g} × the initial learning rate")
                break
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
        n = budget.cap(self.iterations)
        F, g = lin.F, problem.gradient
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
