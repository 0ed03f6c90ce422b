"""The bound service's results: `Bound` (one kind at one θ), `BoundPoint` (every kind at one θ for one
noise model), `Curve`, `FisherPoint`, and the converters from the bound functions' results to a `Bound`."""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from nlosbench.bounds.barankin import barankin
from nlosbench.bounds.fd_step import StepFisher, crlb_term, single
from nlosbench.bounds.hcr import HCRResult
from nlosbench.bounds.hcr_interval import HCRInterval
from nlosbench.bounds.precision import Precision
from nlosbench.bounds.ustat import UStat


@dataclass(frozen=True)
class Bound:
    """One bound (parameter units²), as every study reports it; frozen.

    log10 is exact even where the value underflows; −inf: no usable test point, +inf: no resolved
    information (see `flags`, `reason`). Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    kind : str
        Which bound: "hcr", "crlb", "hcr_neff", "hcr_hat", "barankin" or "zzb" (see the module docstring).
    log10 : float
        log10 of the value to quote (for an interval kind, its lower end).
    delta : tuple of float, optional
        The Δ at the sup (HCR family); None where the kind has none.
    flags : tuple of str, optional
        Short tags: sup-at-smallest-delta, sup-at-largest-delta, unresolved, unresolved-delta, no-bound,
        estimate-only, upper-unbounded, ends-crossed, singular, fd-step-not-converged, fd-step-diverging,
        zero-pixels=N, grid-limited, plug-in, noise-dominated.
    reason : str, optional
        What the value is and why it is flagged.
    lower, upper, point : float, optional
        log10 ends and estimate of an interval bound (None where the kind has none; upper +inf: open).
    level : float, optional
        The one-sided confidence of each end (None without one).
    terms : str, optional
        Which term set each end (e.g. "lower: Δ → 0; upper: Δ = +0.1; point: Δ → 0").
    extra : dict, optional
        Details (e.g. Barankin's number of points, the ZZB's prior variance).
    loo : ndarray of shape (R,), optional
        log10 point estimate without each replicate set (hcr, crlb with R ≥ 3; else empty), for
        jackknifes of quantities that pair two bounds from the same replicate sets.
    lower_note, upper_note : str, optional
        Why that end is not a confidence limit ("" when it is one).

    Examples
    --------
    >>> b = nb.bounds.Bound("crlb", -2.0, flags=("singular",))
    >>> b.value
    0.01
    >>> b.columns()["crlb_flags"]
    'singular'
    """

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
    lower_note: str = ""
    upper_note: str = ""

    @property
    def value(self) -> float:
        """10^log10 (0 where it underflows, +inf where it overflows)."""
        return _exp10(self.log10)

    def columns(self) -> dict:
        """Flat CSV cells of this bound.

        Returns
        -------
        dict
            log10_<kind>, then (where present) <kind>_lower/_upper/_point/_level/_terms, with an interval
            <kind>_lower_note/_upper_note, and <kind>_delta (JSON), <kind>_flags (comma-separated),
            <kind>_reason.
        """
        out = {f"log10_{self.kind}": self.log10}
        for name in ("lower", "upper", "point", "level"):
            if getattr(self, name) is not None:
                out[f"{self.kind}_{name}"] = getattr(self, name)
        if self.lower is not None:
            out[f"{self.kind}_lower_note"], out[f"{self.kind}_upper_note"] = self.lower_note, self.upper_note
        if self.terms:
            out[f"{self.kind}_terms"] = self.terms
        out.update({f"{self.kind}_delta": json.dumps(self.delta), f"{self.kind}_flags": ",".join(self.flags),
                    f"{self.kind}_reason": self.reason})
        return out


def _exp10(lg: float) -> float:
    return math.inf if lg > 308 else (10.0 ** lg if lg > -400 else 0.0)


@dataclass
class BoundPoint:
    """Every bound asked for at one θ for one noise model.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    noise_index : int
        The noise model's index in the service.
    noise : str
        Its name (str of the model).
    theta : ndarray of shape (P,)
        The parameter point, parameter units.
    bounds : dict of str to Bound
        {kind: Bound}.
    precision : Precision, optional
        With a precision target (`BoundService.at(precision=...)`): the target, what was reached and the
        pixel-samples spent (`bounds.precision.Precision`); None without one.

    Examples
    --------
    >>> import numpy as np
    >>> point = nb.bounds.BoundPoint(0, "AWGN(sigma=0.05)", np.array([0.5]), {"crlb": nb.bounds.Bound("crlb", -4.0)})
    >>> row = point.row(["x"])
    >>> row["theta_x"], row["log10_crlb"], point.bounds["crlb"].value
    (0.5, -4.0, 0.0001)
    """

    noise_index: int
    noise: str
    theta: np.ndarray
    bounds: dict[str, Bound]
    precision: Precision | None = None

    def row(self, names: Sequence[str]) -> dict:
        """A CSV row: noise, θ per parameter, then every bound's columns.

        Parameters
        ----------
        names : sequence of str
            The parameter names (P), for the theta_<name> columns.

        Returns
        -------
        dict
            noise_index, noise, theta_<name> per parameter, then `Bound.columns` of every bound, and with a
            precision target the precision_* columns.
        """
        out = {"noise_index": self.noise_index, "noise": self.noise,
               **{f"theta_{n}": float(v) for n, v in zip(names, self.theta, strict=True)}}
        for b in self.bounds.values():
            out.update(b.columns())
        if self.precision is not None:
            out.update(self.precision.columns())
        return out


@dataclass
class Curve:
    """A bound curve over a 1-D grid, returned by `BoundService.curve`.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    points : list of BoundPoint
        A BoundPoint per (noise, θ), noise-major.
    zzb : dict of int to Bound or None
        Per noise index, the ZZB over the grid's range (None when the grid is not uniform, θ is not scalar
        or the ZZB was not asked for).
    zzb_reason : str, optional
        Why there is no ZZB ("" when there is one or it was not asked for).
    precise : list of BoundPoint, optional
        With a precision target (`BoundService.curve(precision=...)`): a BoundPoint per (noise, quoted θ),
        noise-major, with the interval bounds (hcr, with its hcr_neff, and crlb) brought to the target by
        `BoundService.at` and each with its `precision` record; empty without a target.

    Examples
    --------
    The blob's horizontal position over a 5 cm grid; every HCR lower end sits at or below the CRLB:

    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> service = nb.bounds.BoundService(nb.RenderBank(model, seed=0), [nb.noise.AWGN(sigma=0.05)])
    >>> curve = service.curve(np.linspace(0.3, 0.7, 9), spp=4)
    >>> len(curve.points), curve.zzb[0].flags  # the grid is too coarse for the Ziv–Zakai bound at this σ
    (9, ('grid-limited',))
    >>> all(p.bounds["hcr"].lower <= p.bounds["crlb"].log10 for p in curve.points)
    True
    """

    points: list[BoundPoint]
    zzb: dict[int, Bound | None]
    zzb_reason: str = ""
    precise: list[BoundPoint] = field(default_factory=list)


@dataclass
class FisherPoint:
    """Per-pixel Fisher information at one θ, returned by `BoundService.fisher`.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    theta : ndarray of shape (P,)
        The parameter point, parameter units.
    L : torch.Tensor of shape (H, W, C)
        The render at θ (also the Poisson weight image).
    J : torch.Tensor of shape (P, H, W, C)
        The mean FD Jacobian over R independent rounds (at the finest step tried).
    maps : dict of int to ndarray of shape (P, H, W)
        Per noise index, the unbiased per-pixel maps (1/units²; they can be negative where rendering noise
        dominates; they sum to the unbiased F_jj).
    crlb : dict of int to list of Bound
        Per noise index, the CRLB of each parameter (P Bounds with their intervals).
    rounds : torch.Tensor of shape (R, P, H, W, C)
        The R independent FD Jacobians (float64) at `step`, the rounds the maps are U-statistics over.
    step : float
        The FD step ξ of `rounds` and `J` (the finest tried), parameter units.
    weights : dict of int to torch.Tensor of shape (H, W, C)
        Per noise index, the per-pixel weight of the maps (AWGN 1/σ²; Poisson scale/L), float64.
    precise : dict of int to BoundPoint, optional
        With a precision target (`BoundService.fisher(precision=...)`): per noise index the CRLB of θ
        (tr F̂⁻¹) with its `precision` record; empty without one.

    Examples
    --------
    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> service = nb.bounds.BoundService(nb.RenderBank(model, seed=0), [nb.noise.AWGN(sigma=0.05)])
    >>> [fp] = service.fisher([0.5], spp=4)
    >>> fp.maps[0].shape  # (P, H, W)
    (1, 24, 24)
    >>> bool(np.isclose(fp.crlb[0][0].point, -np.log10(fp.maps[0].sum())))  # the maps add up to F; CRLB = 1/F
    True
    """

    theta: np.ndarray
    L: torch.Tensor
    J: torch.Tensor
    maps: dict[int, np.ndarray]
    crlb: dict[int, list[Bound]]
    rounds: torch.Tensor
    step: float
    weights: dict[int, torch.Tensor]
    precise: dict[int, BoundPoint] = field(default_factory=dict)


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


def interval_bound(iv: HCRInterval, extra_flags: tuple = (), step: StepFisher | None = None) -> Bound:
    """The `hcr` Bound from an HCRInterval: log10 = its lower end; `step` adds the FD step note."""
    terms = f"lower: {iv.lower_term}; upper: {iv.upper_term}; point: {iv.point_term}"
    reason = ("both ends are point estimates (fewer than 3 replicates)" if iv.estimate_only else
              f"one-sided {iv.level:.0%} limits from {iv.replicates} replicates over {iv.tested} tested Δ and Δ → 0 "
              "(the CRLB term), the lower end's jointly over those that could reach the sup; the upper end bounds the "
              "HCR over the tested Δ and Δ → 0")
    if iv.unresolved:
        reason += f"; unresolved Δ (λ_L ≤ 0: the upper end is open): {iv.unresolved}"
    if step is not None and step.checked:
        reason += "; " + step.note() + (f" ({step.settle()})" if step.settle() else "")
    return Bound("hcr", iv.lower, None, iv.flags + tuple(extra_flags), reason, lower=iv.lower, upper=iv.upper,
                 point=iv.point, level=iv.level, terms=terms, loo=iv.point_loo, lower_note=iv.lower_note,
                 upper_note=iv.upper_note)


def crlb_bound(sf: StepFisher | UStat, level: float, extra_flags: tuple = (), index: int | None = None,
               kind: str = "crlb", smoothed: bool = False) -> Bound:
    """The `crlb` Bound (trace of F̂⁻¹, units²) from the unbiased Fisher information at every FD stage tried
    (`fd_step`; a UStat of F (P, P): one stage, no step check), with one-sided ends at `level`; with `index` j the
    CRLB of θ_j alone, (F̂⁻¹)_jj, every other parameter unknown (nuisance), under the name `kind`; `smoothed`: of
    the FD-smoothed model at an unchecked step (`fd_step.crlb_term`)."""
    sf = sf if isinstance(sf, StepFisher) else single(sf)
    term = crlb_term(sf, level, index=index, smoothed=smoothed)
    R = sf.final.replicates
    flags = list(extra_flags) + list(term.flags)
    if not math.isfinite(term.point):
        flags.append("singular" if sf.final.est.shape[0] > 1 else "unresolved")
    if R < 3:
        flags.append("estimate-only")
    reason = ("no resolved information: F̂ is not positive" if not math.isfinite(term.point) else
              f"CRLB from an unbiased FI (U-statistic over {R} FD rounds; the FI of the FD-smoothed derivative)"
              if not math.isnan(sf.steps[-1]) else
              f"CRLB from an unbiased FI (U-statistic over {R} independent Jacobians without an FD step, e.g. AD "
              "passes: the FI of the derivative they estimate, biased or not)")
    if sf.checked:
        reason += "; " + (term.zero_note or sf.note()) + (f" ({sf.settle()})" if sf.settle() else "")
    elif term.smoothed:
        reason += f"; of the model smoothed by the FD step ξ = {sf.steps[-1]:.3g} (not checked: not the CRLB of L(θ))"
    if index is not None:
        reason += f"; (F̂⁻¹)_{index}{index} of the full {sf.final.est.shape[0]}-parameter F̂: the others unknown"
    return Bound(kind, term.point, flags=tuple(flags), reason=reason, lower=term.lower, upper=term.upper,
                 point=term.point, level=level if R >= 3 else None, loo=term.loo, lower_note=term.lower_note,
                 upper_note=term.upper_note)


def _barankin(L0, L_alt, deltas, noise, lower, upper) -> Bound:
    r = barankin(L0, L_alt, deltas, noise, lower=lower, upper=upper)
    return Bound("barankin", float(r.log10), tuple(np.atleast_1d(r.deltas).tolist()) or None,
                 ("plug-in",) + (("unresolved",) if r.unresolved else ()), r.reason, point=float(r.log10),
                 extra={"points": len(r.points), "tightening": r.tightening, "cond": r.cond})


