"""Scene registry: `get(name_or_path, **options)` → a ForwardModel.

Built in: the analytic toys `blob2d` and `edge1d` (torch, exact gradients) and every scene spec
`<name>.yaml` in the project's `scenes/` folder (a Mitsuba XML file plus its θ bindings). A path to a
`.yaml` spec works too. Extra folders: the environment variable NLOSBENCH_SCENE_PATH (':'-separated).
"""
from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import yaml

from ..forward import llvm_target
from ..forward.analytic import Blob2D, Edge1D
from ..forward.model import ForwardModel

_BUILTIN: dict[str, Callable[..., ForwardModel]] = {"blob2d": Blob2D, "edge1d": Edge1D}
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
    """Names accepted by `get`."""
    return sorted(set(_BUILTIN) | set(_specs()))


def describe() -> dict[str, str]:
    """name → one line: a spec's `description`, else the first sentence of the factory's docstring."""
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
    """Add a scene factory (called with the options given to `get`)."""
    _BUILTIN[name] = factory


def load_spec(path: str | Path, **options) -> ForwardModel:
    """A MitsubaModel from a scene spec: `file` (XML, relative to the spec), `params`, optional
    `defines` (XML $-defaults such as res, max_depth), `ad_integrator`, `variant`, `remove` (element ids
    dropped from the scene before loading, e.g. [light_c] to see what the bound owes it), `max_pass_samples`
    (a cap on the backend's pass size), `freeze` (the frozen render path; default on) and `llvm_target`
    (native | portable: Dr.Jit's CPU code-generation target). Options given here
    override the spec's top-level keys; `defines` are merged."""
    from ..forward.mitsuba_model import MitsubaModel

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene spec {path} does not exist")
    spec = yaml.safe_load(path.read_text()) or {}
    defines = {**(spec.get("defines") or {}), **(options.pop("defines", None) or {})}
    spec = {**spec, **options}
    for k in ("file", "params"):
        if k not in spec:
            raise ValueError(f"scene spec {path}: missing key {k!r}")
    return MitsubaModel(name=spec.get("name", path.stem), scene_file=path.parent / spec["file"], params=spec["params"],
                        variant=spec.get("variant"), defines={k: str(v) for k, v in defines.items()},
                        ad_integrator=spec.get("ad_integrator"), max_pass_samples=spec.get("max_pass_samples"),
                        cache=spec.get("cache"), remove=spec.get("remove"), freeze=spec.get("freeze"),
                        llvm_target=spec.get("llvm_target"))


def smoke_options(name: str) -> dict:
    """Options that make a scene tiny for smoke runs: the spec's `smoke` key (e.g. {defines: {width: 16,
    height: 12}}); {} for the analytic toys, which are cheap already."""
    if name in _BUILTIN:
        return {}
    path = _specs().get(name) or Path(name)
    if not path.is_file():
        raise FileNotFoundError(f"scene spec {path} does not exist")
    return dict((yaml.safe_load(path.read_text()) or {}).get("smoke") or {})


def get(name: str, **options) -> ForwardModel:
    """The forward model for a registered scene name or a path to a `.yaml` scene spec."""
    if name in _BUILTIN:
        return _BUILTIN[name](**options)
    specs = _specs()
    if name in specs:
        return load_spec(specs[name], **options)
    if name.endswith((".yaml", ".yml")) or os.sep in name:
        return load_spec(name, **options)
    import difflib

    close = difflib.get_close_matches(name, available(), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise KeyError(f"unknown scene {name!r}{hint} (available: {', '.join(available())})")


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
