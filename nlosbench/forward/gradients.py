"""Gradient backends: image Jacobians and vector-Jacobian products by finite differences or AD.

FD is central, ∂L/∂θ_j ≈ (L(θ+ξe_j) − L(θ−ξe_j)) / 2ξ, with common random numbers: both sides of a
stencil use the same render seed, so the rendering noise largely cancels. R rounds with independent
seeds are averaged. Where θ ± ξ leaves Θ the stencil becomes one-sided (θ and the inside neighbour,
same seed). AD asks the model (Mitsuba reverse/forward mode, or exact torch autograd for the toys).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ..seeds import derive
from .model import ForwardModel

METHODS = ("fd", "ad")


@dataclass(frozen=True)
class GradientSettings:
    """How gradients are computed.

    method: "fd" or "ad"; step: FD step ξ per parameter (θ units; a float applies to all);
    rounds: FD rounds averaged (independent seeds); crn: common random numbers across each stencil
    (False draws an independent seed per render — the naive baseline); spp: samples per pixel of
    gradient renders (None: the primal spp); ad: options for the AD integrator (type, max_depth, ...).
    """

    method: str = "fd"
    step: float | tuple = 0.01
    rounds: int = 1
    crn: bool = True
    spp: int | None = None
    ad: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"gradient method must be one of {list(METHODS)}, got {self.method!r}")
        if self.rounds < 1:
            raise ValueError(f"FD rounds must be >= 1, got {self.rounds}")
        if np.any(np.asarray(self.step, dtype=np.float64) <= 0):
            raise ValueError(f"FD step must be > 0, got {self.step}")

    def steps(self, dim: int) -> np.ndarray:
        s = np.broadcast_to(np.asarray(self.step, dtype=np.float64), (dim,))
        return s.copy()


def fd_jacobian(model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings = GradientSettings(),
                indices=None) -> torch.Tensor:
    """FD image Jacobian (P', H, W, C) float32 for parameters `indices` (default all); 2·P'·R renders."""
    t = model.params.validate(theta)
    idx = range(len(t)) if indices is None else list(indices)
    xi = settings.steps(len(t))
    lo, hi = model.params.lower, model.params.upper
    out = []
    for j in idx:
        acc = None
        for r in range(settings.rounds):
            s = derive(seed, "fd", j, r)
            plus, minus = t.copy(), t.copy()
            plus[j] = min(t[j] + xi[j], hi[j])
            minus[j] = max(t[j] - xi[j], lo[j])
            if plus[j] - minus[j] <= 0:
                raise ValueError(f"FD step for {model.params.names[j]!r} leaves no room inside Θ")
            s_minus = s if settings.crn else derive(seed, "fd-independent", j, r)
            d = (model.render(plus, spp, s).double() - model.render(minus, spp, s_minus).double()) / (plus[j] - minus[j])
            acc = d if acc is None else acc + d
        out.append((acc / settings.rounds).float())
    return torch.stack(out)


def ad_jacobian(model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings = GradientSettings("ad"),
                indices=None) -> torch.Tensor:
    """AD image Jacobian (P', H, W, C) float32: one forward-mode pass per parameter."""
    t = model.params.validate(theta)
    idx = range(len(t)) if indices is None else list(indices)
    return torch.stack([model.jvp(t, j, spp, derive(seed, "ad-jvp", j), **settings.ad) for j in idx])


def jacobian(model: ForwardModel, theta, spp: int, seed: int, settings: GradientSettings, indices=None) -> torch.Tensor:
    """Image Jacobian (P', H, W, C) with the method in `settings`."""
    fn = fd_jacobian if settings.method == "fd" else ad_jacobian
    return fn(model, theta, settings.spp or spp, seed, settings, indices)


def vjp(model: ForwardModel, theta, grad_out: torch.Tensor, spp: int, seed: int, settings: GradientSettings) -> np.ndarray:
    """Σ_ω grad_out(ω) ∂L(ω)/∂θ, float64 (P,). FD contracts the FD Jacobian; AD runs one reverse pass."""
    spp = settings.spp or spp
    if settings.method == "ad":
        return model.vjp(theta, grad_out, spp, derive(seed, "ad-vjp"), **settings.ad)
    J = fd_jacobian(model, theta, spp, seed, settings)
    return torch.einsum("p...,...->p", J.double(), grad_out.double()).numpy()
