"""Transient captures in y-tal's HDF5 layout ("HDF5_TAL", y-tal 0.20.0's `tal.io.write_capture`), read and
written with h5py (the `transient` extra); y-tal itself is not needed.

The layout (one dataset per key; lengths in metres of optical path):

    H                                   float32 (T, Sx, Sy) for H_format T_Sx_Sy (confocal or single-laser)
    H_format                            int32 enum {UNKNOWN 0, T_Sx_Sy 1, T_Lx_Ly_Sx_Sy 2, T_Si 3, T_Li_Si 4}, (1,)
    sensor_xyz, laser_xyz               float32 (3,): where the detector and the laser stand
    sensor_grid_xyz, laser_grid_xyz     float32 (Sx, Sy, 3): the points they look at on the relay wall
    sensor_grid_normals, laser_grid_normals   float32 (Sx, Sy, 3)
    sensor_grid_format, laser_grid_format     int32 enum {UNKNOWN 0, N_3 1, X_Y_3 2}, (1,)
    volume_format                       empty (deprecated in y-tal)
    delta_t, t_start                    float32 scalars: bin width and the optical path of bin 0, metres
    t_accounts_first_and_last_bounces   bool scalar: whether H's time includes laser → wall and wall → sensor
    scene_info                          a YAML string (a mapping)

nlosbench's images are (scan_y, scan_x, T, C); y-tal's H is (T, Sx, Sy): H[t, x, y] = image[y, x, t] summed
over C (`CaptureFile.image` goes back, C = 1). `tests/data/ytal_confocal.hdf5` was written by y-tal 0.20.0
itself (`tests/data/make_ytal_fixture.py`, run once in a throwaway environment).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

H_FORMATS = {"UNKNOWN": 0, "T_Sx_Sy": 1, "T_Lx_Ly_Sx_Sy": 2, "T_Si": 3, "T_Li_Si": 4}
GRID_FORMATS = {"UNKNOWN": 0, "N_3": 1, "X_Y_3": 2}
#: every key y-tal 0.20.0 writes, in its order
KEYS = ("H", "H_format", "sensor_xyz", "sensor_grid_xyz", "sensor_grid_normals", "sensor_grid_format", "laser_xyz",
        "laser_grid_xyz", "laser_grid_normals", "laser_grid_format", "volume_format", "delta_t", "t_start",
        "t_accounts_first_and_last_bounces", "scene_info")


class CaptureFileError(ValueError):
    """A capture file or capture data that does not fit y-tal's layout; one line naming the file and the key."""


def _h5py():
    try:
        import h5py
    except ImportError:
        raise ImportError("y-tal capture files need h5py: pip install 'nlosbench[transient]'") from None
    return h5py


@dataclass
class CaptureFile:
    """One confocal or single-laser capture in y-tal's layout (see the module docstring): H (T, Sx, Sy), the
    grids (Sx, Sy, 3), metres."""

    H: np.ndarray
    sensor_grid_xyz: np.ndarray
    laser_grid_xyz: np.ndarray
    delta_t: float
    t_start: float
    sensor_xyz: np.ndarray = field(default_factory=lambda: np.zeros(3))
    laser_xyz: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sensor_grid_normals: np.ndarray | None = None
    laser_grid_normals: np.ndarray | None = None
    t_accounts_first_and_last_bounces: bool = False
    scene_info: dict = field(default_factory=dict)
    H_format: str = "T_Sx_Sy"

    def __post_init__(self):
        self.H = np.asarray(self.H, dtype=np.float32)
        if self.H_format != "T_Sx_Sy":
            raise CaptureFileError(f"H_format {self.H_format!r}: only T_Sx_Sy (confocal or one laser point) is handled")
        if self.H.ndim != 3 or not np.all(np.isfinite(self.H)):
            raise CaptureFileError(f"H must be a finite (T, Sx, Sy) array, got shape {self.H.shape}")
        T, Sx, Sy = self.H.shape
        for name in ("sensor_grid_xyz", "laser_grid_xyz", "sensor_grid_normals", "laser_grid_normals"):
            v = getattr(self, name)
            if v is None and name.endswith("normals"):  # a planar wall facing +z
                v = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (Sx, Sy, 3))
            v = np.asarray(v, dtype=np.float32)
            if name.startswith("laser") and v.shape == (3,):  # one laser point (single capture)
                v = np.broadcast_to(v, (Sx, Sy, 3))
            if v.shape != (Sx, Sy, 3) or not np.all(np.isfinite(v)):
                raise CaptureFileError(f"{name} must be finite with shape (Sx, Sy, 3) = {(Sx, Sy, 3)}, got {v.shape}")
            setattr(self, name, np.ascontiguousarray(v))
        for name in ("sensor_xyz", "laser_xyz"):
            v = np.asarray(getattr(self, name), dtype=np.float32)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise CaptureFileError(f"{name} must be a finite [x, y, z], got {getattr(self, name)!r}")
            setattr(self, name, v)
        if not (math.isfinite(self.delta_t) and self.delta_t > 0):
            raise CaptureFileError(f"delta_t must be finite and > 0 (metres of optical path), got {self.delta_t!r}")
        if not math.isfinite(self.t_start):
            raise CaptureFileError(f"t_start must be finite (metres of optical path), got {self.t_start!r}")
        if not isinstance(self.scene_info, dict):
            raise CaptureFileError(f"scene_info must be a mapping, got {type(self.scene_info).__name__}")

    @classmethod
    def from_image(cls, image, scan_points, delta_t: float, t_start: float, **fields) -> CaptureFile:
        """A confocal capture from an nlosbench image (scan_y, scan_x, T[, C]) (channels summed) and its scan
        points (scan_y, scan_x, 3), metres; `fields` are the other keys (laser_xyz, sensor_xyz, scene_info …)."""
        img = np.asarray(image, dtype=np.float64)
        if img.ndim == 4:
            img = img.sum(axis=-1)
        if img.ndim != 3:
            raise CaptureFileError(f"image must be (scan_y, scan_x, T[, C]), got shape {np.shape(image)}")
        pts = np.asarray(scan_points, dtype=np.float64)
        if pts.shape != img.shape[:2] + (3,):
            raise CaptureFileError(f"scan_points must be (scan_y, scan_x, 3) = {img.shape[:2] + (3,)}, got {pts.shape}")
        grid = pts.transpose(1, 0, 2)
        return cls(H=img.transpose(2, 1, 0), sensor_grid_xyz=grid, laser_grid_xyz=fields.pop("laser_grid_xyz", grid),
                   delta_t=float(delta_t), t_start=float(t_start), **fields)

    def image(self) -> np.ndarray:
        """H as an nlosbench image (scan_y, scan_x, T, 1) float32."""
        return np.ascontiguousarray(self.H.transpose(2, 1, 0)[..., None])

    def is_confocal(self) -> bool:
        """Laser and detector on the same wall points (y-tal's `is_confocal`)."""
        return bool(np.allclose(self.sensor_grid_xyz, self.laser_grid_xyz))


def write_ytal(path, capture: CaptureFile) -> Path:
    """Write `capture` in y-tal's HDF5 layout (every key of `KEYS`); the file is only created once the data has
    been checked (`CaptureFile` checks on construction). Returns the path."""
    h5py = _h5py()
    import yaml

    if not isinstance(capture, CaptureFile):
        raise CaptureFileError(f"expected a CaptureFile, got {type(capture).__name__}")
    path = Path(path)
    h_enum = h5py.enum_dtype(H_FORMATS, basetype="i")
    g_enum = h5py.enum_dtype(GRID_FORMATS, basetype="i")
    with h5py.File(path, "w") as f:
        f["H"] = capture.H
        f.create_dataset("H_format", (1,), dtype=h_enum)[0] = H_FORMATS[capture.H_format]
        for who in ("sensor", "laser"):
            f[f"{who}_xyz"] = getattr(capture, f"{who}_xyz")
            f[f"{who}_grid_xyz"] = getattr(capture, f"{who}_grid_xyz")
            f[f"{who}_grid_normals"] = getattr(capture, f"{who}_grid_normals")
            f.create_dataset(f"{who}_grid_format", (1,), dtype=g_enum)[0] = GRID_FORMATS["X_Y_3"]
        f["volume_format"] = h5py.Empty(float)
        f["delta_t"] = np.float32(capture.delta_t)
        f["t_start"] = np.float32(capture.t_start)
        f["t_accounts_first_and_last_bounces"] = bool(capture.t_accounts_first_and_last_bounces)
        f["scene_info"] = yaml.safe_dump(capture.scene_info)
    return path


def read_ytal(path) -> CaptureFile:
    """A capture from a y-tal HDF5 file (H_format T_Sx_Sy, grids X_Y_3); CaptureFileError naming the file and key
    for anything else."""
    h5py = _h5py()
    import yaml

    path = Path(path)
    if not path.is_file():
        raise CaptureFileError(f"{path}: no such capture file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise CaptureFileError(f"{path}: not an HDF5 file ({e})") from None
    with f:
        need = ("H", "H_format", "sensor_grid_xyz", "laser_grid_xyz", "delta_t", "t_start")
        missing = [k for k in need if k not in f]
        if missing:
            raise CaptureFileError(f"{path}: not a y-tal capture (HDF5_TAL): missing {missing}")

        def val(key, default=None):
            if key not in f or f[key].shape is None:  # absent, or h5py.Empty
                return default
            v = f[key][()]
            return v.reshape(-1)[0] if isinstance(v, np.ndarray) and v.size == 1 and v.ndim == 1 else v

        hf = {v: k for k, v in H_FORMATS.items()}.get(int(val("H_format")), "?")
        for who in ("sensor", "laser"):
            g = val(f"{who}_grid_format", GRID_FORMATS["X_Y_3"])
            if int(g) != GRID_FORMATS["X_Y_3"]:
                raise CaptureFileError(f"{path}: {who}_grid_format {int(g)}: only X_Y_3 grids are handled")
        info = val("scene_info", b"")
        info = yaml.safe_load(info.decode() if isinstance(info, bytes) else str(info)) or {}
        try:
            return CaptureFile(H=val("H"), H_format=hf, sensor_grid_xyz=val("sensor_grid_xyz"),
                               laser_grid_xyz=val("laser_grid_xyz"), delta_t=float(val("delta_t")),
                               t_start=float(val("t_start")), sensor_xyz=val("sensor_xyz", np.zeros(3)),
                               laser_xyz=val("laser_xyz", np.zeros(3)),
                               sensor_grid_normals=val("sensor_grid_normals"),
                               laser_grid_normals=val("laser_grid_normals"),
                               t_accounts_first_and_last_bounces=bool(val("t_accounts_first_and_last_bounces", False)),
                               scene_info=info if isinstance(info, dict) else {"scene_info": info})
        except CaptureFileError as e:
            raise CaptureFileError(f"{path}: {e}") from None
