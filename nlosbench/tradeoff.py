"""Fidelity: the cheapest scene model whose bound matches the highest-fidelity one (pure logic on a
cost/accuracy table; `studies/fidelity.py` measures the table).

A knob (spp, binning, path depth, gradient method, ...) takes several values around a reference (its
highest-fidelity value). Each value has a cost (seconds, or pixel-samples) and an error: the relative
difference |b/b_ref − 1| of its bound from the reference bound, aggregated over the θ grid (and noise
models, bound kinds) by `max` (the default: every point within tolerance) or `median`. Bounds from
Monte Carlo renders are noisy: `error_limits` gives each error joint confidence limits from a jackknife
over the replicate render sets both bounds share, and a value qualifies when its upper limit does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

AGGREGATES = ("max", "median")


def relative_error(log10_b, log10_ref) -> np.ndarray:
    """|b / b_ref − 1| elementwise (float64) from log10 bounds, exact for tiny differences (expm1).

    0 where both are the same ±inf (both unresolved, or both without a bound); +inf where exactly one
    is infinite. NaN input raises ValueError."""
    a = np.asarray(log10_b, dtype=np.float64)
    r = np.asarray(log10_ref, dtype=np.float64)
    if np.isnan(a).any() or np.isnan(r).any():
        raise ValueError("relative_error: log10 bounds contain NaN")
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.abs(np.expm1((a - r) * math.log(10.0)))
    return np.where(np.isinf(a) | np.isinf(r), np.where(a == r, 0.0, np.inf), err)


def aggregate(errors, how: str = "max") -> float:
    """One error from many (over θ, noise models, bounds): `max` or `median`; 0 for no values."""
    if how not in AGGREGATES:
        raise ValueError(f"aggregate must be one of {list(AGGREGATES)}, got {how!r}")
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        return 0.0
    return float(np.max(e) if how == "max" else np.median(e))


def error_limits(log10_b, log10_ref, loo_b, loo_ref, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Joint confidence limits (lower, upper) on the errors |b/b_ref − 1| of M paired bounds.

    log10_b, log10_ref: (M,) point estimates; loo_b, loo_ref: (M, R) the same without replicate set k, for
    two models whose replicate sets are paired by k (the same seeds where settings share them, which
    cancels their common rendering noise; independent sets are paired by index, which is as valid).
    The log ratio d = log10 b − log10 b_ref gets the delete-one jackknife SE over the R pairs,
    √((R−1)/R Σ_k (d_k − d̄)²), and a two-sided Student-t interval (R − 1 degrees of freedom), each at
    1 − (1 − level)/M' (Bonferroni over the M' distinct finite comparisons: a value repeated exactly, with
    its leave-one-outs, as an HCR set by its Δ → 0 term repeats the CRLB, is one event and counts once), so
    with probability ≥ `level` every d lies in its interval; the error's
    limits are |10^d − 1| over it (lower 0 where it holds d = 0). Non-finite inputs, or R < 3, give
    (0, +inf) there: nothing is resolved."""
    if not 0 < level < 1:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    with np.errstate(invalid="ignore"):  # ∞ − ∞ (both unresolved) is NaN: left unresolved below
        d = np.asarray(log10_b, dtype=np.float64) - np.asarray(log10_ref, dtype=np.float64)
        dk = np.asarray(loo_b, dtype=np.float64) - np.asarray(loo_ref, dtype=np.float64)
    M = d.size
    if dk.shape[:1] != (M,) or dk.ndim != 2:
        raise ValueError(f"error_limits: need leave-one-outs (M, R) for M = {M} bounds, got {dk.shape}")
    lower, upper = np.zeros(M), np.full(M, np.inf)
    R = dk.shape[1]
    ok = np.isfinite(d) & np.all(np.isfinite(dk), axis=1)
    if R < 3 or not ok.any():
        return lower, upper
    from scipy import stats

    se = np.sqrt((R - 1) / R * ((dk[ok] - dk[ok].mean(axis=1, keepdims=True)) ** 2).sum(axis=1))
    distinct = np.unique(np.column_stack([d[ok], dk[ok]]), axis=0).shape[0]
    t = float(stats.t.ppf(1.0 - (1.0 - level) / (2 * distinct), R - 1))
    lo, hi = d[ok] - t * se, d[ok] + t * se
    err = lambda x: np.abs(np.expm1(x * math.log(10.0)))  # noqa: E731
    upper[ok] = np.maximum(err(lo), err(hi))
    lower[ok] = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(err(lo), err(hi)))
    return lower, upper


def jackknife_noise(log10_b, loo_b, level: float = 0.95) -> np.ndarray:
    """Relative Monte Carlo noise of M bounds' point estimates: 10^(t·se) − 1 per bound, se the delete-one
    jackknife SE of log10 b over its R replicate sets, √((R−1)/R Σ_k (b_k − b̄)²) from loo_b (M, R), t the
    one-sided Student-t quantile at `level` with R − 1 degrees of freedom (log10 b ± t·se: each end a one-sided
    limit at `level`). The noise of the point alone: the spread between the FD variants an interval end also
    covers (step bias) is not in it. +inf where a value is not finite; NaN for R < 3 (no interval)."""
    d = np.asarray(log10_b, dtype=np.float64).reshape(-1)
    dk = np.asarray(loo_b, dtype=np.float64).reshape(d.size, -1)
    R = dk.shape[1]
    if R < 3:
        return np.full(d.size, np.nan)
    from scipy import stats

    ok = np.isfinite(d) & np.all(np.isfinite(dk), axis=1)
    out = np.full(d.size, np.inf)
    se = np.sqrt((R - 1) / R * ((dk[ok] - dk[ok].mean(axis=1, keepdims=True)) ** 2).sum(axis=1))
    out[ok] = np.expm1(float(stats.t.ppf(level, R - 1)) * se * math.log(10.0))
    return out


def check_tolerance(tolerance: float) -> float:
    """A relative bound tolerance as float > 0, else ValueError."""
    if isinstance(tolerance, bool) or not (
        isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0
    ):
        raise ValueError(f"tolerance must be a finite number > 0 (relative error of the bound), got {tolerance!r}")
    return float(tolerance)


@dataclass(frozen=True)
class Point:
    """One value of a knob: its cost (seconds or pixel-samples, > 0), aggregated bound error, and the
    upper confidence limit of that error (None: no limits, the error itself decides)."""

    value: object
    cost: float
    error: float
    upper: float | None = None

    @property
    def decisive(self) -> float:
        """The error a recommendation tests (`decisive`)."""
        return decisive(self.error, self.upper)


def decisive(error: float, upper: float | None) -> float:
    """The error that decides "within tolerance": its upper confidence limit where there is one (not None or
    NaN), else the error itself."""
    return error if upper is None or math.isnan(upper) else upper


@dataclass(frozen=True)
class Recommendation:
    """The cheapest value of `knob` whose error (its upper confidence limit, where known) ≤ tolerance (the
    reference always qualifies); `upper`: the chosen value's upper limit (None where unknown).

    speedup = reference cost / chosen cost (> 1 means cheaper than the reference)."""

    knob: str
    value: object
    cost: float
    error: float
    reference: object
    reference_cost: float
    speedup: float
    tolerance: float
    upper: float | None = None


def recommend(knob: str, points: list[Point], reference, tolerance: float) -> Recommendation:
    """The cheapest point within tolerance (`Point.decisive` ≤ tolerance: resolved within it where the
    point has confidence limits); on equal cost the one listed first. `reference` is the value of the
    highest-fidelity point, which must be among `points`."""
    tol = check_tolerance(tolerance)
    if not points:
        raise ValueError(f"knob {knob!r}: no points")
    for p in points:
        if not (math.isfinite(p.cost) and p.cost > 0):
            raise ValueError(f"knob {knob!r}: cost of {p.value!r} must be finite and > 0, got {p.cost!r}")
        if math.isnan(p.error) or p.error < 0:
            raise ValueError(f"knob {knob!r}: error of {p.value!r} must be >= 0, got {p.error!r}")
    ref = [p for p in points if p.value == reference]
    if not ref:
        raise ValueError(f"knob {knob!r}: reference {reference!r} is not among the points {[p.value for p in points]}")
    ok = [p for p in points if p.decisive <= tol or p.value == reference]
    best = min(ok, key=lambda p: p.cost)
    return Recommendation(
        knob=knob,
        value=best.value,
        cost=best.cost,
        error=best.error,
        reference=reference,
        reference_cost=ref[0].cost,
        speedup=ref[0].cost / best.cost,
        tolerance=tol,
        upper=best.upper,
    )


def settled(values: list, errors: list[float], tolerance: float):
    """The first of `values` (in the given order, e.g. increasing path depth) from which on every error
    is ≤ tolerance: where the bound stops changing. The last value always qualifies (it is the reference)."""
    tol = check_tolerance(tolerance)
    if len(values) != len(errors) or not values:
        raise ValueError(f"settled: need as many errors as values (> 0), got {len(values)} and {len(errors)}")
    k = len(values) - 1
    while k > 0 and errors[k - 1] <= tol:
        k -= 1
    return values[k]


def pareto_front(costs, errors) -> list[int]:
    """Indices of the points no other point dominates (cost ≤ and error ≤, one of them <), ordered by
    cost: the speed–accuracy trade-offs worth having. Points with a non-finite cost or error are left out."""
    c, e = np.asarray(costs, dtype=np.float64), np.asarray(errors, dtype=np.float64)
    if c.shape != e.shape or c.ndim != 1:
        raise ValueError(f"pareto_front: costs and errors must be 1-D of one length, got {c.shape} and {e.shape}")
    ok = [i for i in range(c.size) if math.isfinite(c[i]) and math.isfinite(e[i])]
    front, best = [], math.inf
    for i in sorted(ok, key=lambda i: (c[i], e[i])):
        if e[i] < best:
            front.append(i)
            best = e[i]
    return front

