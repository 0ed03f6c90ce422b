"""`multi-start`: a local estimator run from several starts; the fit with the lowest NLL wins.

The candidates are compared on renders at `spp` that share one seed, so rendering noise does not
decide between two equally good fits. The render and time budgets are shared: each start gets what
the previous ones left.
"""
from __future__ import annotations

import numpy as np
import torch

from ..params import ParamSpace
from ..seeds import derive
from .base import Budget, Estimator, Outcome, Problem, Tracker, nll, render_seed


class MultiStart(Estimator):
    """A local estimator from several starts, keeping the fit with the lowest NLL.

    Parameters
    ----------
    base : str, default "mle-adam"
        The estimator run from each start (not "multi-start").
    starts : int, default 4
        The number of starts: the given start, then uniform random points of Θ.
    options : dict, optional
        The base estimator's options.
    spp : int, default 1024
        Samples per pixel of the common render on which the candidates' NLL is compared.

    Examples
    --------
    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.5], spp=64, seed=0)
    >>> est = nb.estimators.MultiStart(base="gauss-newton", starts=3, options={"spp": 16}, spp=16)
    >>> fit = est.fit(problem, y, init=[0.25], rng=np.random.default_rng(0))
    >>> fit.theta.round(4), fit.reason.startswith("best of 3 start(s)")
    (array([0.5]), True)
    """

    name = "multi-start"
    no_prediction = ("no linearised update: the fit kept is chosen among starts by a noisy NLL, which selects on "
                     "the error itself")
    valid_when = ("Multimodal likelihoods (hard edges, NLOS, weak signal far from θ*) where a local estimator "
                  "finds the global optimum from some starts; costs `starts` times the base estimator.")

    def __init__(self, base: str = "mle-adam", starts: int = 4, options: dict | None = None, spp: int = 1024):
        from . import get

        if isinstance(starts, bool) or int(starts) != starts or starts < 1:
            raise ValueError(f"multi-start: starts must be a positive integer, got {starts!r}")
        if isinstance(spp, bool) or int(spp) != spp or spp < 1:
            raise ValueError(f"multi-start: spp must be a positive integer, got {spp!r}")
        if base == self.name:
            raise ValueError("multi-start: base must be another estimator")
        self.base_name, self.starts, self.options, self.spp = base, int(starts), dict(options or {}), int(spp)
        self._base = get(base, **self.options)

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int] | None:
        """The base estimator's grid (its fits get the problem as it is, `grids` included).

        Parameters
        ----------
        params : ParamSpace
            The parameter space Θ of the problem.

        Returns
        -------
        tuple of (numpy.ndarray, int) or None
            The base estimator's grid (G, P) and spp, or None.
        """
        return self._base.grid_wanted(params)

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        seed = derive(render_seed(rng), "multi-start")
        b = tracker.budget
        best, iterations = None, 0
        for s in range(self.starts):
            stop = tracker.exhausted()
            if stop:
                break
            used = tracker.used()
            left = Budget(iterations=b.iterations,
                          renders=None if b.renders is None else b.renders - used.renders - used.grad_passes,
                          seconds=None if b.seconds is None else max(b.seconds - tracker.seconds(), 1e-9))
            init = theta0 if s == 0 else problem.params.sample_uniform(rng)
            est = self._base.fit(problem, y, init, rng, left)
            iterations += est.iterations
            score = nll(problem, y, problem.model.render(est.theta, self.spp, seed))
            tracker.record(s, score, est.theta)
            if best is None or score < best[0]:
                best = (score, s, est)
        if best is None:
            raise RuntimeError(f"multi-start: the budget was used up before the first start ({stop})")
        score, s, est = best
        done = len(tracker.trace)
        reason = f"best of {done} start(s) is start {s}: {est.reason}"
        if done < self.starts:
            reason += f"; only {done} of {self.starts} starts fitted the budget"
        return Outcome(est.theta, iterations, est.status if done == self.starts else "budget", reason, score)
