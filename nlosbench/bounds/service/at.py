"""Every bound at θ* (`BoundService.at`), with a precision target through the stopping rule of
`bounds.precision`."""
from __future__ import annotations

import copy
import itertools
from collections.abc import Sequence

import numpy as np
import torch

from nlosbench.bounds.fd_step import converge
from nlosbench.bounds.hcr import hcr_from_lambda
from nlosbench.bounds.hcr_interval import hcr_interval
from nlosbench.bounds.inexact import inexact_hcr
from nlosbench.bounds.precision import Raw, SetCost, check_precision, refine
from nlosbench.bounds.service.points import (
    Bound,
    BoundPoint,
    _barankin,
    crlb_bound,
    hcr_bound,
    interval_bound,
)
from nlosbench.bounds.service.renders import (
    RenderSets,
    _check_step,
    _FixedWeight,
    _need_replicates,
    per_theta,
)
from nlosbench.bounds.ustat import pixel_ustat


def axis_offsets(params, theta: np.ndarray, count: int, step: float) -> np.ndarray:
    """Axis offsets θ* ± ξ·2^k e_j (k < count) inside Θ, as points (M, P)."""
    pts = []
    for j, k, sgn in itertools.product(range(params.dim), range(count), (-1.0, 1.0)):
        t = theta.copy()
        t[j] += sgn * step * 2.0 ** k
        if params.contains(t):
            pts.append(t)
    return np.array(pts).reshape(-1, params.dim)


class AtTheta(RenderSets):
    """`at` (the service's module docstring)."""

    def at(self, thetas, spp: int, want: Sequence[str] = ("hcr", "crlb"), seeds: str = "common",
           replicates: int = 3, test_grid: int = 21, offsets: int = 4, fd_step=0.01,
           levels: Sequence[int] = (1024, 2048), noises=None, step_tol=0.1,
           max_halvings: int = 3, precision=None, budget: int | None = None,
           looks: int = 2) -> list[BoundPoint]:
        """Every bound in `want` (hcr, crlb, hcr_neff, barankin, hcr_hat) at each θ* (T, P).

        Test Δ: a `test_grid`^P grid over Θ (shared by every θ*, points equal to θ* skipped) and the
        offsets ±ξ·2^k (k < `offsets`) along each axis; the Δ → 0 term and the CRLB from FD rounds at step
        ξ, halved (with the same seeds) until F is shown to have stopped rising within 1 + `step_tol`, at
        most `max_halvings` times (`fd_step`); HCR-hat fits λ over the spp `levels`. "hcr" also reports the
        paper's hcr_neff. Poisson weights come from one independent render per θ*.
        With a `precision` target p (relative half-width, linear units): fresh replicate sets are added only
        where an interval is wider than p, within `budget` pixel-samples, in at most `looks` looks, each on sets of
        its own, with α = 1 − level spent along the path (the pilot's ends at α/20, the fresh looks' the rest), so
        the reported ends hold at `level` whatever the stopping (`bounds.precision`); each BoundPoint then carries a
        `precision` record.

        Parameters
        ----------
        thetas : array_like of shape (T, P) or (T,)
            The points θ*, parameter units.
        spp : int
            Samples per pixel of each replicate render.
        want : sequence of str, optional
            The kinds to compute, from "hcr", "crlb", "crlb_each" (each θ_j's CRLB (F̂⁻¹)_jj with the other
            parameters unknown, as kinds "crlb_<name>"), "hcr_neff", "barankin" (scalar θ only), "hcr_hat".
        seeds : {"common", "independent"}, optional
            Common random numbers across θ within a replicate, or a seed per θ.
        replicates : int, optional
            R ≥ 2 independent replicates of every render set (≥ 3 for confidence limits). With R ≥ 4 the
            standard errors are unbiased and the ends are at their stated level; with R = 3 they come from the
            jackknife, which overstates the noise × noise variance, so the ends are conservative (`bounds.ustat`).
        test_grid : int, optional
            Points per axis of the grid of test points over Θ.
        offsets : int, optional
            Number of axis offsets ±ξ·2^k per side and axis.
        fd_step : float or array_like of shape (T,), optional
            The first FD step ξ, parameter units (also the base of the axis offsets): one for every θ*, or one
            each (an edge at pixel scale in line of sight wants a small start, a smooth L(θ) a large one).
        levels : sequence of int, optional
            spp levels of the HCR-hat fit (at least 2 distinct).
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute bounds for; None: every model.
        step_tol : float or array_like of shape (T,), optional
            Relative tolerance of the step check (0.1: F within 10 %): one for every θ*, or one each (a looser
            target may take a looser check).
        max_halvings : int, optional
            The most halvings of ξ, in [0, 12].
        precision : float or array_like of shape (T,), optional
            The target p > 0 (one for every θ*, or one each): every interval bound asked for (hcr, crlb) has
            upper/point ≤ 1 + p and point/lower ≤ 1 + p (an open end or one that is not a confidence limit does
            not meet it). None: one fixed set of `replicates` (today's behaviour).
        budget : int, optional
            A cap on the pixel-samples (spp × H × W × renders) this call may spend (with a precision target only);
            None: the default ceiling, `bounds.precision.CEILING` × the pilot's.
        looks : int, optional
            K ≥ 1: the pilot and at most K − 1 fresh looks, each on sets of its own (K = 1: the pilot alone at the
            full level); α spent along the path
            (the pilot α/20, the fresh looks the rest: `bounds.precision.spending`).

        Returns
        -------
        list of BoundPoint
            A BoundPoint per (noise, θ*), noise-major, with a Bound per kind asked for.
        """
        known = {"hcr", "crlb", "crlb_each", "hcr_neff", "barankin", "hcr_hat"}
        bad = sorted(set(want) - known)
        if bad:
            raise ValueError(f"unknown bound kinds {bad}; known: {sorted(known)}")
        if "barankin" in want and self.params.dim > 1:
            raise ValueError(f"barankin bounds a scalar θ; this model has {list(self.params.names)}")
        p, R = self.params, _need_replicates(replicates)
        _check_step(fd_step, step_tol, max_halvings, tol_per_theta=True)
        check_precision(precision, budget, looks, want, R)
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, p.dim)
        steps, tols = per_theta(fd_step, len(thetas)), per_theta(step_tol, len(thetas), "step_tol", "tolerance")
        if precision is not None and np.size(precision) not in (1, len(thetas)):
            raise ValueError(f"precision: one target or one per θ* ({len(thetas)}), got {np.size(precision)}")
        args = (spp, want, seeds, test_grid, offsets, levels, noises)
        if precision is None:
            return self._at(thetas, steps, R, 0, *args, tols, max_halvings)
        need_alt = bool({"hcr", "hcr_neff", "barankin", "hcr_hat"} & set(want))
        need_fi = bool({"hcr", "crlb", "crlb_each"} & set(want))
        cost = SetCost(p.grid(test_grid).shape[0] if need_alt else 0,
                       np.array([1 + (len(axis_offsets(p, t, offsets, xi)) if need_alt else 0)
                                 for t, xi in zip(thetas, steps, strict=True)]),
                       2 * p.dim if need_fi else 0, max_halvings + 1, int(need_fi and seeds == "independent"))

        def look(idx: np.ndarray, reps: int, first: int, level: float, keep: dict, window, tested) -> list[BoundPoint]:
            sub = copy.copy(self)
            sub.level = level
            stages = {} if window is None else {"fd_start": steps[idx] / 2**window.start,
                                                "halvings": window.halvings}
            return sub._at(thetas[idx], steps[idx], reps, first, *args, tols[idx], max_halvings, keep=keep,
                           tested=tested, **stages)

        return refine(look, len(thetas), list(self._select(noises)), R, precision, budget, looks, 1 - self.level,
                      cost, spp, self.bank)

    def _at(self, thetas: np.ndarray, fd_step: np.ndarray, R: int, first: int, spp: int, want: Sequence[str],
            seeds: str, test_grid: int, offsets: int, levels: Sequence[int], noises, step_tol,
            max_halvings: int, keep: dict | None = None, fd_start: np.ndarray | None = None,
            halvings: int | None = None, tested: dict | None = None) -> list[BoundPoint]:
        """`at` on the replicate sets first … first + R − 1 at the service's level, θ*'s first FD step `fd_step`
        (T,) and step tolerance `step_tol` (one, or (T,)); `keep`, when given, is filled with {(noise index, θ
        index): the raw data a precision plan needs (`precision.Raw`)}; a precision look's FD stages start at
        `fd_start` (T,) and halve at most `halvings` times (None: `fd_step`, `max_halvings`; the axis offsets keep
        `fd_step` as their base), and where `tested` {θ index: mask or None} gives a mask over θ*'s test points (the
        grid's other points, then the offsets) only those are rendered and tested."""
        p = self.params
        grid = p.grid(test_grid)
        step_tol = per_theta(step_tol, len(thetas), "step_tol", "tolerance")
        need_alt = bool({"hcr", "hcr_neff", "barankin", "hcr_hat"} & set(want))
        need_fi = bool({"hcr", "crlb", "crlb_each"} & set(want))
        center = self.replicates(thetas, spp, seeds, R, "bound renders at θ*", first).double()
        tests = []  # per θ*: (its grid points, its offsets)
        for i, theta in enumerate(thetas):
            near = np.flatnonzero(np.abs((grid - theta) / (p.upper - p.lower)).max(axis=1) > 1e-9)
            offs = axis_offsets(p, theta, offsets, float(fd_step[i]))
            mask = None if tested is None else tested.get(i)
            if mask is not None:
                near, offs = near[mask[:len(near)]], offs[mask[len(near):]]
            tests.append((near, offs))
        used = np.unique(np.concatenate([n for n, _ in tests])).astype(np.int64) if tests else np.empty(0, np.int64)
        column = {int(g): c for c, g in enumerate(used)}
        grid_X = self.replicates(grid[used], spp, seeds, R, "bound test renders", first).double() if (
            need_alt and used.size) else None
        weights = self._weights(thetas, spp, center.mean(dim=0), noises)
        stages = None
        if need_fi:
            common = center if seeds == "common" else None
            most = max_halvings if halvings is None else halvings
            stages = self._refine(thetas, lambda idx, xi: self._stages(  # a torch index: a numpy one is ~500× slower
                thetas[idx], None if common is None else common[:, torch.as_tensor(idx)], spp, seeds, R, xi, first,
                sided=most > 0), {j: [w for w, _ in rows] for j, rows in weights.items()},
                                  fd_step if fd_start is None else fd_start, step_tol, most)
        rows: dict[tuple[int, int], BoundPoint] = {}
        for i, theta in enumerate(thetas):
            near, offs = tests[i]
            pts = np.concatenate([grid[near], offs])
            alt = None
            if need_alt:  # a torch index: a numpy one is ~500× slower
                parts = [grid_X[:, torch.as_tensor([column[int(g)] for g in near], dtype=torch.int64)]] if len(
                    near) else []
                if len(offs):
                    parts.append(self.replicates(offs, spp, seeds, R, "bound offset renders", first).double())
                alt = torch.cat(parts, dim=1)
            lower, upper = p.lower - theta, p.upper - theta
            deltas = pts - theta if p.dim > 1 else (pts - theta)[:, 0]
            lv = None
            if "hcr_hat" in want:  # the level renders do not depend on the noise model: once per θ*
                lv = self.bank.levels_at(np.concatenate([theta[None], pts]), levels, 1, "bounds-at-levels",
                                         seeds == "common")
            L0 = center[:, i].mean(dim=0)
            for j, noise in self._select(noises).items():
                wflat, zero_flags = weights[j][i]
                w = torch.from_numpy(wflat).reshape(L0.shape)
                b: dict[str, Bound] = {}
                sf = converge(stages[i], wflat, self.level, float(step_tol[i]), spp) if need_fi else None
                if "crlb" in want:
                    b["crlb"] = crlb_bound(sf, self.level, zero_flags)
                if "crlb_each" in want:  # each θ_j's own CRLB from the full F̂, the other parameters unknown
                    b.update({f"crlb_{n}": crlb_bound(sf, self.level, zero_flags, k, f"crlb_{n}")
                              for k, n in enumerate(p.names)})
                D = lam = None
                if need_alt and {"hcr", "hcr_neff"} & set(want):
                    if "hcr" in want:
                        D = (alt - center[:, i][:, None]).reshape(R, alt.shape[1], -1).numpy()  # (R, K, N)
                        lam = pixel_ustat(D, wflat, self.group)
                        iv = hcr_interval(lam, deltas, sf, self.level, lower, upper)
                        b["hcr"] = interval_bound(iv, zero_flags, sf)
                    plug = _FixedWeight(w).chi2_exponent(L0, alt.mean(dim=0))
                    b["hcr_neff"] = hcr_bound(hcr_from_lambda(plug, deltas, lower, upper))
                if "barankin" in want:
                    b["barankin"] = _barankin(L0, alt.mean(dim=0), deltas, noise, lower, upper)
                if "hcr_hat" in want:
                    r = inexact_hcr(lv[:, :, 0], lv[:, :, 1:], deltas, levels, _FixedWeight(w), L0[None],
                                    alt.mean(dim=0)[None], spp * R, lower, upper)
                    b["hcr_hat"] = hcr_bound(r.hcr_hat, "hcr_hat")
                rows[j, i] = BoundPoint(j, str(noise), theta.copy(), b)
                if keep is not None:
                    keep[j, i] = Raw(D, lam, sf, stages[i] if need_fi else [], wflat, deltas, lower, upper,
                                     int(np.prod(center.shape[2:4])), self.group)
        return [rows[j, i] for j in self._select(noises) for i in range(len(thetas))]

