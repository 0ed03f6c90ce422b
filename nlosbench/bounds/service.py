"""The bound service: every bound at θ*, and bound curves over a grid, from the run's render bank.

Studies and the trials summary ask here; nothing else assembles bounds. The service plans the render
sets a bound needs (through the bank, which derives their seeds), computes the bounds with the functions
of this package and returns one result type, `Bound`, per (noise model, θ, kind), grouped in BoundPoints.

Render sets. Every θ the service uses (θ*, test points θ* + Δ, FD stencils θ* ± ξ) is rendered in R
independent replicates (purpose "bounds", replicate r = 0 … R−1). `seeds="common"` gives every θ of a
replicate the same seed (common random numbers across θ: differences L(θ+Δ) − L(θ) carry far less
rendering noise); "independent" a seed per θ. A curve renders each grid θ R times and serves every θ* and
every Δ from them (R·G renders, not G²); the FD stencils of the Δ → 0 term are the grid neighbours (no
extra render). Bounds at θ* reuse the same sets, so a θ* on a curve's grid costs no new render.

Kinds (parameter units²; `Bound.log10` is the value to quote):
  hcr       the HCR on the MSE as a confidence interval with its Δ → 0 term (`hcr_interval`): log10 = the
            lower end (a one-sided lower confidence limit at `level`), `upper` the upper end, `point` the
            estimate, `terms` which term set each end. λ(Δ) and F are U-statistics over the R replicates
            (`ustat`): unbiased, so rendering noise no longer inflates λ (the C/N term) or F;
  crlb      the CRLB from the unbiased Fisher information (trace of F̂⁻¹; 1/F̂ for a scalar θ): log10 the
            central value (+inf when F̂ ≤ 0: no resolved information), `lower`/`upper` its ends (from the
            upper / lower confidence limit of F). It bounds the FI of the FD-smoothed derivative at step ξ;
            the step is checked by changing it 2× (flag fd-step-sensitive when F moves beyond 2 SE);
  hcr_neff  the paper's HCR_Neff: the plug-in λ̃ of the replicate means (R·spp samples per image), sup
            over the tested Δ only (no Δ → 0 term, so it can fall far below the CRLB: the paper's 80 cm row);
  hcr_hat   the paper's HCR-hat (bias-corrected λ̂ from a fit over spp levels), point estimate;
  barankin  multi-point Barankin bound on Var θ̂ of a scalar θ from the replicate means (plug-in);
  zzb       (curves on a uniform grid) the Ziv–Zakai bound on the Bayesian MSE over the prior on the grid's
            range, for every estimator (`zzb`): log10 the lower end, with `upper`, `point`.

Poisson weights scale/L0 need the mean image at θ*; the service uses the mean of its R replicates (a
relative bias O(Var/(L0² R·N)) remains, stated) and the *zero-pixel policy*: a pixel whose mean is exactly
0 (no sample found light) gets the weight of the smallest positive mean in that image instead of +inf, and
the count of such pixels is in the flags (never a silent −inf or a dropped Δ).
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
from nlosbench.bounds.grid import pairwise_lambda
from nlosbench.bounds.hcr import HCRResult, hcr_from_lambda
from nlosbench.bounds.hcr_interval import HCRInterval, hcr_interval
from nlosbench.bounds.inexact import InexactHCR, inexact_hcr
from nlosbench.bounds.unbiased_fisher import unbiased_fisher
from nlosbench.bounds.ustat import UStat, pairwise_ustat, pixel_ustat, t_quantile
from nlosbench.bounds.zzb import uniform_spacing, zzb_interval
from nlosbench.noise import AWGN, NoiseModel, Poisson, QuadraticNoise, to_float64
from nlosbench.seeds import derive

SEEDS = ("independent", "common")
PURPOSE = "bounds"


@dataclass(frozen=True)
class Bound:
    """One bound (parameter units²). log10 is exact even where the value underflows; −inf: no usable
    test point, +inf: no resolved information (see `flags`, `reason`). lower/upper/point: log10 ends and
    estimate of an interval bound (None where the kind has none); level: the one-sided confidence of each
    end; terms: which term set each end; delta: the Δ at the sup (HCR family); flags: short tags
    (sup-at-smallest-delta, sup-at-largest-delta, unresolved, unresolved-delta, no-bound, estimate-only,
    upper-unbounded, singular, fd-step-sensitive, zero-pixels=N, grid-limited, plug-in); extra: details;
    loo: (R,) log10 point estimate without each replicate set (hcr, crlb with R ≥ 3; else empty), for
    jackknifes of quantities that pair two bounds from the same replicate sets."""

    kind: str
    log10: float
    delta: tuple | None = None
    flags: tuple[str, ...] = ()
    reason: str = ""
    lower: float | None = None
    upper: float | None = None
    point: float | None = None
    level: float | None = None
    terms: str = ""
    extra: dict = field(default_factory=dict)
    loo: np.ndarray = field(default_factory=lambda: np.empty(0), compare=False)

    @property
    def value(self) -> float:
        """10^log10 (0 where it underflows, +inf where it overflows)."""
        return _exp10(self.log10)

    def columns(self) -> dict:
        """Flat CSV cells: log10_<kind>, then (where present) <kind>_lower/_upper/_point/_level/_terms, and
        <kind>_delta (JSON), <kind>_flags, <kind>_reason."""
        out = {f"log10_{self.kind}": self.log10}
        for name in ("lower", "upper", "point", "level"):
            if getattr(self, name) is not None:
                out[f"{self.kind}_{name}"] = getattr(self, name)
        if self.terms:
            out[f"{self.kind}_terms"] = self.terms
        out.update({f"{self.kind}_delta": json.dumps(self.delta), f"{self.kind}_flags": ",".join(self.flags),
                    f"{self.kind}_reason": self.reason})
        return out


def _exp10(lg: float) -> float:
    return math.inf if lg > 308 else (10.0 ** lg if lg > -400 else 0.0)


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
class Curve:
    """A bound curve: a BoundPoint per (noise, θ), noise-major, and per noise index the ZZB over the
    grid's range (None with `zzb_reason` when the grid is not uniform or θ is not scalar)."""

    points: list[BoundPoint]
    zzb: dict[int, Bound | None]
    zzb_reason: str = ""


@dataclass
class FisherPoint:
    """Per-pixel Fisher information at one θ: the render L (H, W, C), the mean FD Jacobian J (P, H, W, C)
    over R independent rounds and, per noise index, the unbiased per-pixel maps (P, H, W) (1/units²; they
    can be negative where rendering noise dominates; they sum to the unbiased F_jj) and the CRLB per
    parameter (a Bound with its interval)."""

    theta: np.ndarray
    L: torch.Tensor
    J: torch.Tensor
    maps: dict[int, np.ndarray]
    crlb: dict[int, list[Bound]]


def hcr_bound(r: HCRResult, kind: str = "hcr_neff") -> Bound:
    """A point-estimate Bound from an HCRResult (the paper's columns)."""
    flags = []
    if r.at_edge:
        flags.append(f"sup-at-{r.at_edge}-delta")
    if r.unresolved:
        flags.append("unresolved")
    if r.index < 0:
        flags.append("no-bound")
    delta = None if r.delta is None else tuple(np.atleast_1d(r.delta).tolist())
    return Bound(kind, float(r.log10), delta, tuple(flags), r.reason, point=float(r.log10))


def interval_bound(iv: HCRInterval, extra_flags: tuple = ()) -> Bound:
    """The `hcr` Bound from an HCRInterval: log10 = its lower end."""
    terms = f"lower: {iv.lower_term}; upper: {iv.upper_term}; point: {iv.point_term}"
    reason = ("both ends are point estimates (fewer than 3 replicates)" if iv.estimate_only else
              f"one-sided {iv.level:.0%} limits from {iv.replicates} replicates, Bonferroni over the tested Δ and "
              "Δ → 0; the upper end bounds the HCR over the resolved Δ and Δ → 0")
    if iv.unresolved:
        reason += f"; unresolved Δ (λ_L ≤ 0, left out of the upper end): {iv.unresolved}"
    return Bound("hcr", iv.lower, None, iv.flags + tuple(extra_flags), reason, lower=iv.lower, upper=iv.upper,
                 point=iv.point, level=iv.level, terms=terms, loo=iv.point_loo)


def crlb_bound(F: UStat, level: float, extra_flags: tuple = (), step_note: str = "") -> Bound:
    """The `crlb` Bound (trace of F̂⁻¹, units²) from an unbiased Fisher information F (a UStat of shape (P, P)),
    with one-sided ends at `level` (Student t with the SE's degrees of freedom)."""
    P, R = F.est.shape[0], F.replicates
    value = _trace_inv(F.est)
    flags = list(extra_flags)
    if not math.isfinite(value):
        flags.append("singular" if P > 1 else "unresolved")
    lo = hi = value
    if R >= 3:
        if P == 1:
            f, s, t = F.est[0, 0], F.se[0, 0], float(t_quantile(level, F.dof[0, 0]))
            lo = 1.0 / (f + t * s) if f + t * s > 0 else math.inf
            hi = 1.0 / (f - t * s) if f - t * s > 0 else math.inf
        else:
            loo = np.array([_trace_inv(Fk) for Fk in F.loo])
            se = math.sqrt((R - 1) / R * ((loo - loo.mean()) ** 2).sum()) if np.all(np.isfinite(loo)) else math.inf
            t = float(t_quantile(level, R - 1))
            lo, hi = max(value - t * se, 0.0), value + t * se
    else:
        flags.append("estimate-only")
    log = (lambda v: math.log10(v) if v > 0 else -math.inf)
    reason = ("no resolved information: F̂ is not positive" if not math.isfinite(value) else
              f"CRLB from an unbiased FI (U-statistic over {R} FD rounds; the FI of the FD-smoothed derivative)")
    if step_note:
        reason += f"; {step_note}"
    loo = np.array([log(_trace_inv(Fk)) for Fk in F.loo]) if F.loo.size else np.empty(0)
    return Bound("crlb", log(value), flags=tuple(flags), reason=reason, lower=log(lo), upper=log(hi),
                 point=log(value), level=level if R >= 3 else None, loo=loo)


def fisher_ustat(J: torch.Tensor, w) -> UStat:
    """The unbiased Fisher information (P, P) from R FD rounds J (R, P, *S) and a per-pixel weight w (*S):
    for P = 1 the per-pixel U-statistic (`pixel_ustat`: SE from independent pixels), else the Gram U-statistic
    over rounds (`unbiased_fisher`: SE from the rounds)."""
    R, P = J.shape[:2]
    if P == 1:
        u = pixel_ustat(J.reshape(R, 1, -1).numpy(), to_float64(w).expand(J.shape[2:]).reshape(-1).numpy())
        return UStat(u.est.reshape(1, 1), u.se.reshape(1, 1), u.loo.reshape(-1, 1, 1), R, u.df.reshape(1, 1))
    fi = unbiased_fisher(J, to_float64(w).expand(J.shape[2:]))
    return UStat(fi.F, fi.se, fi.leave_one_out, R)


def _trace_inv(F: np.ndarray) -> float:
    """trace(F⁻¹), +inf where F is not (numerically) positive definite."""
    try:
        np.linalg.cholesky(F)
    except np.linalg.LinAlgError:
        return math.inf
    return float(np.trace(np.linalg.inv(F)))


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
    """Bounds from the render bank `bank` for the noise models `noises` (index → model, or a list), with
    one-sided confidence `level` for every interval end."""

    def __init__(self, bank: RenderBank, noises: dict[int, NoiseModel] | Sequence[NoiseModel], level: float = 0.95):
        if not 0 < level < 1:
            raise ValueError(f"confidence level must lie in (0, 1), got {level}")
        self.bank = bank
        self.noises = dict(noises) if isinstance(noises, dict) else dict(enumerate(noises))
        self.params = bank.model.params
        self.level = float(level)

    def _select(self, noises) -> dict[int, NoiseModel]:
        return self.noises if noises is None else {j: self.noises[j] for j in noises}

    # -- render sets -----------------------------------------------------------------------------------
    def replicates(self, points, spp: int, seeds: str, R: int, desc: str = "bound renders") -> torch.Tensor:
        """Renders (R, N, *S) of points (N, P) in the R replicate sets (see the module docstring)."""
        _check(seeds, R)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, self.params.dim)
        return torch.stack([self.bank.at(pts, spp, PURPOSE, seeds == "common", r, desc=f"{desc} (replicate {r})")
                            for r in range(R)])

    def _stencils(self, thetas: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
        """FD stencil points (T, P, 2, P): θ ± ξ e_j clipped into Θ (one-sided at its edge), and their
        separations (T, P)."""
        p = self.params
        T = len(thetas)
        st = np.repeat(thetas[:, None, None, :], 2, axis=2).repeat(p.dim, axis=1)  # (T, P, 2, P)
        for j in range(p.dim):
            st[:, j, 0, j] = np.minimum(thetas[:, j] + step, p.upper[j])
            st[:, j, 1, j] = np.maximum(thetas[:, j] - step, p.lower[j])
        sep = np.stack([st[:, j, 0, j] - st[:, j, 1, j] for j in range(p.dim)], axis=1).reshape(T, p.dim)
        if np.any(sep <= 0):
            raise ValueError(f"FD step {step} leaves no room inside Θ")
        return st, sep

    def _fd_rounds(self, thetas: np.ndarray, spp: int, seeds: str, R: int, step: float) -> torch.Tensor:
        """FD Jacobians (R, T, P, *S) at thetas (T, P), round r independent of the others and with common
        random numbers inside each stencil: with common seeds the central differences of replicate r's
        renders (stencils shared with the grid); with independent seeds the bank's FD Jacobians (a seed per
        stencil, θ and round)."""
        if seeds == "independent":
            return torch.stack([self.bank.jacobians_at(thetas, spp, step, PURPOSE, False, r,
                                                       desc=f"FD Jacobians (round {r})") for r in range(R)]).double()
        st, sep = self._stencils(thetas, step)
        T, P = sep.shape
        X = self.replicates(st.reshape(-1, P), spp, seeds, R, "FD stencil renders")  # (R, T·P·2, *S)
        X = X.reshape(R, T, P, 2, *X.shape[2:]).double()
        d = torch.as_tensor(sep, dtype=torch.float64).reshape(1, T, P, *([1] * (X.ndim - 4)))
        return (X[:, :, :, 0] - X[:, :, :, 1]) / d

    def _weight(self, noise: NoiseModel, mean_image) -> tuple[object, tuple]:
        """(per-pixel weight for λ and F at an image, flags): AWGN 1/σ²; Poisson scale/L under the zero-pixel
        policy."""
        if isinstance(noise, Poisson):
            L, n = poisson_weight_image(mean_image)
            return noise.weight(L), ((f"zero-pixels={n}",) if n else ())
        if isinstance(noise, QuadraticNoise):
            return noise.weight(to_float64(mean_image)), ()
        raise TypeError(f"bounds from replicated renders need a quadratic noise model (AWGN, Poisson), got "
                        f"{type(noise).__name__}")

    # -- curves ------------------------------------------------------------------------------------------
    def curve(self, thetas, spp: int, seeds: str = "common", replicates: int = 3, crlb: bool = True,
              barankin: bool = False, zzb: bool = True, prior=None, noises=None, fd_step: float | None = None,
              gradient: str = "fd", ad: dict | None = None, check_step: bool = True) -> Curve:
        """Every bound at each θ of a 1-D grid (G,) over Θ from R·G renders: the HCR interval (test points:
        the other grid points inside Θ, and Δ → 0), the CRLB, the paper's HCR_Neff, optionally Barankin, and
        on a uniform grid the ZZB over the grid's range (`prior`: a density on the grid, default uniform).
        The Δ → 0 term's Jacobian: FD from the grid neighbours (fd_step None with common seeds: no extra render;
        checked against the neighbours two steps away), FD at θ ± ξ (with independent seeds ξ defaults to the
        grid's smallest spacing) (fd_step ξ: 2R renders per θ, checked against ξ/2 with 2R
        more unless `check_step` is off), or with gradient "ad" Mitsuba AD with integrator options `ad`. A
        BoundPoint per (noise, θ), noise-major."""
        if self.params.dim != 1:
            raise ValueError(f"a bound curve needs one parameter; the model has {list(self.params.names)}")
        T = np.asarray(thetas, dtype=np.float64).reshape(-1)
        if T.size < 3 or np.any(np.diff(T) <= 0):
            raise ValueError("a bound curve needs at least 3 increasing grid points")
        R = _need_replicates(replicates)
        X = self.replicates(T, spp, seeds, R, "bound-curve renders")  # (R, G, *S)
        Xd = X.double()
        G = len(T)
        if gradient == "fd" and fd_step is None and seeds == "common":  # the Δ → 0 term always needs F
            J1, J2 = _grid_fd(Xd, T, 1), _grid_fd(Xd, T, 2)  # (R, G, *S) at steps ~h and ~2h
        elif gradient == "fd":  # explicit stencils (independent seeds: the grid's renders share no seed)
            fd_step = fd_step or float(np.min(np.diff(T)))
            J1 = self._fd_rounds(T[:, None], spp, seeds, R, fd_step)[:, :, 0]
            J2 = self._fd_rounds(T[:, None], spp, seeds, R, fd_step / 2)[:, :, 0] if check_step else None
        else:
            J1 = torch.stack([self.bank.jacobians_at(T, spp, float(T[1] - T[0]), PURPOSE, seeds == "common", r,
                                                     method=gradient, ad=ad)[:, 0] for r in range(R)]).double()
            J2 = None
        lo, hi = self.params.lower[0], self.params.upper[0]
        pooled = Xd.mean(dim=0)
        zzb_reason = ""
        try:
            uniform_spacing(T)
        except ValueError as e:
            zzb_reason = str(e)
        points, zzbs = [], {}
        for j, noise in self._select(noises).items():
            W, zero_flags = zip(*[self._weight(noise, pooled[g]) for g in range(G)], strict=True)
            Wflat = torch.stack([w.expand(pooled.shape[1:]).reshape(-1) for w in W]).numpy()
            lam = pairwise_ustat(Xd.reshape(R, G, -1).numpy(), Wflat)
            F1 = pixel_ustat(J1.reshape(R, G, -1).numpy(), Wflat)
            F2 = pixel_ustat(J2.reshape(R, G, -1).numpy(), Wflat) if J2 is not None else None
            plug = pairwise_lambda(pooled, noise) if not isinstance(noise, Poisson) else _plugin_poisson(pooled, Wflat)
            for g, t in enumerate(T):
                others = np.flatnonzero(np.arange(G) != g)
                deltas = T[others] - t
                b: dict[str, Bound] = {}
                fi = _slice(F1, g)
                note, step_flag = "", ()
                if J2 is not None:
                    note, step_flag = _step_check(fi, _slice(F2, g), "doubling" if fd_step is None else "halving")
                loo = lam.loo[:, g, others] if lam.loo.size else lam.loo
                sub = UStat(lam.est[g, others], lam.se[g, others], loo, R)
                iv = hcr_interval(sub, deltas, fi, self.level, lo - t, hi - t)
                b["hcr"] = interval_bound(iv, zero_flags[g] + step_flag)
                if crlb:
                    b["crlb"] = crlb_bound(fi, self.level, zero_flags[g] + step_flag, note)
                b["hcr_neff"] = hcr_bound(hcr_from_lambda(plug[g, others], deltas, lo - t, hi - t))
                if barankin:
                    b["barankin"] = _barankin(pooled[g], pooled[others], deltas, noise, lo - t, hi - t)
                points.append(BoundPoint(j, str(noise), np.array([t]), b))
            if zzb and not zzb_reason:
                zzbs[j] = self._zzb(Xd, T, noise, Wflat, prior)
            else:
                zzbs[j] = None
        return Curve(points, zzbs, zzb_reason)

    def _zzb(self, Xd: torch.Tensor, T: np.ndarray, noise: NoiseModel, Wflat: np.ndarray, prior) -> Bound:
        R = Xd.shape[0]
        if isinstance(noise, Poisson):
            stat = pairwise_ustat(np.sqrt(Xd.clamp_min(0).reshape(R, len(T), -1).numpy()), 0.5 * noise.scale)
            kind = "bhattacharyya"
        else:
            stat = pairwise_ustat(Xd.reshape(R, len(T), -1).numpy(), Wflat)
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

    # -- bounds at θ* --------------------------------------------------------------------------------------
    def at(self, thetas, spp: int, want: Sequence[str] = ("hcr", "crlb"), seeds: str = "common",
           replicates: int = 3, test_grid: int = 21, offsets: int = 4, fd_step: float = 0.01,
           levels: Sequence[int] = (1024, 2048), noises=None) -> list[BoundPoint]:
        """Every bound in `want` (hcr, crlb, hcr_neff, barankin, hcr_hat) at each θ* (T, P), a BoundPoint per
        (noise, θ*), noise-major. Test Δ: a `test_grid`^P grid over Θ (shared by every θ*, points equal to
        θ* skipped) and the offsets ±ξ·2^k (k < `offsets`) along each axis; the Δ → 0 term and the CRLB
        from FD rounds at step ξ (checked against ξ/2); HCR-hat fits λ over the spp `levels`. "hcr" also
        reports the paper's hcr_neff."""
        known = {"hcr", "crlb", "hcr_neff", "barankin", "hcr_hat"}
        bad = sorted(set(want) - known)
        if bad:
            raise ValueError(f"unknown bound kinds {bad}; known: {sorted(known)}")
        if "barankin" in want and self.params.dim > 1:
            raise ValueError(f"barankin bounds a scalar θ; this model has {list(self.params.names)}")
        p, R = self.params, _need_replicates(replicates)
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, p.dim)
        grid = p.grid(test_grid)
        need_alt = bool({"hcr", "hcr_neff", "barankin", "hcr_hat"} & set(want))
        need_fi = bool({"hcr", "crlb"} & set(want))
        center = self.replicates(thetas, spp, seeds, R, "bound renders at θ*").double()
        grid_X = self.replicates(grid, spp, seeds, R, "bound test renders").double() if need_alt else None
        J1 = self._fd_rounds(thetas, spp, seeds, R, fd_step) if need_fi else None
        J2 = self._fd_rounds(thetas, spp, seeds, R, fd_step / 2) if need_fi else None
        rows: dict[tuple[int, int], BoundPoint] = {}
        for i, theta in enumerate(thetas):
            near = np.flatnonzero(np.abs((grid - theta) / (p.upper - p.lower)).max(axis=1) > 1e-9)
            offs = axis_offsets(p, theta, offsets, fd_step)
            pts = np.concatenate([grid[near], offs])
            alt = None
            if need_alt:
                alt = grid_X[:, near]
                if len(offs):
                    alt = torch.cat([alt, self.replicates(offs, spp, seeds, R, "bound offset renders").double()], dim=1)
            lower, upper = p.lower - theta, p.upper - theta
            deltas = pts - theta if p.dim > 1 else (pts - theta)[:, 0]
            lv = None
            if "hcr_hat" in want:  # the level renders do not depend on the noise model: once per θ*
                lv = self.bank.levels_at(np.concatenate([theta[None], pts]), levels, 1, "bounds-at-levels",
                                         seeds == "common")
            L0 = center[:, i].mean(dim=0)
            for j, noise in self._select(noises).items():
                w, zero_flags = self._weight(noise, L0)
                b: dict[str, Bound] = {}
                if need_fi:
                    fi = fisher_ustat(J1[:, i], w)
                    note, step_flag = _step_check(fi, fisher_ustat(J2[:, i], w), "halving")
                    if "crlb" in want:
                        b["crlb"] = crlb_bound(fi, self.level, zero_flags + step_flag, note)
                if need_alt and {"hcr", "hcr_neff"} & set(want):
                    if "hcr" in want:
                        D = (alt - center[:, i][:, None]).reshape(R, alt.shape[1], -1).numpy()  # (R, K, N)
                        lam = pixel_ustat(D, to_float64(w).expand(L0.shape).reshape(-1).numpy())
                        iv = hcr_interval(lam, deltas, fi, self.level, lower, upper)
                        b["hcr"] = interval_bound(iv, zero_flags + step_flag)
                    plug = _FixedWeight(w).chi2_exponent(L0, alt.mean(dim=0))
                    b["hcr_neff"] = hcr_bound(hcr_from_lambda(plug, deltas, lower, upper))
                if "barankin" in want:
                    b["barankin"] = _barankin(L0, alt.mean(dim=0), deltas, noise, lower, upper)
                if "hcr_hat" in want:
                    r = inexact_hcr(lv[:, :, 0], lv[:, :, 1:], deltas, levels, _FixedWeight(w), L0[None],
                                    alt.mean(dim=0)[None], spp * R, lower, upper)
                    b["hcr_hat"] = hcr_bound(r.hcr_hat, "hcr_hat")
                rows[j, i] = BoundPoint(j, str(noise), theta.copy(), b)
        return [rows[j, i] for j in self._select(noises) for i in range(len(thetas))]

    # -- Fisher information ------------------------------------------------------------------------------
    def fisher(self, thetas, spp: int, fd_step: float = 0.01, rounds: int = 3, reduce: str = "sum",
               noises=None) -> list[FisherPoint]:
        """Unbiased per-pixel Fisher information maps and the CRLB per parameter at each θ (T, P): a render
        (purpose "fisher", the Poisson weight image) and `rounds` independent central-FD Jacobians (step ξ,
        common random numbers inside each stencil; purpose "fisher-fd", replicate r) per θ."""
        if rounds < 2:
            raise ValueError(f"an unbiased Fisher information needs >= 2 independent FD rounds, got {rounds}")
        if reduce not in ("sum", "mean"):
            raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        Ls = self.bank.at(thetas, spp, "fisher", desc="Fisher-map renders")
        Js = torch.stack([self.bank.jacobians_at(thetas, spp, fd_step, "fisher", replicate=r,
                                                 desc=f"Fisher-map FD Jacobians (round {r})") for r in range(rounds)])
        out = []
        for i, (t, L) in enumerate(zip(thetas, Ls, strict=True)):
            maps, bounds = {}, {}
            for j, noise in self._select(noises).items():
                w, flags = self._weight(noise, L)
                m = unbiased_fisher(Js[:, i], w.expand(L.shape)).pixel_map  # (P, H, W, C)
                maps[j] = m.sum(axis=-1) if reduce == "sum" else m.mean(axis=-1)
                bounds[j] = [crlb_bound(fisher_ustat(Js[:, i, k:k + 1], w), self.level, flags)
                             for k in range(self.params.dim)]
            out.append(FisherPoint(t, L, Js[:, i].mean(dim=0), maps, bounds))
        return out

    # -- the paper's HCR intervals from inexact renders -----------------------------------------------------
    def interval(self, thetas, deltas, levels: Sequence[int], n_eff: int, replicates: int, power: float = 1.0,
                 bootstrap: int = 0, confidence: float = 0.9, boot_seed: int = 0, seeds: str = "independent",
                 noises=None) -> list[tuple[BoundPoint, InexactHCR]]:
        """The paper's [HCR_Neff, HCR-hat] at each scalar θ* from render sets of every θ* and θ* + Δ (Δ inside
        Θ): k spp levels × R replicates (purpose "inexact-levels") and R replicates at N_eff (purpose
        "inexact-neff"); a render serves every θ* that uses it. Returns (BoundPoint with hcr_neff and
        hcr_hat, the full InexactHCR) per (noise, θ*), noise-major. `boot_seed` drives the bootstrap."""
        if self.params.dim != 1:
            raise ValueError(f"the HCR interval needs one parameter; the model has {list(self.params.names)}")
        _check(seeds, replicates)
        points, plan = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        common = seeds == "common"
        X = self.bank.levels_at(points, levels, replicates, "inexact-levels", common)
        Xe = self.bank.levels_at(points, [n_eff], replicates, "inexact-neff", common)[0]
        out = []
        for m, (j, noise) in enumerate(self._select(noises).items()):
            for t, (theta, (q0, d, qd)) in enumerate(zip(np.asarray(thetas, dtype=np.float64), plan, strict=True)):
                r = inexact_hcr(X[:, :, q0], X[:, :, qd], d, levels, noise, Xe[:, q0], Xe[:, qd], n_eff, power=power,
                                bootstrap=bootstrap, confidence=confidence,
                                seed=derive(boot_seed, "interval-bootstrap", m, t))
                neff, hat = hcr_bound(r.hcr_neff, "hcr_neff"), hcr_bound(r.hcr_hat, "hcr_hat")
                if r.fit.noise_dominated.any():
                    hat = Bound(hat.kind, hat.log10, hat.delta, hat.flags + ("noise-dominated",), hat.reason,
                                point=hat.point)
                out.append((BoundPoint(j, str(noise), np.array([theta]), {"hcr_neff": neff, "hcr_hat": hat}), r))
        return out

    def interval_renders(self, thetas, deltas, levels: Sequence[int], replicates: int,
                         seeds: str = "independent") -> torch.Tensor:
        """The level renders (k, R, Q, H, W, C) of `interval`'s render points (from the bank: no new
        renders once `interval` ran), e.g. for the 1/N decay check."""
        points, _ = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        return self.bank.levels_at(points, levels, replicates, "inexact-levels", seeds == "common")


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


def _step_check(fine: UStat, coarse: UStat, how: str) -> tuple[str, tuple]:
    """(note, flags) comparing F at two FD steps (scalar θ: F; vector: the trace)."""
    a, b = float(np.trace(fine.est)), float(np.trace(coarse.est))
    sa = float(np.sqrt(np.nansum(np.diag(fine.se) ** 2)))
    sb = float(np.sqrt(np.nansum(np.diag(coarse.se) ** 2)))
    ratio = a / b if b > 0 and a > 0 else math.nan
    note = f"FD step {how}: F changes by ×{ratio:.3g}" if math.isfinite(ratio) else f"FD step {how}: F unresolved"
    sensitive = math.isfinite(sa) and math.isfinite(sb) and abs(a - b) > 2 * math.hypot(sa, sb)
    return note, (("fd-step-sensitive",) if sensitive else ())


def _slice(F: UStat, g: int) -> UStat:
    """The scalar UStat (1, 1) of quantity g of a vector UStat (est (G,), loo (R, G))."""
    loo = F.loo[:, g].reshape(-1, 1, 1) if F.loo.size else F.loo.reshape(0, 1, 1)
    return UStat(F.est[g].reshape(1, 1), F.se[g].reshape(1, 1), loo, F.replicates, F.dof[g].reshape(1, 1))


def _barankin(L0, L_alt, deltas, noise, lower, upper) -> Bound:
    r = barankin(L0, L_alt, deltas, noise, lower=lower, upper=upper)
    return Bound("barankin", float(r.log10), tuple(np.atleast_1d(r.deltas).tolist()) or None,
                 ("plug-in",) + (("unresolved",) if r.unresolved else ()), r.reason, point=float(r.log10),
                 extra={"points": len(r.points), "tightening": r.tightening, "cond": r.cond})


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


__all__ = ["AWGN", "Bound", "BoundPoint", "BoundService", "Curve", "FisherPoint", "interval_points"]
