"""Noise models: observations Y of an image with mean radiance L (independent pixels).

Every model implements sampling, the negative log-likelihood, the χ² exponent
λ with χ²(p_L1 ‖ p_L0) = exp(λ) − 1 (the HCR bound's divergence), the Barankin Gram exponent
log E_L0[ℓ_i ℓ_j] (ℓ = likelihood ratio p_Li / p_L0) and the per-pixel Fisher information.
Divergences and information are float64 and use direct differences L1 − L0.

The two built-in models are *quadratic*: all three quantities are Σ_ω w(L0)·(·)(·) for a per-pixel
weight w (AWGN: 1/σ², Poisson: scale/L0). A new model (e.g. Poisson + Gaussian read noise)
subclasses `NoiseModel` (or `QuadraticNoise` when its χ² exponent has that form) and registers
itself with `@register("name")`; `get(name, **kw)` builds it.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from .binning import check_bin


def to_float64(x, what: str = "input") -> torch.Tensor:
    """`x` (tensor, numpy array or memmap, any float dtype) as a float64 torch tensor (same device)."""
    if isinstance(x, torch.Tensor):
        return x.detach().to(torch.float64)
    try:
        return torch.as_tensor(np.asarray(x, dtype=np.float64))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: not a numeric array ({e})") from None


def check_finite(x: torch.Tensor, what: str) -> None:
    """Raise ValueError naming `what` if `x` holds NaN or ±Inf."""
    bad = ~torch.isfinite(x)
    if bool(bad.any()):
        n_nan = int(torch.isnan(x).sum())
        first = tuple(int(i) for i in torch.nonzero(bad)[0]) if x.ndim else ()
        raise ValueError(f"{what} contains {n_nan} NaN and {int(bad.sum()) - n_nan} Inf values "
                         f"(first at index {first})")


class NoiseModel(ABC):
    """Observation model Y ~ p_L for an image of mean radiance L (shape *S, pixels independent)."""

    name: ClassVar[str] = ""
    #: chi2_exponent(L0, L1) == chi2_exponent(L1, L0) for every pair (pairwise λ then computes half)
    symmetric: ClassVar[bool] = False

    def validate(self, L: torch.Tensor, what: str) -> None:
        """Raise ValueError naming `what` if `L` is not a valid mean image (default: finite)."""
        check_finite(L, what)

    @abstractmethod
    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """One noisy observation y of the image L, same shape and dtype, in radiance units."""

    @abstractmethod
    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """−log p_L(y) up to an L-independent constant: float64 scalar, differentiable in L."""

    @abstractmethod
    def chi2_exponent(self, L0, L1, check: bool = True) -> torch.Tensor:
        """λ = log(1 + χ²(p_L1 ‖ p_L0)), float64 ≥ 0 (+inf allowed).

        L0: (*S); L1: (*B, *S) → λ of shape (*B) (0-dim without batch dims).
        `check=False` skips input validation (for callers that validated once already)."""

    @abstractmethod
    def gram_exponent(self, L0, Li, Lj) -> torch.Tensor:
        """log E_L0[ℓ_i ℓ_j] with ℓ = p_L / p_L0: Li (A, *S) or (*S), Lj (B, *S) or (*S) → (A, B)
        (batch dims dropped where absent). The diagonal i = j equals `chi2_exponent`."""

    @abstractmethod
    def fisher(self, L, dL) -> torch.Tensor:
        """Per-pixel Fisher information, float64. dL = ∂L/∂θ with the shape of L → (*S);
        dL of shape (P, *S) → (P, P, *S)."""

    def variance(self, L) -> torch.Tensor:
        """Per-pixel variance of an observation of the image L (radiance², float64, broadcastable to L). The
        default, 1 / (Fisher information per unit dL²), is exact for exponential families in their mean
        (AWGN, Poisson); a model where it is not overrides this."""
        L = to_float64(L, "L")
        return 1.0 / self.fisher(L, torch.ones_like(L))

    def binned(self, b: int) -> NoiseModel:
        """The model of one b×b-binned pixel whose value is the mean of the block's b² independent
        observations (radiance units; see `nlosbench.binning`). Models that support binning override this."""
        raise NotImplementedError(f"noise model {type(self).__name__} does not define binned(b)")

    def _inputs(self, check: bool, **arrays) -> list[torch.Tensor]:
        out = [to_float64(a, k) for k, a in arrays.items()]
        if check:
            for k, a in zip(arrays, out, strict=True):
                self.validate(a, k)
        return out


class QuadraticNoise(NoiseModel):
    """Models with λ = Σ_ω w(L0)(L1 − L0)², log E[ℓ_i ℓ_j] = Σ_ω w(L0)(Li − L0)(Lj − L0) and
    per-pixel Fisher information w(L)(∂L/∂θ)². A pixel with infinite weight contributes 0 where the
    difference (or derivative) is 0 and +inf otherwise — never NaN."""

    @abstractmethod
    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        """Per-pixel weight w(L0) ≥ 0, float64, broadcastable to L0 (+inf allowed)."""

    def _flat_weight(self, L0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(finite weight with 0 at infinite entries, mask of infinite entries), both flat (N,)."""
        w = self.weight(L0).expand(L0.shape).reshape(-1)
        inf = torch.isinf(w)
        return torch.where(inf, torch.zeros_like(w), w), inf

    def chi2_exponent(self, L0, L1, check: bool = True) -> torch.Tensor:
        L0, L1 = self._inputs(check, L0=L0, L1=L1)
        D, batch = _differences(L0, L1, "L1")
        wf, inf = self._flat_weight(L0)
        hit = (D[:, inf] != 0).any(dim=1) if bool(inf.any()) else None
        lam = D.square_() @ wf
        if hit is not None:
            lam[hit] = math.inf
        return lam.reshape(batch)

    def gram_exponent(self, L0, Li, Lj) -> torch.Tensor:
        L0, Li, Lj = self._inputs(True, L0=L0, Li=Li, Lj=Lj)
        Di, bi = _differences(L0, Li, "Li")
        Dj, bj = _differences(L0, Lj, "Lj")
        wf, inf = self._flat_weight(L0)
        g = (Di * wf) @ Dj.T
        if bool(inf.any()):
            hit = (Di[:, inf] != 0).to(torch.float64) @ (Dj[:, inf] != 0).to(torch.float64).T
            g[hit > 0] = math.inf
        return g.reshape(bi + bj)

    def fisher(self, L, dL) -> torch.Tensor:
        (L,) = self._inputs(True, L=L)
        dL = to_float64(dL, "dL")
        check_finite(dL, "dL")
        if dL.shape == L.shape:
            return self.fisher(L, dL[None])[0, 0]
        if dL.shape[1:] != L.shape:
            raise ValueError(f"dL must have shape {tuple(L.shape)} or (P, {tuple(L.shape)}), "
                             f"got {tuple(dL.shape)}")
        prod = dL[:, None] * dL[None, :]
        return torch.where(prod == 0, torch.zeros_like(prod), prod * self.weight(L))


def _differences(L0: torch.Tensor, L1: torch.Tensor, what: str) -> tuple[torch.Tensor, tuple]:
    """Direct differences L1 − L0 flattened to (B, N) and the batch shape of L1."""
    nb = L1.ndim - L0.ndim
    if nb < 0 or tuple(L1.shape[nb:]) != tuple(L0.shape):
        raise ValueError(f"{what} must have shape (*batch, {tuple(L0.shape)}), got {tuple(L1.shape)}")
    batch = tuple(L1.shape[:nb])
    return (L1 - L0).reshape(math.prod(batch), -1), batch


_REGISTRY: dict[str, type[NoiseModel]] = {}


def register(name: str) -> Callable[[type[NoiseModel]], type[NoiseModel]]:
    """Class decorator adding a NoiseModel subclass to the registry under `name`."""

    def deco(cls: type[NoiseModel]) -> type[NoiseModel]:
        if not (isinstance(cls, type) and issubclass(cls, NoiseModel)):
            raise TypeError(f"{cls!r} is not a NoiseModel subclass")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return deco


def get(name: str, **kw) -> NoiseModel:
    """Build the registered noise model `name` with keyword parameters, e.g. get("awgn", sigma=0.1)."""
    try:
        cls = _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown noise model {name!r}; available: {available()}") from None
    return cls(**kw)


def available() -> list[str]:
    """Names of the registered noise models."""
    return sorted(_REGISTRY)


@register("awgn")
@dataclass(frozen=True)
class AWGN(QuadraticNoise):
    """Additive white Gaussian noise Y = L + ε, ε ~ N(0, σ²), σ in radiance units."""

    sigma: float
    symmetric: ClassVar[bool] = True  # λ = ‖L1 − L0‖² / σ²

    def __post_init__(self):
        if not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"AWGN sigma must be finite and > 0, got {self.sigma}")

    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        return torch.tensor(1.0 / self.sigma**2, dtype=torch.float64, device=L0.device)

    def binned(self, b: int) -> AWGN:
        """Mean of b² pixels with independent N(0, σ²) noise: σ/b (the block's sum carries b·σ)."""
        return AWGN(self.sigma / check_bin(b))

    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        check_finite(L, "L")
        eps = torch.randn(L.shape, generator=generator, dtype=L.dtype, device=L.device)
        return L + self.sigma * eps

    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """Σ (y − L)² / (2σ²)."""
        r = (torch.as_tensor(y).to(torch.float64) - L.to(torch.float64)) / self.sigma
        return 0.5 * (r * r).sum()


@register("poisson")
@dataclass(frozen=True)
class Poisson(QuadraticNoise):
    """Photon counts K ~ Poisson(scale·L); `scale` = expected photons per unit radiance.

    Observations are reported in radiance units, y = K / scale (so E[y] = L, Var[y] = L / scale).
    The bound depends on `scale`: λ = scale·Σ(L1 − L0)²/L0 (exact for Poisson)."""

    scale: float

    def __post_init__(self):
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"Poisson scale must be finite and > 0, got {self.scale}")

    def validate(self, L: torch.Tensor, what: str) -> None:
        check_finite(L, what)
        neg = int((L < 0).sum())
        if neg:
            raise ValueError(f"{what} has {neg} negative values; a Poisson mean must be >= 0")

    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        return self.scale / L0  # +inf where L0 = 0

    def binned(self, b: int) -> Poisson:
        """Counts of b² pixels summed (a b² larger pixel): Poisson(scale·Σ L) = b²·scale photons per unit
        of the block's mean radiance."""
        return Poisson(self.scale * check_bin(b) ** 2)

    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        self.validate(L, "L")
        counts = torch.poisson(self.scale * L.to(torch.float64), generator=generator)
        return (counts / self.scale).to(L.dtype)

    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """scale·Σ (L − y·log L), i.e. −log p up to a constant; y = 0 pixels add scale·L even at
        L = 0 (finite value and gradient), y > 0 at L = 0 gives +inf."""
        y = torch.as_tensor(y).to(torch.float64)
        L = L.to(torch.float64)
        safe = torch.where(y > 0, L, torch.ones_like(L))
        return self.scale * (L - y * torch.log(safe)).sum()
