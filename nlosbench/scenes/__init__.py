"""Scene registry: `get(name_or_path, **options)` → a ForwardModel.

Built in: the analytic toys `blob2d`, `edge1d` and `spot_rgb` (torch, exact gradients) and every scene spec
`<name>.yaml` in the project's `scenes/` folder (a Mitsuba XML file plus its θ bindings). A path to a
`.yaml` spec works too. Extra folders: the environment variable NLOSBENCH_SCENE_PATH (':'-separated).

A spec that cannot be used (missing, a folder, a Mitsuba XML file or a YAML list or string where the spec
mapping belongs, a missing or mistyped key, a binding or scene file that does not load) is a `SpecError`
(a ConfigError: one line naming the spec and saying how to write one, `HOW`).
"""
from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import yaml

from ..forward import llvm_target
from ..forward.analytic import Blob2D, Edge1D, SpotRGB
from ..forward.model import ForwardModel
from ..schema import ConfigError

#: how to write a scene spec (the end of every SpecError about a spec's shape)
HOW = ("a scene spec is a YAML mapping with `file:` (the Mitsuba XML, relative to the spec) and `params:` (a list "
       "of θ bindings: name, kind, object or key, lower, upper, default); check one with `nlosbench check-scene "
       "SPEC.yaml`; a worked example: examples/own_scene.py")


class SpecError(ConfigError):
    """A scene name or spec that cannot be used; `str()` is one line: `name or path: what is wrong`.

    The command line reports it as bad input (exit 2) before anything is rendered or written.

    Parameters
    ----------
    path : str
        The scene name, spec file or spec key the message is about.
    message : str
        What is wrong, and how to write it right.

    Examples
    --------
    >>> str(nb.scenes.SpecError("room.yaml: params", "expected a non-empty list of bindings"))
    'room.yaml: params: expected a non-empty list of bindings'
    """


_BUILTIN: dict[str, Callable[..., ForwardModel]] = {"blob2d": Blob2D, "edge1d": Edge1D, "spot_rgb": SpotRGB}
SCENE_DIR = Path(__file__).resolve().parents[2] / "scenes"


def _search_dirs() -> list[Path]:
    extra = [Path(p) for p in os.environ.get("NLOSBENCH_SCENE_PATH", "").split(os.pathsep) if p]
    return extra + [SCENE_DIR]


def _specs() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for d in reversed(_search_dirs()):
        for f in sorted(d.glob("*.yaml")) if d.is_dir() else []:
            found[f.stem] = f
    return found


def available() -> list[str]:
    """Names accepted by `get`.

    Returns
    -------
    list of str
        The names, sorted: the built-in scenes and toys, then the registered specs.

    Examples
    --------
    >>> "blob2d" in nb.scenes.available()
    True
    """
    return sorted(set(_BUILTIN) | set(_specs()))


def describe() -> dict[str, str]:
    """name → one line: a spec's `description`, else the first sentence of the factory's docstring.

    Returns
    -------
    dict of str to str
        Per available scene, its one-line description.

    Examples
    --------
    >>> nb.scenes.describe()["blob2d"]  # doctest: +ELLIPSIS
    'A Gaussian spot at θ = (x, y) metres on a size×size image plane...'
    """
    specs = _specs()
    out = {}
    for name in available():
        if name in _BUILTIN:
            doc = " ".join((_BUILTIN[name].__doc__ or "").split())
            out[name] = re.split(r"[.:]\s", doc, maxsplit=1)[0]
        else:
            out[name] = str((yaml.safe_load(specs[name].read_text()) or {}).get("description", ""))
    return out


def register(name: str, factory: Callable[..., ForwardModel]) -> None:
    """Add a scene factory (called with the options given to `get`).

    Examples
    --------
    >>> nb.scenes.register("small-blob", lambda **options: nb.scenes.get("blob2d", size=8, **options))
    >>> nb.scenes.get("small-blob").render([0.5, 0.5], spp=1, seed=0).shape, "small-blob" in nb.scenes.available()
    (torch.Size([8, 8, 1]), True)
    """
    _BUILTIN[name] = factory


def read_spec(path: str | Path) -> dict:
    """The top level of a scene spec file, checked (SpecError naming the file otherwise): a readable YAML
    mapping, not a Mitsuba XML file, with `file` (a string) and `params` (a non-empty list of mappings), and
    `defines` / `smoke` mappings where given. Renders and loads nothing."""
    path = Path(path)
    if path.suffix.lower() == ".xml":
        raise SpecError(str(path), f"is a Mitsuba XML file, not a scene spec; {HOW}")
    if path.is_dir():
        raise SpecError(str(path), f"is a folder, not a scene spec file; {HOW}")
    if not path.is_file():
        raise SpecError("scene spec", f"{path} does not exist")
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise SpecError(str(path), f"is not a text file; {HOW}") from None
    if text.lstrip().startswith("<"):
        raise SpecError(str(path), f"holds XML, not a scene spec; {HOW}")
    try:
        spec = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise SpecError(str(path), f"is not valid YAML: {' '.join(str(e).split())}") from None
    if not isinstance(spec, dict):
        raise SpecError(str(path), f"holds a YAML {type(spec).__name__}, not a mapping; {HOW}")
    for k in ("file", "params"):
        if k not in spec:
            raise SpecError(str(path), f"missing key {k!r}; {HOW}")
    if not isinstance(spec["file"], str) or not spec["file"]:
        raise SpecError(f"{path}: file", f"expected the scene XML's path, got {spec['file']!r}")
    params = spec["params"]
    if not isinstance(params, list) or not params or not all(isinstance(q, dict) for q in params):
        raise SpecError(f"{path}: params", f"expected a non-empty list of bindings (mappings), got {params!r}")
    for k in ("defines", "smoke"):
        if spec.get(k) is not None and not isinstance(spec[k], dict):
            raise SpecError(f"{path}: {k}", f"expected a mapping, got {spec[k]!r}")
    return spec


def load_spec(path: str | Path, **options) -> ForwardModel:
    """A MitsubaModel from a scene spec: `file` (XML, relative to the spec), `params`, optional
    `defines` (XML $-defaults such as res, max_depth), `ad_integrator`, `variant`, `remove` (element ids
    dropped from the scene before loading, e.g. [light_c] to see what the bound owes it), `max_pass_samples`
    (a cap on the backend's pass size), `freeze` (the frozen render path; default on) and `llvm_target`
    (native | portable: Dr.Jit's CPU code-generation target). Options given here
    override the spec's top-level keys; `defines` are merged. SpecError for a spec that does not load.

    Examples
    --------
    >>> model = nb.scenes.load_spec("scenes/cornell_ball.yaml", defines={"res": 8})
    >>> model.params.names, model.size
    (('ball_x', 'ball_radius', 'ball_red'), (8, 8))
    """
    from ..forward.mitsuba_model import MitsubaModel

    path = Path(path)
    spec = read_spec(path)
    given = options.pop("defines", None) or {}
    if not isinstance(given, dict):
        raise SpecError("defines", f"expected a mapping of XML defaults, got {given!r}")
    defines = {**(spec.get("defines") or {}), **given}
    spec = {**spec, **options}
    try:
        return MitsubaModel(name=spec.get("name", path.stem), scene_file=path.parent / spec["file"],
                            params=spec["params"], variant=spec.get("variant"),
                            defines={k: str(v) for k, v in defines.items()}, ad_integrator=spec.get("ad_integrator"),
                            max_pass_samples=spec.get("max_pass_samples"), cache=spec.get("cache"),
                            remove=spec.get("remove"), freeze=spec.get("freeze"), llvm_target=spec.get("llvm_target"))
    except FileNotFoundError as e:
        if e.errno is not None:  # the file system's own error: an environment problem
            raise
        raise SpecError(str(path), str(e)) from None
    except (TypeError, ValueError, KeyError) as e:  # a binding, a define or the scene file: the spec's content
        raise SpecError(str(path), " ".join(str(e.args[0] if isinstance(e, KeyError) and e.args else e).split())) \
            from None


def smoke_options(name: str) -> dict:
    """Options that make a scene tiny for smoke runs: the spec's `smoke` key (e.g. {defines: {width: 16,
    height: 12}}); {} for the analytic toys, which are cheap already."""
    if name in _BUILTIN:
        return {}
    return dict(read_spec(_specs().get(name) or Path(name)).get("smoke") or {})


def get(name: str, **options) -> ForwardModel:
    """The forward model of a registered scene or of a scene spec file.

    Parameters
    ----------
    name : str
        A registered name (`available`: the analytic toys blob2d and edge1d, and every spec in scenes/ or
        NLOSBENCH_SCENE_PATH) or a path to a `.yaml` scene spec.
    **options
        Passed to the scene: for a spec, `defines` (XML `<default>` values, e.g. {"res": 16}, merged over the
        spec's), `variant`, `remove`, `max_pass_samples`, `freeze`, `llvm_target`, `ad_integrator`, `cache`
        (`load_spec`); for a toy, its constructor's keywords (e.g. size, render_noise).

    Returns
    -------
    ForwardModel
        The model: `params` (its θ components and Θ) and `render(theta, spp, seed)` → an image (H, W, C),
        float32, radiance units. A Mitsuba scene is loaded once, here.

    Raises
    ------
    SpecError
        For an unknown name (with a close match), a spec that cannot be read or a scene that does not load.

    Examples
    --------
    >>> model = nb.scenes.get("blob2d", size=16)
    >>> model.params.names, model.render([0.5, 0.5], spp=1, seed=0).shape
    (('x', 'y'), torch.Size([16, 16, 1]))
    """
    if not isinstance(name, str) or not name:
        raise SpecError("scene", f"expected a scene name or a spec path, got {name!r}")
    if name in _BUILTIN:
        try:
            return _BUILTIN[name](**options)
        except (TypeError, ValueError) as e:
            raise SpecError(name, f"options {options!r}: {e}") from None
    check_name(name)
    specs = _specs()
    return load_spec(specs.get(name, name), **options)


def check_name(name: str) -> None:
    """SpecError unless `name` is a registered scene or a path to a usable spec file (`read_spec`); renders
    and loads nothing."""
    if name in _BUILTIN or name in _specs():
        return
    if name.lower().endswith((".yaml", ".yml", ".xml")) or os.sep in name or Path(name).exists():
        read_spec(name)
        return
    import difflib

    close = difflib.get_close_matches(name, available(), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise SpecError(name, f"unknown scene{hint} (available: {', '.join(available())}; or a path to a scene spec "
                          ".yaml)")


def build(spec: dict) -> ForwardModel:
    """The forward model from a picklable spec {name, options, params, fixed, variant, llvm_target, cache}:
    loaded once per process (workers call this in their initialiser), restricted to `params` when given."""
    if spec.get("llvm_target"):  # before the scene loads: its first kernel is compiled for the pinned target
        llvm_target.pin(spec["llvm_target"])
    opts = dict(spec.get("options") or {})
    if spec.get("variant"):
        opts["variant"] = spec["variant"]
    if spec.get("cache"):
        opts["cache"] = spec["cache"]
    model = get(spec["name"], **opts)
    if spec.get("params"):
        model = model.restrict(spec["params"], spec.get("fixed") or {})
    return model


def _transient_patch(**options) -> ForwardModel:
    """A confocal transient capture of a 10 cm patch 0.75 m behind a 1 m relay wall, rendered with mitransient (the
    `transient` extra); θ = (x, y, depth offset, albedo)."""
    from ..forward.transient import transient_patch

    return transient_patch(**options)


def _register_transient() -> None:
    from ..forward.analytic import TransientPoint

    register("transient_point", TransientPoint)
    register("transient_patch", _transient_patch)


_register_transient()
