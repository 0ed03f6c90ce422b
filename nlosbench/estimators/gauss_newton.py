"""`gauss-newton`: Fisher scoring with Levenberg–Marquardt damping, using the bounds module's Fisher matrix.

Each iteration renders L_θ and its Jacobian J = ∂L/∂θ (FD with common random numbers, or AD, as the
problem says) with one seed, and proposes θ + (F + μ·diag F)⁻¹ s with the score s = −Jᵀ ∂NLL/∂L and
F = `bounds.fisher_matrix(L, J, noise)` (for AWGN this is Gauss–Newton: F = JᵀJ/σ²) — a plug-in FI from one
FD pair, biased high by rendering noise, which only scales the step (not the FI any bound uses). The step is
clipped to Θ and accepted when the NLL at the new θ, rendered with the *same* seed (so rendering noise
cancels in the comparison), is not higher; otherwise μ grows and the step shrinks.

Predicted variance (`fit_cov`). Near ê (the score's fixed point on y, `predict.target`) write d_k = θ_k − ê,
r = y's residual at ê (JᵀW r = 0), ε_k the render error of iteration k (s = `spp` samples, fresh seed each
iteration) and Ĵ_k = J + δJ_k its Jacobian. The undamped step F̂⁻¹ Ĵᵀ W (r − J d_k − ε_k) gives

    d_{k+1} = (I − F̂⁻¹ F) d_k + F̂⁻¹ (δJ_kᵀ W r − Ĵ_kᵀ W ε_k),   F̂ = F + E[δJᵀ W δJ]

(F̂: the plug-in FI of one FD pair, in expectation). The contraction itself is random, F̂⁻¹(F + δJᵀ W J): its
fluctuation adds F̂⁻¹ E[δJᵀ W J d dᵀ Jᵀ W δJ] F̂⁻¹ (`Linearisation.drift_noise`), which matters when few pixels
carry the information. With exact Jacobians the start is gone after one step
and θ̂ − ê = −F⁻¹ JᵀW ε_last: the last accepted step's render enters like the truth's,
F⁻¹ JᵀW Σ_render(s) WJ F⁻¹. With noisy ones (NLOS: F̂ far above F) each step removes only F̂⁻¹F of the
error, so (I − F̂⁻¹F)^k of the start's error survives k iterations, and the forcing adds
F̂⁻¹ [JᵀW Σ_render WJ + E[δJᵀ W (Σ_obs + Σ_truth + Σ_render) W δJ]] F̂⁻¹ per iteration (`predict.score_noise`;
the Σ per pixel a block over its colour channels). Where J is a secant over ±ξ and the image moves by the
derivative J₀ (`Linearisation.response`), F in B and in the fixed point becomes G = JᵀW J₀. The second moment
follows V_{k+1} = B V_k Bᵀ + Q, B = I − F̂⁻¹G, from V_0 = the start's second moment about ê
(`predict.start_moment`), averaged over the fits' iteration counts. Damping (μ → 0 after a few accepted steps),
rejected steps and Θ's box are not modelled: a fit that stops on a rejected step near ê is not this recursion.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ..bounds.crlb import fisher_matrix
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
    nll,
    nll_gradient,
    render_seed,
)
from .predict import Linearisation, propagate, score_noise, start_moment


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

    Examples
    --------
    From a far start, under Poisson noise (20 photons per unit radiance):

    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d")
    >>> problem = nb.estimators.Problem(model, nb.noise.Poisson(scale=20.0))
    >>> y = model.render([0.45, 0.55], spp=64, seed=0)
    >>> fit = nb.estimators.GaussNewton(spp=16, iterations=10).fit(problem, y, init=[0.4, 0.6],
    ...                                                              rng=np.random.default_rng(0))
    >>> fit.theta.round(4), fit.status
    (array([0.45, 0.55]), 'converged')
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

    def fit_cov(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None,
                budget: Budget, statuses: Sequence[str] | None = None) -> tuple[np.ndarray, str]:
        """Covariance of θ̂ − ê after the fits' iterations (module docstring): the last step's render noise, the
        Jacobian noise, and the start's error that the contraction F̂⁻¹F has not removed.

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
        Fh = F + lin.jacobian_excess(self.spp, g, lin.w)
        Fhi = np.linalg.inv(Fh)
        B = np.eye(len(F)) - Fhi @ lin.G  # the step's response: G = Jᵀ W J₀ (F for an exact Jacobian)
        Q = Fhi @ score_noise(lin, self.spp, g) @ Fhi.T
        if iterations is None:
            ks = [budget.cap(self.iterations)]
        else:  # a fit that stopped on a rejected step or a stall counted that iteration, which applied no step
            sts = list(statuses) if statuses is not None else [""] * len(iterations)
            ks = [max(int(k) - (st in ("step-rejected", "stalled")), 0) for k, st in zip(iterations, sts, strict=True)]
        V = propagate(B, Q, start_moment(lin), ks, lambda V: Fhi @ lin.drift_noise(self.spp, g, V) @ Fhi.T)
        ratio = float(np.trace(Fh) / np.trace(F))
        return V, (f"Gauss–Newton fixed point at {self.spp} spp; one Jacobian's plug-in F̂ / F = {ratio:.3g}, "
                   f"contraction (1 − F/F̂) per step; {np.mean(ks):.3g} steps on average")
