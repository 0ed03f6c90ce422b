"""The bound service: every bound at θ*, and bound curves over a grid, from the run's render bank.

Studies and the trials summary ask here; nothing else assembles bounds. The service plans the render
sets a bound needs (through the bank, which derives their seeds), computes the bounds with the
functions of this package and returns one result type, `Bound`, per (noise model, θ, kind), grouped in
`BoundPoint`s. Kinds (values in parameter units²):

  hcr       HCR (Hammersley–Chapman–Robbins) on the MSE: sup over the tested Δ of ‖Δ‖²/(exp λ(Δ) − 1),
            λ = the noise model's χ² exponent between the render at θ* and the render at θ* + Δ;
  crlb      CRLB: trace of F⁻¹, F from the render at θ* and a central-FD Jacobian there (step ξ, common
            random numbers inside each stencil);
  barankin  multi-point Barankin (McAulay–Seidman) bound on Var θ̂ of a scalar θ, from the HCR's renders;
  hcr_neff, hcr_hat
            the HCR interval from inexact renders (`bounds.inexact`): the direct bound from one render set
            at N_eff spp, and the bound from the bias-corrected λ̂ (fit of λ̃ = λ + C/N^p over k spp levels).

Render sets. A curve renders each grid θ once (purpose "bounds"; it serves as θ* and as θ* + Δ for
every other grid point: G renders, not G²). A bound at θ* (`at`) renders θ*, a Θ grid shared by every
θ* and small offsets ±ξ·2^k along each axis (purpose "bounds-at"). `seeds="common"` gives every θ of a
set the same seed (common random numbers across θ: far less λ inflation by rendering noise, at the
price of errors correlated along the curve); "independent" a seed per θ.
"""
from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from nlosbench.bank import RenderBank
from nlosbench.bounds.barankin import barankin
from nlosbench.bounds.crlb import crlb, crlb_log10, fisher_matrix
from nlosbench.bounds.fisher_maps import fisher_maps
from nlosbench.bounds.grid import hcr_curve
from nlosbench.bounds.hcr import HCRResult, hcr
from nlosbench.bounds.inexact import InexactHCR, inexact_hcr
from nlosbench.noise import NoiseModel
from nlosbench.seeds import derive

KINDS = ("hcr", "crlb", "barankin", "hcr_neff", "hcr_hat")
SEEDS = ("independent", "common")


@dataclass(frozen=True)
class Bound:
    """One bound (parameter units²). log10 is exact even where the value underflows: −inf means "no
    usable test point" or infinite information, +inf "no resolved information" (see `flags`, `reason`).
    delta: the Δ at the sup (HCR family), parameter units; flags: short machine-readable tags
    (sup-at-smallest-delta, sup-at-largest-delta, unresolved, no-bound, singular, infinite-fisher,
    noise-dominated); extra: kind-specific diagnostics (e.g. Barankin's test points)."""

    kind: str
    log10: float
    delta: tuple | None = None
    flags: tuple[str, ...] = ()
    reason: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def value(self) -> float:
        """10^log10 (0 where it underflows, +inf where it overflows)."""
        if self.log10 > 308:
            return math.inf
        return 10.0 ** self.log10 if self.log10 > -400 else 0.0

    def columns(self) -> dict:
        """Flat CSV cells: log10_<kind>, <kind>_delta (JSON), <kind>_flags, <kind>_reason."""
        return {f"log10_{self.kind}": self.log10, f"{self.kind}_delta": json.dumps(self.delta),
                f"{self.kind}_flags": ",".join(self.flags), f"{self.kind}_reason": self.reason}


@dataclass
class BoundPoint:
    """Every bound asked for at one θ for one noise model: noise index and name, θ (P,), {kind: Bound}."""

    noise_index: int
    noise: str
    theta: np.ndarray
    bounds: dict[str, Bound]

    def row(self, names: Sequence[str]) -> dict:
        """A CSV row: noise, θ per parameter, then every bound's columns."""
        out = {"noise_index": self.noise_index, "noise": self.noise,
               **{f"theta_{n}": float(v) for n, v in zip(names, self.theta, strict=True)}}
        for b in self.bounds.values():
            out.update(b.columns())
        return out


@dataclass
class FisherPoint:
    """Per-pixel Fisher information at one θ: the render L (H, W, C), its FD Jacobian J (P, H, W, C) and,
    per noise index, the maps (P, H, W) (1/units², summing to F_jj) and the CRLB per parameter."""

    theta: np.ndarray
    L: torch.Tensor
    J: torch.Tensor
    maps: dict[int, np.ndarray]
    crlb: dict[int, list[Bound]]


def hcr_bound(r: HCRResult, kind: str = "hcr", log10: float | None = None) -> Bound:
    """A Bound from an HCRResult (`log10` overrides its value, e.g. a per-component bound)."""
    flags = []
    if r.at_edge:
        flags.append(f"sup-at-{r.at_edge}-delta")
    if r.unresolved:
        flags.append("unresolved")
    if r.index < 0:
        flags.append("no-bound")
    delta = None if r.delta is None else tuple(np.atleast_1d(r.delta).tolist())
    return Bound(kind, float(r.log10 if log10 is None else log10), delta, tuple(flags), r.reason)


def crlb_bound(L, J, noise: NoiseModel) -> Bound:
    """The CRLB on the MSE (trace of F⁻¹) from an image L (*S) and its Jacobian J (P, *S)."""
    F = fisher_matrix(L, J, noise)
    if not np.all(np.isfinite(F)):
        return Bound("crlb", -math.inf, flags=("infinite-fisher",),
                     reason="infinite Fisher information (Poisson pixel with L = 0 that changes)")
    c = crlb(F)
    with np.errstate(divide="ignore"):
        return Bound("crlb", float(np.log10(c.trace)), flags=("singular",) if c.singular else (), reason=c.reason)


def axis_offsets(params, theta: np.ndarray, count: int, step: float) -> np.ndarray:
    """Axis offsets θ* ± ξ·2^k e_j (k < count) inside Θ, as points (M, P)."""
    pts = []
    for j, k, sgn in itertools.product(range(params.dim), range(count), (-1.0, 1.0)):
        t = theta.copy()
        t[j] += sgn * step * 2.0 ** k
        if params.contains(t):
            pts.append(t)
    return np.array(pts).reshape(-1, params.dim)


class BoundService:
    """Bounds from the render bank `bank` for the noise models `noises` (index → model, or a list)."""

    def __init__(self, bank: RenderBank, noises: dict[int, NoiseModel] | Sequence[NoiseModel]):
        self.bank = bank
        self.noises = dict(noises) if isinstance(noises, dict) else dict(enumerate(noises))
        self.params = bank.model.params

    def _select(self, noises) -> dict[int, NoiseModel]:
        return self.noises if noises is None else {j: self.noises[j] for j in noises}

    # -- curves --------------------------------------------------------------------------------------
    def curve(self, thetas, spp: int, seeds: str = "independent", crlb: bool = True, barankin: bool = False,
              fd_step: float = 0.01, noises=None, gradient: str = "fd", ad: dict | None = None) -> list[BoundPoint]:
        """HCR (and CRLB, Barankin) at every θ of a 1-D grid (G,) over Θ from G renders (and G Jacobians:
        central FD with step ξ, or with gradient "ad" Mitsuba AD with integrator options `ad`): a BoundPoint
        per (noise, θ), noise-major. Test points are the other grid points inside Θ."""
        if self.params.dim != 1:
            raise ValueError(f"a bound curve needs one parameter; the model has {list(self.params.names)}")
        _check_seeds(seeds)
        T = np.asarray(thetas, dtype=np.float64).reshape(-1)
        common = seeds == "common"
        renders = self.bank.at(T, spp, "bounds", common, desc="bound-curve renders")
        jac = self.bank.jacobians_at(T, spp, fd_step, "bounds", common, method=gradient, ad=ad) if crlb else None
        lo, hi = self.params.lower[0], self.params.upper[0]
        out = []
        for j, noise in self._select(noises).items():
            c = hcr_curve(renders, T, noise, lo, hi)
            for g, t in enumerate(T):
                b = {"hcr": Bound("hcr", float(c.log10[g]), None if np.isnan(c.delta[g]) else (float(c.delta[g]),),
                                  _curve_flags(c, g), c.reason[g])}
                if jac is not None:
                    b["crlb"] = crlb_bound(renders[g], jac[g], noise)
                if barankin:
                    b["barankin"] = self._barankin(renders[g], renders[np.arange(len(T)) != g],
                                                   T[np.arange(len(T)) != g] - t, noise, lo - t, hi - t)
                out.append(BoundPoint(j, str(noise), np.array([t]), b))
        return out

    # -- bounds at θ* ----------------------------------------------------------------------------------
    def at(self, thetas, spp: int, want: Sequence[str] = ("hcr", "crlb"), seeds: str = "independent",
           test_grid: int = 21, offsets: int = 4, fd_step: float = 0.01, levels: Sequence[int] = (1024, 2048),
           noises=None) -> list[BoundPoint]:
        """Every bound in `want` (hcr, crlb, barankin, hcr_hat) at each θ* (T, P), a BoundPoint per (noise,
        θ*), noise-major. The HCR tests Δ = a `test_grid`^P grid over Θ (shared by every θ*, points
        equal to θ* skipped) and the offsets ±ξ·2^k (k < `offsets`) along each axis; the CRLB's Jacobian
        has step ξ; HCR-hat fits λ over the spp `levels` (renders of θ* and every test point at each)."""
        bad = sorted(set(want) - {"hcr", "crlb", "barankin", "hcr_hat"})
        if bad:
            raise ValueError(f"unknown bound kinds {bad}; known: hcr, crlb, barankin, hcr_hat")
        if "barankin" in want and self.params.dim > 1:
            raise ValueError(f"barankin bounds a scalar θ; this model has {list(self.params.names)}")
        _check_seeds(seeds)
        p, common = self.params, seeds == "common"
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, p.dim)
        grid = p.grid(test_grid)
        center = self.bank.at(thetas, spp, "bounds-at", common, desc="bound renders at θ*")
        need_alt = bool({"hcr", "barankin", "hcr_hat"} & set(want))
        grid_imgs = self.bank.at(grid, spp, "bounds-at", common, desc="bound test renders") if need_alt else None
        jac = self.bank.jacobians_at(thetas, spp, fd_step, "bounds-at", common) if "crlb" in want else None
        rows: dict[tuple[int, int], BoundPoint] = {}
        for i, theta in enumerate(thetas):
            near = np.flatnonzero(np.abs((grid - theta) / (p.upper - p.lower)).max(axis=1) > 1e-9)
            offs = axis_offsets(p, theta, offsets, fd_step)
            pts = np.concatenate([grid[near], offs])
            alt = None
            if need_alt:
                alt = grid_imgs[near]
                if len(offs):
                    alt = torch.cat([alt, self.bank.at(offs, spp, "bounds-at", common, desc="bound offset renders")])
            lower, upper = p.lower - theta, p.upper - theta
            deltas = pts - theta if p.dim > 1 else (pts - theta)[:, 0]
            lv = None
            if "hcr_hat" in want:  # the level renders do not depend on the noise model: once per θ*
                lv = self.bank.levels_at(np.concatenate([theta[None], pts]), levels, 1, "bounds-at-levels", common)
            for j, noise in self._select(noises).items():
                b = {}
                if "hcr" in want:
                    b["hcr"] = hcr_bound(hcr(center[i], alt, deltas, noise, lower, upper))
                if "crlb" in want:
                    b["crlb"] = crlb_bound(center[i], jac[i], noise)
                if "barankin" in want:
                    b["barankin"] = self._barankin(center[i], alt, deltas, noise, lower, upper)
                if "hcr_hat" in want:
                    r = inexact_hcr(
                        lv[:, :, 0], lv[:, :, 1:], deltas, levels, noise, center[i][None], alt[None], spp, lower, upper
                    )
                    b["hcr_hat"] = hcr_bound(r.hcr_hat, "hcr_hat")
                rows[j, i] = BoundPoint(j, str(noise), theta.copy(), b)
        return [rows[j, i] for j in self._select(noises) for i in range(len(thetas))]

    @staticmethod
    def _barankin(L0, L_alt, deltas, noise, lower, upper) -> Bound:
        r = barankin(L0, L_alt, deltas, noise, lower=lower, upper=upper)
        return Bound(
            "barankin",
            float(r.log10),
            tuple(np.atleast_1d(r.deltas).tolist()) or None,
            ("unresolved",) if r.unresolved else (),
            r.reason,
            {"points": len(r.points), "tightening": r.tightening, "cond": r.cond},
        )

    # -- Fisher information ------------------------------------------------------------------------------
    def fisher(
        self, thetas, spp: int, fd_step: float = 0.01, rounds: int = 1, reduce: str = "sum", noises=None
    ) -> list[FisherPoint]:
        """Per-pixel Fisher information maps and the CRLB per parameter at each θ (T, P): a render and a
        central-FD Jacobian (step ξ, `rounds` rounds) per θ (purpose "fisher", a seed per θ)."""
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        Ls = self.bank.at(thetas, spp, "fisher", desc="Fisher-map renders")
        Js = self.bank.jacobians_at(thetas, spp, fd_step, "fisher", rounds=rounds, desc="Fisher-map FD Jacobians")
        out = []
        for t, L, J in zip(thetas, Ls, Js, strict=True):
            maps, bounds = {}, {}
            for j, noise in self._select(noises).items():
                maps[j] = fisher_maps(L, J, noise, reduce)
                logs, flag = crlb_log10(L, J, noise)
                bounds[j] = [Bound("crlb", float(v), flags=(flag,) if flag else (), reason=flag) for v in logs]
            out.append(FisherPoint(t, L, J, maps, bounds))
        return out

    # -- HCR intervals from inexact renders -----------------------------------------------------------------
    def interval(
        self,
        thetas,
        deltas,
        levels: Sequence[int],
        n_eff: int,
        replicates: int,
        power: float = 1.0,
        bootstrap: int = 0,
        confidence: float = 0.9,
        boot_seed: int = 0,
        seeds: str = "independent",
        noises=None,
    ) -> list[tuple[BoundPoint, InexactHCR]]:
        """[HCR_Neff, HCR-hat] at each scalar θ* from render sets of every θ* and θ* + Δ (Δ inside Θ): k spp
        levels × R replicates (purpose "inexact-levels") and R replicates at N_eff (purpose "inexact-neff");
        a render serves every θ* that uses it. Returns (BoundPoint with hcr_neff and hcr_hat, the full
        InexactHCR) per (noise, θ*), noise-major. `boot_seed` drives the bootstrap (derive it)."""
        if self.params.dim != 1:
            raise ValueError(f"the HCR interval needs one parameter; the model has {list(self.params.names)}")
        _check_seeds(seeds)
        points, plan = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        common = seeds == "common"
        X = self.bank.levels_at(points, levels, replicates, "inexact-levels", common)
        Xe = self.bank.levels_at(points, [n_eff], replicates, "inexact-neff", common)[0]
        out = []
        for m, (j, noise) in enumerate(self._select(noises).items()):
            for t, (theta, (q0, d, qd)) in enumerate(zip(np.asarray(thetas, dtype=np.float64), plan, strict=True)):
                r = inexact_hcr(
                    X[:, :, q0],
                    X[:, :, qd],
                    d,
                    levels,
                    noise,
                    Xe[:, q0],
                    Xe[:, qd],
                    n_eff,
                    power=power,
                    bootstrap=bootstrap,
                    confidence=confidence,
                    seed=_mix(boot_seed, m, t),
                )
                neff, hat = hcr_bound(r.hcr_neff, "hcr_neff"), hcr_bound(r.hcr_hat, "hcr_hat")
                if r.fit.noise_dominated.any():
                    hat = Bound(hat.kind, hat.log10, hat.delta, hat.flags + ("noise-dominated",), hat.reason)
                out.append((BoundPoint(j, str(noise), np.array([theta]), {"hcr_neff": neff, "hcr_hat": hat}), r))
        return out

    def interval_renders(
        self, thetas, deltas, levels: Sequence[int], replicates: int, seeds: str = "independent"
    ) -> torch.Tensor:
        """The level renders (k, R, Q, H, W, C) of `interval`'s render points (from the bank: no new
        renders once `interval` ran), e.g. for the 1/N decay check."""
        points, _ = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        return self.bank.levels_at(points, levels, replicates, "inexact-levels", seeds == "common")


def interval_points(thetas, deltas, lo: float, hi: float) -> tuple[np.ndarray, list]:
    """Unique render points (Q,) of θ* and θ* + Δ inside [lo, hi], and per θ*: (its point index, its usable
    Δ (D_t,), their point indices). ValueError when a θ* has no usable Δ."""
    index: dict[float, int] = {}

    def at(v: float) -> int:
        return index.setdefault(round(float(v), 12), len(index))

    deltas = np.asarray(deltas, dtype=np.float64)
    deltas = deltas[deltas != 0]
    plan = []
    for t in np.asarray(thetas, dtype=np.float64).reshape(-1):
        d = deltas[(t + deltas >= lo) & (t + deltas <= hi)]
        if d.size == 0:
            raise ValueError(f"no Δ in {deltas.tolist()} keeps θ* = {t:g} + Δ inside [{lo:g}, {hi:g}]")
        plan.append((at(t), d, np.array([at(t + x) for x in d], dtype=np.int64)))
    return np.array(list(index), dtype=np.float64), plan


def _curve_flags(c, g: int) -> tuple[str, ...]:
    flags = []
    if c.at_edge[g]:
        flags.append(f"sup-at-{c.at_edge[g]}-delta")
    if c.unresolved[g]:
        flags.append("unresolved")
    if c.index[g] < 0:
        flags.append("no-bound")
    return tuple(flags)


def _check_seeds(seeds: str) -> None:
    if seeds not in SEEDS:
        raise ValueError(f"seeds must be one of {list(SEEDS)}, got {seeds!r}")


def _mix(seed: int, *idx: int) -> int:
    return derive(seed, "interval-bootstrap", *idx)
