"""TransientModel: a time-resolved relay-wall capture rendered with mitransient (the optional extra
`nlosbench[transient]`), θ bound to the hidden scene like a steady scene's (`bindings.py`).

Set-up (`Capture`, metres): a relay wall of `wall` = (width, height) in the plane z = 0, centred on the origin,
facing +z, where the hidden objects are; a scan grid of `scan` = (nx, ny) points; `bins` time bins of
`bin_width` metres of optical path from `start` (the wall-to-laser and wall-to-detector legs excluded, y-tal's
t_accounts_first_and_last_bounces = False; paths that never leave the wall are discarded). Scan point (i, j)
(row i, column j) sits at x = −w/2 + (j + ½)·w/nx, y = −h/2 + (i + ½)·h/ny (checked against renders: a patch
at +x or +y arrives first at high j or high i). "confocal" scans laser and detector together; "single" keeps
the laser on the wall's centre. "exhaustive" aims the laser at every point of a laser grid `laser_scan` (lx, ly) in
turn, detectors on the scan grid, one "single" capture per laser point, each from seeds of its own: the image is
(ly·scan_y, lx·scan_x, T, C), block (i, j) the capture with the laser on laser point (i, j) (placed on the wall as
the scan points are); a (laser, detector) pair is one "pixel". Its size is checked before anything loads
(`EXHAUSTIVE_MAX_BYTES` per image, float64 while the passes add up): a larger one is refused naming its size.

Images are (scan_y, scan_x, T, C) float32 (exhaustive: (ly·scan_y, lx·scan_x, T, C)) in mitransient's units
(radiance per bin; C = 3 in RGB variants, 1 in mono ones); a scan point's T·C values come from the same paths
(`channels`). What a detector sees (temporal response, gating, background, photon budget) is applied after
rendering by `forward.detector.Detected`.

Renders follow `MitsubaModel` (whose θ writing, pass splitting and content key this class reuses): power-of-two
passes with seeds derived from (seed, pass), θ written with `mi.traverse` + `params.update()`, no reload; the
same (θ, spp, seed) gives the same image in one process (tests/test_transient_model.py). Passes run traced: the
transient integrator returns a (steady, transient) pair that the frozen `mi.render` path does not take.
Derivatives are FD only: mitransient's AD does not reach the hidden object's transform (the feasibility probe:
"not attached to the AD graph", or exactly 0 with VCallRecord off), so `jvp` / `vjp` raise.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from .. import interrupts
from .. import variant as _variant
from ..capture_io import CaptureFile, read_ytal
from ..params import ParamSpace
from ..seeds import derive
from . import llvm_target as _llvm_target
from .bindings import Binding, SceneBinder
from .mitsuba_model import MitsubaModel
from .model import ForwardModel
from .passes import FrozenRender, pass_samples

#: the mitransient version the extra pins and the tests ran with
MITRANSIENT_VERSION = "1.3.1"
CAPTURE_TYPES = ("confocal", "single", "exhaustive")
#: the largest exhaustive image (bytes while its passes add up in float64: L·N·T·3·8) a render may build
EXHAUSTIVE_MAX_BYTES = 2 << 30
HIDDEN_TYPES = ("rectangle", "sphere", "obj")


class TransientUnavailable(ImportError):
    """mitransient is not installed (install the extra: pip install 'nlosbench[transient]')."""


def import_mitransient():
    """The mitransient module (it registers its plugins for the active Mitsuba variant); TransientUnavailable with
    the install command when it is missing."""
    try:
        import mitransient
    except ImportError as e:
        raise TransientUnavailable(f"transient scenes need mitransient ({e}); install the extra: "
                                   f"pip install 'nlosbench[transient]' (mitransient=={MITRANSIENT_VERSION})") from None
    return mitransient


def _vec3(v, what: str) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a finite [x, y, z] in metres, got {v!r}")
    return tuple(float(x) for x in a)


@dataclass(frozen=True)
class Capture:
    """A relay-wall capture set-up (see the module docstring); lengths in metres, optical path included.

    Parameters
    ----------
    scan : (int, int)
        Scan points (nx, ny) over the wall.
    bins : int
        Time bins T.
    bin_width : float
        Bin width, metres of optical path (1 ps = 0.2998 mm).
    start : float
        Optical path at the start of bin 0, metres.
    wall : (float, float)
        Relay wall width and height, metres.
    laser_origin, sensor_origin : [x, y, z]
        Where the laser and the detector stand (in front of the wall, z > 0 is the hidden side: use z > 0 only
        for a set-up that sees the wall past the occluder), metres.
    capture_type : {"confocal", "single", "exhaustive"}
        Laser and detector scanned together, the laser fixed on the wall's centre, or the laser on every point of
        `laser_scan` in turn (one single capture each).
    max_depth : int
        Path depth of the transient integrator (3: laser → wall → hidden → wall).
    laser_scan : (int, int), optional
        Exhaustive captures: laser points (lx, ly) over the wall (default: `scan`); None for the others.
    """

    scan: tuple = (16, 16)
    bins: int = 128
    bin_width: float = 0.004
    start: float = 1.2
    wall: tuple = (1.0, 1.0)
    laser_origin: tuple = (-0.5, 0.0, 0.25)
    sensor_origin: tuple = (-0.5, 0.0, 0.25)
    capture_type: str = "confocal"
    max_depth: int = 3
    laser_scan: tuple | None = None

    def __post_init__(self):
        for name, v in (("scan", self.scan), ("wall", self.wall)):
            if not isinstance(v, (tuple, list)) or len(v) != 2:
                raise ValueError(f"capture {name} must be a pair (x, y), got {v!r}")
        for v in (*self.scan, self.bins, self.max_depth):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"capture scan, bins and max_depth must be positive integers, got {v!r}")
        for name, v in (("bin_width", self.bin_width), ("wall", self.wall[0]), ("wall", self.wall[1])):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"capture {name} must be finite and > 0 (metres), got {v!r}")
        if not (np.isfinite(self.start) and self.start >= 0):
            raise ValueError(f"capture start must be finite and >= 0 (metres of optical path), got {self.start!r}")
        if self.capture_type not in CAPTURE_TYPES:
            raise ValueError(f"capture_type must be one of {list(CAPTURE_TYPES)}, got {self.capture_type!r}")
        object.__setattr__(self, "scan", (int(self.scan[0]), int(self.scan[1])))
        if self.capture_type == "exhaustive":
            lasers = self.scan if self.laser_scan is None else self.laser_scan
            if not isinstance(lasers, (tuple, list)) or len(lasers) != 2 or any(
                    isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1 for v in lasers):
                raise ValueError(f"capture laser_scan must be a pair of positive integers (lx, ly), got {lasers!r}")
            object.__setattr__(self, "laser_scan", (int(lasers[0]), int(lasers[1])))
            size = int(np.prod(self.laser_scan)) * int(np.prod(self.scan)) * self.bins * 3 * 8
            if size > EXHAUSTIVE_MAX_BYTES:
                raise ValueError(f"an exhaustive capture of {self.laser_scan[0]} × {self.laser_scan[1]} laser points, "
                                 f"{self.scan[0]} × {self.scan[1]} scan points and {self.bins} bins takes "
                                 f"{size / 2**30:.3g} GiB per render (at most {EXHAUSTIVE_MAX_BYTES / 2**30:g}): use "
                                 "fewer laser or scan points or bins")
        elif self.laser_scan is not None:
            raise ValueError(f"capture laser_scan is for exhaustive captures, not {self.capture_type!r} ones")
        object.__setattr__(self, "wall", (float(self.wall[0]), float(self.wall[1])))
        object.__setattr__(self, "laser_origin", _vec3(self.laser_origin, "laser_origin"))
        object.__setattr__(self, "sensor_origin", _vec3(self.sensor_origin, "sensor_origin"))

    def scan_points(self, grid: tuple | None = None) -> np.ndarray:
        """Scan point positions (ny, nx, 3) on the wall, metres (z = 0); of another grid (nx, ny) (e.g. the laser
        points, `laser_scan`) placed the same way."""
        (nx, ny), (w, h) = grid or self.scan, self.wall
        x = -w / 2 + (np.arange(nx) + 0.5) * w / nx
        y = -h / 2 + (np.arange(ny) + 0.5) * h / ny
        Y, X = np.meshgrid(y, x, indexing="ij")
        return np.stack([X, Y, np.zeros_like(X)], axis=-1)

    def bin_edges(self) -> np.ndarray:
        """Optical path at the bin edges (T + 1,), metres."""
        return self.start + self.bin_width * np.arange(self.bins + 1)

    def as_dict(self) -> dict:
        """The fields (laser_scan only where it is set: the other captures' content keys stay as they were)."""
        d = asdict(self)
        if d["laser_scan"] is None:
            del d["laser_scan"]
        return d

    def to_file(self, image, scene_info: dict | None = None) -> CaptureFile:
        """A capture in y-tal's layout (`capture_io.CaptureFile`: write it with `capture_io.write_ytal`) of an image
        (scan_y, scan_x, T[, C]) of this set-up (channels summed). Confocal only."""
        if self.capture_type != "confocal":
            raise ValueError("only confocal captures are written in y-tal's layout here")
        return CaptureFile.from_image(image, self.scan_points(), self.bin_width, self.start,
                                      laser_xyz=np.array(self.laser_origin), sensor_xyz=np.array(self.sensor_origin),
                                      t_accounts_first_and_last_bounces=False, scene_info=dict(scene_info or {}))

    @classmethod
    def from_file(cls, capture: CaptureFile | str | Path, **options) -> Capture:
        """The set-up of a y-tal capture (a `CaptureFile` or its path): a confocal, regular scan grid on the plane
        z = 0, centred on the origin, normals +z, time without the first and last bounces (what this model
        renders); ValueError naming what differs otherwise. `options` override Capture fields (e.g. max_depth)."""
        cf = capture if isinstance(capture, CaptureFile) else read_ytal(capture)
        g = cf.sensor_grid_xyz.astype(np.float64)  # (Sx, Sy, 3)
        Sx, Sy = g.shape[:2]
        if not cf.is_confocal():
            raise ValueError("the capture is not confocal (laser and sensor grids differ)")
        if cf.t_accounts_first_and_last_bounces:
            raise ValueError("the capture's time includes the first and last bounces; this model's does not")
        if Sx < 2 or Sy < 2:
            raise ValueError(f"the scan grid must have at least 2 points per axis, got {Sx} × {Sy}")
        if not np.allclose(g[..., 2], 0, atol=1e-6) or not np.allclose(cf.sensor_grid_normals[..., 2], 1, atol=1e-6):
            raise ValueError("the relay wall must be the plane z = 0 with normals +z")
        dx, dy = g[1, 0, 0] - g[0, 0, 0], g[0, 1, 1] - g[0, 0, 1]
        want = Capture(scan=(Sx, Sy), wall=(Sx * abs(dx), Sy * abs(dy))).scan_points().transpose(1, 0, 2)
        if dx <= 0 or dy <= 0 or not np.allclose(g, want, atol=1e-5):
            raise ValueError("the scan grid must be regular, increasing in x along Sx and in y along Sy, and centred "
                             "on the origin")
        fields = {"scan": (Sx, Sy), "wall": (Sx * dx, Sy * dy), "bins": int(cf.H.shape[0]),
                  "bin_width": float(cf.delta_t), "start": float(cf.t_start),
                  "laser_origin": tuple(cf.laser_xyz.tolist()), "sensor_origin": tuple(cf.sensor_xyz.tolist())}
        return cls(**{**fields, **options})


@dataclass(frozen=True)
class Hidden:
    """A hidden object: a square patch facing the wall, a sphere or an OBJ mesh, centred at `center` (metres)
    with half-extent (or radius) `size` metres and a diffuse `albedo`. Its Mitsuba id is `id`: bind θ to it
    (`translate`, `radius` with object `id`; `reflectance` with key `<id>.bsdf.reflectance.value`)."""

    id: str = "hidden"
    type: str = "rectangle"
    center: tuple = (0.0, 0.0, 0.75)
    size: float = 0.05
    albedo: float = 1.0
    filename: str | None = None
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.type not in HIDDEN_TYPES:
            raise ValueError(f"hidden object {self.id!r}: type must be one of {list(HIDDEN_TYPES)}, got {self.type!r}")
        object.__setattr__(self, "center", _vec3(self.center, f"hidden object {self.id!r} center"))
        if self.center[2] <= 0:
            raise ValueError(f"hidden object {self.id!r}: center z must be > 0 (in front of the wall), got "
                             f"{self.center[2]}")
        if not (np.isfinite(self.size) and self.size > 0):
            raise ValueError(f"hidden object {self.id!r}: size must be finite and > 0 (metres), got {self.size!r}")
        if not (np.isfinite(self.albedo) and 0 <= self.albedo <= 1):
            raise ValueError(f"hidden object {self.id!r}: albedo must lie in [0, 1], got {self.albedo!r}")
        if self.type == "obj" and not (self.filename and Path(self.filename).is_file()):
            raise ValueError(f"hidden object {self.id!r}: type obj needs an existing `filename`, got {self.filename!r}")

    def mitsuba(self) -> dict:
        """The Mitsuba dict of this object (needs an active variant)."""
        import mitsuba as mi

        T = mi.ScalarTransform4f
        c = list(self.center)
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [self.albedo] * 3}}
        if self.type == "sphere":
            return {"type": "sphere", "to_world": T().translate(c) @ T().scale(self.size), "bsdf": bsdf}
        # rectangles and meshes face the wall: Mitsuba's rectangle is one-sided with a +z normal, hence the flip
        to_world = T().translate(c) @ T().rotate([1, 0, 0], 180) @ T().scale([self.size, self.size, self.size])
        out = {"type": self.type, "to_world": to_world, "bsdf": bsdf}
        if self.type == "obj":
            out.update({"filename": str(Path(self.filename).resolve()), "face_normals": True})
        return out


def _hidden(h) -> Hidden:
    return h if isinstance(h, Hidden) else Hidden(**h)


class TransientModel(MitsubaModel):
    """A transient relay-wall capture (see the module docstring): θ ↦ image (scan_y, scan_x, T, C) float32.

    Parameters
    ----------
    name : str
        The scene's name.
    capture : Capture or dict
        The set-up (a dict is passed to `Capture`).
    hidden : sequence of Hidden or dict
        The hidden objects (dicts are passed to `Hidden`); ids must be distinct.
    params : list of dict
        θ bindings, as in a steady scene spec (`bindings.Binding.from_spec`): e.g. {name: depth, kind: translate,
        object: hidden, axis: [0, 0, 1], lower: -0.2, upper: 0.2, default: 0.0}.
    variant, max_pass_samples, cache, llvm_target
        As for `MitsubaModel` (default variant: the process's; `llvm_ad_mono` renders one channel).
    """

    def __init__(self, name: str, capture: Capture | dict, hidden, params: list[dict], variant: str | None = None,
                 max_pass_samples: int | None = None, cache=None, llvm_target: str | None = None):
        # every check before anything loads
        self.capture = capture if isinstance(capture, Capture) else Capture(**capture)
        self.hidden = [_hidden(h) for h in hidden]
        ids = [h.id for h in self.hidden]
        if not ids or len(set(ids)) != len(ids) or {"relay_wall", "laser"} & set(ids):
            raise ValueError(f"hidden objects need distinct ids other than relay_wall and laser, got {ids}")
        bindings = [Binding.from_spec(p) for p in params]
        with interrupts.deferred():
            self.llvm_target = _llvm_target.pin(llvm_target)
            self.variant = _variant.select(variant)
            self.mitransient_version = import_mitransient().__version__
            self.scene = self._build()
        import mitsuba as mi

        MitsubaModel.loads += 1
        self._params = mi.traverse(self.scene)
        self.binder = SceneBinder(self._params, bindings)
        ForwardModel.__init__(self, name, ParamSpace([b.param for b in bindings]), cache)
        self.max_pass_samples = pass_samples(self.variant, max_pass_samples)
        (nx, ny), (lx, ly) = self.capture.scan, self.capture.laser_scan or (1, 1)
        self.size = (lx * nx, ly * ny)  # (W, H) of the image, as a film's crop size
        self.scene_file, self.defines, self.remove = None, {}, []
        self.ad_defaults, self._ad_cache, self._applied = {}, {}, None
        self._renderer = FrozenRender(False, label=f"scene {name!r}")
        self._hash = self._content_hash()

    def _build(self):
        """The Mitsuba scene of the capture and the hidden objects (a scene dict; mitransient's plugins)."""
        import mitsuba as mi

        c = self.capture
        T = mi.ScalarTransform4f
        sensor = {"type": "nlos_capture_meter", "sampler": {"type": "independent", "sample_count": 1},
                  "sensor_origin": mi.ScalarPoint3f(*c.sensor_origin),
                  "film": {"type": "transient_hdr_film", "width": c.scan[0], "height": c.scan[1],
                           "temporal_bins": c.bins, "bin_width_opl": c.bin_width, "start_opl": c.start,
                           "rfilter": {"type": "box"}}}
        scene = {"type": "scene",
                 "integrator": {"type": "transient_nlos_path", "nlos_laser_sampling": True,
                                "nlos_hidden_geometry_sampling": True,
                                "nlos_hidden_geometry_sampling_do_rroulette": False,
                                "nlos_hidden_geometry_sampling_includes_relay_wall": False,
                                "account_first_and_last_bounces": False, "discard_direct_paths": True,
                                "max_depth": c.max_depth, "temporal_filter": "box",
                                "capture_type": "single" if c.capture_type == "exhaustive" else c.capture_type},
                 "relay_wall": {"type": "rectangle", "to_world": T().scale([c.wall[0] / 2, c.wall[1] / 2, 1.0]),
                                "bsdf": {"type": "diffuse", "reflectance": 1.0}, "nlos_sensor": sensor},
                 "laser": {"type": "projector", "irradiance": 100.0, "fov": 0.2,
                           "to_world": T().translate(list(c.laser_origin))}}
        for h in self.hidden:
            scene[h.id] = h.mitsuba()
        try:
            loaded = mi.load_dict(scene, optimize=False)
        except RuntimeError as e:
            from .mitsuba_model import SceneError, _first_line

            raise SceneError(f"transient scene {self.capture!r}: does not load: {_first_line(e)}") from None
        if c.capture_type == "single":
            import mitransient as mitr

            wall = next(s for s in loaded.shapes() if s.id() == "relay_wall")
            mitr.nlos.focus_emitter_at_relay_wall_pixel(mi.Point2f(c.scan[0] / 2, c.scan[1] / 2), wall,
                                                        loaded.emitters()[0])
        return loaded

    def _content_hash(self) -> str:
        h = hashlib.sha256(json.dumps({"capture": self.capture.as_dict(),
                                       "hidden": [{**asdict(x), "extra": None} for x in self.hidden]},
                                      sort_keys=True, default=str).encode())
        for x in self.hidden:
            if x.filename:
                h.update(hashlib.sha256(Path(x.filename).read_bytes()).digest())
        return h.hexdigest()

    @property
    def channels(self) -> int:
        """T·C: a scan point's time bins and colour channels, which share path samples."""
        return self.capture.bins * (1 if "mono" in self.variant else 3)

    def _render(self, theta: np.ndarray, spp: int, seed: int) -> torch.Tensor:
        """Image (scan_y, scan_x, T, C) float32: θ written, then the passes (traced), spp-weighted; exhaustive: a
        capture per laser point (its seeds derived from (seed, laser index)), blocks (ly·scan_y, lx·scan_x, T, C)."""
        self._apply(theta)
        c = self.capture
        if c.capture_type != "exhaustive":
            return torch.from_numpy(self._capture(spp, seed).astype(np.float32))
        import mitransient as mitr
        import mitsuba as mi

        (lx, ly), (nx, ny) = c.laser_scan, c.scan
        wall = next(s for s in self.scene.shapes() if s.id() == "relay_wall")
        blocks = []
        for k, p in enumerate(c.scan_points(c.laser_scan).reshape(-1, 3)):
            target = mi.Point3f(*(float(v) for v in p))
            mitr.nlos.focus_emitter_at_relay_wall_3dpoint(target, wall, self.scene.emitters()[0])
            blocks.append(self._capture(spp, derive(seed, "laser", k)))
        img = np.stack(blocks).reshape(ly, lx, ny, nx, *blocks[0].shape[2:]).swapaxes(1, 2)
        return torch.from_numpy(img.reshape(ly * ny, lx * nx, *blocks[0].shape[2:]).astype(np.float32))

    def _capture(self, spp: int, seed: int) -> np.ndarray:
        """One capture at the θ written: the passes (traced), spp-weighted, (scan_y, scan_x, T, C) float64. A
        single or exhaustive capture renders on one thread: its film takes atomic adds from every scan point's
        paths, whose order across threads changed the last bits (7e-9 on a 3 × 3 capture); one thread keeps the
        same (θ, spp, seed) bit for bit, at the cost of the other cores."""
        import drjit as dr

        threads = dr.thread_count()
        if self.capture.capture_type != "confocal":
            dr.set_thread_count(1)
        try:
            integrator = self.scene.integrator()
            acc = None
            for s, pass_seed in self._passes(spp, seed):
                _, transient = integrator.render(self.scene, seed=pass_seed, spp=s)
                dr.eval(transient)
                x = np.asarray(transient, dtype=np.float64) * (s / spp)
                acc = x if acc is None else acc + x
        finally:
            dr.set_thread_count(threads)
        return acc

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        raise NotImplementedError("transient scenes have FD derivatives only (gradient 'fd'): mitransient's AD does "
                                  "not reach the hidden object's transform")

    def vjp(self, theta, grad_out, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        raise NotImplementedError("transient scenes have FD derivatives only (gradient 'fd'): mitransient's AD does "
                                  "not reach the hidden object's transform")

    def ad_integrator(self, indices=None, **options):
        raise NotImplementedError("transient scenes have no AD integrator (FD only)")

    def content_key(self) -> dict:
        """`MitsubaModel.content_key` (the hash over the capture, the hidden objects and their mesh files) plus
        the mitransient version."""
        return {**super().content_key(), "mitransient": self.mitransient_version}


def transient_patch(scan: int = 8, bins: int = 96, bin_width: float = 0.006, start: float = 1.3,
                    depth: float = 0.75, size: float = 0.05, **options) -> TransientModel:
    """A 10 cm square patch (half-extent `size` m) `depth` metres in front of a 1 m relay wall, confocal
    scan×scan, `bins` bins of `bin_width` m from `start` m of optical path; θ = (x, y, depth offset, albedo):
    the patch's offsets (m) from (0, 0, depth) and its diffuse albedo."""
    params = [
        {"name": "x", "kind": "translate", "object": "hidden", "axis": [1, 0, 0], "lower": -0.2, "upper": 0.2,
         "default": 0.0, "description": "patch offset along the wall's x"},
        {"name": "y", "kind": "translate", "object": "hidden", "axis": [0, 1, 0], "lower": -0.2, "upper": 0.2,
         "default": 0.0, "description": "patch offset along the wall's y"},
        {"name": "depth", "kind": "translate", "object": "hidden", "axis": [0, 0, 1], "lower": -0.2, "upper": 0.2,
         "default": 0.0, "description": f"patch offset from {depth} m in front of the wall"},
        {"name": "albedo", "kind": "reflectance", "key": "hidden.bsdf.reflectance.value", "lower": 0.05,
         "upper": 1.0, "default": 0.8, "description": "the patch's diffuse albedo"},
    ]
    return TransientModel("transient_patch", Capture(scan=(scan, scan), bins=bins, bin_width=bin_width, start=start),
                          [Hidden(center=(0.0, 0.0, depth), size=size)], params, **options)


def confocal_geometry(model: ForwardModel) -> tuple[np.ndarray, np.ndarray]:
    """(scan points (scan_y, scan_x, 3), bin edges (T + 1,)) of a confocal transient model, metres (optical path
    for the edges), looked up through wrappers (`Restricted`, `Detected`): a `TransientModel`'s capture or the
    analytic `TransientPoint`'s grid. ValueError for anything else."""
    m = model
    while m is not None:
        cap = getattr(m, "capture", None)
        if isinstance(cap, Capture):
            if cap.capture_type != "confocal":
                raise ValueError(f"{model.name!r}: a {cap.capture_type} capture, not a confocal one")
            return cap.scan_points(), cap.bin_edges()
        if hasattr(m, "points") and hasattr(m, "edges"):
            return np.asarray(m.points), np.asarray(m.edges)
        m = getattr(m, "base", None)
    raise ValueError(f"{model.name!r} is not a confocal transient model (no capture geometry)")


def position_map(model: ForwardModel) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), A (P, 3)): the hidden object's centre is origin + Σ_j θ_j A_j, metres, for θ in `model`'s
    parameter order; A_j = 0 for a parameter that does not translate it (albedo, radius …). Known for the
    analytic `TransientPoint` (θ = (x, y, depth)) and for a `TransientModel` whose translate bindings move one
    object; through `Restricted` (held parameters enter the origin) and `Detected`. ValueError otherwise."""
    from .model import Restricted

    if isinstance(model, Restricted):
        o, A = position_map(model.base)
        return o + model.full @ A - model.full[model.index] @ A[model.index], A[model.index]
    if isinstance(model, TransientModel):
        objs = {b.object for b in model.binder.bindings if b.kind == "translate"}
        if len(objs) != 1 or any(b.kind == "path" for b in model.binder.bindings):
            raise ValueError(f"{model.name!r}: localisation needs translate bindings of one object, got {sorted(objs)}")
        (obj,) = objs
        A = np.array([b.axis if b.kind == "translate" else np.zeros(3) for b in model.binder.bindings])
        return np.asarray(model.binder.objects[obj].center, dtype=np.float64), A
    if hasattr(model, "points") and hasattr(model, "edges") and tuple(model.params.names)[:3] == ("x", "y", "depth"):
        return np.zeros(3), np.vstack([np.eye(3), np.zeros((model.params.dim - 3, 3))])  # albedo: no translation
    if getattr(model, "base", None) is not None:
        return position_map(model.base)
    raise ValueError(f"{model.name!r}: no known map from θ to the hidden object's position")
