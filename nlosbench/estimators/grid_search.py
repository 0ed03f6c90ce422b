"""`grid-search`: profile likelihood on cached grid renders, then a derivative-free local refinement.

A tensor grid of `num` points per parameter over Θ (`grid_wanted`) comes from the run's render bank when a
study passes it in `Problem.grids` (the trials study does: rendered once per run, shared with a bound grid of
the same θ, spp and seeds); otherwise it is rendered once per process (seeds derived from the problem's seed,
so every fit sees the same grid renders) and kept in memory. A fit evaluates the
NLL of y at every grid render (no render), takes the minimum, then refines with Powell's method
(Brent line searches; no derivative, so kinks and edges are fine) inside the neighbouring grid cells,
on renders at `refine_spp` that share one seed (the objective is deterministic during the search);
for a scalar θ the refinement is Brent's bounded search, which stops on the θ tolerance alone.
"""
from __future__ import annotations

import json

import numpy as np
import scipy.optimize
import torch

from ..params import ParamSpace
from ..seeds import derive
from .base import MAX_GRID, Estimator, Outcome, Problem, Tracker, finite_or_raise, nll, render_seed


class _OutOfBudget(Exception):
    """Raised inside the refinement objective when the budget is used up."""


class GridSearch(Estimator):
    """Profile likelihood on a cached grid of renders over Θ, refined locally (Brent / Powell).

    Parameters
    ----------
    num : int, default 65
        Grid points per parameter, ≥ 2 (num^P renders, cached per process).
    spp : int, default 1024
        Samples per pixel of the grid renders.
    refine : bool, default True
        Refine around the grid minimum (else θ̂ is the grid point).
    refine_spp : int, optional
        Samples per pixel of refinement renders (default: `spp`).
    refine_evals : int, default 150
        Maximum refinement renders.
    xtol : float, default 1e-4
        The refinement's θ tolerance, in units of Θ's width.
    max_grid : int, default MAX_GRID (100000)
        Refuse grids with more points than this.

    Examples
    --------
    Without refinement θ̂ is the grid point nearest the minimum, for the grid's renders alone:

    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.5], spp=64, seed=0)
    >>> fit = nb.estimators.GridSearch(num=9, spp=16, refine=False).fit(problem, y, rng=np.random.default_rng(0))
    >>> fit.theta, fit.renders
    (array([0.5]), 9)
    """

    name = "grid-search"
    no_prediction = ("no linearised update: a profile over grid renders and a derivative-free search, whose "
                     "error depends on the grid's renders and the search's tolerance")
    valid_when = ("Any likelihood shape (multimodal, kinked at hard edges or occlusions, flat regions) as long "
                  "as the grid spacing is finer than the likelihood's main lobe. Costs num^P renders once per "
                  "process plus the refinement per fit: practical for P ≤ 2. Without refinement θ̂ is quantised "
                  "to the grid; the grid renders' own noise enters the profile.")

    def __init__(self, num: int = 65, spp: int = 1024, refine: bool = True, refine_spp: int | None = None,
                 refine_evals: int = 150, xtol: float = 1e-4, max_grid: int = MAX_GRID):
        ints = {"num": num, "spp": spp, "refine_spp": spp if refine_spp is None else refine_spp,
                "refine_evals": refine_evals, "max_grid": max_grid}
        for k, v in ints.items():
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"grid-search: {k} must be a positive integer, got {v!r}")
        if num < 2 or not xtol > 0:
            raise ValueError(f"grid-search: need num >= 2 and xtol > 0, got num={num}, xtol={xtol}")
        self.num, self.spp, self.refine = int(num), int(spp), bool(refine)
        self.refine_spp = int(ints["refine_spp"])
        self.refine_evals, self.xtol, self.max_grid = int(refine_evals), float(xtol), int(max_grid)
        self._grids: dict[str, tuple[np.ndarray, list[torch.Tensor]]] = {}

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int]:
        """The tensor grid of `num` points per parameter over Θ and its spp.

        Parameters
        ----------
        params : ParamSpace
            The parameter space Θ.

        Returns
        -------
        tuple of (numpy.ndarray, int)
            The grid (G, P) float64 in parameter units, G = num^P, and the spp of its renders.

        Raises
        ------
        ValueError
            If num^P exceeds `max_grid`.
        """
        G = self.num ** params.dim
        if G > self.max_grid:
            raise ValueError(f"grid-search: {self.num}^{params.dim} = {G} grid renders exceed max_grid = "
                             f"{self.max_grid}")
        return params.grid(self.num), self.spp

    def grid(self, problem: Problem) -> tuple[np.ndarray, list[torch.Tensor]]:
        """(θ grid (G, P), renders) for this problem: the run's renders when the problem carries them
        (`Problem.find_grid`), else rendered on first use and cached in this process.

        Parameters
        ----------
        problem : Problem
            The problem (its grids, model, parameter space and seed).

        Returns
        -------
        tuple of (numpy.ndarray, list of torch.Tensor)
            The grid (G, P) float64 in parameter units, G = num^P, and its G renders (H, W, C) float32.
        """
        thetas, spp = self.grid_wanted(problem.params)
        given = problem.find_grid(thetas, spp)
        if given is not None:
            return np.asarray(given.thetas, dtype=np.float64), list(given.images)
        key = json.dumps([problem.model.content_key(), problem.params.names, self.num, self.spp, problem.seed],
                         sort_keys=True, default=repr)
        if key not in self._grids:
            renders = [problem.model.render(t, self.spp, derive(problem.seed, "grid-search", g))
                       for g, t in enumerate(thetas)]
            self._grids[key] = (thetas, renders)
        return self._grids[key]

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        thetas, renders = self.grid(problem)
        profile = np.array([nll(problem, y, L) for L in renders])
        g = int(np.argmin(profile))
        best = [problem.to_unit(thetas[g]), finite_or_raise(float(profile[g]), "NLL at the grid minimum")]
        tracker.record(0, best[1], thetas[g])
        if not self.refine:
            return Outcome(thetas[g], 1, "converged", f"grid minimum of {len(thetas)} points (no refinement)", best[1])
        seed = derive(render_seed(rng), "grid-search-refine")
        h = 1.0 / (self.num - 1)
        box = [(max(0.0, c - h), min(1.0, c + h)) for c in best[0]]
        evals = [0]

        def objective(u: np.ndarray) -> float:
            stop = tracker.exhausted()
            if stop:
                raise _OutOfBudget(stop)
            theta = problem.from_unit(u)
            f = finite_or_raise(nll(problem, y, problem.model.render(theta, self.refine_spp, seed)),
                                "NLL during refinement")
            evals[0] += 1
            tracker.record(evals[0], f, theta)
            if f < best[1]:
                best[:] = [np.asarray(u, dtype=np.float64).copy(), f]
            return f

        try:
            # the grid value came from another render; the refinement compares on its own seed only
            best[1] = objective(best[0])
            if len(box) == 1:  # Brent's bounded search: stops on the θ tolerance alone
                res = scipy.optimize.minimize_scalar(lambda v: objective(np.array([v])), bounds=box[0],
                                                     method="bounded",
                                                     options={"xatol": self.xtol, "maxiter": self.refine_evals})
            else:
                # ftol: relative NLL change; float32 renders make smaller changes noise
                res = scipy.optimize.minimize(objective, best[0], method="Powell", bounds=box,
                                              options={"xtol": self.xtol, "ftol": 1e-7, "maxfev": self.refine_evals})
            status, reason = ("converged" if res.success else "max-iterations"), f"refined: {res.message}"
        except _OutOfBudget as e:
            status, reason = "budget", str(e)
        return Outcome(problem.from_unit(best[0]), 1 + evals[0], status, reason, best[1])
