"""Render sets of the bound service (its module docstring says which): replicate sets, FD stages with their
one-sided variants, the step's halving, the noise models' weights; the argument checks every question shares."""
from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import torch

from nlosbench.bank import RenderBank, Request
from nlosbench.bounds.fd_step import Stage, halving
from nlosbench.noise import NoiseModel, Poisson, QuadraticNoise, bounds_refusal, to_float64

SEEDS = ("independent", "common")
PURPOSE = "bounds"

def poisson_weight_image(L) -> tuple[torch.Tensor, int]:
    """The zero-pixel policy for Monte Carlo means (see the module docstring): L (*S) float64 with every
    exact 0 raised to the smallest positive value, and the number of such pixels."""
    L = to_float64(L, "L").clone()
    zero = L == 0
    n = int(zero.sum())
    if n:
        pos = L[L > 0]
        L[zero] = float(pos.min()) if pos.numel() else 1.0
    return L, n


class RenderSets:
    """The service's state (bank, noise models, parameter space, channel groups, level) and the render sets every
    question asks for; `BoundService` is this with one mixin per question."""

    def __init__(self, bank: RenderBank, noises: dict[int, NoiseModel] | Sequence[NoiseModel], level: float = 0.95):
        if not 0 < level < 1:
            raise ValueError(f"confidence level must lie in (0, 1), got {level}")
        self.bank = bank
        self.noises = dict(noises) if isinstance(noises, dict) else dict(enumerate(noises))
        self.params = bank.model.params
        #: the values per pixel that share path samples (the model's channels): every standard error groups them
        self.group = bank.model.channels
        self.level = float(level)

    def _select(self, noises) -> dict[int, NoiseModel]:
        return self.noises if noises is None else {j: self.noises[j] for j in noises}

    # -- render sets -----------------------------------------------------------------------------------
    def replicates(self, points, spp: int, seeds: str, R: int, desc: str = "bound renders",
                   first: int = 0) -> torch.Tensor:
        """Renders (R, N, *S) of points (N, P) in the R replicate sets first … first + R − 1 (see the module
        docstring).

        Parameters
        ----------
        points : array_like of shape (N, P) or (N,)
            The parameter points, parameter units.
        spp : int
            Samples per pixel of each render.
        seeds : {"common", "independent"}
            "common": every θ of a replicate shares its seed (common random numbers across θ);
            "independent": a seed per θ.
        R : int
            The number of replicate sets (replicate r = 0 … R−1 of purpose "bounds").
        desc : str, optional
            Progress label.
        first : int, default 0
            The first replicate index (a precision target's fresh sets start after the pilot's).

        Returns
        -------
        torch.Tensor of shape (R, N, *S)
            The renders, float32 (as the bank returns them).
        """
        _check(seeds, R)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, self.params.dim)
        return self.bank.sets(pts, spp, PURPOSE, range(first, first + R), seeds == "common", desc)

    def _stencils(self, thetas: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FD stencil points (T, P, 2, P): θ ± ξ e_j clipped into Θ (one-sided at its edge), ξ (T,) one per θ, and
        their separations (T, P)."""
        p = self.params
        T = len(thetas)
        st = np.repeat(thetas[:, None, None, :], 2, axis=2).repeat(p.dim, axis=1)  # (T, P, 2, P)
        for j in range(p.dim):
            st[:, j, 0, j] = np.minimum(thetas[:, j] + xi, p.upper[j])
            st[:, j, 1, j] = np.maximum(thetas[:, j] - xi, p.lower[j])
        sep = np.stack([st[:, j, 0, j] - st[:, j, 1, j] for j in range(p.dim)], axis=1).reshape(T, p.dim)
        if np.any(sep <= 0):
            raise ValueError(f"FD step {xi.tolist()} leaves no room inside Θ")
        return st, sep

    def fd_rounds(self, thetas, spp: int, seeds: str, R: int, step: float) -> torch.Tensor:
        """The R central-FD Jacobian rounds at step ξ that `at` uses for its first FD stage at each θ (the same
        render sets: no new render once `at` ran with these arguments).

        Parameters
        ----------
        thetas : array_like of shape (T, P) or (T,)
            The points θ, parameter units.
        spp : int
            Samples per pixel of each stencil render.
        seeds : {"common", "independent"}
            As in `at`.
        R : int
            The number of rounds (replicate sets 0 … R − 1).
        step : float or array_like of shape (T,)
            The FD step ξ, parameter units (stencils clipped into Θ turn one-sided): one, or one per θ.

        Returns
        -------
        torch.Tensor of shape (R, T, P, N)
            The rounds, float64, pixels flattened (N = H·W·C); units radiance per parameter unit.
        """
        _check(seeds, R)
        pts = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        stages = self._stages(pts, None, spp, seeds, R, step)
        return torch.from_numpy(np.stack([s.rounds["central"] for s in stages], axis=1))

    def _stages(self, thetas: np.ndarray, center: torch.Tensor | None, spp: int, seeds: str, R: int,
                step, first: int = 0, purpose: str = PURPOSE, sided: bool = True) -> list[Stage]:
        """One FD Stage at step ξ (one for all, or one per θ) per θ of thetas (T, P), R rounds, each independent of
        the others and with common random numbers inside each stencil: the central differences of round r's stencil
        renders (θ ± ξ e_j clipped into Θ) and, from a render of θ under the stencil's seed, the forward and backward
        differences —
        the one-sided variants the step check needs near a kink (`fd_step`). Common seeds: round r is replicate
        set r (every θ shares its seed) and θ's render is `center` (R, T, *S) of the same replicates (None: no
        one-sided variants); independent seeds: a seed per θ and round, shared by its stencil and θ's own render
        (purpose `purpose` + "-stencil", not by other θ), the same at every step, so stages pair; `sided` False
        leaves θ's render out (one step, no check: the one-sided variants would decide nothing; with common seeds
        `center` costs nothing and is used regardless). Rounds are the replicate sets first … first + R − 1."""
        T, P = thetas.shape
        xi = per_theta(step, T)
        st, sep = self._stencils(thetas, xi)
        if seeds == "independent":
            own = 1 if sided else 0
            reqs = [Request.of(pt, spp, self.bank.seed(purpose + "-stencil", spp, thetas[t], r))
                    for r in range(first, first + R) for t in range(T)
                    for pt in itertools.chain([thetas[t]] * own, st[t].reshape(2 * P, P))]
            imgs = self.bank.images(reqs, "FD stencil renders").double().reshape(R, T, own + 2 * P, -1)
            X, center = imgs[:, :, own:].reshape(R, T, P, 2, -1), (imgs[:, :, 0] if sided else None)
        else:
            X = self.replicates(st.reshape(-1, P), spp, seeds, R, "FD stencil renders", first).double().reshape(
                R, T, P, 2, -1)
        diag = np.arange(P)
        out = []
        for t in range(T):
            rounds = {"central": _diff(X[:, t, :, 0], X[:, t, :, 1], sep[t])}
            if center is not None:
                c = center[:, t].reshape(R, 1, -1)
                fwd, bwd = st[t, diag, 0, diag] - thetas[t], thetas[t] - st[t, diag, 1, diag]
                if np.all(fwd > 0):
                    rounds["forward"] = _diff(X[:, t, :, 0], c, fwd)
                if np.all(bwd > 0):
                    rounds["backward"] = _diff(c, X[:, t, :, 1], bwd)
            out.append(Stage(float(xi[t]), rounds, self.group))
        return out

    def _refine(self, thetas: np.ndarray, stage_fn, weights: dict, step, step_tol,
                max_halvings: int) -> list[list[Stage]]:
        """FD stages (coarse to fine) per θ of thetas (T, P): ξ, then ξ/2, ξ/4 … (ξ one step, or one per θ) for
        the θ whose last check is, for some weight in `weights` ({noise index: [w per θ]}), neither steady nor
        hopeless (`fd_step.halving` at that θ's `step_tol`, one for all or one per θ: converged and not falling; an
        SE no halving can shrink), at most `max_halvings` times. stage_fn(index array, ξ (one per index)) gives the
        stages of those θ."""
        _check_step(step, step_tol, max_halvings, tol_per_theta=True)
        xi, tol = per_theta(step, len(thetas)), per_theta(step_tol, len(thetas), "step_tol", "tolerance")
        stages: list[list[Stage]] = [[] for _ in thetas]
        active = np.arange(len(thetas))
        for k in range(max_halvings + 1):
            for i, stage in zip(active, stage_fn(active, xi[active] / 2**k), strict=True):
                stages[i].append(stage)
            if k == max_halvings:
                break
            if k:
                active = np.array([i for i in active if not all(
                    halving(stages[i][-2], stages[i][-1], w[i], self.level, float(tol[i])).stops
                    for w in weights.values())], dtype=np.int64)
                if active.size == 0:
                    break
        return stages

    def _weights(self, thetas: np.ndarray, spp: int, mean_images: torch.Tensor, noises) -> dict:
        """{noise index: [(weight (N,) float64 or a scalar, flags) per θ]}: AWGN 1/σ²; Poisson scale/Y under the
        zero-pixel policy (any model whose weight is `signal_dependent`: w(Y)), Y an independent render of θ
        (purpose "bounds-weight", spp) — never the replicates
        the U-statistics use, so the weight is independent of them (E[1/Y] ≥ 1/L: the weight errs high, by
        about Var(Y)/L², which raises λ̂ and F̂ and so lowers the bounds' ends). mean_images (T, *S): the
        images AWGN weights are taken at (any: the weight is constant)."""
        sel = self._select(noises)
        Y = None
        if any(n.signal_dependent for n in sel.values()):
            Y = self.bank.at(thetas, spp, PURPOSE + "-weight", desc="weight renders").double()
        out = {}
        for j, noise in sel.items():
            rows = []
            for i in range(len(thetas)):
                w, flags = self._weight(noise, Y[i] if noise.signal_dependent else mean_images[i])
                shape = mean_images.shape[1:]
                rows.append((to_float64(w).expand(shape).reshape(-1).numpy(), flags))
            out[j] = rows
        return out

    def _weight(self, noise: NoiseModel, image) -> tuple[object, tuple]:
        """(per-pixel weight for λ and F at an image, flags): AWGN 1/σ²; Poisson scale/L under the zero-pixel
        policy."""
        if isinstance(noise, Poisson):
            L, n = poisson_weight_image(image)
            return noise.weight(L), ((f"zero-pixels={n}",) if n else ())
        if isinstance(noise, QuadraticNoise):
            return noise.weight(to_float64(image)), ()
        raise TypeError(bounds_refusal(noise))


class _FixedWeight(QuadraticNoise):
    """A quadratic noise model with a given per-pixel weight (λ = Σ w (L1 − L0)²), so λ and Grams of
    Monte Carlo renders use the zero-pixel policy's weight instead of one computed from L0."""

    def __init__(self, w: torch.Tensor):
        self.w = w

    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        return self.w.to(L0.device)

    def sample(self, L, generator):  # pragma: no cover - a weight carrier, not an observation model
        raise NotImplementedError

    def nll(self, y, L):  # pragma: no cover
        raise NotImplementedError


def _diff(a: torch.Tensor, b: torch.Tensor, sep) -> np.ndarray:
    """FD rounds (R, P, N) (a − b) / sep from renders a, b (R, P or 1, *S) float64 and separations (P,)."""
    d = a - b
    P = len(sep)
    return (d / torch.as_tensor(np.asarray(sep, dtype=np.float64)).reshape(1, P, *([1] * (d.ndim - 2)))
            ).reshape(d.shape[0], P, -1).numpy()


def _flat(J: torch.Tensor) -> np.ndarray:
    """One-parameter FD rounds (R, *S) as (R, 1, N) float64."""
    return J.reshape(J.shape[0], 1, -1).double().numpy()


def _check_step(step, step_tol, max_halvings, tol_per_theta: bool = False) -> None:
    """ValueError unless `step` is a positive number (or a sequence of them: one per θ), `step_tol` one (a sequence
    too where `tol_per_theta`) and max_halvings an integer in [0, 12]."""
    if not _positive(step):
        raise ValueError(f"fd_step must be a positive number of parameter units (or one per θ), got {step!r}")
    if not _positive(step_tol) or (not tol_per_theta and isinstance(step_tol, (list, tuple, np.ndarray))):
        raise ValueError(f"step_tol must be a positive number (e.g. 0.1: F within 10 %)"
                         f"{' or one per θ' if tol_per_theta else ''}, got {step_tol!r}")
    if isinstance(max_halvings, bool) or int(max_halvings) != max_halvings or not 0 <= max_halvings <= 12:
        raise ValueError(f"max_halvings must be an integer in [0, 12], got {max_halvings!r}")


def _positive(value) -> bool:
    """Whether `value` is a finite number > 0, or a non-empty sequence of them."""
    values = value if isinstance(value, (list, tuple, np.ndarray)) else [value]
    return len(values) > 0 and all(isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
                                   and math.isfinite(v) and v > 0 for v in values)


def per_theta(value, T: int, name: str = "fd_step", what: str = "step") -> np.ndarray:
    """A value (an FD step, a step tolerance) for each of T points (T,): one for all, or one per θ (checked by
    `_check_step`)."""
    values = np.asarray(value, dtype=np.float64).reshape(-1)
    if values.size not in (1, T):
        raise ValueError(f"{name}: one {what} or one per θ ({T}), got {values.size}")
    return np.broadcast_to(values, (T,)).copy()


def _need_replicates(R) -> int:
    if isinstance(R, bool) or int(R) != R or R < 2:
        raise ValueError(f"bounds from replicated renders need replicates >= 2 (U-statistics; >= 3 for confidence "
                         f"limits), got {R!r}")
    return int(R)


def _check(seeds: str, replicates: int) -> None:
    if seeds not in SEEDS:
        raise ValueError(f"seeds must be one of {list(SEEDS)}, got {seeds!r}")
    if isinstance(replicates, bool) or int(replicates) != replicates or replicates < 1:
        raise ValueError(f"replicates must be a positive integer, got {replicates!r}")

