"""`nlosbench init-scene`: from a plain Mitsuba XML file to a scene spec skeleton that `check-scene` accepts.

The scene is loaded once (as a MitsubaModel loads it: `optimize=False`, the given defines) and its
`mi.traverse` keys are sorted into what a θ binding can reach (`forward.bindings`):
  shapes    an id with `.to_world` or `.vertex_positions`: kinds translate, path, radius (`object:`), listed
            with the centre and size that the bindings use (`ObjectGeometry`);
  colours   Color3f keys: kind reflectance (a BSDF's colour) or radiance (an emitter's), `key:`;
  floats    every other scalar (a camera's field of view, a sampling weight): listed, with no binding kind;
            change them in the XML or through its `<default>`s (`defines:`).
The skeleton binds the chosen shapes (default: the smallest shape that is not an emitter, usually the
object of the question): its offsets along x, y and z (±its size), its radius (½ to 1½ times its size) and its
own colour, scaled (when it has a BSDF of its own); every other binding is written as a commented line to
uncomment. Θ's ends are placeholders to edit to the question; `check-scene` then says whether each binding
moves what it claims.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import SpecError, read_spec

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}


@dataclass
class SceneKeys:
    """What `mi.traverse` offers a θ binding in one scene file.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    xml : Path
        The scene file.
    shapes : dict of str to tuple
        Shape (or sensor) id → (traverse key, centre (3,) in metres, size in metres: a sphere's radius, half of a
        mesh's largest bounding-box side), for those with an id in the XML.
    emitters : set of str
        Ids of the shapes that emit light.
    sensors : set of str
        Ids of the cameras (kind translate only).
    defaults : dict of str to str
        The file's `<default>` names and values (what `defines:` can override).
    colours : dict of str to tuple
        Colour key → its (r, g, b) value.
    floats : dict of str to float
        Every other scalar float key → its value.
    """

    xml: Path
    shapes: dict
    emitters: set
    sensors: set
    defaults: dict
    colours: dict
    floats: dict

    def listing(self) -> str:
        """The keys, one per line under a heading per kind, with the binding kinds that reach them."""
        lines = [f"{self.xml}: {len(self.shapes)} shapes with ids, {len(self.colours)} colours, "
                 f"{len(self.floats)} other floats (mi.traverse keys)",
                 "shapes (kinds translate, path, radius: `object: ID`):"]
        for sid, (key, c, size) in self.shapes.items():
            lines.append(f"  {sid:<16} centre ({', '.join(f'{v:.3g}' for v in c)}) m, size {size:.3g} m"
                         + (", emits light" if sid in self.emitters else "")
                         + (", a camera (translate only)" if sid in self.sensors else "") + f"   [{key}]")
        lines.append("colours (kinds reflectance, radiance: `key: KEY`, optional `channel: 0|1|2`):")
        lines += [f"  {k}  ({', '.join(f'{v:.3g}' for v in rgb)})" for k, rgb in self.colours.items()]
        lines.append("other floats (no binding kind: set them in the XML or through its <default>s, `defines:`):")
        lines += [f"  {k} = {v:.6g}" for k, v in self.floats.items()]
        if self.defaults:
            lines.append("<default>s (`defines:` in the spec, --define on the command line): "
                         + ", ".join(f"{k} = {v}" for k, v in self.defaults.items()))
        return "\n".join(lines)


def scene_keys(xml: str | Path, defines: dict | None = None) -> SceneKeys:
    """Load a Mitsuba XML file once and sort its `mi.traverse` keys (see the module docstring).

    Parameters
    ----------
    xml : str or Path
        The scene file.
    defines : dict, optional
        Values for the file's `<default>`s (str → str), e.g. {"res": "16"}.

    Returns
    -------
    SceneKeys
        Its shapes, colours and other floats.

    Raises
    ------
    SpecError
        If the file is missing, not XML or does not load.
    """
    from .. import variant
    from ..forward.bindings import ObjectGeometry

    path = Path(xml)
    if not path.is_file():
        raise SpecError(str(path), "does not exist (expected a Mitsuba scene .xml)")
    try:
        tree = ET.parse(path)
    except ET.ParseError as e:
        raise SpecError(str(path), f"is not an XML file: {e}") from None
    ids = {e.get("id") for e in tree.iter() if e.get("id")}
    sensors = {e.get("id") for e in tree.iter("sensor") if e.get("id")}
    defaults = {e.get("name"): e.get("value") for e in tree.iter("default") if e.get("name")}
    variant.select()
    import mitsuba as mi

    try:
        params = mi.traverse(mi.load_file(str(path), optimize=False, **{k: str(v) for k, v in (defines or {}).items()}))
    except RuntimeError as e:  # Mitsuba's parser: invalid scene, unknown plugin, missing asset, bad define
        raise SpecError(str(path), f"does not load: {str(e).strip().splitlines()[0]}") from None
    shapes, emitters, colours, floats = {}, set(), {}, {}
    for key in params.keys():
        head, _, rest = key.partition(".")
        value = params[key]
        if rest in ("to_world", "vertex_positions") and head in ids and head not in shapes:
            geo = ObjectGeometry(params, head)
            shapes[head] = (geo.key, tuple(float(v) for v in geo.center), geo.size)
        elif isinstance(value, mi.Color3f):
            colours[key] = tuple(np.array(value, dtype=np.float64).reshape(-1)[:3].tolist())
            if rest == "emitter.radiance.value":
                emitters.add(head)
        elif isinstance(value, float) or (isinstance(value, mi.Float) and len(value) == 1):
            floats[key] = float(np.array(value, dtype=np.float64).reshape(-1)[0])
    return SceneKeys(path, shapes, emitters, sensors, defaults, colours, floats)


def skeleton(keys: SceneKeys, spec_path: str | Path, objects: list[str] | None = None) -> str:
    """The text of a scene spec binding `objects` (default: the smallest shape that does not emit light).

    Parameters
    ----------
    keys : SceneKeys
        The scene's keys (`scene_keys`).
    spec_path : str or Path
        Where the spec will be written (its `file:` is the XML's path relative to it).
    objects : list of str, optional
        Shape ids to bind (translate x, y, z; radius; their own colour).

    Returns
    -------
    str
        The spec, YAML with comments; `read_spec` accepts it.

    Raises
    ------
    SpecError
        If an object is not a shape with an id, or the scene has no shape to bind.
    """
    candidates = [s for s in keys.shapes if s not in keys.emitters | keys.sensors]
    if objects:
        for o in objects:
            if o not in keys.shapes:
                raise SpecError("--object", f"{o!r} is not a shape with an id in {keys.xml} (shapes: "
                                f"{', '.join(keys.shapes) or 'none'})")
    elif candidates:
        objects = [min(candidates, key=lambda s: keys.shapes[s][2])]
    else:
        raise SpecError(str(keys.xml), "has no shape with an id to bind; give the object of your question an id "
                        "(<shape ... id=\"name\">)")
    rel = os.path.relpath(keys.xml.resolve(), Path(spec_path).resolve().parent)
    if rel.startswith(os.pardir + os.sep + os.pardir):  # far apart: the absolute path reads better
        rel = str(keys.xml.resolve())
    defines = ", ".join(f"{k}: {v}" for k, v in keys.defaults.items())
    out = [f"# {Path(spec_path).name}: scene spec for {keys.xml.name}, written by `nlosbench init-scene`.",
           "# Each entry of `params:` binds one component of θ to the scene (kinds: translate, path, radius,",
           "# reflectance, radiance; see the scene guide). Θ's ends below are placeholders: set them to the range your",
           "# question allows, then check the bindings with `nlosbench check-scene` on this file.",
           f"file: {rel}",
           f"description: {keys.xml.stem} with θ bound to {', '.join(objects)}",
           *([f"# defines: {{{defines}}}   # the XML's <default>s, overridden here (e.g. a smaller image)"] if defines
             else []),
           "params:"]
    commented = []
    for sid, (_, _, size) in keys.shapes.items():
        chosen = sid in objects
        reach = size if sid not in keys.sensors else 0.1  # a camera: 10 cm either way
        lines = [f"{{name: {sid}_{a}, kind: translate, object: {sid}, axis: {list(v)}, lower: {-reach:.4g}, "
                 f"upper: {reach:.4g}, default: 0.0, units: m}}" for a, v in AXES.items() if chosen or a == "x"]
        if sid not in keys.sensors:
            lines.append(f"{{name: {sid}_radius, kind: radius, object: {sid}, lower: {size / 2:.4g}, "
                         f"upper: {1.5 * size:.4g}, default: {size:.4g}, units: m}}")
        own = f"{sid}.bsdf.reflectance.value"
        if chosen and own in keys.colours:
            top = max(keys.colours[own]) or 1.0
            lines.append(f"{{name: {sid}_paint, kind: reflectance, key: {own}, lower: 0.5, "
                         f"upper: {min(1.5, 0.99 / top):.3g}, default: 1.0, units: \"1\"}}  # scales its colour")
        (out if chosen else commented).extend(("  - " if chosen else "#  - ") + text for text in lines)
    for key in keys.colours:
        if not any(key == f"{s}.bsdf.reflectance.value" for s in objects):
            kind = "radiance" if key.endswith("emitter.radiance.value") else "reflectance"
            name = key.removesuffix(".value").replace(".", "_")
            commented.append(f"#  - {{name: {name}, kind: {kind}, key: {key}, lower: 0.5, upper: 1.5, default: 1.0, "
                             f"units: \"1\"}}")
    out += ["# more bindings: uncomment to add them to θ", *commented]
    return "\n".join(out) + "\n"


def init_scene(xml: str | Path, out: str | Path | None = None, objects: list[str] | None = None,
               defines: dict | None = None, force: bool = False) -> tuple[SceneKeys, Path]:
    """List a scene's keys and write a spec skeleton beside it (see the module docstring).

    Parameters
    ----------
    xml : str or Path
        The Mitsuba scene file.
    out : str or Path, optional
        The spec to write (default: the XML's name with .yaml, beside it).
    objects : list of str, optional
        Shape ids to bind (default: the smallest shape that does not emit light).
    defines : dict, optional
        Values for the file's `<default>`s while listing.
    force : bool, default False
        Overwrite an existing spec.

    Returns
    -------
    tuple of (SceneKeys, Path)
        The keys and the spec written.

    Raises
    ------
    SpecError
        If the XML does not load, an object is unknown or the spec exists (without `force`); nothing is written.
    """
    spec = Path(out) if out is not None else Path(xml).with_suffix(".yaml")
    if spec.suffix.lower() not in (".yaml", ".yml"):
        raise SpecError("--out", f"expected a .yaml path for the spec, got {spec}")
    if spec.exists() and not force:
        raise SpecError("--out", f"{spec} exists; pass --force to overwrite it or choose another --out")
    keys = scene_keys(xml, defines)
    text = skeleton(keys, spec, objects)
    spec.parent.mkdir(parents=True, exist_ok=True)
    spec.write_text(text)
    read_spec(spec)  # the shape `check-scene` reads
    return keys, spec
