"""Parameter space Θ: named scalar parameters with units, box bounds and defaults (θ as float64 (P,))."""
from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class Param:
    """One component of θ: `lower <= value <= upper`, in `units` (metres for positions and radii)."""

    name: str
    lower: float
    upper: float
    default: float
    units: str = "m"
    description: str = ""

    def __post_init__(self):
        if not (np.isfinite(self.lower) and np.isfinite(self.upper) and self.lower < self.upper):
            raise ValueError(f"parameter {self.name!r}: need finite lower < upper, got [{self.lower}, {self.upper}]")
        if not self.lower <= self.default <= self.upper:
            raise ValueError(f"parameter {self.name!r}: default {self.default} outside [{self.lower}, {self.upper}]")


class ParamSpace:
    """An ordered set of parameters; θ vectors follow this order."""

    def __init__(self, params: Sequence[Param]):
        if not params:
            raise ValueError("a parameter space needs at least one parameter")
        names = [p.name for p in params]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate parameter names in {names}")
        self.params = tuple(params)
        self.names = tuple(names)
        self.units = tuple(p.units for p in params)
        self.lower = np.array([p.lower for p in params], dtype=np.float64)
        self.upper = np.array([p.upper for p in params], dtype=np.float64)
        self.default = np.array([p.default for p in params], dtype=np.float64)

    def __len__(self) -> int:
        return len(self.params)

    @property
    def dim(self) -> int:
        return len(self.params)

    def __repr__(self) -> str:
        body = ", ".join(f"{p.name} ∈ [{p.lower:g}, {p.upper:g}] {p.units}" for p in self.params)
        return f"ParamSpace({body})"

    def index(self, name: str) -> int:
        """Position of parameter `name` in θ; a clear error naming the known parameters otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown parameter {name!r}; this model has {list(self.names)}") from None

    def subset(self, names: Sequence[str]) -> ParamSpace:
        return ParamSpace([self.params[self.index(n)] for n in names])

    def validate(self, theta) -> np.ndarray:
        """θ as float64 (P,), after checking its length, finiteness and Θ's bounds."""
        if isinstance(theta, torch.Tensor):
            theta = theta.detach().cpu().double().numpy()
        t = np.atleast_1d(np.asarray(theta, dtype=np.float64))
        if t.ndim != 1 or t.shape[0] != self.dim:
            raise ValueError(f"θ must have {self.dim} value(s) {list(self.names)}, got shape {np.shape(theta)}")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"θ must be finite, got {t.tolist()}")
        bad = [f"{n}={v:g} outside [{lo:g}, {hi:g}] {u}" for n, v, lo, hi, u in
               zip(self.names, t, self.lower, self.upper, self.units, strict=True) if not lo <= v <= hi]
        if bad:
            raise ValueError("θ out of range: " + "; ".join(bad))
        return t

    def contains(self, theta) -> bool:
        t = np.asarray(theta, dtype=np.float64)
        return bool(np.all((t >= self.lower) & (t <= self.upper)))

    def sample_uniform(self, generator: np.random.Generator) -> np.ndarray:
        """A uniform random point of Θ, float64 (P,)."""
        return generator.uniform(self.lower, self.upper)

    def grid(self, num: int) -> np.ndarray:
        """The tensor grid of `num` points per axis over Θ, ends included: (num^P, P) float64, the last
        parameter varying fastest."""
        axes = [np.linspace(lo, hi, num) for lo, hi in zip(self.lower, self.upper, strict=True)]
        return np.array(list(itertools.product(*axes)), dtype=np.float64).reshape(-1, self.dim)
