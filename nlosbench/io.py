"""Files a run writes, each atomically: EXR images for data (float32, lossless), PNG for people
(matplotlib, optional log scale; every figure goes through `save_figure`), CSV tables, JSON and text
(`write_text`: config.yaml, report.md). No file is ever left half-written under its final name; the
append-only record logs are the one exception, and `records` handles their torn last line."""
from __future__ import annotations

import csv
import json
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np


@contextmanager
def atomic(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path` (unique per writer); once the body has written it, it is
    fsynced and renamed onto `path`, so a run killed while writing never leaves a torn file that a
    resumed run would read back, and concurrent writers never mix. On error it is removed.
    An OSError (disk full, read-only folder, permissions) names `path`, not the temporary file.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        if e.errno is None or e.filename == str(path):
            raise
        raise OSError(e.errno, e.strerror, str(path)) from e  # the subclass follows errno (PermissionError, ...)
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # the folder itself is gone or read-only: nothing was left there
            pass


def write_text(path: str | Path, text: str) -> Path:
    """Write a text file (UTF-8) atomically."""
    with atomic(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(fig, path: str | Path, **savefig) -> Path:
    """Save a matplotlib figure atomically (format from the suffix of `path`, default png) and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic(path) as tmp:
            fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **savefig)
    finally:
        plt.close(fig)
    return path


def _as_hwc(array) -> np.ndarray:
    """(H, W, C) float32 of an image (H, W), (H, W, C) or (H, W, *S) (the trailing axes flattened into channels,
    C-ordered: a transient image (scan_y, scan_x, T, C) gives T·C channels, bin-major)."""
    a = np.asarray(array.detach().cpu() if hasattr(array, "detach") else array, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim < 3:
        raise ValueError(f"expected an image (H, W), (H, W, C) or (H, W, *S), got shape {a.shape}")
    return a.reshape(*a.shape[:2], -1)


def write_exr(path: str | Path, array) -> Path:
    """Write an image (H, W), (H, W, C) or (H, W, *S) (trailing axes flattened into channels) as float32 EXR
    (atomically); 1 channel → Y, 3 → RGB, else C0..Cn."""
    import OpenEXR

    a = _as_hwc(array)
    c = a.shape[2]
    names = {1: ["Y"], 3: ["R", "G", "B"]}.get(c, [f"C{i}" for i in range(c)])
    channels = {n: np.ascontiguousarray(a[..., i]) for i, n in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic(path) as tmp, OpenEXR.File(header, channels) as f:
        try:
            f.write(str(tmp))
        except RuntimeError as e:  # OpenEXR reports a failed write (disk full, ...) as RuntimeError with the text
            raise _os_error(str(e), path) from e
    return Path(path)


def _os_error(message: str, path) -> Exception:
    """The OSError (named for `path`) whose strerror appears in a library's error message, else a RuntimeError."""
    import errno

    for code in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOENT, errno.EIO):
        if os.strerror(code) in message:
            return OSError(code, os.strerror(code), str(path))
    return RuntimeError(message)


def read_exr(path: str | Path) -> np.ndarray:
    """Read an EXR written by write_exr → float32 (H, W, C)."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        order = [n for n in ("R", "G", "B") if n in ch] or [n for n in ("Y",) if n in ch]
        order = order or sorted(ch, key=lambda n: int(n[1:]) if n[1:].isdigit() else n)
        return np.stack([np.asarray(ch[n].pixels, dtype=np.float32) for n in order], axis=-1)


def write_png(path: str | Path, array, log: bool = False, title: str | None = None,
              cbar_label: str | None = None, cmap: str = "inferno", symmetric: bool = False) -> Path:
    """Save an image as PNG. RGB (H, W, 3) radiance is tone-mapped (sRGB, clipped); a single
    channel gets a colour map and a colour bar, on a log10 scale when `log` (zeros masked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = _as_hwc(array).astype(np.float64)
    fig, ax = plt.subplots(figsize=(5, 5 * a.shape[0] / max(a.shape[1], 1) + 0.6))
    if a.shape[2] == 3 and not log:
        srgb = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.clip(a, 0, None) ** (1 / 2.4) - 0.055)
        ax.imshow(np.clip(srgb, 0, 1), interpolation="nearest")
    else:
        m = a.mean(axis=2) if a.shape[2] > 1 else a[..., 0]
        if log:
            pos = m[m > 0]
            m = np.where(m > 0, np.log10(np.where(m > 0, m, 1.0)), np.nan)
            vmin, vmax = (np.log10(pos.min()), np.log10(pos.max())) if pos.size else (0.0, 1.0)
            cbar_label = f"log10 {cbar_label}" if cbar_label else "log10"
        elif symmetric:
            vmax = float(np.nanmax(np.abs(m))) or 1.0
            vmin, cmap = -vmax, "RdBu_r"
        else:
            vmin, vmax = float(np.nanmin(m)), float(np.nanmax(m))
        im = ax.imshow(m, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        fig.colorbar(im, ax=ax, label=cbar_label or "", fraction=0.046, pad=0.04)
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows of dicts as CSV, written atomically (header from the first row's keys in order, plus any later new keys).
    Floats are written to float64's 15 significant digits: θ = 0.79 from a linspace reads 0.79, not
    0.7899999999999999."""
    keys: list = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with atomic(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows({k: f"{v:.15g}" if isinstance(v, float) else v for k, v in r.items()} for r in rows)
    return path


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_json(path: Path, data) -> Path:
    return write_text(path, json.dumps(data, indent=2, default=_json_default))


def _json_default(o):
    import numpy as np

    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
