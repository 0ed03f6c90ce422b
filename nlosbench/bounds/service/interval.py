"""The paper's HCR intervals [HCR_Neff, HCR-hat] from inexact renders at spp levels (`BoundService.interval`)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from nlosbench.bounds.inexact import InexactHCR, inexact_hcr
from nlosbench.bounds.service.points import (
    Bound,
    BoundPoint,
    hcr_bound,
)
from nlosbench.bounds.service.renders import (
    RenderSets,
    _check,
)
from nlosbench.seeds import derive


class PaperIntervals(RenderSets):
    """`interval` and `interval_renders` (the service's module docstring)."""

    def interval(self, thetas, deltas, levels: Sequence[int], n_eff: int, replicates: int, power: float = 1.0,
                 bootstrap: int = 0, confidence: float = 0.9, boot_seed: int = 0, seeds: str = "independent",
                 noises=None) -> list[tuple[BoundPoint, InexactHCR]]:
        """The paper's [HCR_Neff, HCR-hat] at each scalar θ* (see `inexact_hcr`).

        From render sets of every θ* and θ* + Δ (Δ inside Θ): k spp levels × R replicates (purpose
        "inexact-levels") and R replicates at N_eff (purpose "inexact-neff"); a render serves every θ* that
        uses it.

        Parameters
        ----------
        thetas : array_like of shape (T,)
            The points θ* of the (scalar) parameter, parameter units.
        deltas : array_like of shape (K,)
            Offsets Δ (0 and those that leave Θ are dropped per θ*).
        levels : sequence of int
            Total spp per level (at least 2 distinct), each divisible by `replicates`.
        n_eff : int
            N_eff, the spp of the direct render set (equal budget: N_eff ≈ Σ N_i), divisible by `replicates`.
        replicates : int
            R replicates of each render set (N/R spp each).
        power : float, optional
            Decay rate p of the fit λ̃ = λ + C/N^p.
        bootstrap : int, optional
            Half-sample bootstrap resamples (0: none).
        confidence : float, optional
            Level of the bootstrap intervals, in (0, 1).
        boot_seed : int, optional
            Drives the bootstrap (a stream per noise model and θ* is derived from it).
        seeds : {"independent", "common"}, optional
            A seed per θ, or common random numbers across θ within a (level, replicate).
        noises : iterable of int, optional
            The noise indices (keys of the service's `noises`) to compute bounds for; None: every model.

        Returns
        -------
        list of (BoundPoint, InexactHCR)
            Per (noise, θ*), noise-major: a BoundPoint with the hcr_neff and hcr_hat Bounds, and the full
            InexactHCR.
        """
        if self.params.dim != 1:
            raise ValueError(f"the HCR interval needs one parameter; the model has {list(self.params.names)}")
        _check(seeds, replicates)
        points, plan = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        common = seeds == "common"
        X = self.bank.levels_at(points, levels, replicates, "inexact-levels", common)
        Xe = self.bank.levels_at(points, [n_eff], replicates, "inexact-neff", common)[0]
        out = []
        for m, (j, noise) in enumerate(self._select(noises).items()):
            for t, (theta, (q0, d, qd)) in enumerate(zip(np.asarray(thetas, dtype=np.float64), plan, strict=True)):
                r = inexact_hcr(X[:, :, q0], X[:, :, qd], d, levels, noise, Xe[:, q0], Xe[:, qd], n_eff, power=power,
                                bootstrap=bootstrap, confidence=confidence,
                                seed=derive(boot_seed, "interval-bootstrap", m, t))
                neff, hat = hcr_bound(r.hcr_neff, "hcr_neff"), hcr_bound(r.hcr_hat, "hcr_hat")
                if r.fit.noise_dominated.any():
                    hat = Bound(hat.kind, hat.log10, hat.delta, hat.flags + ("noise-dominated",), hat.reason,
                                point=hat.point)
                out.append((BoundPoint(j, str(noise), np.array([theta]), {"hcr_neff": neff, "hcr_hat": hat}), r))
        return out

    def interval_renders(self, thetas, deltas, levels: Sequence[int], replicates: int,
                         seeds: str = "independent") -> torch.Tensor:
        """The level renders of `interval`'s render points (no new renders once `interval` ran), e.g. for
        the 1/N decay check.

        Parameters
        ----------
        thetas : array_like of shape (T,)
            The points θ*, as given to `interval`.
        deltas : array_like of shape (K,)
            The offsets Δ, as given to `interval`.
        levels : sequence of int
            Total spp per level, as given to `interval`.
        replicates : int
            R, as given to `interval`.
        seeds : {"independent", "common"}, optional
            As given to `interval`.

        Returns
        -------
        torch.Tensor of shape (k, R, Q, H, W, C)
            The renders of the Q unique render points (θ* and θ* + Δ inside Θ) at each level and replicate.
        """
        points, _ = interval_points(thetas, deltas, self.params.lower[0], self.params.upper[0])
        return self.bank.levels_at(points, levels, replicates, "inexact-levels", seeds == "common")


def interval_points(thetas, deltas, lo: float, hi: float) -> tuple[np.ndarray, list]:
    """Unique render points (Q,) of θ* and θ* + Δ inside [lo, hi], and per θ*: (its point index, its usable
    Δ (D_t,), their point indices). ValueError when a θ* has no usable Δ."""
    index: dict[float, int] = {}

    def at(v: float) -> int:
        return index.setdefault(round(float(v), 12), len(index))

    deltas = np.asarray(deltas, dtype=np.float64)
    deltas = deltas[deltas != 0]
    plan = []
    for t in np.asarray(thetas, dtype=np.float64).reshape(-1):
        d = deltas[(t + deltas >= lo) & (t + deltas <= hi)]
        if d.size == 0:
            raise ValueError(f"no Δ in {deltas.tolist()} keeps θ* = {t:g} + Δ inside [{lo:g}, {hi:g}]")
        plan.append((at(t), d, np.array([at(t + x) for x in d], dtype=np.int64)))
    return np.array(list(index), dtype=np.float64), plan


