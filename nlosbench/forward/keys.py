"""Render keys: everything that fixes an image, as a dict of named components, and its hex digest.

A key is built from the fields its caller names (a model's `content_key`, θ, spp, seed, or a render bank's
request) joined with the components of `COMPONENTS`, which hold what every render depends on beyond
them: `code`, a hash of the source files that make images (`nlosbench/forward/` and the package modules
it imports, see `sources.closure`). Another component joins every key (render cache, run store, run
fingerprint) by adding one entry to `COMPONENTS`: a name and a function returning a JSON value.

`RenderKey.fields` is the JSON-normalised dict (what a stored render carries, see `cache.py`);
`RenderKey.hex` its SHA-256 (the entry's file name). Two keys are equal when their digests are.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

from .. import sources


def render_code() -> str:
    """SHA-256 hex of the source files that make an image (forward/ and what it imports)."""
    return sources.digest(sources.closure("forward"))


#: components joined to every render key: name → () → JSON value (computed once per process)
COMPONENTS: dict[str, Callable[[], object]] = {"code": render_code}


@lru_cache(maxsize=1)
def _environment(names: tuple[str, ...]) -> str:
    return json.dumps({name: COMPONENTS[name]() for name in names}, sort_keys=True, default=repr)


def environment() -> dict:
    """The values of `COMPONENTS` in this process (each computed once)."""
    return json.loads(_environment(tuple(sorted(COMPONENTS))))


@dataclass(frozen=True)
class RenderKey:
    """A render's key: `fields` (JSON-normalised named components) and `hex` (their SHA-256)."""

    fields: dict = field(compare=False, hash=False)
    hex: str

    def __str__(self) -> str:
        return self.hex


def canonical(fields: dict) -> str:
    """The JSON text of `fields` (sorted keys; values that JSON cannot hold as their repr)."""
    return json.dumps(fields, sort_keys=True, default=repr)


def render_key(**fields) -> RenderKey:
    """The key of a render from its caller's fields (θ as a list of float64 repr strings) and `COMPONENTS`."""
    text = canonical({**environment(), **fields})
    return RenderKey(json.loads(text), hashlib.sha256(text.encode()).hexdigest())
