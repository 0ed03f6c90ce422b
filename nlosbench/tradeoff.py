"""Fidelity: the cheapest scene model whose bound matches the highest-fidelity one (pure logic on a
cost/accuracy table; `studies/fidelity.py` measures the table).

A knob (spp, binning, path depth, gradient method, ...) takes several values around a reference (its
highest-fidelity value). Each value has a cost (seconds, or pixel-samples) and an error: the relative
difference |b/b_ref − 1| of its bound from the reference bound, aggregated over the θ grid (and noise
models, bound kinds) by `max` (the default: every point within tolerance) or `median`.
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


def check_tolerance(tolerance: float) -> float:
    """A relative bound tolerance as float > 0, else ValueError."""
    if isinstance(tolerance, bool) or not (
        isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0
    ):
        raise ValueError(f"tolerance must be a finite number > 0 (relative error of the bound), got {tolerance!r}")
    return float(tolerance)


@dataclass(frozen=True)
class Point:
    """One value of a knob: its cost (seconds or pixel-samples, > 0) and aggregated bound error."""

    value: object
    cost: float
    error: float


@dataclass(frozen=True)
class Recommendation:
    """The cheapest value of `knob` whose error ≤ tolerance (the reference always qualifies).

    speedup = reference cost / chosen cost (> 1 means cheaper than the reference)."""

    knob: str
    value: object
    cost: float
    error: float
    reference: object
    reference_cost: float
    speedup: float
    tolerance: float


def recommend(knob: str, points: list[Point], reference, tolerance: float) -> Recommendation:
    """The cheapest point within tolerance; on equal cost the one listed first. `reference` is the value
    of the highest-fidelity point, which must be among `points`."""
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
    ok = [p for p in points if p.error <= tol or p.value == reference]
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

