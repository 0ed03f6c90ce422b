"""On-disk render cache: one file per render, keyed by a hash of everything that defines the image.

Entry layout: 8-byte magic, 32-byte SHA-256 of the payload, payload = 4-byte length + JSON header
{"key": the render key's fields, "meta": what the writer adds, e.g. the renders it cost} + `np.save` of the
float32 image. Writes go to a unique temporary file then `os.replace` (atomic on POSIX), so two processes
writing the same key at once both leave a complete entry. A truncated or corrupt entry fails the checksum;
an entry whose header holds another key (a valid file copied over another: a restore, a sync or dedup
tool, merged folders) fails the key check. Either is reported (a warning with its key, once), removed,
and the caller re-renders.

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
import struct
import warnings
from pathlib import Path

import numpy as np
import torch

from ..io import atomic
from .keys import RenderKey, canonical, render_key

__all__ = ["CacheWarning", "MemoryCache", "RenderCache", "RenderKey", "render_key"]

_MAGIC = b"NLOSRC02"


class CacheWarning(UserWarning):
    """The render cache could not read, write or clean an entry; the run goes on without it."""


class RenderCache:
    """Images (H, W, C) float32 stored under `root/ab/abcdef….npc`.

    Best-effort: a failure to make the folder, read, write or clean an entry is a `CacheWarning`, not an
    error. Counters `hits`, `misses`, `corrupt` and `failures` say what happened.

    Parameters
    ----------
    root : str or os.PathLike
        The cache folder (made if missing).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     model = nb.scenes.get("blob2d", cache=tmp)
    ...     first, again = (model.render([0.5, 0.5], spp=4, seed=0) for _ in range(2))
    >>> model.cache.misses, model.cache.hits, model.stats.renders  # the second image came from the disk
    (1, 1, 1)
    """

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

    def get(self, key: RenderKey) -> torch.Tensor | None:
        """The image stored under `key`, or None (a miss; a corrupt entry or one of another key warns).

        Parameters
        ----------
        key : RenderKey
            The render's key (`render_key`).

        Returns
        -------
        torch.Tensor or None
            The image (H, W, C) float32, or None on a miss.
        """
        entry = self.read(key)
        return None if entry is None else entry[0]

    def read(self, key: RenderKey) -> tuple[torch.Tensor, dict] | None:
        """(image, meta) stored under `key` with its key verified, or None (see `get`).

        Parameters
        ----------
        key : RenderKey
            The render's key (`render_key`).

        Returns
        -------
        tuple of (torch.Tensor, dict) or None
            The image (H, W, C) float32 and the `meta` it was stored with, or None on a miss.
        """
        path = self._path(key.hex)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            self.misses += 1
            return None
        except OSError as e:
            self.misses += 1
            self._warn("read", f"render cache {self.root}: cannot read {path} ({_why(e)}); rendering instead")
            return None
        entry, problem = _decode(raw)
        if entry is not None and entry[2] != key.fields:
            entry, problem = None, f": it holds the render of another key ({_differs(entry[2], key.fields)})"
        if entry is None:
            self.corrupt += 1
            self.misses += 1
            self._warn(f"corrupt {key.hex}", f"render cache {self.root}: entry {key.hex} is corrupt{problem}; "
                                             "re-rendering")
            try:
                path.unlink(missing_ok=True)
            except OSError as e:
                self._warn(f"unlink {key.hex}", f"render cache {self.root}: cannot delete the corrupt entry {path} "
                                                f"({_why(e)}); it is ignored")
            return None
        self.hits += 1
        return entry[0], entry[1]

    def put(self, key: RenderKey, image: torch.Tensor, **meta) -> None:
        """Store `image` under `key`, the key's fields and `meta` (JSON values) in its checksummed payload.

        Parameters
        ----------
        key : RenderKey
            The render's key (`render_key`).
        image : torch.Tensor
            The image (H, W, C), stored as float32.
        **meta
            JSON values stored with it (e.g. the renders it cost); `read` returns them.
        """
        header = canonical({"key": key.fields, "meta": meta}).encode()
        buf = io.BytesIO()
        np.save(buf, image.detach().cpu().numpy().astype(np.float32), allow_pickle=False)
        payload = struct.pack("<I", len(header)) + header + buf.getvalue()
        try:
            with atomic(self._path(key.hex)) as tmp:
                tmp.write_bytes(_MAGIC + hashlib.sha256(payload).digest() + payload)
        except OSError as e:
            self._warn("write", f"render cache {self.root}: cannot write ({_why(e)}); renders go on without "
                                "being cached")


class MemoryCache:
    """Renders kept in memory for one piece of work (the same get / put as `RenderCache`, nothing written):
    several views of the same renders (detectors of one transient capture) render each once. Holds images up to
    `max_bytes` in all, then stores no more (a later request of an image it did not keep renders again).

    Examples
    --------
    >>> model = nb.scenes.get("blob2d")
    >>> model.cache = nb.forward.cache.MemoryCache()
    >>> a = model.render([0.5, 0.5], spp=4, seed=0); b = model.render([0.5, 0.5], spp=4, seed=0)
    >>> model.stats.renders, bool((a == b).all())
    (1, True)
    """

    def __init__(self, max_bytes: int = 2 << 30):
        self.max_bytes, self.bytes, self.hits = int(max_bytes), 0, 0
        self._images: dict[str, torch.Tensor] = {}

    def get(self, key: RenderKey) -> torch.Tensor | None:
        """The image stored under `key` (a copy: callers may write to it), or None."""
        img = self._images.get(key.hex)
        if img is None:
            return None
        self.hits += 1
        return img.clone()

    def put(self, key: RenderKey, image: torch.Tensor, **meta) -> None:
        """Keep a float32 copy of `image` under `key` while the budget allows (`meta` is not kept)."""
        img = image.detach().cpu().to(torch.float32).clone()
        size = img.numel() * 4
        if key.hex not in self._images and self.bytes + size <= self.max_bytes:
            self._images[key.hex] = img
            self.bytes += size


def _decode(raw: bytes) -> tuple[tuple[torch.Tensor, dict, dict] | None, str]:
    """((image, meta, key fields), '') from an entry's bytes, or (None, what is wrong with them)."""
    payload = raw[40:]
    if raw[:8] != _MAGIC or hashlib.sha256(payload).digest() != raw[8:40]:
        return None, " (checksum)"
    try:
        (n,) = struct.unpack("<I", payload[:4])
        header = json.loads(payload[4:4 + n])
        image = torch.from_numpy(np.load(io.BytesIO(payload[4 + n:]), allow_pickle=False))
        return (image, header["meta"], header["key"]), ""
    except (ValueError, KeyError, TypeError, struct.error):  # checksummed, but not written by this code
        return None, " (not a render entry)"


def _differs(stored: dict, wanted: dict) -> str:
    """The components (top-level names) in which two keys differ, e.g. 'seed, theta differ'."""
    names = sorted(k for k in set(stored) | set(wanted) if stored.get(k) != wanted.get(k))
    return ", ".join(names) + (" differs" if len(names) == 1 else " differ")


def _why(e: OSError) -> str:
    """'No space left on device (ENOSPC)' from an OSError."""
    import errno

    name = errno.errorcode.get(e.errno, "") if e.errno else ""
    return f"{e.strerror or e}" + (f" ({name})" if name else "")
