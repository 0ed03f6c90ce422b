"""Experiment config: YAML → validated dict. Top level and per-study blocks (from each study's SCHEMA).

Paths. Keys naming something inside the run folder are single names (`schema.folder_name`: the run's
`name`, a study's `id`, a Fisher map's `labels`): '/', '..' and the like are refused, so nothing a run writes
can land outside its folder. Keys that may point anywhere, outside the run folder included, are read or
chosen by the user on purpose (`schema.path_string`): `scene.name` (a scene spec; read only), `cache` (the
render cache shared across runs), `output` (the folder runs go under) and an estimator's gradient
`verdicts` (a file read). `scene.name` is checked here (a registered name or a readable spec mapping:
`scenes.check_name`), so a wrong one is refused before anything is loaded or written."""
from __future__ import annotations

from pathlib import Path

import yaml

from .. import noise, scenes, studies
from ..schema import ConfigError, Field, folder_name, integer_in, path_string, positive_number, validate_block
from ..studies.context import noise_options

NOISE = {"model": Field(str, help="noise model name: awgn, poisson or a plug-in (nlosbench list noise)"),
         "sigma": Field(float, None, "AWGN standard deviation (radiance units)", nullable=True),
         "scale": Field(float, None, "Poisson: expected photons per unit radiance", nullable=True),
         "options": Field(dict, {}, "a plug-in noise model's parameters, e.g. {scale: 1000, dark: 300}")}

STUDY = {"id": Field(folder_name, None, "folder name of the study in the run directory (default: NN-type); one name, "
                                        "never a path out of the run folder", nullable=True)}

TOP = {
    "name": Field(folder_name, "experiment", "a short name for the run (the run folder OUTPUT/NAME without --out): "
                                             "one name, no '/' or '..'"),
    "seed": Field(int, 0, "experiment seed; every random draw derives from it"),
    "scene": Field({"name": Field(path_string, help="registered scene name or path to a scene spec .yaml (may lie "
                                                   "outside the run folder; read only)"),
                    "options": Field(dict, {}, "options for the scene (e.g. defines: {res: 32})"),
                    "params": Field(list, None, "θ components studied (default: all)", items=str, nullable=True),
                    "fixed": Field(dict, {}, "values of the other parameters (default: their defaults)"),
                    "variant": Field(str, None, "Mitsuba variant (default: cuda_ad_rgb if usable, else llvm_ad_rgb)",
                                     nullable=True),
                    "llvm_target": Field(str, None, "Dr.Jit's CPU code-generation target: native (the host's ISA) "
                                                    "or portable (x86-64-v3 at width 4: the same kernels on any "
                                                    "x86-64 CPU with AVX2; default: $NLOSBENCH_LLVM_TARGET, else "
                                                    "native)",
                                         choices=("native", "portable"), nullable=True)}),
    "noise": Field(list, [{"model": "awgn", "sigma": 0.1}], "noise models", items=NOISE),
    "executor": Field({"type": Field(str, "local", choices=("local", "serial", "dask")),
                       "workers": Field(integer_in(1, 1024), 2, "worker processes (local, or a dask LocalCluster)"),
                       "address": Field(str, None, "dask scheduler address (default: a LocalCluster)", nullable=True),
                       "connect_timeout": Field(positive_number, 10.0, "seconds to wait for the dask scheduler at "
                                                                       "`address` before giving up"),
                       "worker_timeout": Field(positive_number, 60.0, "dask: seconds without a live worker (none at "
                                                                      "the start, or all lost mid-run) before the run "
                                                                      "gives up (exit 1; finished work is kept)")}),
    "cache": Field(path_string, None, "render cache folder shared across runs (default: none; may lie outside the "
                                      "run folder)", nullable=True),
    "keep_renders": Field(bool, True, "keep every render of the run in RUN/renders/ (checksummed), so a resumed "
                                      "run renders nothing twice"),
    "output": Field(path_string, "runs", "folder under which the run directory is made (any path)"),
    "studies": Field(list, help="studies to run, each {type: ..., ...}"),
}


def load(path: str | Path, overrides: list[str] = (), smoke: bool = False) -> dict:
    """Read a YAML config, apply `key.path=value` overrides, validate; raises ConfigError.
    smoke: shrink it to a seconds-long run through the same code path (see `smoke`)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError("", f"config file {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise ConfigError("", f"{path} is not valid YAML: {' '.join(str(e).split())}") from None
    except UnicodeDecodeError:
        raise ConfigError("", f"{path} is not a text file (a YAML config)") from None
    if not isinstance(raw, dict):
        raise ConfigError("", f"{path} holds a YAML {type(raw).__name__}, not a mapping of config keys (name, scene, "
                              "noise, studies, ...; nlosbench list keys)")
    for item in overrides:
        apply_override(raw, item)
    _scene_beside(raw, path.parent)
    cfg = resolve(raw)
    return smoke_config(cfg) if smoke else cfg


def _scene_beside(raw: dict, folder: Path) -> None:
    """A relative scene spec path (`scene.name` ending in .yaml or holding a '/') is read from the config's
    folder when it is there (else from the working folder, as before): made absolute in place."""
    sc = raw.get("scene")
    name = sc.get("name") if isinstance(sc, dict) else None
    if not isinstance(name, str) or not (name.endswith((".yaml", ".yml")) or "/" in name) or Path(name).is_absolute():
        return
    beside = folder / name
    if beside.is_file():
        sc["name"] = str(beside.resolve())


def smoke_config(cfg: dict) -> dict:
    """A tiny copy of a validated config: the scene's own `smoke` options (its spec's tiny image size
    and depth) over the config's, and every study block through its module's `smoke(block)`.
    The result is validated again, so a smoke run exercises exactly what the full run would."""
    from .. import scenes

    sc = cfg["scene"]
    tiny = scenes.smoke_options(sc["name"])
    options = {**sc["options"], **{k: v for k, v in tiny.items() if k != "defines"}}
    if "defines" in tiny:
        options["defines"] = {**(sc["options"].get("defines") or {}), **tiny["defines"]}
    raw = {**cfg, "name": f"{cfg['name']}-smoke", "scene": {**sc, "options": options},
           "studies": [{"type": b["type"], **studies.get(b["type"]).smoke(
               {k: v for k, v in b.items() if k != "type"})} for b in cfg["studies"]]}
    return resolve(raw)


def apply_override(raw: dict, item: str) -> None:
    """`a.b.c=value` (value parsed as YAML; list indices as numbers: studies.0.spp=64). The value keeps its
    YAML type: `grid="11"` is the string '11', which the schema then refuses where numbers are expected."""
    if "=" not in item:
        raise ConfigError(item, "an override must look like key.path=value")
    key, value = item.split("=", 1)
    parts = key.split(".")
    if not all(parts):
        raise ConfigError(key, "an override must look like key.path=value (no empty key)")
    try:
        val = yaml.safe_load(value)
    except yaml.YAMLError as e:
        raise ConfigError(key, f"the value {value!r} is not valid YAML: {str(e).splitlines()[0]}") from None
    node = raw
    for i, p in enumerate(parts):
        where = ".".join(parts[:i + 1])
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not p.isdigit() or int(p) >= len(node):
                raise ConfigError(where, f"expected an index below {len(node)} into the list "
                                         f"{'.'.join(parts[:i]) or '<config>'}, got {p!r}")
            if last:
                node[int(p)] = val
            else:
                node = node[int(p)]
        elif isinstance(node, dict):
            if last:
                node[p] = val
            else:
                node = node.setdefault(p, [] if parts[i + 1].isdigit() else {})
        else:
            raise ConfigError(where, f"{'.'.join(parts[:i])} is a {type(node).__name__}, not a mapping or a list")


def resolve(raw: dict) -> dict:
    """Validate the top level and every study block; fill defaults."""
    cfg = validate_block(raw, TOP)
    try:
        scenes.check_name(cfg["scene"]["name"])
    except ConfigError as e:
        raise ConfigError("scene.name", str(e)) from None
    for i, n in enumerate(cfg["noise"]):
        need = {"awgn": "sigma", "poisson": "scale"}.get(n["model"])
        if need is not None and (n[need] is None or n[need] <= 0):
            raise ConfigError(f"noise[{i}].{need}", f"{n['model']} needs {need} > 0, got {n[need]!r}")
        if n["model"] not in noise.available():
            raise ConfigError(f"noise[{i}].model", f"expected one of {', '.join(noise.available())} (a plug-in once "
                              f"installed; nlosbench list noise), got {n['model']!r}")
        try:
            model = noise.get(n["model"], **noise_options(n))
        except ValueError as e:  # its parameters (a plug-in that does not import: ImportError, an environment error)
            raise ConfigError(f"noise[{i}]", str(e)) from None
        refusal = noise.bounds_refusal(model)
        if refusal:
            raise ConfigError(f"noise[{i}].model", f"{n['model']} cannot be used by the bounds: {refusal}")
    out = []
    for i, block in enumerate(cfg["studies"]):
        path = f"studies[{i}]"
        if not isinstance(block, dict) or "type" not in block:
            raise ConfigError(path, "each study needs a `type`")
        if not isinstance(block["type"], str):
            raise ConfigError(f"{path}.type", f"expected a study type (one of {', '.join(studies.available())}), got "
                                              f"{type(block['type']).__name__} {block['type']!r}")
        try:
            mod = studies.get(block["type"])
        except KeyError as e:
            raise ConfigError(f"{path}.type", e.args[0]) from None
        body = validate_block({k: v for k, v in block.items() if k != "type"}, study_schema(mod), path)
        if hasattr(mod, "check"):  # checks beyond the schema (e.g. registered names), before anything runs
            mod.check(body, path)
        out.append({"type": block["type"], **body})
    if not out:
        raise ConfigError("studies", "expected at least one study")
    cfg["studies"] = out
    return cfg


def study_schema(mod) -> dict:
    """The keys a study block may have: the common ones (`id`) and the study module's SCHEMA."""
    return {**STUDY, **mod.SCHEMA}
