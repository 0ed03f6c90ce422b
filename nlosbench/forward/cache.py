"""On-disk render cache: one file per render, keyed by a hash of everything that defines the image.

Entry layout: 8-byte magic, 32-byte SHA-256 of the payload, payload = `np.save` of the float32 image.
Writes go to a unique temporary file then `os.replace` (atomic on POSIX), so two processes writing
the same key at once both leave a complete entry. A truncated or corrupt entry fails the checksum,
is reported (a warning with its key, once), removed, and the caller re-renders.

The cache is best-effort: it never stops a run whose render succeeded. A folder that cannot be made,
an entry that cannot be read, a write that fails (read-only folder, full disk) or a corrupt entry that
cannot be deleted gives a `CacheWarning` (once per kind of failure and key) and the run goes on
without it. Used by a model's render cache and by the render bank's store of a run (RUN/renders/).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
from pathlib import Path

import numpy as np
import torch

from ..io import atomic

_MAGIC = b"NLOSRC01"


class CacheWarning(UserWarning):
    """The render cache could not read, write or clean an entry; the run goes on without it."""


def render_key(**fields) -> str:
    """Hex key from JSON-serialisable fields (θ is passed as a list of float64 repr strings)."""
    blob = json.dumps(fields, sort_keys=True, default=repr).encode()
    return hashlib.sha256(blob).hexdigest()


class RenderCache:
    """Images (H, W, C) float32 stored under `root/ab/abcdef….npc`."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.hits = 0
        self.misses = 0
        self.corrupt = 0
        self.failures = 0
        self._warned: set = set()
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            self._warn("mkdir", f"render cache {self.root} cannot be made ({_why(e)}); renders are not cached")

    def _warn(self, kind: str, message: str) -> None:
        """A CacheWarning, once per `kind` (e.g. one for all failed writes, one per corrupt key)."""
        self.failures += 1
        if kind not in self._warned:
            self._warned.add(kind)
            warnings.warn(message, CacheWarning, stacklevel=3)

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.npc"

    def get(self, key: str) -> torch.Tensor | None:
        path = self._path(key)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            self.misses += 1
            return None
        except OSError as e:
            self.misses += 1
            self._warn("read", f"render cache {self.root}: cannot read {path} ({_why(e)}); rendering instead")
            return None
        payload = raw[40:]
        image = None
        if raw[:8] == _MAGIC and hashlib.sha256(payload).digest() == raw[8:40]:
            try:
                image = torch.from_numpy(np.load(io.BytesIO(payload), allow_pickle=False))
            except ValueError:  # a checksummed entry that is not an array: written by something else
                image = None
        if image is None:
            self.corrupt += 1
            self.misses += 1
            self._warn(f"corrupt {key}", f"render cache {self.root}: entry {key} is corrupt (checksum); re-rendering")
            try:
                path.unlink(missing_ok=True)
            except OSError as e:
                self._warn(f"unlink {key}", f"render cache {self.root}: cannot delete the corrupt entry {path} "
                                            f"({_why(e)}); it is ignored")
            return None
        self.hits += 1
        return image

    def put(self, key: str, image: torch.Tensor) -> None:
        buf = io.BytesIO()
        np.save(buf, image.detach().cpu().numpy().astype(np.float32), allow_pickle=False)
        payload = buf.getvalue()
        try:
            with atomic(self._path(key)) as tmp:
                tmp.write_bytes(_MAGIC + hashlib.sha256(payload).digest() + payload)
        except OSError as e:
            self._warn("write", f"render cache {self.root}: cannot write ({_why(e)}); renders go on without "
                                "being cached")


def _why(e: OSError) -> str:
    """'No space left on device (ENOSPC)' from an OSError."""
    import errno

    name = errno.errorcode.get(e.errno, "") if e.errno else ""
    return f"{e.strerror or e}" + (f" ({name})" if name else "")
