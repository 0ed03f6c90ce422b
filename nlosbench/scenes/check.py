"""`nlosbench check-scene SPEC`: does each θ binding of a scene spec move what it claims?

For every parameter, three renders with the others at their defaults: θ at Θ's lower end, mid-point and
upper end, all with one seed (common random numbers: with the box filter on the CPU two renders differ
only where the binding changed the scene, so a binding that moves nothing gives identical images). Per step
(lower → mid, mid → upper) it reports the total image change Σ|ΔL| over pixels and channels (radiance ×
pixels), that change relative to Σ|L| of the first image, the fraction of pixels that change (by more than
τ, below, and by more than 10 % of the mean radiance: a moving silhouette or shadow rather than the faint
indirect-light change that reaches most pixels) and the share of the change in the outermost ring of pixels.
A figure, check.png (rows: parameters; columns: lower / mid / upper and the two difference images), and
check.json go to the output folder.

Warnings (heuristics, stated so their limits are clear):
- pixel filter: the film's reconstruction filter is not `box` (renders then differ between identical calls,
  which breaks FD with common random numbers); also any warning the scene load raised;
- reproducibility: the default θ rendered twice with the same seed gives different images (max |ΔL| given);
- dark: the image at the default θ is all zeros (no light reaches the camera);
- default: writing θ = the spec's `default` changes the scene from the XML as loaded (the `mi.traverse`
  values a binding writes — a shape's to_world or vertex positions, a colour — differ before and after the
  write by more than `DEFAULT_TOL` relative): a translate default that is not 0, a radius default that is not
  the object's size, a colour default that is not the XML's. Studies that hold a parameter at its default
  then see another scene than the XML file shows. Checked without rendering;
- moves nothing: no pixel changes between Θ's ends — the binding writes something the camera cannot see
  (an occluded or unlit object, an unused BSDF) or a value the scene ignores;
- flat half: the image changes in one half of Θ but not in the other (the object leaves the view, hides
  behind something or saturates part of the way);
- frame (geometry bindings only): the object's world-space axis-aligned bounding box, projected through the
  camera, is not wholly inside the image at lower / mid / upper (`partly outside`, `outside` or `behind the
  camera`). The box is larger than the object (a sphere's corners stick out of it), so an object close to
  the border can be flagged while its silhouette is still inside; only the three θ are checked (a `path`
  may leave the frame in between); occlusion is not considered (a box inside the frame may be hidden by a
  wall: that shows up as "moves nothing" or "flat half"). For a non-line-of-sight scene an object out of
  the frame is intended — the warning says where, not that it is wrong.
A pixel "changes" where some channel differs by more than τ = max(the reproducibility difference,
1e-6 × mean |L|): bit-exact renders make τ tiny, so any real change counts (on CUDA, whose renders differ
by ≈ 1e-7 between identical calls, τ rises to that difference).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..io import write_json
from ..schema import ConfigError
from . import get

#: relative tolerance of "θ = default leaves the XML's values" (float32 scene values: a few ulps)
DEFAULT_TOL = 1e-5
#: τ relative to the mean |L| of the default image (see the module docstring)
REL_TOL = 1e-6
#: a "visible" change: some channel moves by more than this fraction of the default image's mean |L|
VISIBLE = 0.1
COLUMNS = ("lower", "mid", "upper")


@dataclass
class Step:
    """The image change between two renders of one parameter (the others at their defaults).

    total: Σ|ΔL| over pixels and channels (radiance units × pixels); relative: total / Σ|L| of the first image;
    changed: fraction of pixels (0…1) where some channel changes by more than τ; visible: fraction where it
    changes by more than VISIBLE × the default image's mean |L| (a silhouette or shadow moving, not a faint
    change of indirect light); border: share (0…1) of `total` in the outermost ring of pixels (NaN when
    nothing changes)."""

    frm: str
    to: str
    total: float
    relative: float
    changed: float
    visible: float
    border: float


@dataclass
class ParamCheck:
    """One parameter: name, binding kind, units, θ at lower / mid / upper (3,), the two steps, where its object
    lies relative to the frame at each θ (geometry bindings; else empty), its warnings, and whether θ = its
    spec default leaves the scene as the XML has it (`default_key`: the traverse key it writes; `default_diff`:
    max |after − before| of that key's values; `default_ok`: within DEFAULT_TOL; None for analytic models)."""

    name: str
    kind: str
    units: str
    thetas: list[float]
    steps: list[Step]
    frame: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    default: float = math.nan
    default_key: str = ""
    default_diff: float = math.nan
    default_ok: bool | None = None


@dataclass
class SceneCheck:
    """The result of `check_scene`: the scene, spp and seed of every render, image size (W, H), per-parameter
    checks, scene-wide warnings, the reproducibility difference (max |ΔL| of two identical renders), τ, and
    the files written (figure, check.json)."""

    scene: str
    spp: int
    seed: int
    size: tuple[int, int]
    params: list[ParamCheck]
    warnings: list[str]
    repeat_diff: float
    tau: float
    files: list[str] = field(default_factory=list)

    @property
    def all_warnings(self) -> list[str]:
        """Scene-wide warnings, then each parameter's."""
        return self.warnings + [w for p in self.params for w in p.warnings]


def _step(a: np.ndarray, b: np.ndarray, tau: float, visible: float, frm: str, to: str) -> Step:
    """The change from image a to b, both (H, W, C) float64; τ and the visible threshold in radiance units."""
    d = np.abs(b - a)
    total = float(d.sum())
    ring = np.ones(d.shape[:2], dtype=bool)
    ring[1:-1, 1:-1] = False
    ref = float(np.abs(a).sum())
    dmax = d.max(axis=2)
    return Step(frm, to, total, total / ref if ref > 0 else (math.inf if total > 0 else 0.0),
                float((dmax > tau).mean()), float((dmax > visible).mean()),
                float(d[ring].sum() / total) if total > 0 else math.nan)


def _unit(units: str) -> str:
    """' m' for units 'm'; '' for dimensionless ('1' or empty)."""
    return "" if units in ("1", "") else f" {units}"


def _film_warnings(model) -> list[str]:
    """A warning when the film's pixel filter is not a box filter (Mitsuba models only)."""
    scene = getattr(model, "scene", None)
    if scene is None:
        return []
    rfilter = str(scene.sensors()[0].film().rfilter())
    if rfilter.startswith("BoxFilter"):
        return []
    return [f"pixel filter {rfilter.split('[')[0].strip()} is not a box filter: identical renders differ slightly "
            "(multi-threaded splatting), so FD with common random numbers and resumed runs are not "
            "bit-reproducible; use <rfilter type=\"box\"/> in the film"]


def _camera_local(sensor, points: np.ndarray) -> np.ndarray:
    """World points (N, 3) in the camera's frame (N, 3): +z looks into the scene."""
    m = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    h = np.c_[points, np.ones(len(points))] @ np.linalg.inv(m).T
    return h[:, :3]


def frame_status(model, object_id: str) -> str:
    """Where the world AABB of shape `object_id` (in the scene's current state) projects: 'inside', 'partly
    outside', 'outside', 'behind the camera', 'partly behind the camera' or 'n/a (reason)'."""
    import drjit as dr
    import mitsuba as mi

    scene = model.scene
    shapes = [s for s in scene.shapes() if s.id() == object_id]
    if not shapes:
        return f"n/a (no shape {object_id!r})"
    lo = np.min([np.array(s.bbox().min, dtype=np.float64).reshape(3) for s in shapes], axis=0)
    hi = np.max([np.array(s.bbox().max, dtype=np.float64).reshape(3) for s in shapes], axis=0)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    sensor = scene.sensors()[0]
    near = float(sensor.near_clip()) if hasattr(sensor, "near_clip") else 0.0
    depth = _camera_local(sensor, corners)[:, 2]
    front = depth > near
    if not front.any():
        return "behind the camera"
    try:
        it = dr.zeros(mi.Interaction3f, int(front.sum()))
        c = corners[front].astype(np.float32)
        it.p = mi.Point3f(c[:, 0], c[:, 1], c[:, 2])
        ds, _ = sensor.sample_direction(it, mi.Point2f(0.5, 0.5))
        uv = np.array(ds.uv, dtype=np.float64).reshape(2, -1).T
    except Exception as e:  # noqa: BLE001 - a sensor without a projection (e.g. irradiance meter)
        return f"n/a ({type(sensor).__name__} has no point projection: {type(e).__name__})"
    if not np.all(np.isfinite(uv)):
        return "n/a (projection not finite)"
    if not front.all():
        return "partly behind the camera"
    W, H = (int(v) for v in sensor.film().crop_size())
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    area = max(u1 - u0, 1e-12) * max(v1 - v0, 1e-12)
    overlap = max(0.0, min(u1, W) - max(u0, 0)) * max(0.0, min(v1, H) - max(v0, 0))
    if overlap >= area * (1 - 1e-9):
        return "inside"
    return "outside" if overlap <= 0 else "partly outside"


def _values(v) -> np.ndarray:
    """A traverse value (Float, Transform4f, Color3f, ...) as a flat float64 array."""
    return np.array(v.matrix if "Transform" in type(v).__name__ else v, dtype=np.float64).reshape(-1)


def default_agreement(model) -> dict[str, tuple[str, float, bool]]:
    """Per binding of a Mitsuba model: (the traverse key it writes, max |Δ| of that key's values between the XML
    as loaded and the scene after writing θ = the spec defaults, whether that is within DEFAULT_TOL relative).
    Writes θ (no render); {} for models without bindings."""
    binder = getattr(model, "binder", None)
    if binder is None:
        return {}
    keys = [binder.objects[b.object].key if b.object in binder.objects else b.key for b in binder.bindings]
    rest = {geo.key: _values(geo.rest) for geo in binder.objects.values()}
    rest.update({k: np.asarray(c, dtype=np.float64) for k, c in binder.colors.items()})
    model._apply(np.asarray(model.params.default, dtype=np.float64))
    out = {}
    for b, key in zip(binder.bindings, keys, strict=True):
        before, after = rest[key], _values(model._params[key])[:rest[key].size]
        diff = float(np.abs(after - before).max())
        out[b.param.name] = (key, diff, diff <= DEFAULT_TOL * max(1.0, float(np.abs(before).max())))
    return out


def check_scene(spec: str, spp: int = 64, seed: int = 0, defines: dict | None = None,
                out: str | Path | None = None) -> SceneCheck:
    """Render every parameter of the scene `spec` (a registered name or a path to a .yaml spec) at Θ's lower
    end, mid-point and upper end (the others at their defaults, one seed), measure the image change per step,
    check the object's frame for geometry bindings and collect warnings (module docstring). With `out`, write
    check.png (the figure) and check.json there. FileNotFoundError / KeyError / ValueError for a bad spec."""
    if isinstance(spp, bool) or int(spp) != spp or spp < 1:
        raise ConfigError("spp", f"expected a positive integer, got {spp!r}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = get(spec, **({"defines": defines} if defines else {}))
    model.cache = None  # every render below is made, not read back (the reproducibility check needs that)
    scene_warnings = _film_warnings(model)
    for w in caught:  # the scene's own warnings join the report (less the pixel-filter one restated above)
        if not issubclass(w.category, UserWarning):  # e.g. a library's DeprecationWarning: not about the scene
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        elif not (scene_warnings and "box filter" in str(w.message)):
            scene_warnings.append(str(w.message))
    p = model.params
    default = p.default.copy()
    agree = default_agreement(model)  # before any render: the XML's values against θ = default, no render
    base = model.render(default, spp, seed).double().numpy()
    again = model._render(default, spp, seed).double().numpy() if hasattr(model, "_render") else base
    repeat = float(np.abs(again - base).max())
    tau = max(repeat, REL_TOL * float(np.abs(base).mean()))
    visible = max(tau, VISIBLE * float(np.abs(base).mean()))
    if repeat > 0:
        scene_warnings.append(f"two renders at the default θ with the same seed differ (max |ΔL| = {repeat:.3g}): "
                              "renders are not bit-reproducible, so FD with common random numbers carries noise")
    if not np.any(base):
        scene_warnings.append("the image at the default θ is all zeros: no light reaches the camera")
    bindings = getattr(getattr(model, "binder", None), "bindings", None)
    checks, images = [], []
    for j, name in enumerate(p.names):
        kind = bindings[j].kind if bindings else "analytic"
        thetas = [float(p.lower[j]), float((p.lower[j] + p.upper[j]) / 2), float(p.upper[j])]
        imgs, frame = [], []
        for t in thetas:
            th = default.copy()
            th[j] = t
            imgs.append(model.render(th, spp, seed).double().numpy())
            if bindings and bindings[j].object is not None:
                model._apply(th)  # the scene holds θ even when the render came from memory
                frame.append(frame_status(model, bindings[j].object))
        steps = [_step(imgs[0], imgs[1], tau, visible, "lower", "mid"),
                 _step(imgs[1], imgs[2], tau, visible, "mid", "upper")]
        pc = ParamCheck(name, kind, p.units[j], thetas, steps, frame, default=float(default[j]))
        unit = _unit(p.units[j])
        if name in agree:
            pc.default_key, pc.default_diff, pc.default_ok = agree[name]
            if not pc.default_ok:
                pc.warnings.append(f"{name}: θ = its default {default[j]:g}{unit} does not leave the scene as the XML "
                                   f"has it: {pc.default_key} changes by up to {pc.default_diff:.3g} when the spec's "
                                   "defaults are written (studies that hold it at its default see another scene; "
                                   "make `default` the XML's value: 0 for translate, the object's size for radius, "
                                   "the XML's colour)")
        moved = [s.changed > 0 for s in steps]
        if not any(moved):
            pc.warnings.append(f"{name}: no pixel changes between θ = {thetas[0]:g} and {thetas[2]:g}{unit}: "
                               f"the binding ({kind}) moves nothing the camera sees (occluded or unlit object, "
                               "unused key?)")
        elif not all(moved):
            flat = steps[moved.index(False)]
            a, b = thetas[COLUMNS.index(flat.frm)], thetas[COLUMNS.index(flat.to)]
            pc.warnings.append(f"{name}: no pixel changes between {flat.frm} and {flat.to} ({a:g} → {b:g}{unit}) "
                               "while the other half of Θ does: the object may leave the view, "
                               "hide or stop mattering there")
        off = [(c, f) for c, f in zip(COLUMNS, frame, strict=False) if f != "inside" and not f.startswith("n/a")]
        if off:
            pc.warnings.append(f"{name}: the bounding box of shape {bindings[j].object!r} is " + ", ".join(
                f"{f} at {c} ({thetas[COLUMNS.index(c)]:g}{unit})" for c, f in off)
                + " (conservative: the box is larger than the object; intended in a non-line-of-sight scene)")
        checks.append(pc)
        images.append(imgs)
    W, H = base.shape[1], base.shape[0]
    result = SceneCheck(model.name, int(spp), int(seed), (W, H), checks, scene_warnings, repeat, tau)
    if out is not None:
        out = Path(out)
        result.files = [str(figure(result, images, out / "check.png")), str(out / "check.json")]
        write_json(out / "check.json", {**asdict(result), "warnings_all": result.all_warnings})
    return result


def figure(result: SceneCheck, images: list[list[np.ndarray]], path: Path) -> Path:
    """A PNG grid: a row per parameter; columns lower / mid / upper (sRGB, clipped) and |mid − lower|,
    |upper − mid| (Σ over channels; one colour scale per row, shown on the colour bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(images)
    W, H = result.size
    fig, axes = plt.subplots(n, 5, figsize=(12.5, 2.5 * H / W * n + 0.6 * n), squeeze=False)
    srgb = lambda a: np.clip(np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.clip(a, 0, None) ** (1 / 2.4) - 0.055),
                             0, 1)
    for r, (pc, imgs) in enumerate(zip(result.params, images, strict=True)):
        diffs = [np.abs(imgs[1] - imgs[0]).sum(axis=2), np.abs(imgs[2] - imgs[1]).sum(axis=2)]
        vmax = max(float(d.max()) for d in diffs) or 1.0
        for c in range(3):
            ax = axes[r, c]
            ax.imshow(srgb(imgs[c]), interpolation="nearest")
            frame = f"\nbox {pc.frame[c]}" if pc.frame else ""
            ax.set_title(f"{pc.name} = {pc.thetas[c]:.4g}{_unit(pc.units)} ({COLUMNS[c]}){frame}", fontsize=8)
        for c, (d, s) in enumerate(zip(diffs, pc.steps, strict=True)):
            ax = axes[r, 3 + c]
            im = ax.imshow(d, cmap="magma", vmin=0, vmax=vmax, interpolation="nearest")
            ax.set_title(f"|{s.to} − {s.frm}|: Σ = {s.total:.3g}\npixels changed: {s.changed:.0%} (> 10 %: "
                         f"{s.visible:.0%})", fontsize=8)
            if c == 1:
                fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="Σ_c |ΔL|")
        for ax in axes[r]:
            ax.set_axis_off()
    fig.suptitle(f"check-scene {result.scene}: {result.spp} spp, seed {result.seed}, one seed for every render",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_report(result: SceneCheck) -> str:
    """The check as text: a line per parameter and step, then the warnings (or 'no warnings')."""
    W, H = result.size
    lines = [f"check-scene {result.scene}: {W}×{H} px, {result.spp} spp, seed {result.seed} (every render; "
             f"repeat difference {result.repeat_diff:.3g}, a pixel changes above τ = {result.tau:.3g})",
             f"{'parameter':<16} {'kind':<12} {'step':<22} {'Σ|ΔL|':>10} {'relative':>9} {'px > τ':>7} "
             f"{'px > 10%':>8} {'at border':>9}"]
    for pc in result.params:
        for s in pc.steps:
            t0, t1 = pc.thetas[COLUMNS.index(s.frm)], pc.thetas[COLUMNS.index(s.to)]
            border = "–" if math.isnan(s.border) else f"{s.border:.0%}"
            lines.append(f"{pc.name:<16} {pc.kind:<12} {f'{t0:.4g} → {t1:.4g}{_unit(pc.units)}':<22} {s.total:>10.4g} "
                         f"{s.relative:>9.2%} {s.changed:>7.0%} {s.visible:>8.0%} {border:>9}")
        if pc.frame:
            lines.append(f"{'':<16} {'':<12} bounding box at lower / mid / upper: {' / '.join(pc.frame)}")
        if pc.default_ok is not None:
            state = "leaves the scene as the XML has it" if pc.default_ok else \
                f"CHANGES {pc.default_key} (max |Δ| {pc.default_diff:.3g})"
            lines.append(f"{'':<16} {'':<12} θ = default {pc.default:.4g}{_unit(pc.units)}: {state}")
    ws = result.all_warnings
    lines += [f"warning: {w}" for w in ws] or ["no warnings"]
    lines += [f"wrote {f}" for f in result.files]
    return "\n".join(lines)

