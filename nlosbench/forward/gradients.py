"""Gradient backends: image Jacobians and vector-Jacobian products by finite differences or AD.

FD is central, ∂L/∂θ_j ≈ (L(θ+ξe_j) − L(θ−ξe_j)) / 2ξ, with common random numbers: both sides of a
stencil use the same render seed, so the rendering noise largely cancels. R rounds with independent
seeds are averaged. Where θ ± ξ leaves Θ the stencil becomes one-sided (θ and the inside neighbour,
same seed). AD asks the model (Mitsuba reverse/forward mode, or exact torch autograd for the toys).
"mixed" differentiates the parameters `ad_params` by AD and the others by FD. "auto" is a request,
not a method this layer runs: it is resolved above the forward layer (`nlosbench.diagnostics.
resolve_gradient`, from measured verdicts or the paper's prior) into one of the other three, which is
what reaches `jacobian` and `vjp`.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from os import PathLike

import numpy as np
import torch

from ..seeds import derive
from .model import ForwardModel

METHODS = ("fd", "ad", "mixed", "auto")


@dataclass(frozen=True)
class GradientSettings:
    """How gradients are computed.

    Parameters
    ----------
    method : {"fd", "ad", "mixed", "auto"}, default "fd"
        Finite differences, AD, AD for `ad_params` and FD for the others, or a policy resolved above
        the forward layer (`nlosbench.resolve_gradient`).
    step : float or tuple of float, default 0.01
        FD step ξ per parameter, in θ units; a float applies to all.
    rounds : int, default 1
        FD rounds averaged (independent seeds).
    crn : bool, default True
        Common random numbers across each stencil (False draws an independent seed per render — the
        naive baseline).
    spp : int, optional
        Samples per pixel of gradient renders (None: the primal spp).
    ad : dict, optional
        Options for the AD integrator (type, max_depth, ...).
    ad_params : tuple of int, default ()
        With "mixed", the parameter indices differentiated by AD (the others by FD).
    verdicts : str, os.PathLike, mapping or None, optional
        With "auto", a `gradients` study's verdicts.json (or its folder) or a mapping
        {parameter: Verdict}; None uses the prior.
    chosen : str, default ""
        Set when "auto" is resolved (`nlosbench.diagnostics.resolve_gradient`): what it chose and why.
        Not compared.

    Examples
    --------
    >>> nb.GradientSettings("fd", step=(0.01, 0.02)).steps(2)
    array([0.01, 0.02])
    """

    method: str = "fd"
    step: float | tuple = 0.01
    rounds: int = 1
    crn: bool = True
    spp: int | None = None
    ad: dict = field(default_factory=dict)
    ad_params: tuple = ()
    verdicts: str | PathLike | Mapping | None = None
    chosen: str = field(default="", compare=False)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"gradient method must be one of {list(METHODS)}, got {self.method!r}")
        if self.rounds < 1:
            raise ValueError(f"FD rounds must be >= 1, got {self.rounds}")
        if np.any(np.asarray(self.step, dtype=np.float64) <= 0):
            raise ValueError(f"FD step must be > 0, got {self.step}")
        if (self.method == "mixed") != bool(self.ad_params):
            raise ValueError("ad_params (the indices differentiated by AD) go with method 'mixed', and it needs "
                             f"at least one; got method {self.method!r}, ad_params {self.ad_params!r}")
        if not all(isinstance(j, (int, np.integer)) and j >= 0 for j in self.ad_params):
            raise ValueError(f"ad_params must be non-negative parameter indices, got {self.ad_params!r}")
        object.__setattr__(self, "ad_params", tuple(sorted({int(j) for j in self.ad_params})))
        if self.verdicts is not None and self.method != "auto":
            raise ValueError(f"verdicts are read by method 'auto' only, got method {self.method!r}")
        if self.verdicts is not None and not isinstance(self.verdicts, (str, PathLike, Mapping)):
            raise ValueError("verdicts must be a path or a mapping {parameter: Verdict}, "
                             f"got {type(self.verdicts).__name__}")

    def steps(self, dim: int) -> np.ndarray:
        """The FD step ξ of each parameter.

        Parameters
        ----------
        dim : int
            The number of parameters P.

        Returns
        -------
        numpy.ndarray
            ξ, float64 (P,), in θ units (`step` broadcast).
        """
        s = np.broadcast_to(np.asarray(self.step, dtype=np.float64), (dim,))
        return s.copy()


def check_concrete(settings: GradientSettings) -> None:
    """ValueError unless `settings` names a method this layer runs (fd, ad, mixed)."""
    if settings.method == "auto":
        raise ValueError("grad='auto' is a policy resolved above the forward layer: pass the settings through "
                         "nlosbench.diagnostics.resolve_gradient(model, settings) (nb.render does this)")


def fd_jacobian(model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings = GradientSettings(),
                indices=None) -> torch.Tensor:
    """FD image Jacobian (P', H, W, C) float32 for parameters `indices` (default all); 2·P'·R renders."""
    t = model.params.validate(theta)
    idx = range(len(t)) if indices is None else list(indices)
    xi = settings.steps(len(t))
    lo, hi = model.params.lower, model.params.upper
    out = []
    for j in idx:
        plus, minus = t.copy(), t.copy()
        plus[j] = min(t[j] + xi[j], hi[j])
        minus[j] = max(t[j] - xi[j], lo[j])
        if plus[j] - minus[j] <= 0:
            raise ValueError(f"FD step for {model.params.names[j]!r} leaves no room inside Θ")
        seeds = [derive(seed, "fd", j, r) for r in range(settings.rounds)]
        # every round's θ + ξ, then every round's θ − ξ: the scene is written twice, not twice per round
        P = [model.render(plus, spp, s).double() for s in seeds]
        M = [model.render(minus, spp, s if settings.crn else derive(seed, "fd-independent", j, r)).double()
             for r, s in enumerate(seeds)]
        acc = None
        for p_r, m_r in zip(P, M, strict=True):
            d = (p_r - m_r) / (plus[j] - minus[j])
            acc = d if acc is None else acc + d
        out.append((acc / settings.rounds).float())
    return torch.stack(out)


def ad_jacobian(
    model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings = GradientSettings("ad"), indices=None
) -> torch.Tensor:
    """AD image Jacobian (P', H, W, C) float32: one forward-mode pass per parameter."""
    t = model.params.validate(theta)
    idx = range(len(t)) if indices is None else list(indices)
    return torch.stack([model.jvp(t, j, spp, derive(seed, "ad-jvp", j), **settings.ad) for j in idx])


def _uses_ad(settings: GradientSettings, j: int) -> bool:
    return settings.method == "ad" or (settings.method == "mixed" and j in settings.ad_params)


def _check_ad_params(model: ForwardModel, settings: GradientSettings) -> None:
    if settings.ad_params and settings.ad_params[-1] >= len(model.params):
        raise ValueError(
            f"ad_params {settings.ad_params} index past the {len(model.params)} parameters of {model.name!r}"
        )


def jacobian(model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings, indices=None) -> torch.Tensor:
    """Image Jacobian (P', H, W, C) with the method in `settings` (fd, ad or mixed)."""
    check_concrete(settings)
    _check_ad_params(model, settings)
    spp = settings.spp or spp
    idx = list(range(len(model.params))) if indices is None else list(indices)
    if settings.method != "mixed":
        fn = ad_jacobian if settings.method == "ad" else fd_jacobian
        return fn(model, theta, spp, seed, settings, idx)
    return torch.stack(
        [
            (ad_jacobian if _uses_ad(settings, j) else fd_jacobian)(model, theta, spp, seed, settings, [j])[0]
            for j in idx
        ]
    )


def vjp(
    model: ForwardModel, theta, grad_out: torch.Tensor, spp: int, seed: int, settings: GradientSettings
) -> np.ndarray:
    """Σ_ω grad_out(ω) ∂L(ω)/∂θ, float64 (P,). FD contracts the FD Jacobian of its parameters; AD runs
    one reverse pass; "mixed" does both."""
    check_concrete(settings)
    _check_ad_params(model, settings)
    spp = settings.spp or spp
    P = len(model.params)
    out = np.zeros(P)
    ad_idx = [j for j in range(P) if _uses_ad(settings, j)]
    fd_idx = [j for j in range(P) if j not in ad_idx]
    if ad_idx:
        # `indices`: a colour-only AD part gets `prb` even when the FD parameters move geometry
        out[ad_idx] = np.asarray(
            model.vjp(theta, grad_out, spp, derive(seed, "ad-vjp"), indices=ad_idx, **settings.ad)
        )[ad_idx]
    if fd_idx:
        J = fd_jacobian(model, theta, spp, seed, settings, fd_idx)
        out[fd_idx] = torch.einsum("p...,...->p", J.double(), grad_out.double()).numpy()
    return out
