"""Unbiased per-pixel Fisher information maps and the CRLB per parameter (`BoundService.fisher`), and the CRLB of θ
from independent cameras (`cameras_crlb`)."""
from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np
import torch

from nlosbench.bounds.fd_step import Stage, converge
from nlosbench.bounds.precision import Raw, SetCost, check_precision, refine
from nlosbench.bounds.service.points import (
    Bound,
    BoundPoint,
    FisherPoint,
    crlb_bound,
)
from nlosbench.bounds.service.renders import (
    RenderSets,
    _check_step,
)
from nlosbench.bounds.unbiased_fisher import unbiased_fisher
from nlosbench.noise import to_float64


class FisherInformation(RenderSets):
    """`fisher` (the service's module docstring)."""

    def fisher(self, thetas, spp: int, fd_step: float = 0.01, rounds: int = 3, reduce: str = "sum",
               noises=None, step_tol: float = 0.1, max_halvings: int = 3, precision: float | None = None,
               budget: int | None = None, looks: int = 2, smoothed: bool = False, gradient: str = "fd",
               ad: dict | None = None) -> list[FisherPoint]:
        """Unbiased per-pixel Fisher information maps and the CRLB per parameter at each θ (T, P).

        Per θ: a render (purpose "fisher", the Poisson weight image) and `rounds` independent FD rounds at step ξ:
        round r renders θ ± ξ e_j and θ itself under one seed (purpose "fisher-stencil", replicate r; common
        random numbers inside the stencil), so the step check has the one-sided differences as well as the
        central one (θ's render is left out with `max_halvings` 0: no check); ξ is halved with the same seeds until
        F has stopped rising within 1 + `step_tol` (at most `max_halvings` times); maps (from the central
        differences) and bounds from the finest step.
        With a `precision` target p: the CRLB of θ (tr F̂⁻¹; for a scalar θ its only CRLB) to ±p by the
        stopping rule of `bounds.precision` — the given rounds are the pilot, fresh rounds (replicates
        `rounds`, `rounds` + 1, …) are added only at the θ whose CRLB interval is wider than asked, within
        `budget` pixel-samples, in at most `looks` looks on disjoint rounds with α spent along the path; the maps,
        the per-parameter CRLBs and the rounds are then the reported look's (the pilot's where it met the
        target), and `precise` carries the CRLB of θ with its `precision` record.
        With `gradient` "ad" the rounds are `rounds` independent Mitsuba forward-mode AD passes (integrator options
        `ad`; purpose "fisher-ad", replicate r): no FD step, so nothing to halve or check (`fd_step`, `step_tol`
        and `max_halvings` are not used) and the ends are confidence limits of the information of AD's derivative,
        whatever bias the AD integrator has (the `gradients` study and a converged FD reference say whether it has
        one).

        Parameters
        ----------
        thetas : array_like of shape (T, P) or (T,)
            The parameter points, parameter units.
        spp : int
            Samples per pixel of each render.
        fd_step : float, optional
            The first FD step ξ, parameter units.
        rounds : int, optional
            R ≥ 2 independent FD rounds (≥ 3 for confidence limits and for a precision target).
        reduce : {"sum", "mean"}, optional
            How each map combines the channels (sum: the map sums to F_jj).
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute maps for; None: every model.
        step_tol : float, optional
            Relative tolerance of the step check (0.1: F within 10 %).
        max_halvings : int, optional
            The most halvings of ξ, in [0, 12].
        precision : float, optional
            The target p > 0 on the CRLB of θ: upper/point ≤ 1 + p and point/lower ≤ 1 + p (an open end or
            one that is not a confidence limit does not meet it). None: the `rounds` given (no fresh round).
        budget : int, optional
            A cap on the pixel-samples (spp × H × W × renders) this call may spend (with a precision target only);
            None: the default ceiling, `bounds.precision.CEILING` × the pilot's.
        looks : int, optional
            K ≥ 1: the pilot and at most K − 1 fresh looks, each on rounds of its own; α spent along the path
            (the pilot α/20, the fresh looks the rest; K = 1 the pilot alone at the full level:
            `bounds.precision.spending`).
        smoothed : bool, optional
            With `max_halvings` 0: quote the CRLBs of the model smoothed by the FD step (the information of
            (L(θ + ξ) − L(θ − ξ)) / 2ξ, what maps compared at one ξ show), whose ends are confidence limits of that
            quantity (flag "fd-smoothed", no label), so a precision target can be met; False: the lower ends
            are labelled "not a confidence limit" (no step check).
        gradient : {"fd", "ad"}, optional
            Central FD rounds (the step rule above) or independent AD passes.
        ad : dict, optional
            The AD integrator's options with gradient "ad" (`type`: prb, direct_projective, prb_projective;
            `guiding`, `sppc`, `sppp`, `sppi`, `max_depth` …); None: the model's choice for the parameter's kind.

        Returns
        -------
        list of FisherPoint
            One per θ: the render, the mean Jacobian, and per noise index the maps and CRLBs.
        """
        if rounds < 2:
            raise ValueError(f"an unbiased Fisher information needs >= 2 independent FD rounds, got {rounds}")
        if reduce not in ("sum", "mean"):
            raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
        if gradient not in ("fd", "ad"):
            raise ValueError(f"gradient must be 'fd' or 'ad', got {gradient!r}")
        if gradient == "ad" and precision is not None:
            raise ValueError("a precision target plans fresh FD rounds and their step; with gradient 'ad' give the "
                             "number of AD passes as `rounds`")
        if gradient == "fd" and ad:
            raise ValueError(f"AD integrator options {ad} need gradient 'ad'")
        _check_step(fd_step, step_tol, max_halvings)
        check_precision(precision, budget, looks, ("crlb",), rounds)
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        args = (spp, reduce, noises, step_tol, smoothed)
        if precision is None:
            return self._fisher(thetas, rounds, 0, *args, fd_step, max_halvings,
                                ad=(ad or {}) if gradient == "ad" else None)[0]
        found: dict[int, FisherPoint] = {}

        def look(idx: np.ndarray, reps: int, first: int, level: float, keep: dict, window, tested) -> list[BoundPoint]:
            sub = copy.copy(self)
            sub.level = level
            start, halvings = (fd_step, max_halvings) if window is None else (fd_step / 2**window.start,
                                                                              window.halvings)
            fps, pts = sub._fisher(thetas[idx], reps, first, *args, start, halvings, keep)
            found.update({int(i): fp for i, fp in zip(idx, fps, strict=True)})
            return pts

        cost = SetCost(0, np.zeros(len(thetas), dtype=np.int64), 2 * self.params.dim, max_halvings + 1,
                       int(max_halvings > 0))
        pts = refine(look, len(thetas), list(self._select(noises)), rounds, precision, budget, looks,
                     1 - self.level, cost, spp, self.bank)
        for n, pt in enumerate(pts):
            found[n % len(thetas)].precise[pt.noise_index] = pt
        return [found[i] for i in range(len(thetas))]

    def _fisher(self, thetas: np.ndarray, rounds: int, first: int, spp: int, reduce: str, noises, step_tol: float,
                smoothed: bool, fd_step: float, max_halvings: int, keep: dict | None = None, ad: dict | None = None
                ) -> tuple[list[FisherPoint], list]:
        """`fisher` from FD rounds first … first + rounds − 1 at the service's level (or, with `ad` given, from
        that many AD passes: one stage, step NaN): the FisherPoints and the CRLB of θ (tr F̂⁻¹) as BoundPoints
        (noise-major); `keep`, when given, is filled with {(noise index, θ index): the raw data a precision plan
        needs (`precision.Raw`)}."""
        P = self.params.dim
        Ls = self.bank.at(thetas, spp, "fisher", desc="Fisher-map renders")
        sel = self._select(noises)
        weights = {j: [self._weight(noise, L) for L in Ls] for j, noise in sel.items()}
        wflat = {j: [to_float64(w).expand(Ls.shape[1:]).reshape(-1).numpy() for w, _ in rows]
                 for j, rows in weights.items()}

        def stage_fn(idx, xi):  # independent rounds, θ rendered under each stencil's seed: one-sided variants too
            return self._stages(thetas[idx], None, spp, "independent", rounds, xi, first, purpose="fisher",
                                sided=max_halvings > 0)

        if ad is None:
            stages = self._refine(thetas, stage_fn, wflat, fd_step, step_tol, max_halvings)
        else:  # independent AD passes: one stage without a step
            J = torch.stack([self.bank.jacobians_at(thetas, spp, fd_step, "fisher-ad", False, first + r,
                                                    desc="Fisher-map AD passes", method="ad", ad=ad)
                             for r in range(rounds)]).double()  # (R, T, P, H, W, C)
            stages = [[Stage(math.nan, {"central": J[:, i].reshape(rounds, P, -1).numpy()}, self.group)]
                      for i in range(len(thetas))]
        out, rows = [], {}
        for i, (t, L) in enumerate(zip(thetas, Ls, strict=True)):
            Jf = torch.from_numpy(stages[i][-1].rounds["central"]).reshape(rounds, P, *L.shape)
            maps, bounds, ws = {}, {}, {}
            for j, noise in sel.items():
                w, flags = weights[j][i]
                ws[j] = to_float64(w).expand(L.shape)
                m = unbiased_fisher(Jf, ws[j]).pixel_map  # (P, H, W, *S): S = (C,), or (T, C) for a transient image
                m = m.reshape(*m.shape[:3], -1)  # a pixel's (scan point's) values together
                maps[j] = m.sum(axis=-1) if reduce == "sum" else m.mean(axis=-1)
                sf = converge(stages[i], wflat[j][i], self.level, step_tol, spp)
                joint = crlb_bound(sf, self.level, flags, smoothed=smoothed)  # tr F̂⁻¹: a scalar θ's only CRLB
                bounds[j] = [joint] if P == 1 else [
                    crlb_bound(converge([Stage(s.step, {"central": s.rounds["central"][:, k:k + 1]}, s.group)
                                         for s in stages[i]], wflat[j][i], self.level, step_tol, spp),
                               self.level, flags, smoothed=smoothed) for k in range(P)]
                rows[j, i] = BoundPoint(j, str(noise), t.copy(), {"crlb": joint})
                if keep is not None:
                    keep[j, i] = Raw(None, None, sf, stages[i], wflat[j][i], np.empty((0, P)), self.params.lower - t,
                                     self.params.upper - t, int(np.prod(L.shape[:2])), self.group, smoothed)
            out.append(FisherPoint(t, L, Jf.mean(dim=0), maps, bounds, Jf, stages[i][-1].step, ws))
        return out, [rows[j, i] for j in sel for i in range(len(thetas))]


def cameras_crlb(points: Sequence[FisherPoint], noise: int, level: float = 0.95, group: int = 1,
                 smoothed: bool = False) -> tuple[np.ndarray, Bound]:
    """The CRLB of θ (tr F̂⁻¹, units²) from independent cameras, each a FisherPoint of `BoundService.fisher`:
    their Fisher matrices add.

    The cameras' FD rounds at one step are joined pixel by pixel (round r of the set is round r of every
    camera: independent rounds stay independent), so F̂ = Σ F̂_camera is the same U-statistic and its ends come
    from the joint jackknife over rounds, as for one camera. One camera gives `fisher`'s own CRLB of θ at that
    step (no step check: the lower end is labelled so).

    Parameters
    ----------
    points : sequence of FisherPoint
        One per camera, all at the same θ, with the same number of rounds R and FD step ξ.
    noise : int
        The noise index (a key of every point's `weights`).
    level : float, optional
        One-sided confidence of each end, in (0, 1).
    group : int, optional
        The values per pixel that share path samples (`ForwardModel.channels`).
    smoothed : bool, optional
        Quote the CRLB of the model smoothed by the FD step (`BoundService.fisher`): ends that are limits of it.

    Returns
    -------
    F : ndarray of shape (P, P)
        The summed unbiased Fisher matrix, 1/(parameter units)².
    Bound
        The `crlb` Bound of tr F̂⁻¹ with one-sided ends at `level` and `loo` (R ≥ 3); flags carry the cameras'
        zero-pixel counts (Poisson weights).

    Examples
    --------
    Two cameras (here two render seeds of one scene) whose information adds:

    >>> model, noise = nb.scenes.get("blob2d"), nb.noise.AWGN(sigma=0.05)
    >>> cams = [nb.bounds.BoundService(nb.RenderBank(model, seed=s), [noise]).fisher(
    ...     [[0.4, 0.6]], spp=4, rounds=3, max_halvings=0)[0] for s in (0, 1)]
    >>> F, both = nb.bounds.cameras_crlb(cams, 0)
    >>> F.shape, both.kind, both.lower <= both.point <= both.upper
    ((2, 2), 'crlb', True)
    >>> both.point < nb.bounds.cameras_crlb(cams[:1], 0)[1].point  # two cameras: a lower CRLB than one
    True
    """
    if not points:
        raise ValueError("cameras_crlb needs at least one camera's FisherPoint")
    shapes = {tuple(fp.rounds.shape[:2]) for fp in points}
    steps = {float(fp.step) for fp in points}
    if len(shapes) != 1 or len(steps) != 1:
        raise ValueError(f"the cameras' FD rounds must share R, P and the step ξ, got (R, P) {sorted(shapes)} and "
                         f"ξ {sorted(steps)}")
    if any(noise not in fp.weights for fp in points):
        raise ValueError(f"noise index {noise} is missing from a camera's Fisher maps")
    R, P = shapes.pop()
    J = np.concatenate([fp.rounds.reshape(R, P, -1).numpy() for fp in points], axis=2)
    w = np.concatenate([fp.weights[noise].reshape(-1).numpy() for fp in points])
    zeros = sum(int(f.split("=")[1]) for fp in points for f in fp.crlb[noise][0].flags if f.startswith("zero-pixels="))
    sf = converge([Stage(steps.pop(), {"central": J}, group)], w, level, step_tol=0.1)
    return sf.final.est, crlb_bound(sf, level, (f"zero-pixels={zeros}",) if zeros else (), smoothed=smoothed)
