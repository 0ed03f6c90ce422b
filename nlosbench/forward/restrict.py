"""A forward model restricted to some of its parameters, the others held fixed (θ_sub ↦ full θ)."""
from __future__ import annotations

import numpy as np
import torch

from .model import ForwardModel


class Restricted(ForwardModel):
    """`base` seen through the parameters `names` only; the rest stay at `fixed` (default: defaults).

    Renders, derivatives and stats go to the base model (one scene load, one render counter)."""

    def __init__(self, base: ForwardModel, names, fixed: dict | None = None):
        self.base = base
        self.index = [base.params.index(n) for n in names]
        full = base.params.default.copy()
        for k, v in (fixed or {}).items():
            full[base.params.index(k)] = v
        self.full = base.params.validate(full)
        super().__init__(base.name, base.params.subset(names), None)
        self.stats = base.stats
        self.exact = base.exact

    def expand(self, theta) -> np.ndarray:
        """Full θ (float64) from the restricted θ."""
        t = self.full.copy()
        t[self.index] = self.params.validate(theta)
        return t

    def render(self, theta, spp: int, seed: int) -> torch.Tensor:
        return self.base.render(self.expand(theta), spp, seed)

    def _render(self, theta, spp, seed):  # render() is delegated whole, with the base's cache
        raise NotImplementedError

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        return self.base.jvp(self.expand(theta), self.index[index], spp, seed, **ad)

    def vjp(self, theta, grad_out, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        wanted = self.index if indices is None else [self.index[j] for j in indices]
        return self.base.vjp(self.expand(theta), grad_out, spp, seed, indices=wanted, **ad)[self.index]

    def content_key(self) -> dict:
        return {"base": self.base.content_key(), "index": self.index, "fixed": self.full.tolist()}
