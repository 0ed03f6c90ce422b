"""The camera of a Mitsuba model moved off its pose and re-aimed (`CameraRig`), and a pose's Fisher information
from the bound service (`viewpoint_information`): what the viewpoint studies (`viewpoints`, `viewpoint-search`)
share.

The camera pose is not part of θ: it is written into the loaded scene's sensor (`mi.traverse` of the sensor,
no reload), and the model's render cache is bypassed while a pose is set (its key does not know the pose).
"""
from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np

from ..bank import RenderBank
from ..bounds import Bound, BoundService, FisherPoint, cameras_crlb
from ..bounds.fd_step import trace_inv
from ..forward.model import ForwardModel
from ..schema import Field

#: the schema keys both viewpoint studies share: the offsets' axes, the point the camera keeps looking at, and the
#: renders' spp and FD step
VIEW_KEYS = {
    "axes": Field(list, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "two world directions of the offsets (x, then z)",
                  items=Field(list, items=float)),
    "target": Field(list, None, "world point the camera keeps looking at (default: the surface point on the "
                    "standard view's optical axis)", items=float, nullable=True),
    "spp": Field(int, 256, "samples per pixel of every render"),
    "fd_step": Field(float, 0.01, "FD step ξ (parameter units)"),
}


class CameraRig:
    """The first sensor of a Mitsuba model, moved by offsets from its pose in the scene file while looking
    at a fixed world point `target` (default: where its optical axis meets the scene), same up vector."""

    def __init__(self, model: ForwardModel, target=None):
        import mitsuba as mi

        self.model = getattr(model, "base", model)
        if not hasattr(self.model, "scene"):
            raise ValueError(f"a viewpoint study needs a Mitsuba scene; {model.name!r} has no camera")
        self.sensor_params = mi.traverse(self.model.scene.sensors()[0])
        self.rest = mi.Transform4f(self.sensor_params["to_world"])
        m = np.array(self.rest.matrix, dtype=np.float64).reshape(4, 4)
        self.origin, self.up = m[:3, 3].copy(), m[:3, 1].copy()
        self.target = self._axis_hit(m[:3, 2]) if target is None else np.asarray(target, dtype=np.float64)
        if self.target.shape != (3,):
            raise ValueError(f"target must be a point [x, y, z], got {target!r}")

    def _axis_hit(self, forward: np.ndarray) -> np.ndarray:
        """The first surface point along the optical axis."""
        import mitsuba as mi

        si = self.model.scene.ray_intersect(mi.Ray3f(_point(self.origin), mi.Vector3f(_point(forward))))
        t = float(np.asarray(si.t).ravel()[0])
        if not math.isfinite(t):
            raise ValueError("the camera's optical axis hits nothing; give the study a `target`")
        return self.origin + t * forward

    @contextmanager
    def at(self, offset):
        """Within the block, renders see the camera moved by `offset` (world metres) and re-aimed."""
        import mitsuba as mi

        o = self.origin + np.asarray(offset, dtype=np.float64)
        cache, self.model.cache = self.model.cache, None
        self.sensor_params["to_world"] = mi.Transform4f().look_at(origin=_point(o), target=_point(self.target),
                                                                  up=_point(self.up))
        self.sensor_params.update()
        try:
            yield
        finally:
            self.sensor_params["to_world"] = self.rest
            self.sensor_params.update()
            self.model.cache = cache


def _point(v):
    """A mi.Point3f from a numpy 3-vector."""
    import mitsuba as mi

    return mi.Point3f(*(float(x) for x in v))


def viewpoint_information(model: ForwardModel, theta, spp: int, seed: int, fd_step: float, rounds: int, noises,
                          reduce: str = "mean", smoothed: bool = False, precision: float | None = None,
                          budget: int | None = None, looks: int = 2) -> FisherPoint:
    """Render, FD Jacobian and per-pixel Fisher maps (P, H, W) per noise model at the current camera pose,
    from the bound service over a render bank of the posed model (its seeds derive from `seed`). The maps
    compare poses at one FD step ξ (no halving: the heat map is of the FD-smoothed information, at the same
    cost per pose); the CRLB of a pose is labelled as not a confidence limit for that reason, unless `smoothed`:
    then it is quoted as the FD-smoothed model's, whose ends are limits of that (`BoundService.fisher`), and a
    `precision` target on it (the A-optimal score tr F̂⁻¹ to ±p, `budget` pixel-samples, `looks`) adds fresh
    rounds at this pose only where its interval is wider than asked (the point's `precise` record)."""
    svc = BoundService(RenderBank(model, seed=seed), noises)
    return svc.fisher([theta], spp, fd_step, rounds, reduce, max_halvings=0, smoothed=smoothed,
                      precision=precision, budget=budget, looks=looks)[0]


def unit_axes(axes) -> np.ndarray:
    """The two offset directions as unit world vectors (2, 3); ValueError unless two non-zero 3-vectors."""
    a = np.asarray(axes, dtype=np.float64)
    if a.shape != (2, 3) or not np.all(np.isfinite(a)) or np.any(np.linalg.norm(a, axis=1) == 0):
        raise ValueError(f"axes must be two non-zero 3-vectors, got {axes!r}")
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def view_scores(points: list[FisherPoint], noises, group: int, smoothed: bool = False) -> list[dict]:
    """Per noise model (index into `noises`), the A-optimal score of independent cameras' FisherPoints as JSON-ready
    cells: the summed unbiased Fisher matrix "F" (P, P) and the bound service's CRLB of θ, tr F̂⁻¹ (units²,
    `bounds.cameras_crlb`): its log10 "log10", one-sided ends "lower"/"upper" (log10), "log_se" (`log_se`),
    "lower_note" and "flags"; `smoothed`: the FD-smoothed model's score (`viewpoint_information`)."""
    out = []
    for k in range(len(noises)):
        F, b = cameras_crlb(points, k, group=group, smoothed=smoothed)
        out.append({"F": F.tolist(), "log10": b.point, "lower": b.lower, "upper": b.upper, "log_se": log_se(b),
                    "lower_note": b.lower_note, "flags": ",".join(b.flags)})
    return out


def score_cells(s: dict, names: list[str]) -> dict:
    """CSV cells of one `view_scores` entry: log10_score, score_lower/_upper (log10), log10_score_se, the lower
    end's note, flags, and F̂'s upper triangle as fisher_<a>_<b> (1/units²)."""
    cells = {"log10_score": s["log10"], "score_lower": s["lower"], "score_upper": s["upper"],
             "log10_score_se": s["log_se"], "score_lower_note": s["lower_note"], "score_flags": s["flags"]}
    F = np.asarray(s["F"])
    cells.update({f"fisher_{a}_{b}": F[i, j] for i, a in enumerate(names) for j, b in enumerate(names) if j >= i})
    return cells


def log_se(b: Bound) -> float:
    """The jackknife standard error of log10 of a Bound's point over its rounds (from `Bound.loo`, R ≥ 3);
    NaN without leave-one-outs or where one is not finite (a round's F̂ not positive definite)."""
    loo = np.asarray(b.loo, dtype=np.float64)
    if loo.size < 3 or not np.all(np.isfinite(loo)):
        return math.nan
    R = loo.size
    return float(np.sqrt((R - 1) / R * ((loo - loo.mean()) ** 2).sum()))


def best_pair(F: np.ndarray, max_pairs: int = 5000) -> tuple[int, int, float, str]:
    """The pair of distinct views whose Fisher matrices' sum has the smallest trace of its inverse.

    Independent cameras' Fisher matrices add, so the pair's A-optimal score is tr (F_a + F_b)⁻¹ (+inf where the
    sum is not positive definite). Point estimates only: a choice among noisy scores, to be confirmed with fresh
    renders.

    Parameters
    ----------
    F : ndarray of shape (n, P, P)
        The n ≥ 2 views' Fisher matrices, 1/(parameter units)².
    max_pairs : int, optional
        Exhaustive over the n(n − 1)/2 pairs up to this many; beyond, greedy: the best single view, the best
        partner for it, then each view re-chosen given the other until neither changes.

    Returns
    -------
    a, b : int
        The views' indices, a < b.
    score : float
        tr (F_a + F_b)⁻¹, parameter units².
    method : str
        "exhaustive" or "greedy".
    """
    F = np.asarray(F, dtype=np.float64)
    n = F.shape[0]
    if F.ndim != 3 or F.shape[1] != F.shape[2] or n < 2:
        raise ValueError(f"need the Fisher matrices of >= 2 views, shape (n, P, P), got {F.shape}")
    pair = lambda i, j: trace_inv(F[i] + F[j])
    if n * (n - 1) // 2 <= max_pairs:
        score, a, b = min((pair(i, j), i, j) for i in range(n) for j in range(i + 1, n))
        return a, b, score, "exhaustive"
    a = min(range(n), key=lambda i: trace_inv(F[i]))
    b = min((j for j in range(n) if j != a), key=lambda j: pair(a, j))
    for _ in range(n):
        a2 = min((i for i in range(n) if i != b), key=lambda i: pair(i, b))
        b2 = min((j for j in range(n) if j != a2), key=lambda j: pair(a2, j))
        if (a2, b2) == (a, b):
            break
        a, b = a2, b2
    return min(a, b), max(a, b), pair(a, b), "greedy"
