"""Estimators of θ from one noisy image, as plug-ins: `get(name, **options)` → an object with
`fit(problem, y, init, rng, budget) → Estimate` (see `base.py` for the contract).

Built in: `mle-adam` (Adam on the NLL through the renderer), `grid-search` (profile likelihood on
cached grid renders + local refinement), `gauss-newton` (Fisher scoring with the bounds module's
Fisher matrix), `multi-start` (any of them from several starts) and `surrogate` (the MLE of a scalar θ on a
polynomial surrogate of L(θ) from a lattice of renders shared by every fit). Third-party estimators register
through the entry-point group `nlosbench.estimators` (name → a factory, usually an Estimator
subclass, called with the options), or at run time with `register(name, factory)`.
"""
from __future__ import annotations

import difflib
import importlib.metadata
from collections.abc import Callable

from .base import BankGrid, Budget, Estimate, Estimator, Outcome, Problem, Tracker
from .gauss_newton import GaussNewton
from .grid_search import GridSearch
from .mle_adam import AdamMLE
from .multi_start import MultiStart
from .surrogate import Surrogate

#: the entry-point group of estimator plug-ins: name = "package.module:factory" (usually an Estimator subclass)
ENTRY_POINT_GROUP = "nlosbench.estimators"

_BUILTIN: dict[str, Callable[..., Estimator]] = {c.name: c for c in (AdamMLE, GridSearch, GaussNewton, MultiStart,
                                                                     Surrogate)}
_REGISTERED: dict[str, Callable[..., Estimator]] = {}


def register(name: str, factory: Callable[..., Estimator]) -> None:
    """Add an estimator factory (called with the options given to `get`) under `name`.

    Parameters
    ----------
    name : str
        The name `get` builds it by; it takes precedence over a built-in or plug-in of that name.
    factory : callable
        Called with the options given to `get`; returns an object with a `fit` method (usually an
        `Estimator` subclass).

    Raises
    ------
    TypeError
        If `factory` is not callable.

    Examples
    --------
    A coarse grid search under a name of its own:

    >>> nb.estimators.register("coarse-grid", lambda **options: nb.estimators.GridSearch(num=5, **options))
    >>> est = nb.estimators.get("coarse-grid", spp=8)
    >>> type(est).__name__, est.num, est.spp, "coarse-grid" in nb.estimators.available()
    ('GridSearch', 5, 8, True)
    """
    if not callable(factory):
        raise TypeError(f"estimator factory for {name!r} is not callable: {factory!r}")
    _REGISTERED[name] = factory


def _entry_points() -> dict:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def available() -> list[str]:
    """Names accepted by `get`: built-ins, factories added by `register` and installed entry points.

    Returns
    -------
    list of str
        The names, sorted.

    Examples
    --------
    >>> "mle-adam" in nb.estimators.available()
    True
    """
    return sorted(set(_BUILTIN) | set(_REGISTERED) | set(_entry_points()))


def factory(name: str) -> Callable[..., Estimator]:
    """The factory registered under `name`; KeyError (with a close match) for an unknown name.

    Parameters
    ----------
    name : str
        An estimator's name (see `available`).

    Returns
    -------
    callable
        The factory (a registered one first, then a built-in, then an installed entry point).

    Raises
    ------
    KeyError
        If no estimator has that name.
    ImportError
        If the entry-point plug-in of that name fails to load.

    Examples
    --------
    >>> nb.estimators.factory("grid-search") is nb.estimators.GridSearch
    True
    >>> nb.estimators.factory("grid-serch")
    Traceback (most recent call last):
    KeyError: "unknown estimator 'grid-serch'; did you mean 'grid-search'? (available: ...)"
    """
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in _BUILTIN:
        return _BUILTIN[name]
    eps = _entry_points()
    if name in eps:
        try:
            return eps[name].load()
        except Exception as e:  # noqa: BLE001 - any import failure of a plug-in is reported with its source
            raise ImportError(f"estimator plug-in {name!r} ({eps[name].value}, entry-point group "
                              f"{ENTRY_POINT_GROUP!r}) failed to load: {type(e).__name__}: {e}") from e
    close = difflib.get_close_matches(name, available(), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise KeyError(f"unknown estimator {name!r}{hint} (available: {', '.join(available())})")


def get(name: str, **options) -> Estimator:
    """Build the estimator `name` with its options, e.g. get("mle-adam", lr=0.05, iterations=100).

    Parameters
    ----------
    name : str
        An estimator's name (see `available`).
    **options
        The estimator's options (its constructor's keywords).

    Returns
    -------
    Estimator
        The estimator (an object with a `fit` method).

    Raises
    ------
    ValueError
        If the factory rejects the options.

    Examples
    --------
    >>> nb.estimators.get("gauss-newton", spp=16).spp
    16
    """
    make = factory(name)
    try:
        est = make(**options)
    except TypeError as e:
        raise ValueError(f"estimator {name!r}: bad options {sorted(options)}: {e}") from None
    if not callable(getattr(est, "fit", None)):
        raise TypeError(f"estimator {name!r} built {type(est).__name__}, which has no fit() method")
    return est


def describe() -> dict[str, str]:
    """name → one line: what it is, then when it is valid (for `nlosbench list estimators`).

    Returns
    -------
    dict of str to str
        Per available estimator, the first line of its docstring and its `valid_when`.

    Examples
    --------
    >>> nb.estimators.describe()["gauss-newton"]  # doctest: +ELLIPSIS
    'Fisher scoring / Gauss–Newton with Levenberg–Marquardt damping...'
    """
    out = {}
    for name in available():
        try:
            cls = factory(name)
        except ImportError as e:
            out[name] = f"(fails to load: {e})"
            continue
        doc = (cls.__doc__ or "").strip().splitlines()
        valid = getattr(cls, "valid_when", "")
        out[name] = " ".join(filter(None, [doc[0] if doc else "", f"Valid when: {valid}" if valid else ""]))
    return out


__all__ = ["BankGrid", "Budget", "Estimate", "Estimator", "Outcome", "Problem", "Tracker", "AdamMLE", "GridSearch",
           "GaussNewton", "MultiStart", "Surrogate", "ENTRY_POINT_GROUP", "register", "available", "factory", "get",
           "describe"]


def _backprojection(**options) -> Estimator:
    """The backprojection peak localiser of confocal transient captures (`estimators.backprojection`)."""
    from .backprojection import Backprojection

    return Backprojection(**options)


register("backprojection", _backprojection)
