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
  hcr       the HCR on the MSE as a confidence interval with its Δ → 0 term, the CRLB term (`hcr_interval`):
            log10 = the lower end (a one-sided lower confidence limit at `level`), `upper` the upper end (+inf:
            open, whenever a tested Δ is unresolved), `point` the estimate, `terms` which term set each end.
            λ(Δ) and F are U-statistics over the R replicates (`ustat`): unbiased, so rendering noise no longer
            inflates λ (the C/N term) or F;
  crlb      the CRLB from the unbiased Fisher information (trace of F̂⁻¹; 1/F̂ for a scalar θ): log10 the
            central value (+inf when F̂ ≤ 0: no resolved information), `lower`/`upper` its ends (from the
            largest upper / smallest lower confidence limit of F over the FD steps tried). F is the FI of the
            FD-smoothed derivative, biased low where an edge crosses a pixel within the step: `at` and `fisher`
            halve the step until F is shown to have stopped rising (`fd_step`), `curve` checks h against 2h;
            a lower end whose step did not converge carries `lower_note` "not a confidence limit: …";
  hcr_neff  the paper's HCR_Neff: the plug-in λ̃ of the replicate means (R·spp samples per image), sup
            over the tested Δ only (no Δ → 0 term, so it can fall far below the CRLB: the paper's 80 cm row);
  hcr_hat   the paper's HCR-hat (bias-corrected λ̂ from a fit over spp levels), point estimate: an upper bound
            in expectation on the HCR restricted to the tested Δ (not on the HCR over every Δ);
  barankin  multi-point Barankin bound on Var θ̂ of a scalar θ from the replicate means (plug-in);
  zzb       (curves on a uniform grid) the Ziv–Zakai bound on the Bayesian MSE over the prior on the grid's
            range, for every estimator (`zzb`): log10 the lower end (the bound to quote: P_e is convex in the
            distance, so the point errs either way), with `upper`, `point`; for Poisson noise the Bhattacharyya
            distance is an upper estimate (`zzb.bhattacharyya_ustat`) whose weight comes from R weight renders,
            one per replicate set, so the ends carry the weight's noise too.

Poisson weights scale/L come from one render of each θ independent of every replicate (purpose
"bounds-weight", spp samples): a weight computed from the same replicates as a U-statistic would correlate
with it (E[1/L̄] > 1/L enters as a cross term). E[1/Y] ≥ 1/L, so the weight errs high by about Var(Y)/L²
(stated, not corrected). The *zero-pixel policy*: a pixel whose weight render is exactly 0 (no sample found
light) gets the weight of the smallest positive value in that image instead of +inf, and the count of such
pixels is in the flags (never a silent −inf or a dropped Δ).
"""
from __future__ import annotations

import copy
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from nlosbench.bank import RenderBank, Request
from nlosbench.bounds.barankin import barankin
from nlosbench.bounds.fd_step import Stage, StepFisher, converge, crlb_term, halving, single
from nlosbench.bounds.grid import pairwise_lambda
from nlosbench.bounds.hcr import HCRResult, hcr_from_lambda
from nlosbench.bounds.hcr_interval import HCRInterval, hcr_interval
from nlosbench.bounds.inexact import InexactHCR, inexact_hcr
from nlosbench.bounds.precision import Precision, Raw, SetCost, check_precision, refine
from nlosbench.bounds.unbiased_fisher import unbiased_fisher
from nlosbench.bounds.ustat import UStat, pairwise_ustat, pixel_ustat
from nlosbench.bounds.zzb import bhattacharyya_ustat, uniform_spacing, zzb_interval
from nlosbench.noise import AWGN, NoiseModel, Poisson, QuadraticNoise, bounds_refusal, to_float64
from nlosbench.seeds import derive

SEEDS = ("independent", "common")
PURPOSE = "bounds"


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
    """

    points: list[BoundPoint]
    zzb: dict[int, Bound | None]
    zzb_reason: str = ""
    precise: list[BoundPoint] = field(default_factory=list)


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
                 point=iv.point, level=iv.level, terms=terms, loo=iv.point_loo, lower_note=iv.lower_note)


def crlb_bound(sf: StepFisher | UStat, level: float, extra_flags: tuple = (), index: int | None = None,
               kind: str = "crlb") -> Bound:
    """The `crlb` Bound (trace of F̂⁻¹, units²) from the unbiased Fisher information at every FD stage tried
    (`fd_step`; a UStat of F (P, P): one stage, no step check), with one-sided ends at `level`; with `index` j the
    CRLB of θ_j alone, (F̂⁻¹)_jj, every other parameter unknown (nuisance), under the name `kind`."""
    sf = sf if isinstance(sf, StepFisher) else single(sf)
    term = crlb_term(sf, level, index=index)
    R = sf.final.replicates
    flags = list(extra_flags) + list(term.flags)
    if not math.isfinite(term.point):
        flags.append("singular" if sf.final.est.shape[0] > 1 else "unresolved")
    if R < 3:
        flags.append("estimate-only")
    reason = ("no resolved information: F̂ is not positive" if not math.isfinite(term.point) else
              f"CRLB from an unbiased FI (U-statistic over {R} FD rounds; the FI of the FD-smoothed derivative)")
    if sf.checked:
        reason += "; " + (term.zero_note or sf.note()) + (f" ({sf.settle()})" if sf.settle() else "")
    if index is not None:
        reason += f"; (F̂⁻¹)_{index}{index} of the full {sf.final.est.shape[0]}-parameter F̂: the others unknown"
    return Bound(kind, term.point, flags=tuple(flags), reason=reason, lower=term.lower, upper=term.upper,
                 point=term.point, level=level if R >= 3 else None, loo=term.loo, lower_note=term.lower_note)


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
    """Bounds from a render bank for a set of noise models (see the module docstring).

    Parameters
    ----------
    bank : RenderBank
        The run's render bank (`nlosbench.RenderBank`): it renders, caches and seeds every render set, and
        its model's parameter space Θ bounds every Δ.
    noises : dict of int to NoiseModel, or sequence of NoiseModel
        The noise models (index → model; a list is indexed 0, 1, …). Bounds from replicated renders need
        quadratic models (AWGN, Poisson).
    level : float, optional
        One-sided confidence of every interval end, in (0, 1).

    See Also
    --------
    nlosbench.bound : One bound at one θ* from a scene's name, with stated defaults.

    Examples
    --------
    >>> bank = nb.RenderBank(nb.scenes.get("edge1d"), seed=0)
    >>> service = nb.bounds.BoundService(bank, [nb.noise.AWGN(sigma=0.05)])
    >>> [point] = service.at([0.5], spp=4)
    >>> sorted(point.bounds)
    ['crlb', 'hcr', 'hcr_neff']
    >>> crlb = point.bounds["crlb"]
    >>> crlb.lower <= crlb.point <= crlb.upper
    True
    """

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
        return torch.stack([self.bank.at(pts, spp, PURPOSE, seeds == "common", r, desc=f"{desc} (replicate {r})")
                            for r in range(first, first + R)])

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
        step : float
            The FD step ξ, parameter units (stencils clipped into Θ turn one-sided).

        Returns
        -------
        torch.Tensor of shape (R, T, P, N)
            The rounds, float64, pixels flattened (N = H·W·C); units radiance per parameter unit.
        """
        _check(seeds, R)
        pts = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        stages = self._stages(pts, None, spp, seeds, R, float(step))
        return torch.from_numpy(np.stack([s.rounds["central"] for s in stages], axis=1))

    def _stages(self, thetas: np.ndarray, center: torch.Tensor | None, spp: int, seeds: str, R: int,
                step: float, first: int = 0, purpose: str = PURPOSE, sided: bool = True) -> list[Stage]:
        """One FD Stage at step ξ per θ of thetas (T, P), R rounds, each independent of the others and with
        common random numbers inside each stencil: the central differences of round r's stencil renders (θ ± ξ e_j
        clipped into Θ) and, from a render of θ under the stencil's seed, the forward and backward differences —
        the one-sided variants the step check needs near a kink (`fd_step`). Common seeds: round r is replicate
        set r (every θ shares its seed) and θ's render is `center` (R, T, *S) of the same replicates (None: no
        one-sided variants); independent seeds: a seed per θ and round, shared by its stencil and θ's own render
        (purpose `purpose` + "-stencil", not by other θ), the same at every step, so stages pair; `sided` False
        leaves θ's render out (one step, no check: the one-sided variants would decide nothing; with common seeds
        `center` costs nothing and is used regardless). Rounds are the replicate sets first … first + R − 1."""
        T, P = thetas.shape
        st, sep = self._stencils(thetas, step)
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
            out.append(Stage(step, rounds, self.group))
        return out

    def _refine(self, thetas: np.ndarray, stage_fn, weights: dict, step: float, step_tol: float,
                max_halvings: int) -> list[list[Stage]]:
        """FD stages (coarse to fine) per θ of thetas (T, P): ξ, then ξ/2, ξ/4 … for the θ whose step has not
        converged (`fd_step.halving`) for every weight in `weights` ({noise index: [w per θ]}), at most
        `max_halvings` times. stage_fn(index array, ξ) gives the stages of those θ."""
        _check_step(step, step_tol, max_halvings)
        stages: list[list[Stage]] = [[] for _ in thetas]
        active = np.arange(len(thetas))
        for k in range(max_halvings + 1):
            for i, stage in zip(active, stage_fn(active, step / 2**k), strict=True):
                stages[i].append(stage)
            if k == max_halvings:
                break
            if k:
                active = np.array([i for i in active if not all(
                    halving(stages[i][-2], stages[i][-1], w[i], self.level, step_tol).converged
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

    # -- curves ------------------------------------------------------------------------------------------
    def curve(self, thetas, spp: int, seeds: str = "common", replicates: int = 3, crlb: bool = True,
              barankin: bool = False, zzb: bool = True, prior=None, noises=None, fd_step: float | None = None,
              gradient: str = "fd", ad: dict | None = None, check_step: bool = True, step_tol: float = 0.1,
              precision: float | None = None, budget: int | None = None, looks: int = 3, quote=None,
              max_halvings: int = 3) -> Curve:
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
        (`quote_test_grid`), `at`'s default axis offsets, its FD step `fd_step` or the grid's smallest spacing,
        halved at most `max_halvings` times, and fresh replicate sets where an interval is wider than ±p
        (`bounds.precision`), in `Curve.precise`.

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
        precision : float, optional
            The target p > 0 of the quoted bounds (relative half-width, linear units; as in `at`); None: no
            quoted bounds.
        budget : int, optional
            A cap on the pixel-samples (spp × H × W × renders) the quoted bounds may spend beyond the curve's
            renders; None: unlimited (with a precision target only).
        looks : int, optional
            K ≥ 2: the pilot and at most K − 1 looks at fresh sets, each quoted end at level 1 − (1 − level)/K.
        quote : array_like of shape (Q,), optional
            The θ to quote (on or off the grid, inside Θ), parameter units; None: every grid θ (with a precision
            target only).
        max_halvings : int, optional
            The most halvings of the quoted bounds' FD step, in [0, 12].

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
        kinds = ("hcr", "crlb") if crlb else ("hcr",)
        check_precision(precision, budget, looks, kinds, R)
        if quote is not None and precision is None:
            raise ValueError("quote needs a precision target (precision=...)")
        quoted = T if quote is None else np.array(
            [self.params.validate([t])[0] for t in np.asarray(quote, dtype=np.float64).reshape(-1)])
        if quoted.size == 0:
            raise ValueError("quote must hold at least one θ (None: every grid θ)")
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
        points, zzbs = [], {}
        for j, noise in self._select(noises).items():
            Wflat = np.stack([w for w, _ in weights[j]])
            plug = pairwise_lambda(pooled, noise) if not isinstance(noise, Poisson) else _plugin_poisson(pooled, Wflat)
            for g, t in enumerate(T):
                others = np.flatnonzero(np.arange(G) != g)
                deltas = T[others] - t
                flags = weights[j][g][1]
                sf = converge(stages[g], Wflat[g], self.level, step_tol, spp)
                # row g of the pairwise λ (`pairwise_ustat`), with the per-pixel terms the lower end's joint level uses
                sub = pixel_ustat((Xd[:, others] - Xd[:, g:g + 1]).reshape(R, G - 1, -1).numpy(), Wflat[g], self.group)
                b: dict[str, Bound] = {}
                b["hcr"] = interval_bound(hcr_interval(sub, deltas, sf, self.level, lo - t, hi - t), flags, sf)
                if crlb:
                    b["crlb"] = crlb_bound(sf, self.level, flags)
                b["hcr_neff"] = hcr_bound(hcr_from_lambda(plug[g, others], deltas, lo - t, hi - t))
                if barankin:
                    b["barankin"] = _barankin(pooled[g], pooled[others], deltas, noise, lo - t, hi - t)
                points.append(BoundPoint(j, str(noise), np.array([t]), b))
            zzbs[j] = self._zzb(Xd, T, noise, Wflat, prior, spp) if zzb and not zzb_reason else None
        precise = [] if precision is None else self.at(
            quoted[:, None], spp, kinds, seeds, R, quote_test_grid(self.params, T),
            fd_step=fd_step or float(np.diff(T).min()), noises=noises, step_tol=step_tol, max_halvings=max_halvings,
            precision=precision, budget=budget, looks=looks)
        return Curve(points, zzbs, zzb_reason, precise)

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
            Y = torch.stack([self.bank.at(T, spp, PURPOSE + "-weight", replicate=r,
                                          desc=f"Poisson weight renders (replicate {r})") for r in range(R)]).double()
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

    # -- bounds at θ* --------------------------------------------------------------------------------------
    def at(self, thetas, spp: int, want: Sequence[str] = ("hcr", "crlb"), seeds: str = "common",
           replicates: int = 3, test_grid: int = 21, offsets: int = 4, fd_step: float = 0.01,
           levels: Sequence[int] = (1024, 2048), noises=None, step_tol: float = 0.1,
           max_halvings: int = 3, precision: float | None = None, budget: int | None = None,
           looks: int = 3) -> list[BoundPoint]:
        """Every bound in `want` (hcr, crlb, hcr_neff, barankin, hcr_hat) at each θ* (T, P).

        Test Δ: a `test_grid`^P grid over Θ (shared by every θ*, points equal to θ* skipped) and the
        offsets ±ξ·2^k (k < `offsets`) along each axis; the Δ → 0 term and the CRLB from FD rounds at step
        ξ, halved (with the same seeds) until F is shown to have stopped rising within 1 + `step_tol`, at
        most `max_halvings` times (`fd_step`); HCR-hat fits λ over the spp `levels`. "hcr" also reports the
        paper's hcr_neff. Poisson weights come from one independent render per θ*.
        With a `precision` target p (relative half-width, linear units): fresh replicate sets are added only
        where an interval is wider than p, within `budget` pixel-samples, in at most `looks` looks with ends
        at level 1 − (1 − level)/looks, so coverage holds whatever the stopping (`bounds.precision`); each
        BoundPoint then carries a `precision` record.

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
            R ≥ 2 independent replicates of every render set (≥ 3 for confidence limits).
        test_grid : int, optional
            Points per axis of the grid of test points over Θ.
        offsets : int, optional
            Number of axis offsets ±ξ·2^k per side and axis.
        fd_step : float, optional
            The first FD step ξ, parameter units (also the base of the axis offsets).
        levels : sequence of int, optional
            spp levels of the HCR-hat fit (at least 2 distinct).
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute bounds for; None: every model.
        step_tol : float, optional
            Relative tolerance of the step check (0.1: F within 10 %).
        max_halvings : int, optional
            The most halvings of ξ, in [0, 12].
        precision : float, optional
            The target p > 0: every interval bound asked for (hcr, crlb) has upper/point ≤ 1 + p and
            point/lower ≤ 1 + p (an open end or one that is not a confidence limit does not meet it). None:
            one fixed set of `replicates` (today's behaviour).
        budget : int, optional
            A cap on the pixel-samples (spp × H × W × renders) this call may spend; None: unlimited (with a
            precision target only).
        looks : int, optional
            K ≥ 2: the pilot and at most K − 1 looks at fresh sets, each at level 1 − (1 − level)/K.

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
        _check_step(fd_step, step_tol, max_halvings)
        check_precision(precision, budget, looks, want, R)
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, p.dim)
        args = (spp, want, seeds, test_grid, offsets, fd_step, levels, noises, step_tol, max_halvings)
        if precision is None:
            return self._at(thetas, R, 0, *args)
        need_alt = bool({"hcr", "hcr_neff", "barankin", "hcr_hat"} & set(want))
        need_fi = bool({"hcr", "crlb", "crlb_each"} & set(want))
        cost = SetCost(p.grid(test_grid).shape[0] if need_alt else 0,
                       np.array([1 + (len(axis_offsets(p, t, offsets, fd_step)) if need_alt else 0) for t in thetas]),
                       2 * p.dim if need_fi else 0, max_halvings + 1)

        def look(idx: np.ndarray, reps: int, first: int, level: float, keep: dict, window, tested) -> list[BoundPoint]:
            sub = copy.copy(self)
            sub.level = level
            stages = {} if window is None else {"fd_start": fd_step / 2**window.start, "halvings": window.halvings}
            return sub._at(thetas[idx], reps, first, *args, keep=keep, tested=tested, **stages)

        return refine(look, len(thetas), list(self._select(noises)), R, precision, budget, looks, 1 - self.level,
                      cost, spp, self.bank)

    def _at(self, thetas: np.ndarray, R: int, first: int, spp: int, want: Sequence[str], seeds: str, test_grid: int,
            offsets: int, fd_step: float, levels: Sequence[int], noises, step_tol: float, max_halvings: int,
            keep: dict | None = None, fd_start: float | None = None, halvings: int | None = None,
            tested: dict | None = None) -> list[BoundPoint]:
        """`at` on the replicate sets first … first + R − 1 at the service's level; `keep`, when given, is filled
        with {(noise index, θ index): the raw data a precision plan needs (`precision.Raw`)}; a precision look's
        FD stages start at `fd_start` and halve at most `halvings` times (None: `fd_step`, `max_halvings`; the
        axis offsets keep `fd_step` as their base), and where `tested` {θ index: mask or None} gives a mask over
        θ*'s test points (the grid's other points, then the offsets) only those are rendered and tested."""
        p = self.params
        grid = p.grid(test_grid)
        need_alt = bool({"hcr", "hcr_neff", "barankin", "hcr_hat"} & set(want))
        need_fi = bool({"hcr", "crlb", "crlb_each"} & set(want))
        center = self.replicates(thetas, spp, seeds, R, "bound renders at θ*", first).double()
        tests = []  # per θ*: (its grid points, its offsets)
        for i, theta in enumerate(thetas):
            near = np.flatnonzero(np.abs((grid - theta) / (p.upper - p.lower)).max(axis=1) > 1e-9)
            offs = axis_offsets(p, theta, offsets, fd_step)
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
                sf = converge(stages[i], wflat, self.level, step_tol, spp) if need_fi else None
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

    # -- Fisher information ------------------------------------------------------------------------------
    def fisher(self, thetas, spp: int, fd_step: float = 0.01, rounds: int = 3, reduce: str = "sum",
               noises=None, step_tol: float = 0.1, max_halvings: int = 3, precision: float | None = None,
               budget: int | None = None, looks: int = 3) -> list[FisherPoint]:
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
        `budget` pixel-samples, in at most `looks` looks with ends at level 1 − (1 − level)/looks; the maps,
        the per-parameter CRLBs and the rounds are then the reported look's (the pilot's where it met the
        target), and `precise` carries the CRLB of θ with its `precision` record.

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
            A cap on the pixel-samples (spp × H × W × renders) this call may spend; None: unlimited (with a
            precision target only).
        looks : int, optional
            K ≥ 2: the pilot and at most K − 1 looks at fresh rounds, each at level 1 − (1 − level)/K.

        Returns
        -------
        list of FisherPoint
            One per θ: the render, the mean Jacobian, and per noise index the maps and CRLBs.
        """
        if rounds < 2:
            raise ValueError(f"an unbiased Fisher information needs >= 2 independent FD rounds, got {rounds}")
        if reduce not in ("sum", "mean"):
            raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
        _check_step(fd_step, step_tol, max_halvings)
        check_precision(precision, budget, looks, ("crlb",), rounds)
        thetas = np.asarray(thetas, dtype=np.float64).reshape(-1, self.params.dim)
        args = (spp, reduce, noises, step_tol)
        if precision is None:
            return self._fisher(thetas, rounds, 0, *args, fd_step, max_halvings)[0]
        found: dict[int, FisherPoint] = {}

        def look(idx: np.ndarray, reps: int, first: int, level: float, keep: dict, window, tested) -> list[BoundPoint]:
            sub = copy.copy(self)
            sub.level = level
            start, halvings = (fd_step, max_halvings) if window is None else (fd_step / 2**window.start,
                                                                              window.halvings)
            fps, pts = sub._fisher(thetas[idx], reps, first, *args, start, halvings, keep)
            found.update({int(i): fp for i, fp in zip(idx, fps, strict=True)})
            return pts

        cost = SetCost(0, np.zeros(len(thetas), dtype=np.int64), 2 * self.params.dim, max_halvings + 1)
        pts = refine(look, len(thetas), list(self._select(noises)), rounds, precision, budget, looks,
                     1 - self.level, cost, spp, self.bank)
        for n, pt in enumerate(pts):
            found[n % len(thetas)].precise[pt.noise_index] = pt
        return [found[i] for i in range(len(thetas))]

    def _fisher(self, thetas: np.ndarray, rounds: int, first: int, spp: int, reduce: str, noises, step_tol: float,
                fd_step: float, max_halvings: int, keep: dict | None = None) -> tuple[list[FisherPoint], list]:
        """`fisher` from FD rounds first … first + rounds − 1 at the service's level: the FisherPoints and the
        CRLB of θ (tr F̂⁻¹) as BoundPoints (noise-major); `keep`, when given, is filled with {(noise index, θ
        index): the raw data a precision plan needs (`precision.Raw`)}."""
        P = self.params.dim
        Ls = self.bank.at(thetas, spp, "fisher", desc="Fisher-map renders")
        sel = self._select(noises)
        weights = {j: [self._weight(noise, L) for L in Ls] for j, noise in sel.items()}
        wflat = {j: [to_float64(w).expand(Ls.shape[1:]).reshape(-1).numpy() for w, _ in rows]
                 for j, rows in weights.items()}

        def stage_fn(idx, xi):  # independent rounds, θ rendered under each stencil's seed: one-sided variants too
            return self._stages(thetas[idx], None, spp, "independent", rounds, xi, first, purpose="fisher",
                                sided=max_halvings > 0)

        stages = self._refine(thetas, stage_fn, wflat, fd_step, step_tol, max_halvings)
        out, rows = [], {}
        for i, (t, L) in enumerate(zip(thetas, Ls, strict=True)):
            Jf = torch.from_numpy(stages[i][-1].rounds["central"]).reshape(rounds, P, *L.shape)
            maps, bounds, ws = {}, {}, {}
            for j, noise in sel.items():
                w, flags = weights[j][i]
                ws[j] = to_float64(w).expand(L.shape)
                m = unbiased_fisher(Jf, ws[j]).pixel_map  # (P, H, W, C)
                maps[j] = m.sum(axis=-1) if reduce == "sum" else m.mean(axis=-1)
                sf = converge(stages[i], wflat[j][i], self.level, step_tol, spp)
                joint = crlb_bound(sf, self.level, flags)  # the CRLB of θ, tr F̂⁻¹: for a scalar θ its only one
                bounds[j] = [joint] if P == 1 else [
                    crlb_bound(converge([Stage(s.step, {"central": s.rounds["central"][:, k:k + 1]}, s.group)
                                         for s in stages[i]], wflat[j][i], self.level, step_tol, spp),
                               self.level, flags) for k in range(P)]
                rows[j, i] = BoundPoint(j, str(noise), t.copy(), {"crlb": joint})
                if keep is not None:
                    keep[j, i] = Raw(None, None, sf, stages[i], wflat[j][i], np.empty((0, P)), self.params.lower - t,
                                     self.params.upper - t, int(np.prod(L.shape[:2])), self.group)
            out.append(FisherPoint(t, L, Jf.mean(dim=0), maps, bounds, Jf, stages[i][-1].step, ws))
        return out, [rows[j, i] for j in sel for i in range(len(thetas))]

    # -- the paper's HCR intervals from inexact renders -----------------------------------------------------
    def interval(self, thetas, deltas, levels: Sequence[int], n_eff: int, replicates: int, power: float = 1.0,
                 bootstrap: int = 0, confidence: float = 0.9, boot_seed: int = 0, seeds: str = "independent",
                 noises=None) -> list[tuple[BoundPoint, InexactHCR]]:
        """The paper's [HCR_Neff, HCR-hat] at each scalar θ* (see `inexact_hcr`).

        From render sets of every θ* and θ* + Δ (Δ inside Θ): k spp levels × R replicates (purpose
        "inexact-levels") and R replicates at N_eff (purpose "inexact-neff"); a render serves every θ* that
        uses it.

        Parameters
        ----------
        thetas : array_like of shape (T,)
            The points θ* of the (scalar) parameter, parameter units.
        deltas : array_like of shape (K,)
            Offsets Δ (0 and those that leave Θ are dropped per θ*).
        levels : sequence of int
            Total spp per level (at least 2 distinct), each divisible by `replicates`.
        n_eff : int
            N_eff, the spp of the direct render set (equal budget: N_eff ≈ Σ N_i), divisible by `replicates`.
        replicates : int
            R replicates of each render set (N/R spp each).
        power : float, optional
            Decay rate p of the fit λ̃ = λ + C/N^p.
        bootstrap : int, optional
            Half-sample bootstrap resamples (0: none).
        confidence : float, optional
            Level of the bootstrap intervals, in (0, 1).
        boot_seed : int, optional
            Drives the bootstrap (a stream per noise model and θ* is derived from it).
        seeds : {"independent", "common"}, optional
            A seed per θ, or common random numbers across θ within a (level, replicate).
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute bounds for; None: every model.

        Returns
        -------
        list of (BoundPoint, InexactHCR)
            Per (noise, θ*), noise-major: a BoundPoint with the hcr_neff and hcr_hat Bounds, and the full
            InexactHCR.
        """
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
        """The level renders of `interval`'s render points (no new renders once `interval` ran), e.g. for
        the 1/N decay check.

        Parameters
        ----------
        thetas : array_like of shape (T,)
            The points θ*, as given to `interval`.
        deltas : array_like of shape (K,)
            The offsets Δ, as given to `interval`.
        levels : sequence of int
            Total spp per level, as given to `interval`.
        replicates : int
            R, as given to `interval`.
        seeds : {"independent", "common"}, optional
            As given to `interval`.

        Returns
        -------
        torch.Tensor of shape (k, R, Q, H, W, C)
            The renders of the Q unique render points (θ* and θ* + Δ inside Θ) at each level and replicate.
        """
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


def _diff(a: torch.Tensor, b: torch.Tensor, sep) -> np.ndarray:
    """FD rounds (R, P, N) (a − b) / sep from renders a, b (R, P or 1, *S) float64 and separations (P,)."""
    d = a - b
    P = len(sep)
    return (d / torch.as_tensor(np.asarray(sep, dtype=np.float64)).reshape(1, P, *([1] * (d.ndim - 2)))
            ).reshape(d.shape[0], P, -1).numpy()


def _flat(J: torch.Tensor) -> np.ndarray:
    """One-parameter FD rounds (R, *S) as (R, 1, N) float64."""
    return J.reshape(J.shape[0], 1, -1).double().numpy()


def _check_step(step, step_tol, max_halvings) -> None:
    if not (isinstance(step, (int, float)) and math.isfinite(step) and step > 0):
        raise ValueError(f"fd_step must be a positive number of parameter units, got {step!r}")
    if not (isinstance(step_tol, (int, float)) and math.isfinite(step_tol) and step_tol > 0):
        raise ValueError(f"step_tol must be a positive number (e.g. 0.1: F within 10 %), got {step_tol!r}")
    if isinstance(max_halvings, bool) or int(max_halvings) != max_halvings or not 0 <= max_halvings <= 12:
        raise ValueError(f"max_halvings must be an integer in [0, 12], got {max_halvings!r}")


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
