"""The estimator contract: `fit(problem, y, init, rng, budget) → Estimate`.

A `Problem` bundles what an estimator may use: the forward model (and so Θ), the noise model, the
gradient settings, a seed for renders shared across fits, and optionally a `BankGrid`: renders of a θ
grid the run made already (the bound service's render sets, never the observation's own), over which a
profile-likelihood start costs no render (`profile_start`), and `grids`: renders of θ grids an estimator
asked for (`Estimator.grid_wanted`), made by the run's render bank (shared, counted and kept like every
other render of the run) instead of by the estimator in each process. The negative log-likelihood goes through
`Problem.nll`, whose Poisson policy (a model mean floored at `POISSON_FLOOR` photons per pixel) keeps it
finite where a Monte Carlo render left a pixel at 0 and y > 0, so no fit is dropped for an infinite NLL. A subclass
of `Estimator` implements `_fit`; the base class validates the inputs, draws a uniform random start
when none is given, enforces the `Budget`, and measures renders and wall time from the model's own
counters, so every estimator is accounted for the same way.
"""
from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from ..diagnostics import resolve_gradient
from ..forward.gradients import GradientSettings
from ..forward.model import ForwardModel, RenderStats
from ..noise import NoiseModel, Poisson, check_finite
from ..params import ParamSpace
from .predict import Linearisation, Prediction, target

#: Poisson NLL policy: model means below this many expected photons per pixel are raised to it
POISSON_FLOOR = 1e-3
#: the most points a grid or lattice that an estimator renders before its fits may hold (one render each)
MAX_GRID = 100_000
#: how a fit stopped: its own convergence rule, steps shrunk by the schedule, no acceptable step, the
#: budget, or the iteration cap (only "converged" counts as converged)
STATUSES = ("converged", "stalled", "step-rejected", "budget", "max-iterations")


@dataclass(frozen=True)
class BankGrid:
    """Renders the run made already at a θ grid: thetas (G, P), images (G, H, W, C) float32, their spp.
    They never share a seed with an observation's mean (the bank's TRUTH set), so fitting to them does
    not fit the observation's own rendering noise.

    Parameters
    ----------
    thetas : numpy.ndarray
        The G grid points, (G, P) in parameter units.
    images : torch.Tensor
        Their renders, (G, H, W, C) float32.
    spp : int
        Samples per pixel of the renders.

    Examples
    --------
    Renders of a 5-point grid, found again by the problem they are handed to:

    >>> import torch
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> thetas = model.params.grid(5)
    >>> grid = nb.estimators.BankGrid(thetas, torch.stack([model.render(t, 4, 0) for t in thetas]), spp=4)
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01), bank=grid)
    >>> problem.find_grid(thetas, 4) is grid, problem.find_grid(thetas, 8)
    (True, None)
    """

    thetas: np.ndarray
    images: torch.Tensor
    spp: int


@dataclass(frozen=True)
class Problem:
    """An estimation problem: observations y ~ noise(model.render(θ*)), θ* ∈ model.params.

    Parameters
    ----------
    model : ForwardModel
        The scene; its parameter space is Θ.
    noise : NoiseModel
        The observation noise.
    gradient : GradientSettings, optional
        How estimators that need ∂L/∂θ get it (FD with CRN, AD, mixed, or auto — resolved here, once per
        model, by `nlosbench.resolve_gradient`); default FD.
    seed : int, default 0
        Seed for renders that are the same for every fit (derive it from the experiment seed).
    bank : BankGrid, optional
        Grid renders an estimator may use without rendering (e.g. a profile-likelihood start).
    grids : tuple of BankGrid, default ()
        Further grid renders made for this problem's estimator (what its `grid_wanted` asked for).

    Examples
    --------
    A grid search on the analytic blob, from a noiseless observation:

    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d")
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.4, 0.6], spp=64, seed=0)
    >>> est = nb.estimators.get("grid-search", num=7, spp=16).fit(problem, y, rng=np.random.default_rng(0))
    >>> est.theta.round(3), est.status
    (array([0.4, 0.6]), 'converged')
    """

    model: ForwardModel
    noise: NoiseModel
    gradient: GradientSettings = field(default_factory=GradientSettings)
    seed: int = 0
    bank: BankGrid | None = None
    grids: tuple[BankGrid, ...] = ()

    def find_grid(self, thetas: np.ndarray, spp: int) -> BankGrid | None:
        """Renders the run made already at exactly `thetas` (G, P) and `spp` (in `grids` or `bank`), or None.

        Parameters
        ----------
        thetas : numpy.ndarray
            The grid (G, P) in parameter units (matched to 1e-12).
        spp : int
            Samples per pixel of the renders.

        Returns
        -------
        BankGrid or None
            The matching grid renders, or None when the run made none.
        """
        for g in (*self.grids, self.bank):
            if g is not None and g.spp == spp and np.shape(g.thetas) == np.shape(thetas) \
                    and np.allclose(g.thetas, thetas, rtol=0, atol=1e-12):
                return g
        return None

    def __post_init__(self):
        object.__setattr__(self, "gradient", resolve_gradient(self.model, self.gradient))

    @property
    def params(self) -> ParamSpace:
        return self.model.params

    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """−log p_L(y) (float64 scalar, differentiable in L) under the Poisson policy (module docstring).

        Parameters
        ----------
        y : torch.Tensor
            The observation (H, W, C), radiance units.
        L : torch.Tensor
            A model image (H, W, C), radiance units (floored at `POISSON_FLOOR` photons for Poisson noise).

        Returns
        -------
        torch.Tensor
            The negative log-likelihood up to a constant, float64 0-dim.
        """
        return self.noise.nll(y, floored(self, L))

    def to_unit(self, theta) -> np.ndarray:
        """θ → u = (θ − lower) / (upper − lower) ∈ [0, 1]^P (Θ scaled to the unit box).

        Parameters
        ----------
        theta : array_like
            θ (P,) in parameter units.

        Returns
        -------
        numpy.ndarray
            u, float64 (P,).
        """
        p = self.params
        return (np.asarray(theta, dtype=np.float64) - p.lower) / (p.upper - p.lower)

    def from_unit(self, u) -> np.ndarray:
        """u ∈ [0, 1]^P → θ (float64 (P,)), clipped to Θ against rounding.

        Parameters
        ----------
        u : array_like
            A point of the unit box, (P,).

        Returns
        -------
        numpy.ndarray
            θ, float64 (P,) in parameter units.
        """
        p = self.params
        return np.clip(p.lower + np.asarray(u, dtype=np.float64) * (p.upper - p.lower), p.lower, p.upper)


@dataclass(frozen=True)
class Budget:
    """Limits on one fit (None: no limit). renders counts primal renders plus AD gradient passes;
    an estimator checks the limits before each iteration, so it may overshoot by one iteration.

    Parameters
    ----------
    iterations : int, optional
        The most iterations (caps the estimator's own count).
    renders : int, optional
        The most primal renders plus AD gradient passes.
    seconds : float, optional
        The most wall-clock seconds.

    Examples
    --------
    >>> nb.estimators.Budget(iterations=5).cap(30), nb.estimators.Budget().cap(30)
    (5, 30)
    >>> nb.estimators.Budget(renders=0)
    Traceback (most recent call last):
    ValueError: budget renders must be > 0 or None, got 0
    """

    iterations: int | None = None
    renders: int | None = None
    seconds: float | None = None

    def __post_init__(self):
        for k in ("iterations", "renders", "seconds"):
            v = getattr(self, k)
            if v is not None and not v > 0:
                raise ValueError(f"budget {k} must be > 0 or None, got {v!r}")

    def cap(self, iterations: int) -> int:
        """An estimator's own iteration count, capped by this budget.

        Parameters
        ----------
        iterations : int
            The estimator's iteration count.

        Returns
        -------
        int
            min(iterations, the budget's iterations).
        """
        return iterations if self.iterations is None else min(iterations, int(self.iterations))


@dataclass
class Estimate:
    """Result of one fit. Work is measured from the model's counters (cached renders cost nothing).

    Parameters
    ----------
    theta : numpy.ndarray
        θ̂, float64 (P,) in parameter units.
    iterations : int
        Iterations done.
    converged : bool
        status == "converged" (`reason` says which rule stopped it).
    reason : str
        Why the fit stopped.
    status : str
        How it stopped, one of STATUSES ("converged", "stalled", "step-rejected", "budget",
        "max-iterations").
    renders : int
        Primal renders during the fit.
    grad_passes : int
        AD gradient passes during the fit.
    samples : int
        Pixel samples rendered during the fit.
    seconds : float
        Wall-clock seconds of the fit.
    final_loss : float
        The last negative log-likelihood evaluated.
    init : numpy.ndarray
        The start θ, float64 (P,).
    trace : list of dict, optional
        One dict per iteration {iteration, loss, theta, renders, seconds}, renders and seconds cumulative.

    Examples
    --------
    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.5], spp=64, seed=0)
    >>> fit = nb.estimators.get("gauss-newton", spp=16).fit(problem, y, init=[0.4], rng=np.random.default_rng(0))
    >>> fit.theta.round(6), fit.init, fit.status, fit.converged
    (array([0.5]), array([0.4]), 'converged', True)
    >>> len(fit.trace) == fit.iterations and fit.trace[-1]["renders"] <= fit.renders
    True
    """

    theta: np.ndarray
    iterations: int
    converged: bool
    reason: str
    status: str
    renders: int
    grad_passes: int
    samples: int
    seconds: float
    final_loss: float
    init: np.ndarray
    trace: list[dict] = field(default_factory=list)


class Tracker:
    """Budget and trace bookkeeping for one fit (handed to `Estimator._fit`).

    Parameters
    ----------
    model : ForwardModel
        The model whose counters measure the fit's work (from now on).
    budget : Budget
        The fit's limits.

    Examples
    --------
    >>> model = nb.scenes.get("blob2d")
    >>> tracker = nb.estimators.Tracker(model, nb.estimators.Budget(renders=2))
    >>> tracker.exhausted() is None
    True
    >>> for seed in (1, 2):
    ...     _ = model.render(model.params.default, spp=4, seed=seed)
    >>> tracker.used().renders, tracker.exhausted()
    (2, 'render budget (2) used')
    """

    def __init__(self, model: ForwardModel, budget: Budget):
        self.model = model
        self.budget = budget
        self.start = model.stats.snapshot()
        self.t0 = time.perf_counter()
        self.trace: list[dict] = []

    def used(self) -> RenderStats:
        """The model's work since the fit started.

        Returns
        -------
        RenderStats
            Renders, gradient passes, samples and render seconds since the start.
        """
        return self.model.stats.since(self.start)

    def seconds(self) -> float:
        """Wall-clock seconds since the fit started.

        Returns
        -------
        float
            The elapsed seconds.
        """
        return time.perf_counter() - self.t0

    def exhausted(self) -> str | None:
        """Why the budget is used up (render or time limit), or None.

        Returns
        -------
        str or None
            The reason (e.g. "render budget (100) used"), or None while the fit may go on.
        """
        b = self.budget
        u = self.used()
        if b.renders is not None and u.renders + u.grad_passes >= b.renders:
            return f"render budget ({b.renders}) used"
        if b.seconds is not None and self.seconds() >= b.seconds:
            return f"time budget ({b.seconds:g} s) used"
        return None

    def record(self, iteration: int, loss: float, theta: np.ndarray) -> None:
        """Append one iteration to the trace, with the renders and seconds used so far.

        Parameters
        ----------
        iteration : int
            The iteration's number.
        loss : float
            Its negative log-likelihood.
        theta : numpy.ndarray
            Its θ (P,), in parameter units.
        """
        u = self.used()
        self.trace.append({"iteration": int(iteration), "loss": float(loss), "theta": [float(v) for v in theta],
                           "renders": u.renders + u.grad_passes, "seconds": self.seconds()})


@dataclass
class Outcome:
    """What `_fit` returns: θ̂, iterations done, how it stopped (one of STATUSES) and why, final loss.

    Parameters
    ----------
    theta : numpy.ndarray
        θ̂ (P,), in parameter units.
    iterations : int
        Iterations done.
    status : str
        How the fit stopped, one of STATUSES (True / False, the 0.1 API, read as "converged" /
        "max-iterations").
    reason : str
        Why it stopped.
    final_loss : float
        The last negative log-likelihood evaluated.

    Examples
    --------
    >>> import numpy as np
    >>> nb.estimators.Outcome(np.array([0.5]), 3, True, "a plug-in written for the 0.1 API", 0.0).status
    'converged'
    >>> nb.estimators.Outcome(np.array([0.5]), 3, "done", "", 0.0)
    Traceback (most recent call last):
    ValueError: fit status must be one of ['converged', 'stalled', 'step-rejected', 'budget', 'max-iterations'], ...
    """

    theta: np.ndarray
    iterations: int
    status: str
    reason: str
    final_loss: float

    def __post_init__(self):
        if isinstance(self.status, bool):  # the 0.1 plug-in API returned `converged`: True / False
            self.status = "converged" if self.status else "max-iterations"
        if self.status not in STATUSES:
            raise ValueError(f"fit status must be one of {list(STATUSES)}, got {self.status!r}")


class Estimator(ABC):
    """Base class of estimators. Subclasses set `name` and `valid_when` (when the estimator is the
    right tool, in one or two sentences) and implement `_fit`. Options go to `__init__` as keywords.

    Examples
    --------
    A plug-in that keeps its start; the base class validates the start and counts the render it made:

    >>> import numpy as np
    >>> from nlosbench.estimators import Estimator, Outcome
    >>> class KeepStart(Estimator):
    ...     name = "keep-start"
    ...     valid_when = "never: it shows the contract"
    ...     def _fit(self, problem, y, theta0, rng, tracker):
    ...         loss = float(problem.nll(y, problem.model.render(theta0, 4, 0)))
    ...         return Outcome(theta0, 0, "max-iterations", "no step taken", loss)
    >>> model = nb.scenes.get("edge1d")
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.1))
    >>> fit = KeepStart().fit(problem, model.render([0.5], 4, 0), init=[0.3], rng=np.random.default_rng(0))
    >>> fit.theta, fit.status, fit.renders
    (array([0.3]), 'max-iterations', 1)
    """

    name: ClassVar[str] = ""
    valid_when: ClassVar[str] = ""
    #: "given": start at `init` (or a uniform random point); "profile": at the profile-likelihood minimum over
    #: the problem's bank grid (`profile_start`, no render). Estimators that take a start set it from options.
    start: str = "given"
    #: the seeds a study renders this estimator's grid (`grid_wanted`) with: "common" where its maths needs one
    #: seed across the grid in each set (common random numbers: the surrogate's lattice), whatever the study's
    #: `seeds`; None: the study's
    grid_seeds: ClassVar[str | None] = None

    def fit(self, problem: Problem, y, init=None, rng: np.random.Generator | None = None,
            budget: Budget = Budget()) -> Estimate:
        """θ̂ from the observation y (same shape as a render, radiance units).

        Parameters
        ----------
        problem : Problem
            The model, noise model and gradient settings.
        y : torch.Tensor or array_like
            The observation (H, W, C), radiance units; finite.
        init : array_like, optional
            Start θ (P,) in Θ, or None for a uniform random start drawn from `rng` (ignored with start
            "profile").
        rng : numpy.random.Generator
            Seeded from the experiment seed (starts and render seeds come from it); required.
        budget : Budget, optional
            Limits on the fit; default none.

        Returns
        -------
        Estimate
            θ̂, how the fit stopped and the work it took.

        Raises
        ------
        TypeError
            If `rng` is not a numpy Generator.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy Generator seeded from a derived seed "
                            "(e.g. np.random.default_rng(nlosbench.seeds.derive(seed, purpose, i)))")
        y = torch.as_tensor(y)
        check_finite(y, "observation y")
        if self.start == "profile":
            theta0 = profile_start(problem, y)[0]
        else:
            theta0 = problem.params.sample_uniform(rng) if init is None else problem.params.validate(init)
        tracker = Tracker(problem.model, budget)
        out = self._fit(problem, y, theta0, rng, tracker)
        used = tracker.used()
        return Estimate(theta=problem.params.validate(out.theta), iterations=int(out.iterations),
                        converged=out.status == "converged", reason=out.reason, status=out.status,
                        renders=used.renders,
                        grad_passes=used.grad_passes, samples=used.samples, seconds=tracker.seconds(),
                        final_loss=float(out.final_loss), init=theta0, trace=tracker.trace)

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int] | tuple[np.ndarray, int, int] | \
            list[tuple[np.ndarray, int, int]] | None:
        """A θ grid (G, P) and spp this estimator renders once per process before its fits (None: none), and
        optionally a number K of independent render sets of it (default 1); or a list of such grids (each at its
        own spp). A study with a render bank renders them
        there and passes them as `Problem.grids`, so a grid is made once per run, shared with equal render sets
        (e.g. a bound grid) and counted with the bank's renders; K sets come as one `BankGrid` whose θ are the
        grid repeated K times (K·G, P), set k's renders at rows k·G … (k + 1)·G − 1.

        Parameters
        ----------
        params : ParamSpace
            The parameter space Θ of the problem.

        Returns
        -------
        tuple of (numpy.ndarray, int) or (numpy.ndarray, int, int), or a list of the latter, or None
            The grid (G, P) in parameter units, the spp of its renders and optionally the number of independent
            render sets (or several such grids); None when the estimator needs none.
        """
        return None

    def stand_in(self, params: ParamSpace, theta, gradient: GradientSettings) -> GradientSettings:
        """The gradient setting whose Jacobian noise a predicted variance measures at θ* (a study's
        `predict_jacobians`): the setting's own; an estimator whose slope noise depends on where θ* lies returns the
        one for there (the surrogate's lattice segments).

        Parameters
        ----------
        params : ParamSpace
            The parameter space Θ.
        theta : array_like
            θ* (P,) in parameter units.
        gradient : GradientSettings
            The setting's gradient.

        Returns
        -------
        GradientSettings
            The gradient to measure at θ*.
        """
        return gradient

    @abstractmethod
    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        """The estimator proper: start at θ0 (in Θ), stop when `tracker.exhausted()` says so."""

    #: why `predicted_variance` gives no prediction for this estimator (shown in the summary)
    no_prediction: ClassVar[str] = "the estimator offers no linearised update"

    def predicted_variance(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None = None,
                           budget: Budget = Budget(), statuses: Sequence[str] | None = None) -> Prediction | None:
        """The covariance of θ̂ (P, P, in parts) that this estimator's linearised update predicts at θ*, or None
        (no prediction: `no_prediction` says why). Every linearised estimator aims at the fixed point ê of the
        score on the observation (`predict.target`: F⁻¹ JᵀW (Σ_obs + Σ_truth) WJ F⁻¹); what its own iterations
        leave is `fit_cov`'s. iterations: the fits' iteration counts (None: the estimator's maximum, capped by
        `budget`); statuses: how each of those fits stopped (`Estimate.status`), where the estimator counts an
        iteration that applied no step.

        Parameters
        ----------
        problem : Problem
            The estimation problem (its gradient settings and Θ).
        lin : Linearisation
            The linearisation at θ*: Jacobian, weight, Fisher matrix and the variances of the observation, the
            clean image, the fit renders and the Jacobian noise (`estimators.predict`).
        iterations : sequence of int, optional
            The fits' iteration counts (None: the estimator's maximum, capped by `budget`).
        budget : Budget, optional
            The fits' budget.
        statuses : sequence of str, optional
            How each fit stopped (`Estimate.status`).

        Returns
        -------
        Prediction or None
            The predicted covariance in parts (observation, clean image, fit), parameter units²; None without a
            linearised update.
        """
        fit = self.fit_cov(problem, lin, iterations, budget, statuses)
        if fit is None:
            return None
        obs, truth = target(lin)
        return Prediction(obs, truth, fit[0], fit[1], self.shared_cov(problem, lin))

    def shared_cov(self, problem: Problem, lin: Linearisation) -> np.ndarray | None:
        """The covariance (P, P) of an error of θ̂ that every fit of a run shares, from renders the estimator makes
        once and reuses (None: it has none, the default). It is a bias of the run, not variance: `summarize`
        adds it to the bias test's standard error, as the clean image's Monte Carlo error is there.

        Parameters
        ----------
        problem : Problem
            The estimation problem.
        lin : Linearisation
            The linearisation at θ* (`estimators.predict`).

        Returns
        -------
        numpy.ndarray or None
            (P, P) in parameter units², or None.
        """
        return None

    def fit_cov(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None,
                budget: Budget, statuses: Sequence[str] | None = None) -> tuple[np.ndarray, str] | None:
        """(covariance (P, P) of θ̂ − ê that the estimator's iterations leave, what was assumed), or None when the
        estimator has no linearised update (the default; a plug-in overrides this).

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
        tuple of (numpy.ndarray, str) or None
            The covariance (P, P) in parameter units² and a note of what was assumed; None: no prediction.
        """
        return None

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({opts})"


def check_start(name: str, start: str) -> str:
    """A start option ("given" or "profile"), else ValueError naming the estimator."""
    if start not in ("given", "profile"):
        raise ValueError(f"{name}: start must be 'given' or 'profile', got {start!r}")
    return start


def render_seed(rng: np.random.Generator) -> int:
    """A 32-bit base seed for one fit's renders, drawn from the fit's generator."""
    return int(rng.integers(0, 2**32))


def floored(problem: Problem, L: torch.Tensor) -> torch.Tensor:
    """L with the Poisson policy's floor applied (unchanged for other noise models)."""
    return L.clamp_min(POISSON_FLOOR / problem.noise.scale) if isinstance(problem.noise, Poisson) else L


def nll(problem: Problem, y: torch.Tensor, L: torch.Tensor) -> float:
    """The problem's negative log-likelihood of y at the image L (`Problem.nll`), as a Python float."""
    return float(problem.nll(y, L))


def nll_gradient(problem: Problem, y: torch.Tensor, L: torch.Tensor, J: torch.Tensor) -> np.ndarray:
    """∇_θ NLL = Jᵀ ∂NLL/∂L (float64 (P,), 1/parameter units) from the image L (H, W, C) and its Jacobian J
    (P, H, W, C); the score is its negative."""
    Lg = L.to(torch.float64).requires_grad_(True)
    (dnll,) = torch.autograd.grad(problem.nll(y, Lg), Lg)
    return torch.einsum("p...,...->p", J.double(), dnll).numpy()


def profile_start(problem: Problem, y: torch.Tensor) -> tuple[np.ndarray, int]:
    """(θ0, grid index): the minimum of the NLL of y over the problem's bank grid renders (no render),
    refined for a scalar θ by the vertex of the parabola through the minimum and its two neighbours
    (kept inside them). ValueError when the problem has no bank grid."""
    if problem.bank is None:
        raise ValueError("start: profile needs grid renders from the run (Problem.bank); the trials study "
                         "provides them, a direct fit must pass a BankGrid")
    T, imgs = np.asarray(problem.bank.thetas, dtype=np.float64), problem.bank.images
    prof = np.array([nll(problem, y, L) for L in imgs])
    g = int(np.argmin(prof))
    theta = T[g].copy()
    if T.shape[1] == 1 and 0 < g < len(T) - 1:
        (x0, x1, x2), (f0, f1, f2) = T[g - 1:g + 2, 0], prof[g - 1:g + 2]
        den = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0)
        if den != 0 and np.isfinite(den):
            v = x1 - 0.5 * ((x1 - x0) ** 2 * (f1 - f2) - (x1 - x2) ** 2 * (f1 - f0)) / den
            theta[0] = float(np.clip(v, x0, x2))
    return problem.params.validate(np.clip(theta, problem.params.lower, problem.params.upper)), g


def finite_or_raise(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise FloatingPointError(f"{what} is {value} (e.g. Poisson y > 0 where the render is 0)")
    return value
