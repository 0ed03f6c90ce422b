"""Bound curves over a 1-D grid (`BoundService.curve`): every bound at each grid θ from R·G renders, the ZZB over
the grid's range, and with a precision target the quoted bounds through `at`."""
from __future__ import annotations

import math

import numpy as np
import torch

from nlosbench.bounds.fd_step import Stage, converge
from nlosbench.bounds.grid import pairwise_lambda
from nlosbench.bounds.hcr import hcr_from_lambda
from nlosbench.bounds.hcr_interval import hcr_interval
from nlosbench.bounds.precision import MAX_PREDICT, Precision, Raw, check_precision, plan, reached, spending
from nlosbench.bounds.service.points import (
    Bound,
    BoundPoint,
    Curve,
    _barankin,
    crlb_bound,
    hcr_bound,
    interval_bound,
)
from nlosbench.bounds.service.renders import (
    PURPOSE,
    RenderSets,
    _check_step,
    _diff,
    _flat,
    _need_replicates,
)
from nlosbench.bounds.ustat import pairwise_ustat, pixel_ustat
from nlosbench.bounds.zzb import bhattacharyya_ustat, uniform_spacing, zzb_interval
from nlosbench.noise import AWGN, NoiseModel, Poisson

#: test points over Θ of the bounds a curve quotes when its grid is not `params.grid(G)`
QUOTE_TEST_GRID = 21


def quote_test_grid(params, thetas) -> int:
    """The test grid (points over Θ) of the bounds `BoundService.curve` quotes with a precision target.

    Parameters
    ----------
    params : ParamSpace
        The model's parameter space Θ (one parameter).
    thetas : array_like of shape (G,)
        The curve's increasing grid, parameter units.

    Returns
    -------
    int
        G when the grid is `params.grid(G)` (within 1e-9 of Θ's width: every test point is a curve render), else
        `QUOTE_TEST_GRID`.
    """
    T = np.asarray(thetas, dtype=np.float64).reshape(-1)
    on = np.allclose(params.grid(len(T))[:, 0], T, rtol=0, atol=1e-9 * float(params.upper[0] - params.lower[0]))
    return len(T) if on else QUOTE_TEST_GRID


class Curves(RenderSets):
    """`curve` (the service's module docstring)."""

    def curve(self, thetas, spp: int, seeds: str = "common", replicates: int = 3, crlb: bool = True,
              barankin: bool = False, zzb: bool = True, prior=None, noises=None, fd_step: float | None = None,
              gradient: str = "fd", ad: dict | None = None, check_step: bool = True, step_tol: float = 0.1,
              precision=None, budget: int | None = None, looks: int = 2, quote=None,
              max_halvings: int = 3, offsets: int = 4, quote_step=None, quote_step_tol=None,
              predict=None) -> Curve:
        """Every bound at each θ of a 1-D grid (G,) over Θ from R·G renders; with a precision target, the
        interval bounds at the θ it quotes to that target.

        The HCR interval (test points: the other grid points inside Θ, and Δ → 0), the CRLB, the paper's
        HCR_Neff, optionally Barankin, and on a uniform grid the ZZB over the grid's range. The Δ → 0
        term's Jacobian: FD from the grid neighbours (fd_step None with common seeds: no extra render; the
        step h checked against 2h, with the one-sided neighbour differences as variants), FD at θ ± ξ (with
        independent seeds ξ defaults to the grid's smallest spacing; 2R renders per θ, checked against ξ/2
        with 2R more unless `check_step` is off), or with gradient "ad" Mitsuba AD with integrator options
        `ad`. A curve does not refine its step further (`at` does, and so do the bounds it quotes): where the
        check does not show F converged within 1 + `step_tol`, the Δ → 0 ends are labelled. Poisson
        weights come from one independent render per grid θ.

        With a `precision` target p, after the curve: the bounds at each θ of `quote` from `at` with the same spp,
        seeds and replicates (so its pilot reuses the curve's renders wherever its points coincide: a θ on the
        grid, and every test point when the test grid is the curve's), the kinds hcr (with its hcr_neff) and crlb
        (hcr only when `crlb` is off), its test grid the curve's when the grid is `params.grid(G)`
        (`quote_test_grid`), `offsets` axis offsets, its first FD step `quote_step`, else `fd_step`, else the grid's
        smallest spacing,
        halved at most `max_halvings` times, and fresh replicate sets where an interval is wider than ±p
        (`bounds.precision`), in `Curve.precise`.

        With a `predict` target p (nothing rendered for it), each grid point's `precision` record says whether the
        curve's own sets met ±p and, where not, how many fresh replicate sets of the whole grid the planning model
        (`bounds.precision.plan`, from the curve's sets) predicts would: one such set serves every grid θ, so what
        the curve would cost at p is the largest prediction (`predicted`).

        Parameters
        ----------
        thetas : array_like of shape (G,)
            At least 3 increasing grid points of the (scalar) parameter, parameter units.
        spp : int
            Samples per pixel of each replicate render.
        seeds : {"common", "independent"}, optional
            Common random numbers across θ within a replicate, or a seed per θ.
        replicates : int, optional
            R ≥ 2 independent replicates per grid point (≥ 3 for confidence limits).
        crlb : bool, optional
            Report the CRLB.
        barankin : bool, optional
            Report the plug-in Barankin bound.
        zzb : bool, optional
            Report the ZZB (uniform grids only).
        prior : array_like of shape (G,), optional
            The ZZB's prior density on the grid; None: uniform.
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute bounds for; None: every model.
        fd_step : float, optional
            FD step ξ in parameter units; None: the grid neighbours (common seeds) or the grid's smallest
            spacing (independent seeds).
        gradient : {"fd", "ad"}, optional
            How the Δ → 0 term's Jacobian is computed.
        ad : dict, optional
            Integrator options for gradient "ad".
        check_step : bool, optional
            With explicit FD stencils, also render at ξ/2 to check the step.
        step_tol : float, optional
            Relative tolerance of the step check (0.1: F within 10 %).
        precision : float or array_like of shape (Q,), optional
            The target p > 0 of the quoted bounds (relative half-width, linear units; as in `at`), one for every
            quoted θ or one each; None: no quoted bounds.
        budget : int, optional
            A cap on the pixel-samples (spp × H × W × renders) the quoted bounds may spend beyond the curve's
            renders (with a precision target only); None: the default ceiling, `bounds.precision.CEILING` × the
            quoted bounds' pilot's.
        looks : int, optional
            K ≥ 1: the pilot and at most K − 1 fresh looks for each quoted θ*, each on sets of its own; α spent
            along the path (the pilot α/20, the fresh looks the rest: `bounds.precision.spending`).
        quote : array_like of shape (Q,), optional
            The θ to quote (on or off the grid, inside Θ), parameter units; None: every grid θ (with a precision
            target only).
        max_halvings : int, optional
            The most halvings of the quoted bounds' FD step, in [0, 12].
        offsets : int, optional
            The quoted bounds' axis offsets ±ξ·2^k (k < offsets) per side as extra HCR test points (`at`); 0: the
            curve's grid Δ and Δ → 0 only.
        quote_step : float or array_like of shape (Q,), optional
            The quoted bounds' first FD step ξ (halved per θ until F settles), one for all or one per quoted θ;
            None: `fd_step`, else the grid's smallest spacing. Where L(θ) is smooth over centimetres a large start
            costs the fewest renders; where an edge crosses pixels a small one saves the halvings down to it.
        quote_step_tol : float or array_like of shape (Q,), optional
            The quoted bounds' step tolerance, one for all or one per quoted θ; None: `step_tol`.
        predict : float or array_like of shape (G,), optional
            A target p > 0 (relative half-width, linear units; one, or one per grid θ) for the curve's own points:
            their `precision` records with the fresh sets of the whole grid predicted to meet it (FD gradients only).

        Returns
        -------
        Curve
            A BoundPoint per (noise, θ), noise-major, the ZZB per noise index, and with a precision target the
            quoted BoundPoints (`precise`).
        """
        if self.params.dim != 1:
            raise ValueError(f"a bound curve needs one parameter; the model has {list(self.params.names)}")
        T = np.asarray(thetas, dtype=np.float64).reshape(-1)
        if T.size < 3 or np.any(np.diff(T) <= 0):
            raise ValueError("a bound curve needs at least 3 increasing grid points")
        R = _need_replicates(replicates)
        _check_step(fd_step or 1.0, step_tol, max_halvings)
        quote_tol = step_tol if quote_step_tol is None else quote_step_tol
        _check_step(1.0 if quote_step is None else quote_step, quote_tol, max_halvings, tol_per_theta=True)
        if isinstance(offsets, bool) or not isinstance(offsets, (int, np.integer)) or offsets < 0:
            raise ValueError(f"offsets must be an integer >= 0, got {offsets!r}")
        kinds = ("hcr", "crlb") if crlb else ("hcr",)
        check_precision(precision, budget, looks, kinds, R)
        if predict is not None:
            check_precision(predict, None, looks, kinds, R)
            if gradient != "fd":
                raise ValueError("predict: the cost of more sets is predicted for FD gradients only (an AD pass is not "
                                 "a render)")
            if np.size(predict) not in (1, T.size):
                raise ValueError(f"predict: one target or one per grid θ ({T.size}), got {np.size(predict)}")
        if quote is not None and precision is None:
            raise ValueError("quote needs a precision target (precision=...)")
        quoted = T if quote is None else np.array(
            [self.params.validate([t])[0] for t in np.asarray(quote, dtype=np.float64).reshape(-1)])
        if quoted.size == 0:
            raise ValueError("quote must hold at least one θ (None: every grid θ)")
        if precision is not None and np.size(precision) not in (1, quoted.size):
            raise ValueError(f"precision: one target or one per quoted θ ({quoted.size}), got {np.size(precision)}")
        Xd = self.replicates(T, spp, seeds, R, "bound-curve renders").double()  # (R, G, *S)
        G = len(T)
        stages = self._curve_stages(T, Xd, spp, seeds, R, fd_step, gradient, ad, check_step)
        lo, hi = self.params.lower[0], self.params.upper[0]
        pooled = Xd.mean(dim=0)
        weights = self._weights(T[:, None], spp, pooled, noises)
        zzb_reason = ""
        try:
            uniform_spacing(T)
        except ValueError as e:
            zzb_reason = str(e)
        selected = self._select(noises)
        Wflat = {j: np.stack([w for w, _ in weights[j]]) for j in selected}  # (G, N) per noise model
        plugs = {j: pairwise_lambda(pooled, noise) if not isinstance(noise, Poisson) else
                 _plugin_poisson(pooled, Wflat[j]) for j, noise in selected.items()}
        goal = None if predict is None else np.broadcast_to(np.asarray(predict, dtype=np.float64).reshape(-1), (G,))
        per_set = None if predict is None else G * (1 + (0 if fd_step is None and seeds == "common" else
                                                         2 * len(stages[0]) + (seeds == "independent")))
        points: dict[tuple[int, int], BoundPoint] = {}
        for g, t in enumerate(T):
            others = np.flatnonzero(np.arange(G) != g)
            deltas = T[others] - t
            D = (Xd[:, others] - Xd[:, g:g + 1]).reshape(R, G - 1, -1).numpy()  # replicate differences (R, G − 1, N)
            raws = []
            for j, noise in selected.items():
                w, flags = weights[j][g]
                sf = converge(stages[g], w, self.level, step_tol, spp)
                # row g of the pairwise λ (`pairwise_ustat`), with the per-pixel terms the lower end's joint level uses
                sub = pixel_ustat(D, w, self.group)
                b: dict[str, Bound] = {}
                b["hcr"] = interval_bound(hcr_interval(sub, deltas, sf, self.level, lo - t, hi - t), flags, sf)
                if crlb:
                    b["crlb"] = crlb_bound(sf, self.level, flags)
                b["hcr_neff"] = hcr_bound(hcr_from_lambda(plugs[j][g, others], deltas, lo - t, hi - t))
                if barankin:
                    b["barankin"] = _barankin(pooled[g], pooled[others], deltas, noise, lo - t, hi - t)
                points[j, g] = BoundPoint(j, str(noise), np.array([t]), b)
                if goal is not None:  # what the prediction's plan needs
                    raws.append(Raw(D, sub, sf, stages[g], w, deltas, lo - t, hi - t, int(np.prod(Xd.shape[2:4])),
                                    self.group))
            if goal is not None:
                mine = [points[j, g] for j in selected]
                for pt, pr in zip(mine, predicted(mine, raws, kinds, float(goal[g]), self.level, R, per_set, spp),
                                  strict=True):
                    pt.precision = pr
        zzbs = {j: self._zzb(Xd, T, noise, Wflat[j], prior, spp)
                if zzb and not zzb_reason else None for j, noise in selected.items()}
        precise = [] if precision is None else self.at(
            quoted[:, None], spp, kinds, seeds, R, quote_test_grid(self.params, T), offsets,
            fd_step=quote_step if quote_step is not None else fd_step or float(np.diff(T).min()), noises=noises,
            step_tol=quote_tol, max_halvings=max_halvings, precision=precision, budget=budget, looks=looks)
        return Curve([points[j, g] for j in selected for g in range(G)], zzbs, zzb_reason, precise)

    def _curve_stages(self, T: np.ndarray, Xd: torch.Tensor, spp: int, seeds: str, R: int, fd_step, gradient: str,
                      ad, check_step: bool) -> list[list[Stage]]:
        """The FD stages (coarse to fine) of every grid θ for `curve`."""
        G = len(T)
        if gradient == "fd" and fd_step is None and seeds == "common":  # grid neighbours: no extra render
            J1, J2 = _grid_fd(Xd, T, 1), _grid_fd(Xd, T, 2)  # (R, G, *S) at steps ~h and ~2h
            i = np.arange(G)
            h = (T[np.minimum(i + 1, G - 1)] - T[np.maximum(i - 1, 0)]) / 2
            out = []
            for g in range(G):
                fine = {"central": _flat(J1[:, g])}
                if 0 < g < G - 1:
                    fine["forward"] = _diff(Xd[:, g + 1][:, None], Xd[:, g][:, None], [T[g + 1] - T[g]])
                    fine["backward"] = _diff(Xd[:, g][:, None], Xd[:, g - 1][:, None], [T[g] - T[g - 1]])
                out.append([Stage(2 * h[g], {"central": _flat(J2[:, g])}, self.group), Stage(h[g], fine, self.group)])
            return out
        if gradient == "fd":  # explicit stencils (independent seeds: the grid's renders share no seed)
            fd_step = fd_step or float(np.min(np.diff(T)))
            center = Xd if seeds == "common" else None
            steps = (fd_step, fd_step / 2) if check_step else (fd_step,)
            per = [self._stages(T[:, None], center, spp, seeds, R, xi, sided=check_step) for xi in steps]
            return [[p[g] for p in per] for g in range(G)]
        J = torch.stack([self.bank.jacobians_at(T, spp, float(T[1] - T[0]), PURPOSE, seeds == "common", r,
                                                method=gradient, ad=ad)[:, 0] for r in range(R)]).double()
        return [[Stage(math.nan, {"central": _flat(J[:, g])}, self.group)] for g in range(G)]

    def _zzb(self, Xd: torch.Tensor, T: np.ndarray, noise: NoiseModel, Wflat: np.ndarray, prior, spp: int) -> Bound:
        R = Xd.shape[0]
        if not isinstance(noise, (AWGN, Poisson)):  # P_e from λ is Gaussian noise's: no bound for another model
            return Bound("zzb", -math.inf, flags=("no-bound",), reason=f"the Ziv–Zakai bound is implemented for AWGN "
                         f"and Poisson noise, not {type(noise).__name__}", lower=-math.inf, upper=math.inf,
                         point=math.nan, extra={"prior_variance": math.nan, "halved": math.nan})
        if isinstance(noise, Poisson):
            Y = self.bank.sets(T, spp, PURPOSE + "-weight", range(R), desc="Poisson weight renders").double()
            stat = bhattacharyya_ustat(Xd.reshape(R, len(T), -1).numpy(), Y.reshape(R, len(T), -1).numpy(),
                                       noise.scale, self.group)
            kind = "bhattacharyya"
        else:
            stat = pairwise_ustat(Xd.reshape(R, len(T), -1).numpy(), Wflat, self.group)
            kind = "lambda"
        z = zzb_interval(stat, T, kind, prior, self.level)
        limited = not math.isfinite(z.halved) or abs(z.halved) > math.log10(1.1)  # > 10 % when δ is halved
        flags = (("estimate-only",) if z.estimate_only else ()) + (("grid-limited",) if limited else ())
        reason = (f"Ziv–Zakai bound on the Bayesian MSE over the prior on [{T[0]:g}, {T[-1]:g}] (any estimator); "
                  f"{z.how}; halving the grid spacing changes it by {z.halved:+.3g} decades; prior variance "
                  f"{z.prior_variance:.4g}")
        return Bound("zzb", z.lower, None, flags, reason, lower=z.lower, upper=z.upper, point=z.point,
                     level=None if z.estimate_only else z.level,
                     extra={"prior_variance": z.prior_variance, "halved": z.halved})


def predicted(points: list[BoundPoint], raws: list[Raw], kinds: tuple[str, ...], target: float, level: float,
              R: int, per_set: int, spp: int) -> list[Precision]:
    """What one grid θ's curve points (one per noise model, with their `raws`) reached against `target` and, where
    they did not meet it, the fresh replicate sets of the whole grid predicted to (`precision.plan` from the curve's
    own sets, at the level of a first fresh look, `spending`), each set `per_set` renders of `spp` samples shared by
    every grid θ: so the curve's cost to meet the target at several θ is the largest of their predictions, not the
    sum. Nothing is rendered."""
    pixels = raws[0].pixels
    reach = [{k: reached(pt.bounds[k]) for k in kinds} for pt in points]
    met = max(max(r.values()) for r in reach) <= target
    sets, note, finer = 0.0, "met by the curve's own sets", False
    if not met:
        pl = plan(raws, kinds, target, 1.0 - spending(1.0 - level, 2)[1], MAX_PREDICT)
        sets = math.inf if pl.sets is None else float(pl.sets)
        finer = pl.sets is None and any(r.sf.halvings and r.sf.halvings[-1].rising for r in raws)
        if pl.sets is not None:
            note = f"predicted from the curve's sets: {pl.sets} fresh sets of the whole grid ({per_set} renders each)"
        elif finer:
            note = ("no number of sets at the curve's FD step: F still rises at its finest step (an edge: a finer "
                    "step, quoted with a precision target, may settle it)")
        else:
            note = (f"no number of sets is predicted to meet it at this spp ({pl.predicted:.3g} at {MAX_PREDICT} sets, "
                    "holding the curve's estimates fixed)")
    return [Precision(target, r, bool(met), 1, R, 0, level, R * per_set * spp * pixels, sets,
                      sets * per_set * spp * pixels, note, finer_step=finer) for r in reach]


def _plugin_poisson(pooled: torch.Tensor, Wflat: np.ndarray) -> np.ndarray:
    """Plug-in λ[i, j] = Σ w_i (L_j − L_i)² of the replicate means with the zero-pixel policy's weights."""
    X = pooled.reshape(len(pooled), -1).numpy()
    out = np.zeros((len(X), len(X)))
    for i in range(len(X)):
        d = X - X[i]
        out[i] = (d * d * Wflat[i]).sum(axis=1)
    return out


def _grid_fd(X: torch.Tensor, T: np.ndarray, k: int) -> torch.Tensor:
    """FD rounds (R, G, *S) at each grid point from its neighbours i ± k in every replicate (one-sided at
    the ends): step ≈ k grid spacings, common random numbers when the replicate's seeds are common."""
    G = len(T)
    i = np.arange(G)
    hi, lo = np.minimum(i + k, G - 1), np.maximum(i - k, 0)
    sep = torch.as_tensor(T[hi] - T[lo], dtype=torch.float64).reshape(1, G, *([1] * (X.ndim - 2)))
    return (X[:, hi] - X[:, lo]) / sep


