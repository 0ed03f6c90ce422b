"""The estimator contract: `fit(problem, y, init, rng, budget) → Estimate`.

A `Problem` bundles what an estimator may use: the forward model (and so Θ), the noise model, the
gradient settings and a seed for renders shared across fits (e.g. cached grid renders). A subclass
of `Estimator` implements `_fit`; the base class validates the inputs, draws a uniform random start
when none is given, enforces the `Budget`, and measures renders and wall time from the model's own
counters, so every estimator is accounted for the same way.
"""
from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from ..diagnostics import resolve_gradient
from ..forward.gradients import GradientSettings
from ..forward.model import ForwardModel, RenderStats
from ..noise import NoiseModel, check_finite
from ..params import ParamSpace


@dataclass(frozen=True)
class Problem:
    """An estimation problem: observations y ~ noise(model.render(θ*)), θ* ∈ model.params.

    gradient: how estimators that need ∂L/∂θ get it (forward.GradientSettings: FD with CRN, AD, mixed,
    or auto — resolved here, once per model, by `diagnostics.resolve_gradient`);
    seed: seed for renders that are the same for every fit (derive it from the experiment seed)."""

    model: ForwardModel
    noise: NoiseModel
    gradient: GradientSettings = field(default_factory=GradientSettings)
    seed: int = 0

    def __post_init__(self):
        object.__setattr__(self, "gradient", resolve_gradient(self.model, self.gradient))

    @property
    def params(self) -> ParamSpace:
        return self.model.params

    def to_unit(self, theta) -> np.ndarray:
        """θ → u = (θ − lower) / (upper − lower) ∈ [0, 1]^P (Θ scaled to the unit box)."""
        p = self.params
        return (np.asarray(theta, dtype=np.float64) - p.lower) / (p.upper - p.lower)

    def from_unit(self, u) -> np.ndarray:
        """u ∈ [0, 1]^P → θ (float64 (P,)), clipped to Θ against rounding."""
        p = self.params
        return np.clip(p.lower + np.asarray(u, dtype=np.float64) * (p.upper - p.lower), p.lower, p.upper)


@dataclass(frozen=True)
class Budget:
    """Limits on one fit (None: no limit). renders counts primal renders plus AD gradient passes;
    an estimator checks the limits before each iteration, so it may overshoot by one iteration."""

    iterations: int | None = None
    renders: int | None = None
    seconds: float | None = None

    def __post_init__(self):
        for k in ("iterations", "renders", "seconds"):
            v = getattr(self, k)
            if v is not None and not v > 0:
                raise ValueError(f"budget {k} must be > 0 or None, got {v!r}")

    def cap(self, iterations: int) -> int:
        """An estimator's own iteration count, capped by this budget."""
        return iterations if self.iterations is None else min(iterations, int(self.iterations))


@dataclass
class Estimate:
    """Result of one fit. theta: θ̂ float64 (P,); renders / grad_passes / samples / seconds: work done
    during the fit (from the model's counters; cached renders cost nothing); converged: the
    estimator's own convergence rule fired (`reason` says which rule stopped it); final_loss: the
    last negative log-likelihood evaluated; trace: one dict per iteration {iteration, loss, theta,
    renders, seconds} with cumulative renders and seconds."""

    theta: np.ndarray
    iterations: int
    converged: bool
    reason: str
    renders: int
    grad_passes: int
    samples: int
    seconds: float
    final_loss: float
    init: np.ndarray
    trace: list[dict] = field(default_factory=list)


class Tracker:
    """Budget and trace bookkeeping for one fit (handed to `Estimator._fit`)."""

    def __init__(self, model: ForwardModel, budget: Budget):
        self.model = model
        self.budget = budget
        self.start = model.stats.snapshot()
        self.t0 = time.perf_counter()
        self.trace: list[dict] = []

    def used(self) -> RenderStats:
        return self.model.stats.since(self.start)

    def seconds(self) -> float:
        return time.perf_counter() - self.t0

    def exhausted(self) -> str | None:
        """Why the budget is used up (render or time limit), or None."""
        b = self.budget
        u = self.used()
        if b.renders is not None and u.renders + u.grad_passes >= b.renders:
            return f"render budget ({b.renders}) used"
        if b.seconds is not None and self.seconds() >= b.seconds:
            return f"time budget ({b.seconds:g} s) used"
        return None

    def record(self, iteration: int, loss: float, theta: np.ndarray) -> None:
        u = self.used()
        self.trace.append({"iteration": int(iteration), "loss": float(loss), "theta": [float(v) for v in theta],
                           "renders": u.renders + u.grad_passes, "seconds": self.seconds()})


@dataclass
class Outcome:
    """What `_fit` returns: θ̂, iterations done, whether it converged and why it stopped, final loss."""

    theta: np.ndarray
    iterations: int
    converged: bool
    reason: str
    final_loss: float


class Estimator(ABC):
    """Base class of estimators. Subclasses set `name` and `valid_when` (when the estimator is the
    right tool, in one or two sentences) and implement `_fit`. Options go to `__init__` as keywords."""

    name: ClassVar[str] = ""
    valid_when: ClassVar[str] = ""

    def fit(self, problem: Problem, y, init=None, rng: np.random.Generator | None = None,
            budget: Budget = Budget()) -> Estimate:
        """θ̂ from the observation y (same shape as a render, radiance units).

        init: start θ (P,) in Θ, or None for a uniform random start drawn from `rng`;
        rng: a numpy Generator seeded from the experiment seed (starts and render seeds come from it)."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy Generator seeded from a derived seed "
                            "(e.g. np.random.default_rng(nlosbench.seeds.derive(seed, purpose, i)))")
        y = torch.as_tensor(y)
        check_finite(y, "observation y")
        theta0 = problem.params.sample_uniform(rng) if init is None else problem.params.validate(init)
        tracker = Tracker(problem.model, budget)
        out = self._fit(problem, y, theta0, rng, tracker)
        used = tracker.used()
        return Estimate(theta=problem.params.validate(out.theta), iterations=int(out.iterations),
                        converged=bool(out.converged), reason=out.reason, renders=used.renders,
                        grad_passes=used.grad_passes, samples=used.samples, seconds=tracker.seconds(),
                        final_loss=float(out.final_loss), init=theta0, trace=tracker.trace)

    @abstractmethod
    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        """The estimator proper: start at θ0 (in Θ), stop when `tracker.exhausted()` says so."""

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({opts})"


def render_seed(rng: np.random.Generator) -> int:
    """A 32-bit base seed for one fit's renders, drawn from the fit's generator."""
    return int(rng.integers(0, 2**32))


def nll(problem: Problem, y: torch.Tensor, L: torch.Tensor) -> float:
    """The noise model's negative log-likelihood of y at the image L, as a Python float."""
    return float(problem.noise.nll(y, L))


def finite_or_raise(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise FloatingPointError(f"{what} is {value} (e.g. Poisson y > 0 where the render is 0)")
    return value
