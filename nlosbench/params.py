"""Parameter space Θ: named scalar parameters with units, box bounds and defaults (θ as float64 (P,))."""
from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class Param:
    """One component of θ: `lower <= value <= upper`, in `units` (metres for positions and radii).

    Parameters
    ----------
    name : str
        The parameter's name, unique within its `ParamSpace`.
    lower, upper : float
        The box bounds of Θ along this component, in `units`; finite, lower < upper.
    default : float
        The value used when the parameter is held fixed, in `units`; inside [lower, upper].
    units : str, default "m"
        The units of the value (metres for positions and radii).
    description : str, default ""
        What the parameter is, for tables and plots.

    Examples
    --------
    >>> nb.Param("x", 0.0, 1.0, 0.5)
    Param(name='x', lower=0.0, upper=1.0, default=0.5, units='m', description='')
    >>> nb.Param("x", 0.0, 1.0, 2.0)
    Traceback (most recent call last):
    ValueError: parameter 'x': default 2.0 outside [0.0, 1.0]
    """

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
    """An ordered set of parameters; θ vectors follow this order.

    Parameters
    ----------
    params : sequence of Param
        The parameters, in θ's order; at least one, names unique.

    Examples
    --------
    >>> space = nb.ParamSpace([nb.Param("x", 0.0, 1.0, 0.5), nb.Param("r", 0.1, 0.3, 0.2)])
    >>> space.names, len(space)
    (('x', 'r'), 2)
    """

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
        """Position of parameter `name` in θ; a clear error naming the known parameters otherwise.

        Parameters
        ----------
        name : str
            A parameter's name.

        Returns
        -------
        int
            Its index in θ.

        Raises
        ------
        KeyError
            If no parameter has that name (the message lists the known ones).
        """
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown parameter {name!r}; this model has {list(self.names)}") from None

    def subset(self, names: Sequence[str]) -> ParamSpace:
        """The space of the parameters `names` only, in the order given.

        Parameters
        ----------
        names : sequence of str
            Parameter names of this space.

        Returns
        -------
        ParamSpace
            A space of those parameters (same bounds, defaults and units).
        """
        return ParamSpace([self.params[self.index(n)] for n in names])

    def validate(self, theta) -> np.ndarray:
        """θ as float64 (P,), after checking its length, finiteness and Θ's bounds.

        Parameters
        ----------
        theta : array_like or torch.Tensor
            P values in parameter units (a tensor is detached and copied to the CPU).

        Returns
        -------
        numpy.ndarray
            θ, float64 (P,).

        Raises
        ------
        ValueError
            If θ has the wrong length, a non-finite value or a value outside Θ (each named).
        """
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
        """Whether θ lies in the box Θ (bounds included).

        Parameters
        ----------
        theta : array_like
            P values in parameter units.

        Returns
        -------
        bool
            True when every component is within its [lower, upper].
        """
        t = np.asarray(theta, dtype=np.float64)
        return bool(np.all((t >= self.lower) & (t <= self.upper)))

    def sample_uniform(self, generator: np.random.Generator) -> np.ndarray:
        """A uniform random point of Θ, float64 (P,).

        Parameters
        ----------
        generator : numpy.random.Generator
            The random source.

        Returns
        -------
        numpy.ndarray
            θ, float64 (P,), in parameter units.
        """
        return generator.uniform(self.lower, self.upper)

    def grid(self, num: int) -> np.ndarray:
        """The tensor grid of `num` points per axis over Θ, ends included: (num^P, P) float64, the last
        parameter varying fastest.

        Parameters
        ----------
        num : int
            Points per axis (≥ 1).

        Returns
        -------
        numpy.ndarray
            The grid points, float64 (num^P, P), in parameter units.

        Examples
        --------
        >>> space = nb.ParamSpace([nb.Param("x", 0.0, 1.0, 0.5), nb.Param("r", 0.1, 0.3, 0.2)])
        >>> space.grid(2)
        array([[0. , 0.1],
               [0. , 0.3],
               [1. , 0.1],
               [1. , 0.3]])
        """
        axes = [np.linspace(lo, hi, num) for lo, hi in zip(self.lower, self.upper, strict=True)]
        return np.array(list(itertools.product(*axes)), dtype=np.float64).reshape(-1, self.dim)
