"""`backprojection`: the NLOS field's peak localiser for confocal transient captures, as an estimator plug-in.

From counts y (scan_y, scan_x, T, C), every candidate position v of the hidden object gets the backprojection

    B(v) = Σ_ij Σ_c y_ij(d = 2‖v − p_ij‖, c),

y_ij(d) the histogram of scan point p_ij read at optical path d by linear interpolation between bin centres (0
outside the window). Candidates form a voxel grid in θ: the parameters that translate the object
(`forward.transient.position_map`), over Θ, `voxel` metres apart (the other parameters stay at the start θ).
θ̂ is the best voxel, refined (`refine` "parabolic") by a 3-point parabola through B along each axis (clipped to
half a voxel), then clipped into Θ. No render: the estimator knows the geometry (scan points and bins), not the
radiometry, so it is biased where the r⁻⁴ fall-off or the object's extent moves the peak; its discretisation
error is what it makes of the noise-free mean (`fit` on `model.render` at high spp), apart from its noise error.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch

from ..forward.transient import confocal_geometry, position_map
from .base import Estimator, Outcome, Problem, Tracker

REFINES = ("parabolic", "none")


def backproject(y: np.ndarray, points: np.ndarray, edges: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """B at each of `positions` (M, 3) from counts y (scan_y, scan_x, T[, C]), scan points (scan_y, scan_x, 3)
    and bin edges (T + 1,), metres; float64 (M,). Histograms are read at optical path 2‖v − p‖ by linear
    interpolation between bin centres."""
    y = np.asarray(y, dtype=np.float64)
    if y.ndim == 4:
        y = y.sum(axis=-1)
    S = y.shape[0] * y.shape[1]
    h = y.reshape(S, -1)
    T = h.shape[1]
    p = np.asarray(points, dtype=np.float64).reshape(S, 3)
    w = float(edges[1] - edges[0])
    out = np.zeros(len(positions))
    for s in range(S):
        u = (2.0 * np.linalg.norm(positions - p[s], axis=1) - edges[0]) / w - 0.5  # fractional bin (centres at k)
        k = np.floor(u).astype(np.int64)
        f = u - k
        for kk, ww in ((k, 1.0 - f), (k + 1, f)):
            ok = (kk >= 0) & (kk < T)
            out[ok] += ww[ok] * h[s, kk[ok]]
    return out


class Backprojection(Estimator):
    """Backprojection peak localiser (see the module docstring).

    Parameters
    ----------
    voxel : float, optional
        Voxel spacing along each translated parameter, metres (> 0).
    refine : {"parabolic", "none"}, optional
        Sub-voxel refinement of the peak.
    max_voxels : int, optional
        The most voxels in the grid (an error names the voxel size that fits).
    """

    name: ClassVar[str] = "backprojection"
    valid_when: ClassVar[str] = ("a confocal transient capture of one compact hidden object whose position is θ: a "
                                 "fast, render-free localiser, biased by the radiometry and the object's extent")

    def __init__(self, voxel: float = 0.002, refine: str = "parabolic", max_voxels: int = 2_000_000):
        if not (np.isfinite(voxel) and voxel > 0):
            raise ValueError(f"voxel must be finite and > 0 (metres), got {voxel!r}")
        if refine not in REFINES:
            raise ValueError(f"refine must be one of {list(REFINES)}, got {refine!r}")
        self.voxel, self.refine, self.max_voxels = float(voxel), refine, int(max_voxels)

    def grid(self, problem: Problem, theta0: np.ndarray) -> tuple[list[int], list[np.ndarray]]:
        """(indices of the translated parameters, their voxel coordinates over Θ)."""
        _, A = position_map(problem.model)
        idx = [j for j in range(len(A)) if np.linalg.norm(A[j]) > 0]
        if not idx:
            raise ValueError(f"{problem.model.name!r}: no parameter translates the hidden object")
        p = problem.params
        axes = [np.arange(p.lower[j], p.upper[j] + 1e-12, self.voxel / np.linalg.norm(A[j])) for j in idx]
        n = int(np.prod([len(a) for a in axes]))
        if n > self.max_voxels:
            raise ValueError(f"{n} voxels exceed max_voxels={self.max_voxels}: use a coarser voxel")
        return idx, axes

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        points, edges = confocal_geometry(problem.model)
        origin, A = position_map(problem.model)
        idx, axes = self.grid(problem, theta0)
        mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)  # (*shape, len(idx))
        shape = mesh.shape[:-1]
        base = theta0 @ A - theta0[idx] @ A[idx]  # the held (non-grid) parameters' translation
        pos = origin + base + mesh.reshape(-1, len(idx)) @ A[idx]
        yn = y.detach().cpu().numpy()
        if yn.ndim != 4 or yn.shape[:2] != points.shape[:2] or yn.shape[2] != len(edges) - 1:
            raise ValueError(f"y must be (scan_y, scan_x, T, C) = {points.shape[:2] + (len(edges) - 1,)} + (C,), "
                             f"got {tuple(yn.shape)}")
        B = backproject(yn, points, edges, pos).reshape(shape)
        best = np.unravel_index(int(np.argmax(B)), shape)
        theta = theta0.copy()
        for a, j in enumerate(idx):
            v = axes[a][best[a]]
            if self.refine == "parabolic" and 0 < best[a] < len(axes[a]) - 1:
                lo, hi = list(best), list(best)
                lo[a] -= 1
                hi[a] += 1
                b0, bm, bp = B[best], B[tuple(lo)], B[tuple(hi)]
                curv = bm - 2 * b0 + bp
                if curv < 0:
                    v += float(np.clip(0.5 * (bm - bp) / curv, -0.5, 0.5)) * (axes[a][1] - axes[a][0])
            theta[j] = v
        theta = np.clip(theta, problem.params.lower, problem.params.upper)
        tracker.record(0, float(-B[best]), theta)
        return Outcome(theta, 1, "converged", f"peak of the backprojection over {B.size} voxels "
                       f"({self.voxel * 1e3:g} mm, refine {self.refine})", float(-B[best]))
