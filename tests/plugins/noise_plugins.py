"""Noise models as a third-party package would ship them (registered in tests through the entry-point group
`nlosbench.noise`, never with @register)."""
from dataclasses import dataclass
from typing import ClassVar

import torch

from nlosbench.noise import NoiseModel, QuadraticNoise


@dataclass(frozen=True)
class ShotRead(QuadraticNoise):
    """Gaussian noise of variance read² + L/scale per pixel (shot noise plus read noise, in radiance units).

    λ to second order in the image difference: w(L0) = 1 / (read² + L0/scale)."""

    scale: float
    read: float
    signal_dependent: ClassVar[bool] = True

    def weight(self, L0):
        return 1.0 / (self.read**2 + L0.to(torch.float64) / self.scale)

    def sample(self, L, generator):
        sd = self.weight(L).rsqrt()
        return (L + sd * torch.randn(L.shape, generator=generator, dtype=torch.float64)).to(L.dtype)

    def nll(self, y, L):
        w = self.weight(L)
        return 0.5 * (w * (torch.as_tensor(y, dtype=torch.float64) - L.to(torch.float64)) ** 2 - torch.log(w)).sum()


@dataclass(frozen=True)
class ShotReadFixed(ShotRead):
    """The same model, declared (wrongly for a check) with a weight that does not depend on the signal."""

    signal_dependent: ClassVar[bool] = False


@dataclass(frozen=True)
class Laplace(NoiseModel):
    """Laplace noise of scale b: its χ² exponent is no quadratic form in the image difference."""

    b: float

    def sample(self, L, generator):
        u = torch.rand(L.shape, generator=generator, dtype=torch.float64) - 0.5
        return (L - self.b * torch.sign(u) * torch.log1p(-2 * u.abs())).to(L.dtype)

    def nll(self, y, L):
        return ((torch.as_tensor(y, dtype=torch.float64) - L.to(torch.float64)).abs() / self.b).sum()

    def chi2_exponent(self, L0, L1, check=True):
        raise NotImplementedError

    def gram_exponent(self, L0, Li, Lj):
        raise NotImplementedError

    def fisher(self, L, dL):
        raise NotImplementedError


NOT_A_MODEL = object()
