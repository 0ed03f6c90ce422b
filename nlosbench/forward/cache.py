"""On-disk render cache: one file per render, keyed by a hash of everything that defines the image.

Entry layout: 8-byte magic, 32-byte SHA-256 of the payload, payload = `np.save` of the float32 image.
Writes go to a unique temporary file then `os.replace` (atomic on POSIX), so two processes writing
the same key at once both leave a complete entry. A truncated or corrupt entry fails the checksum,
is removed, and the caller re-renders.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path

import numpy as np
import torch

from ..io import atomic

_MAGIC = b"NLOSRC01"


def render_key(**fields) -> str:
    """Hex key from JSON-serialisable fields (θ is passed as a list of float64 repr strings)."""
    blob = json.dumps(fields, sort_keys=True, default=repr).encode()
    return hashlib.sha256(blob).hexdigest()


class RenderCache:
    """Images (H, W, C) float32 stored under `root/ab/abcdef….npc`."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.hits = 0
        self.misses = 0
        self.corrupt = 0

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.npc"

    def get(self, key: str) -> torch.Tensor | None:
        path = self._path(key)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            self.misses += 1
            return None
        payload = raw[40:]
        if raw[:8] != _MAGIC or hashlib.sha256(payload).digest() != raw[8:40]:
            self.corrupt += 1
            self.misses += 1
            path.unlink(missing_ok=True)
            return None
        self.hits += 1
        return torch.from_numpy(np.load(io.BytesIO(payload), allow_pickle=False))

    def put(self, key: str, image: torch.Tensor) -> None:
        buf = io.BytesIO()
        np.save(buf, image.detach().cpu().numpy().astype(np.float32), allow_pickle=False)
        payload = buf.getvalue()
        with atomic(self._path(key)) as tmp:
            tmp.write_bytes(_MAGIC + hashlib.sha256(payload).digest() + payload)
