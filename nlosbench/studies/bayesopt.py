"""Bayesian optimisation of a noisy score over a box, each evaluation's standard error its known noise, and a
replay harness that measures how often it finds the optimum.

`Search` minimises y(x), e.g. log10 of a camera offset's A-optimal score tr F̂⁻¹ (x in metres), asked and told
in batches: a scrambled Sobol design over the box first (nothing else informs it), then BoTorch's
`SingleTaskGP` with `train_Yvar` = the evaluations' squared standard errors (fixed, heteroscedastic noise) and
`qLogNoisyExpectedImprovement`. What it returns is the evaluated point with the lowest posterior mean (noise-
aware: not the lowest noisy value). An evaluation without a finite value (F̂ not positive definite: no resolved
information) enters the model as the worst finite value seen, and one without a standard error with the largest
variance seen (both stated, not hidden: the caller keeps the raw values). BoTorch is the optional extra
`search` (`pip install 'nlosbench[search]'`), imported only here.

`replay` runs seeded searches on a known objective with Gaussian evaluation noise of a known SD and counts the
successes (with the Clopper–Pearson interval); `grid_objective` turns a grid of measured scores and their SEs
(a resolved `viewpoints` map: `read_grid`) into such an objective by interpolation.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import read_csv

EXTRA = "search"
#: the smallest variance (log10 units²) an evaluation enters the model with (numerical floor)
MIN_VARIANCE = 1e-8


def botorch_modules() -> dict:
    """BoTorch's pieces the search uses; ImportError in one line naming the extra when it is not installed."""
    try:
        from botorch.acquisition.logei import qLogNoisyExpectedImprovement
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskGP
        from botorch.models.transforms import Standardize
        from botorch.optim import optimize_acqf
        from botorch.sampling import SobolQMCNormalSampler
        from gpytorch.mlls import ExactMarginalLogLikelihood
    except ImportError:
        raise ImportError(f"the viewpoint search needs BoTorch: pip install 'nlosbench[{EXTRA}]'") from None
    return {"gp": SingleTaskGP, "standardize": Standardize, "fit": fit_gpytorch_mll, "mll": ExactMarginalLogLikelihood,
            "acq": qLogNoisyExpectedImprovement, "optimize": optimize_acqf, "sampler": SobolQMCNormalSampler}


@contextmanager
def _one_thread(seed: int) -> Iterator[None]:
    """torch on one thread (a GP of tens of points: more threads only add overhead, ×3 CPU time measured) with its
    random state forked and seeded, both restored on exit."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.random.fork_rng():
            torch.manual_seed(seed % 2**31)
            yield
    finally:
        torch.set_num_threads(threads)


def check_box(box) -> np.ndarray:
    """The search box (D, 2) of [low, high] per axis, as float64; ValueError unless finite with low < high."""
    b = np.asarray(box, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1 or not np.all(np.isfinite(b)) or np.any(b[:, 0] >= b[:, 1]):
        raise ValueError(f"box must be [[low, high], ...] with finite low < high per axis, got {box!r}")
    return b


class Search:
    """Ask-and-tell Bayesian optimisation minimising a noisy y(x) over a box (see the module docstring).

    Parameters
    ----------
    box : array_like of shape (D, 2)
        [low, high] per axis, in x's units (metres for camera offsets).
    initial : int
        Points of the Sobol design before the first model-guided batch (≥ 2).
    seed : int
        Seeds the Sobol design and every acquisition optimisation (the same seed and told values: the same asks).
    raw_samples, restarts, mc_samples, maxiter : int, optional
        The acquisition optimiser's random starts, the gradient restarts taken from them, the acquisition's
        quasi-Monte Carlo samples and the optimiser's iterations per restart (the defaults: a fraction of a second
        per batch on one core; an evaluation that renders costs minutes).
    """

    def __init__(self, box, initial: int, seed: int, raw_samples: int = 32, restarts: int = 2, mc_samples: int = 32,
                 maxiter: int = 50):
        self.mods = botorch_modules()
        self.box = check_box(box)
        if initial < 2:
            raise ValueError(f"the initial design needs >= 2 points, got {initial}")
        self.initial, self.seed = int(initial), int(seed)
        self.raw_samples, self.restarts, self.mc_samples, self.maxiter = raw_samples, restarts, mc_samples, maxiter
        self.X = np.empty((0, len(self.box)))
        self.y = np.empty(0)
        self.se = np.empty(0)
        self.phase: list[str] = []
        self._sobol = None

    def __len__(self) -> int:
        return len(self.y)

    def _unit(self, X: np.ndarray) -> np.ndarray:
        return (X - self.box[:, 0]) / (self.box[:, 1] - self.box[:, 0])

    def _scale(self, U: np.ndarray) -> np.ndarray:
        return self.box[:, 0] + U * (self.box[:, 1] - self.box[:, 0])

    def ask(self, q: int) -> tuple[np.ndarray, str]:
        """The next q points (q, D) and their phase: "sobol" while the initial design (or any finite value) is
        missing, then "bo" (one `qLogNoisyExpectedImprovement` batch)."""
        import torch

        if q < 1:
            raise ValueError(f"ask for >= 1 point, got {q}")
        if len(self) < self.initial or not np.any(np.isfinite(self.y)):
            if self._sobol is None:
                self._sobol = torch.quasirandom.SobolEngine(len(self.box), scramble=True, seed=self.seed)
                self._sobol.fast_forward(len(self))
            n = min(q, self.initial - len(self)) if len(self) < self.initial else q
            return self._scale(self._sobol.draw(n).double().numpy()), "sobol"
        m = self.mods
        with _one_thread(self.seed * 1_000_003 + len(self)):
            model, U = self._model()
            acq = m["acq"](model, U, sampler=m["sampler"](torch.Size([self.mc_samples])), prune_baseline=True)
            cube = torch.stack([torch.zeros(len(self.box)), torch.ones(len(self.box))]).double()
            cand, _ = m["optimize"](acq, cube, q=q, num_restarts=self.restarts, raw_samples=self.raw_samples,
                                    options={"maxiter": self.maxiter})
        return self._scale(cand.detach().numpy()), "bo"

    def tell(self, X, y, se, phase: str) -> None:
        """Add evaluations: points X (n, D), values y (n,) (+inf: unresolved) and their standard errors se (n,)
        (NaN: unknown), from the phase `ask` gave."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, len(self.box))
        y, se = np.asarray(y, dtype=np.float64).reshape(-1), np.asarray(se, dtype=np.float64).reshape(-1)
        if not len(X) == len(y) == len(se):
            raise ValueError(f"tell X, y and se of one length, got {len(X)}, {len(y)}, {len(se)}")
        self.X, self.y, self.se = np.vstack([self.X, X]), np.concatenate([self.y, y]), np.concatenate([self.se, se])
        self.phase += [phase] * len(y)

    def model_data(self) -> tuple[np.ndarray, np.ndarray]:
        """(values, variances) (n,) as the model sees them: a non-finite value as the worst finite one, an unknown
        or non-finite SE as the largest finite variance (1 without any), every variance ≥ `MIN_VARIANCE`."""
        finite = np.isfinite(self.y)
        if not finite.any():
            raise ValueError("no evaluation has a finite value yet")
        y = np.where(finite, self.y, self.y[finite].max())
        v = self.se ** 2
        ok = np.isfinite(v) & finite
        v = np.where(ok, v, v[ok].max() if ok.any() else 1.0)
        return y, np.maximum(v, MIN_VARIANCE)

    def _model(self):
        """The fitted GP of −y over the unit cube (BoTorch maximises) and the training inputs, torch float64."""
        import torch

        m = self.mods
        y, v = self.model_data()
        U = torch.from_numpy(self._unit(self.X))
        gp = m["gp"](U, torch.from_numpy(-y)[:, None], train_Yvar=torch.from_numpy(v)[:, None],
                     outcome_transform=m["standardize"](1))
        m["fit"](m["mll"](gp.likelihood, gp))
        return gp, U

    def recommend(self) -> tuple[np.ndarray, float, float]:
        """The evaluated point (D,) with the lowest posterior mean of y, that mean and its posterior SD."""
        import torch

        with _one_thread(self.seed):
            model, U = self._model()
            with torch.no_grad():
                post = model.posterior(U)
        mean = -post.mean.squeeze(-1).numpy()
        sd = post.variance.squeeze(-1).clamp_min(0).sqrt().numpy()
        k = int(np.argmin(mean))
        return self.X[k].copy(), float(mean[k]), float(sd[k])


def run_search(objective: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], box, evaluations: int,
               initial: int, seed: int, batch: int = 1) -> Search:
    """A search to `evaluations` evaluations of objective(X (q, D)) → (y (q,), se (q,)), in batches of `batch`."""
    s = Search(box, initial, seed)
    while len(s) < evaluations:
        X, phase = s.ask(min(batch, evaluations - len(s)))
        y, se = objective(X)
        s.tell(X, y, se, phase)
    return s


@dataclass
class Replays:
    """Seeded replays of a search: found (n, D) the recommended points, success (n,) bool; each attribute as
    named."""

    found: np.ndarray
    success: np.ndarray

    @property
    def rate(self) -> float:
        return float(self.success.mean())

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        """The Clopper–Pearson (exact binomial) two-sided `level` interval of the success probability."""
        from scipy.stats import binomtest

        ci = binomtest(int(self.success.sum()), len(self.success)).proportion_ci(level, method="exact")
        return float(ci.low), float(ci.high)


def replay(mean: Callable[[np.ndarray], np.ndarray], sd: Callable[[np.ndarray], np.ndarray], box,
           success: Callable[[np.ndarray], bool], replays: int, evaluations: int, initial: int, seed: int = 0,
           batch: int = 1) -> Replays:
    """Seeded searches of an objective with known noise: each evaluation of x returns mean(x) + sd(x)·N(0, 1)
    with its SE sd(x) (the search's known noise); replay k draws its noise and its Sobol scramble from (seed, k).

    Parameters
    ----------
    mean, sd : callable
        x (q, D) → (q,): the noise-free objective (log10 units) and the evaluation noise's SD.
    box : array_like of shape (D, 2)
        The search box.
    success : callable
        x (D,) → bool: whether a recommended point counts as found (e.g. within a distance of the optimum).
    replays, evaluations, initial, batch : int
        Replays; evaluations per replay; its Sobol design; points per batch.
    seed : int, optional
        The replays' base seed.

    Returns
    -------
    Replays
        The recommended points and which succeeded.
    """
    found, ok = [], []
    for k in range(replays):
        g = np.random.default_rng([seed, k])

        def objective(X: np.ndarray, g=g) -> tuple[np.ndarray, np.ndarray]:
            s = sd(X)
            return mean(X) + s * g.standard_normal(len(X)), s

        x = run_search(objective, box, evaluations, initial, seed * 100_003 + k, batch).recommend()[0]
        found.append(x)
        ok.append(bool(success(x)))
    return Replays(np.array(found), np.array(ok))


def grid_objective(u0: np.ndarray, u1: np.ndarray, values: np.ndarray, se: np.ndarray
                   ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """(mean, sd) callables x (q, 2) → (q,) interpolating (linearly) a grid of measured values (n0, n1) over
    offsets u0 (n0,), u1 (n1,) [m] and their SEs; an unresolved cell (non-finite value) counts as the worst
    finite value, an unknown SE as the largest finite one."""
    from scipy.interpolate import RegularGridInterpolator

    v, s = np.asarray(values, dtype=np.float64), np.asarray(se, dtype=np.float64)
    if v.shape != (len(u0), len(u1)) or s.shape != v.shape:
        raise ValueError(f"values and se must have shape ({len(u0)}, {len(u1)}), got {v.shape} and {s.shape}")
    if not np.isfinite(v).any() or not np.isfinite(s).any():
        raise ValueError("the grid has no finite value or no finite SE")
    v = np.where(np.isfinite(v), v, v[np.isfinite(v)].max())
    s = np.where(np.isfinite(s), s, s[np.isfinite(s)].max())
    fm = RegularGridInterpolator((u0, u1), v)
    fs = RegularGridInterpolator((u0, u1), s)
    return (lambda X: fm(np.asarray(X, dtype=np.float64).reshape(-1, 2)),
            lambda X: fs(np.asarray(X, dtype=np.float64).reshape(-1, 2)))


def read_grid(path: str | Path, noise: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A `viewpoints` run's A-optimal score map for one noise model from its viewpoints.csv: offsets u0 (n0,),
    u1 (n1,) [m], log10 tr F̂⁻¹ (n0, n1) and its log10 SE (n0, n1) (NaN where a cell is missing)."""
    rows = [r for r in read_csv(Path(path)) if r["noise"] == noise]
    if not rows or "log10_score" not in rows[0]:
        raise ValueError(f"{path} has no A-optimal scores for noise {noise!r}")
    u0 = np.unique([float(r["offset_0"]) for r in rows])
    u1 = np.unique([float(r["offset_1"]) for r in rows])
    val, se = np.full((len(u0), len(u1)), np.nan), np.full((len(u0), len(u1)), np.nan)
    for r in rows:
        i, j = int(np.searchsorted(u0, float(r["offset_0"]))), int(np.searchsorted(u1, float(r["offset_1"])))
        val[i, j], se[i, j] = float(r["log10_score"]), float(r["log10_score_se"])
    return u0, u1, val, se


def grid_replays(path: str | Path, noise: str, replays: int = 50, evaluations: int = 24, initial: int = 8,
                 quantile: float = 0.05, seed: int = 0, batch: int = 1) -> Replays:
    """Replays of the search on a resolved grid's interpolant with its measured noise (`read_grid`,
    `grid_objective`): a replay succeeds when the interpolated score at the view it returns is at most the grid's
    `quantile` of the finite scores."""
    u0, u1, val, se = read_grid(path, noise)
    mean, sd = grid_objective(u0, u1, val, se)
    cut = float(np.quantile(val[np.isfinite(val)], quantile))
    box = [[u0[0], u0[-1]], [u1[0], u1[-1]]]
    return replay(mean, sd, box, lambda x: bool(mean(x)[0] <= cut), replays, evaluations, initial, seed, batch)

