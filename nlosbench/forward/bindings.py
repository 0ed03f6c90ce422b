"""Bindings from θ components to Mitsuba scene parameters (`mi.traverse` keys).

Kinds (as written in a scene spec's `params:` list):
  translate    move object `object` along unit `axis` by θ metres from its position in the file
  path         place the centre of `object` on a polyline `points` at arc length θ metres from points[0]
  radius       scale `object` about its centre so its radius (sphere) / half-extent (mesh) is θ metres
  reflectance  set channel `channel` (0, 1, 2) of the colour at `key` to θ, or scale it by θ if no channel
  radiance     as reflectance, for an emitter's radiance (W·sr⁻¹·m⁻²)
Geometry bindings on one object compose: centre = c0 + Σ offsets, scale = Π factors, so a ball can
move and grow at once. Everything is written with Dr.Jit arithmetic so AD flows from θ to the scene.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..params import Param

GEOMETRY_KINDS = ("translate", "path", "radius")
COLOR_KINDS = ("reflectance", "radiance")
KINDS = GEOMETRY_KINDS + COLOR_KINDS


@dataclass
class Binding:
    """One θ component: its Param and how it reaches the scene."""

    param: Param
    kind: str
    object: str | None = None
    key: str | None = None
    axis: np.ndarray | None = None
    points: np.ndarray | None = None
    channel: int | None = None
    _arclen: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def from_spec(cls, spec: dict) -> Binding:
        spec = dict(spec)
        where = f"parameter {spec.get('name', '?')!r}"
        kind = spec.pop("kind", None)
        if kind not in KINDS:
            raise ValueError(f"{where}: kind must be one of {list(KINDS)}, got {kind!r}")
        b = cls(param=None, kind=kind, object=spec.pop("object", None), key=spec.pop("key", None),  # type: ignore[arg-type]
                channel=spec.pop("channel", None))
        if kind in GEOMETRY_KINDS and not b.object:
            raise ValueError(f"{where}: kind {kind!r} needs `object` (a shape id in the scene file)")
        if kind in COLOR_KINDS and not b.key:
            raise ValueError(
                f"{where}: kind {kind!r} needs `key` (a mi.traverse key, e.g. ball.bsdf.reflectance.value)"
            )
        if b.channel is not None and b.channel not in (0, 1, 2):
            raise ValueError(f"{where}: channel must be 0, 1 or 2, got {b.channel!r}")
        if kind == "translate":
            axis = np.asarray(spec.pop("axis", None), dtype=np.float64)
            if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
                raise ValueError(f"{where}: translate needs a finite, non-zero 3-vector `axis`, got {axis.tolist()}")
            b.axis = axis / np.linalg.norm(axis)
        if kind == "path":
            pts = np.asarray(spec.pop("points", None), dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2 or not np.all(np.isfinite(pts)):
                raise ValueError(f"{where}: path needs `points`, a list of at least two finite [x, y, z]")
            seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
            if np.any(seg <= 0):
                raise ValueError(f"{where}: path has repeated consecutive points")
            b.points, b._arclen = pts, np.concatenate([[0.0], np.cumsum(seg)])
            spec.setdefault("lower", 0.0)
            spec.setdefault("upper", float(b._arclen[-1]))
            if spec["upper"] > b._arclen[-1] + 1e-9 or spec["lower"] < 0:
                raise ValueError(f"{where}: bounds must lie within the path's length [0, {b._arclen[-1]:g}] m")
        units = spec.pop("units", "m" if kind in GEOMETRY_KINDS else "1")
        try:
            b.param = Param(
                name=spec.pop("name"),
                lower=float(spec.pop("lower")),
                upper=float(spec.pop("upper")),
                default=float(spec.pop("default")),
                units=units,
                description=spec.pop("description", ""),
            )
        except KeyError as e:
            raise ValueError(f"{where}: missing {e.args[0]!r}") from None
        if spec:
            raise ValueError(f"{where}: unknown option(s) {sorted(spec)} for kind {kind!r}")
        return b

    def path_point(self, s):
        """Point on the polyline at arc length s (a Dr.Jit Float; the segment is chosen from its value)."""
        i = int(
            np.clip(
                np.searchsorted(self._arclen, float(s[0] if hasattr(s, "__len__") else s), "right") - 1,
                0,
                len(self.points) - 2,
            )
        )
        d = (self.points[i + 1] - self.points[i]) / (self._arclen[i + 1] - self._arclen[i])
        return _vec(self.points[i]) + _vec(d) * (s - float(self._arclen[i]))


def _vec(v):
    """A constant mi.Vector3f from a numpy 3-vector."""
    import mitsuba as mi

    return mi.Vector3f(*(float(x) for x in v))


class ObjectGeometry:
    """Rest state of one shape (to_world or vertex positions) and how to write a moved/scaled copy."""

    def __init__(self, params, object_id: str):
        import drjit as dr
        import mitsuba as mi

        self.id = object_id
        if f"{object_id}.vertex_positions" in params:
            self.key = f"{object_id}.vertex_positions"
            v = np.array(params[self.key], dtype=np.float64).reshape(-1, 3)
            lo, hi = v.min(0), v.max(0)
            self.center, self.size = (lo + hi) / 2, float((hi - lo).max() / 2)
            self.rest = mi.Float(params[self.key])
            dr.eval(self.rest)
        elif f"{object_id}.to_world" in params:
            self.key = f"{object_id}.to_world"
            self.rest = mi.Transform4f(params[self.key])
            m = np.array(self.rest.matrix, dtype=np.float64).reshape(4, 4)
            self.center, self.size = m[:3, 3].copy(), float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
        else:
            shapes = sorted({k.split(".")[0] for k in params.keys() if k.endswith((".to_world", ".vertex_positions"))})
            raise ValueError(f"no movable shape with id {object_id!r} in the scene; shapes with ids: {shapes}")

    def write(self, params, offset, scale) -> None:
        """Set the shape to its rest state scaled by `scale` about its centre, then moved by `offset`."""
        import drjit as dr
        import mitsuba as mi

        c = _vec(self.center)
        if self.key.endswith("to_world"):
            params[self.key] = (
                mi.Transform4f().translate(c + offset).scale(mi.Vector3f(scale)).translate(-c) @ self.rest
            )
        else:
            p = dr.unravel(mi.Point3f, self.rest)
            params[self.key] = dr.ravel((p - c) * scale + c + offset)


class SceneBinder:
    """Applies θ to a traversed scene: geometry per object, colours per key."""

    def __init__(self, params, bindings: list[Binding]):
        import mitsuba as mi

        self.bindings = bindings
        self.objects = {b.object: ObjectGeometry(params, b.object) for b in bindings if b.kind in GEOMETRY_KINDS}
        self.colors = {}
        for b in bindings:
            if b.kind in COLOR_KINDS:
                if b.key not in params:
                    near = [k for k in params.keys() if k.endswith((".value", "radiance.value"))]
                    raise ValueError(f"parameter {b.param.name!r}: no scene parameter {b.key!r}; colour keys: {near}")
                self.colors[b.key] = np.array(mi.Color3f(params[b.key]), dtype=np.float64).reshape(-1)[:3]

    def apply(self, params, theta: list) -> None:
        """Write θ (a list of Dr.Jit Floats, one per binding) into `params` and update the scene."""
        import drjit as dr
        import mitsuba as mi

        offsets = {o: mi.Vector3f(0.0) for o in self.objects}
        scales = {o: mi.Float(1.0) for o in self.objects}
        colors = {k: [mi.Float(float(c)) for c in base] for k, base in self.colors.items()}
        for b, t in zip(self.bindings, theta, strict=True):
            if b.kind == "translate":
                offsets[b.object] = offsets[b.object] + _vec(b.axis) * t
            elif b.kind == "path":
                offsets[b.object] = offsets[b.object] + b.path_point(t) - _vec(self.objects[b.object].center)
            elif b.kind == "radius":
                scales[b.object] = scales[b.object] * t / self.objects[b.object].size
            elif b.channel is None:
                colors[b.key] = [c * t for c in colors[b.key]]
            else:
                colors[b.key][b.channel] = t
        for o, geo in self.objects.items():
            geo.write(params, offsets[o], scales[o])
        for k, c in colors.items():
            params[k] = mi.Color3f(*c)
        params.update()
        dr.eval()
