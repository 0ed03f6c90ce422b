"""`gauss-newton`: Fisher scoring with Levenberg–Marquardt damping, using the bounds module's Fisher matrix.

Each iteration renders L_θ and its Jacobian J = ∂L/∂θ (FD with common random numbers, or AD, as the
problem says) with one seed, and proposes θ + (F + μ·diag F)⁻¹ s with the score s = −Jᵀ ∂NLL/∂L and
F = `bounds.fisher_matrix(L, J, noise)` (for AWGN this is Gauss–Newton: F = JᵀJ/σ²) — a plug-in FI from one
FD pair, biased high by rendering noise, which only scales the step (not the FI any bound uses). The step is
clipped to Θ and accepted when the NLL at the new θ, rendered with the *same* seed (so rendering noise
cancels in the comparison), is not higher; otherwise μ grows and the step shrinks.
"""
from __future__ import annotations

import numpy as np
import torch

from ..bounds.crlb import fisher_matrix
from ..forward.gradients import jacobian
from ..seeds import derive
from .base import (
    Estimator,
    Outcome,
    Problem,
    Tracker,
    check_start,
    finite_or_raise,
    floored,
    nll,
    nll_gradient,
    render_seed,
)


class GaussNewton(Estimator):
    """Fisher scoring / Gauss–Newton with Levenberg–Marquardt damping, Fisher matrix from the bounds module.

    Parameters
    ----------
    iterations : int, default 30
        Maximum iterations.
    spp : int, default 512
        Samples per pixel of every render.
    damping : float, default 1e-3
        Initial μ (relative to diag F).
    tol : float, default 1e-6
        Converged when the accepted step moves every component of θ by less than tol × Θ's width.
    max_tries : int, default 10
        Damping increases per iteration before giving up (status "step-rejected").
    start : {"given", "profile"}, default "given"
        Start at `init` (or a uniform random point), or at the profile-likelihood minimum over the
        problem's bank grid.
    """

    name = "gauss-newton"
    valid_when = ("The image is smooth in θ near θ̂, θ is identifiable (non-singular Fisher matrix) and the "
                  "start lies in the basin of the global optimum; then it converges in a few iterations "
                  "(quadratically for AWGN at high SNR). Not for hard edges or far starts on multimodal "
                  "likelihoods (wrap it in multi-start), nor where the Jacobian is unreliable.")

    def __init__(self, iterations: int = 30, spp: int = 512, damping: float = 1e-3, tol: float = 1e-6,
                 max_tries: int = 10, start: str = "given"):
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise ValueError(f"gauss-newton: iterations must be a positive integer, got {iterations!r}")
        if isinstance(spp, bool) or int(spp) != spp or spp < 1:
            raise ValueError(f"gauss-newton: spp must be a positive integer, got {spp!r}")
        if not damping > 0 or tol < 0 or int(max_tries) != max_tries or max_tries < 1:
            raise ValueError(f"gauss-newton: need damping > 0, tol >= 0, max_tries >= 1; got "
                             f"{damping}, {tol}, {max_tries}")
        self.iterations, self.spp, self.damping, self.tol, self.max_tries = (
            int(iterations), int(spp), float(damping), float(tol), int(max_tries))
        self.start = check_start(self.name, start)

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        model, noise, p = problem.model, problem.noise, problem.params
        n = tracker.budget.cap(self.iterations)
        base = render_seed(rng)
        theta, mu, loss = theta0.copy(), self.damping, float("nan")
        for it in range(n):
            stop = tracker.exhausted()
            if stop:
                return Outcome(theta, it, "budget", stop, loss)
            seed = derive(base, "gauss-newton", it)
            L = model.render(theta, self.spp, seed)
            loss = finite_or_raise(nll(problem, y, L), f"NLL at iteration {it}")
            tracker.record(it, loss, theta)
            J = jacobian(model, theta, self.spp, seed, problem.gradient)
            score = -nll_gradient(problem, y, L, J)
            F = fisher_matrix(floored(problem, L), J, noise)  # the step's plug-in FI (one FD pair: biased high)
            d = np.diag(F)
            if not (d > 0).all():
                dead = [p.names[j] for j in np.flatnonzero(~(d > 0))]
                return Outcome(theta, it + 1, "stalled", f"zero Fisher information for {dead} at θ = "
                                                     f"{theta.tolist()}: the image does not depend on it here", loss)
            for _ in range(self.max_tries):
                step = np.linalg.solve(F + mu * np.diag(d), score)
                new = np.clip(theta + step, p.lower, p.upper)
                new_loss = nll(problem, y, model.render(new, self.spp, seed))
                if new_loss <= loss:
                    mu = max(mu / 3.0, 1e-12)
                    break
                mu *= 4.0
            else:
                return Outcome(theta, it + 1, "step-rejected", f"no damped step lowers the NLL after "
                               f"{self.max_tries} tries (a minimum at this render noise, or a stall)", loss)
            moved = float(np.max(np.abs(problem.to_unit(new) - problem.to_unit(theta))))
            theta, loss = new, new_loss
            if moved < self.tol:
                return Outcome(theta, it + 1, "converged", f"step < {self.tol:g} of Θ's width", loss)
        return Outcome(theta, n, "max-iterations", f"reached max iterations ({n})", loss)
