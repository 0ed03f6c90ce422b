"""A small config schema: typed fields with defaults, choices and nested blocks, validated with
messages that name the key path, what was expected, what was given, and a likely misspelling; and
the θ-grid specs that config blocks share (`GRID`, `grid_values`, `smoke_grid`)."""
from __future__ import annotations

import copy
import difflib
import math
from dataclasses import dataclass
from typing import Any

REQUIRED = object()


class ConfigError(ValueError):
    """A config problem; `str()` is one line: `path: message`.

    Parameters
    ----------
    path : str
        The key path of the problem (``studies.0.spp``); empty for the config as a whole.
    message : str
        What is wrong, in words.

    Examples
    --------
    >>> from nlosbench.schema import ConfigError
    >>> str(ConfigError("studies.0.spp", "must be a positive integer"))
    'studies.0.spp: must be a positive integer'
    """

    def __init__(self, path: str, message: str):
        super().__init__(f"{path or '<config>'}: {message}")
        self.path = path


@dataclass(frozen=True)
class Field:
    """type: int | float | str | bool | list | dict | "any" | a nested schema (dict of Fields) | a check
    function `check(value, path) -> value` raising ConfigError (e.g. `grid_spec`, `noise_spec`);
    `items` validates list entries (a type, a check function or a nested schema); `choices` restricts values."""

    type: Any
    default: Any = REQUIRED
    help: str = ""
    choices: tuple | None = None
    items: Any = None
    nullable: bool = False


def positive_number(value, path: str) -> float:
    """A finite number > 0 (a Field type)."""
    v = _check_type(value, float, path)
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(path, f"expected a finite number > 0, got {value!r}")
    return v


def positive_integer(value, path: str) -> int:
    """An integer > 0 (a Field type)."""
    v = _check_type(value, int, path)
    if v < 1:
        raise ConfigError(path, f"expected an integer > 0, got {value!r}")
    return v


def halvings(value, path: str) -> int:
    """An integer in [0, 12] (a Field type: how often an FD step may be halved)."""
    v = _check_type(value, int, path)
    if not 0 <= v <= 12:
        raise ConfigError(path, f"expected an integer in [0, 12], got {value!r}")
    return v


def integer_in(lo: int, hi: int):
    """A check: an integer in [lo, hi] (a Field type)."""

    def check(value, path: str) -> int:
        v = _check_type(value, int, path)
        if not lo <= v <= hi:
            raise ConfigError(path, f"expected an integer in [{lo}, {hi}], got {value!r}")
        return v

    check.__name__ = f"integer in [{lo}, {hi}]"  # the kind `describe` shows
    return check


def folder_name(value, path: str) -> str:
    """A name that becomes one file or folder inside the run folder (the run's `name`, a study's `id`, a
    Fisher map's label): one path component, so it cannot point outside the run folder (no '/', '\\', '.',
    '..', NUL, nothing empty, at most 200 bytes). A Field type."""
    v = _check_type(value, str, path)
    if v in ("", ".", "..") or any(c in v for c in "/\\\0") or len(v.encode("utf-8", "surrogatepass")) > 200:
        raise ConfigError(path, f"expected a file or folder name inside the run folder (one path component: no "
                                f"'/', no '..', not empty, at most 200 bytes), got {value!r}")
    return v


def path_string(value, path: str) -> str:
    """A file-system path that may point anywhere, outside the run folder included (the scene spec, the
    cross-run render cache, the folder runs go under, a verdicts file): a non-empty string without NUL.
    A Field type."""
    v = _check_type(value, str, path)
    if not v or "\0" in v:
        raise ConfigError(path, f"expected a non-empty path without NUL characters, got {value!r}")
    return v


#: the FD-step rule of the Δ → 0 term and the CRLB at a quoted θ (bounds.fd_step), shared by the studies
STEP_TOL = Field(positive_number, 0.1, "the FD step of the Δ → 0 term and the CRLB counts as converged when the "
                 "paired upper limit of F(ξ/2)/F(ξ) is <= 1 + step_tol; else their lower ends are labelled 'not a "
                 "confidence limit'")
MAX_HALVINGS = Field(halvings, 3, "at most this many halvings of the FD step (same seeds) while F is not shown to "
                     "have stopped rising")

_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "true/false", list: "a list", dict: "a mapping"}


def _check_type(value, typ, path: str):
    if typ == "any":
        return value
    if callable(typ) and not isinstance(typ, type):
        return typ(value, path)
    if typ is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if typ is int and isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, typ) and not (typ is int and isinstance(value, bool)):
        return value
    raise ConfigError(path, f"expected {_NAMES.get(typ, typ)}, got {type(value).__name__} {value!r}")


def validate(value, field: Field | dict, path: str = "") -> Any:
    """Validated copy of `value` with defaults filled in."""
    if isinstance(field, dict):
        field = Field(field)
    if value is None and field.nullable:
        return None
    if isinstance(field.type, dict):
        return validate_block(value, field.type, path)
    value = _check_type(value, field.type, path)
    if field.choices is not None and value not in field.choices:
        close = difflib.get_close_matches(str(value), [str(c) for c in field.choices], n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(path, f"expected one of {list(field.choices)}, got {value!r}{hint}")
    if field.type is list and field.items is not None:
        item = field.items if isinstance(field.items, Field) else Field(field.items)
        value = [validate(v, item, f"{path}[{i}]") for i, v in enumerate(value)]
    return value


def validate_block(block, schema: dict, path: str = "") -> dict:
    """Validate a mapping against a schema (dict of name → Field)."""
    if block is None:
        block = {}
    if not isinstance(block, dict):
        raise ConfigError(path, f"expected a mapping, got {type(block).__name__} {block!r}")
    out = {}
    for key in block:
        if key not in schema:
            close = difflib.get_close_matches(str(key), list(schema), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f"; known keys: {', '.join(schema)}"
            raise ConfigError(_join(path, key), f"unknown key{hint}")
    for key, field in schema.items():
        p = _join(path, key)
        if key in block:
            out[key] = validate(block[key], field, p)
        elif isinstance(field.type, dict) and field.default is REQUIRED:
            out[key] = validate_block({}, field.type, p)
        elif field.default is REQUIRED:
            raise ConfigError(p, f"missing required key ({field.help or _NAMES.get(field.type, field.type)})")
        else:  # a copy: a study that edits its block must not change the schema's default
            out[key] = copy.deepcopy(field.default)
    return out


def _join(path: str, key) -> str:
    return f"{path}.{key}" if path else str(key)


def grid_values(spec) -> list[float]:
    """θ values from a list, from {start, stop, num} (inclusive, like numpy.linspace), or from a list of
    such segments (merged and sorted: e.g. 1 cm steps where θ is well determined, coarser elsewhere)."""
    import numpy as np

    if isinstance(spec, dict):
        return np.linspace(spec["start"], spec["stop"], int(spec["num"])).tolist()
    if any(isinstance(v, dict) for v in spec):
        return sorted({round(t, 12) for seg in spec for t in grid_values(seg if isinstance(seg, dict) else [seg])})
    return [float(v) for v in spec]


def smoke_grid(spec, num: int = 3):
    """A grid spec shrunk to about `num` points over the same range (a list keeps its first and last
    values; each segment of a segment list keeps 2 points)."""
    if isinstance(spec, dict):
        return {**spec, "num": min(int(spec["num"]), num)}
    spec = list(spec)
    if any(isinstance(v, dict) for v in spec):
        return [smoke_grid(v, 2) if isinstance(v, dict) else v for v in spec]
    return spec if len(spec) <= num else spec[:num - 1] + spec[-1:]


# -- value shapes the plain types cannot say (a string is never read as a list of characters) -----------
def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _given(value) -> str:
    return f"{type(value).__name__} {value!r}"


SEGMENT = {"start": Field(float, help="first θ"), "stop": Field(float, help="last θ (included)"),
           "num": Field(int, help="number of points")}


def _segment(value: dict, path: str) -> dict:
    seg = validate_block(value, SEGMENT, path)
    if seg["num"] < 1:
        raise ConfigError(f"{path}.num", f"expected a positive integer, got {seg['num']}")
    return seg


def grid_spec(value, path: str):
    """Check a θ-grid spec: a non-empty list of numbers, {start, stop, num}, or a list mixing numbers and
    such segments (the shapes `grid_values` reads). Numbers become floats."""
    if isinstance(value, dict):
        return _segment(value, path)
    if not isinstance(value, list) or not value:
        raise ConfigError(path, "expected a non-empty list of numbers, {start, stop, num} or a list of such "
                                f"segments, got {_given(value)}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, dict):
            out.append(_segment(v, f"{path}[{i}]"))
        elif _is_number(v):
            out.append(float(v))
        else:
            raise ConfigError(f"{path}[{i}]", f"expected a number or {{start, stop, num}}, got {_given(v)}")
    return out


def point_spec(value, path: str):
    """Check one θ point: a number (1-D θ) or a non-empty list of numbers."""
    if _is_number(value):
        return float(value)
    if isinstance(value, list) and value and all(_is_number(v) for v in value):
        return [float(v) for v in value]
    raise ConfigError(path, f"expected a number or a list of numbers (one θ), got {_given(value)}")


def points_spec(value, path: str):
    """Check θ points: a grid spec (1-D θ) or a non-empty list of lists of numbers (one list per θ)."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return [point_spec(v, f"{path}[{i}]") for i, v in enumerate(value)]
    try:
        return grid_spec(value, path)
    except ConfigError:
        raise ConfigError(path, "expected a non-empty list of θ points: numbers or {start, stop, num} (1-D θ), or "
                                f"lists of numbers, got {_given(value)}") from None


def noise_spec(value, path: str):
    """Check a choice of noise models: 'all', an index, or a non-empty list of indices (ints >= 0)."""
    if value == "all" or (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
        return value
    if isinstance(value, list) and value and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                                                 for v in value):
        return value
    raise ConfigError(path, f"expected 'all', an index (0, 1, ...) or a list of indices, got {_given(value)}")


def number_or(*words: str):
    """A check: a number, or one of the given words (e.g. number_or('measured'))."""

    def check(value, path: str):
        if _is_number(value):
            return float(value)
        if isinstance(value, str) and value in words:
            return value
        raise ConfigError(path, f"expected a number or one of {list(words)}, got {_given(value)}")

    check.__name__ = "number or " + " or ".join(map(repr, words))  # the kind `describe` shows
    return check


GRID = Field(grid_spec, help="θ values: a list, {start, stop, num}, or a list of {start, stop, num} segments")


# -- the keys of a schema as rows (for `nlosbench list keys` and the documentation's config reference) -----
_KINDS = {folder_name: "name", path_string: "path", positive_number: "number > 0", positive_integer: "integer > 0",
          grid_spec: "θ grid", point_spec: "θ point", points_spec: "θ points", noise_spec: "noise choice"}


@dataclass(frozen=True)
class KeyDoc:
    """One config key: its dotted path, the kind of value it takes, its default ("required" when it has
    none) and its help text."""

    path: str
    kind: str
    default: str
    help: str


def _type_name(typ) -> str:
    if isinstance(typ, dict):
        return "mapping"
    name = _KINDS.get(typ) or _NAMES.get(typ) or getattr(typ, "__name__", str(typ))
    return name.removeprefix("an ").removeprefix("a ")


def _kind(field: Field) -> str:
    name = _type_name(field.type)
    items = field.items.type if isinstance(field.items, Field) else field.items
    if items is not None:
        name += f" of {_type_name(items)}s"
    if field.choices:
        name += f": one of {', '.join(map(str, field.choices))}"
    return name


def describe(schema: dict, path: str = "") -> list[KeyDoc]:
    """Every key of `schema` (nested blocks and list items that are blocks included), in schema order."""
    rows = []
    for key, field in schema.items():
        p = _join(path, key)
        default = ("required" if field.default is REQUIRED and not isinstance(field.type, dict)
                   else "" if isinstance(field.type, dict) else "null" if field.default is None
                   else str(field.default).lower() if isinstance(field.default, bool) else repr(field.default))
        rows.append(KeyDoc(p, _kind(field), default, field.help))
        if isinstance(field.type, dict):
            rows += describe(field.type, p)
        elif isinstance(field.items, dict):
            rows += describe(field.items, f"{p}[]")
    return rows
