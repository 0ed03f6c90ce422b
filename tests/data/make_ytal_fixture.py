"""Writes tests/data/ytal_confocal.hdf5 with y-tal 0.20.0's own writer (`tal.io.write_capture`).

Run once in a throwaway environment (y-tal pins Pillow and imageio and needs pyvista, so it is not a dependency):
    python -m venv /tmp/ytal-venv && /tmp/ytal-venv/bin/pip install y-tal==0.20.0
    /tmp/ytal-venv/bin/python tests/data/make_ytal_fixture.py tests/data/ytal_confocal.hdf5
"""
import sys

import numpy as np
import tal
from tal.enums import GridFormat, HFormat
from tal.io.capture_data import NLOSCaptureData

T, Sx, Sy = 16, 3, 2
cd = NLOSCaptureData()
cd.H = np.random.default_rng(0).uniform(size=(T, Sx, Sy)).astype(np.float32)
cd.H_format = HFormat.T_Sx_Sy
X, Y = np.meshgrid(np.linspace(-0.4, 0.4, Sx), np.linspace(-0.25, 0.25, Sy), indexing="ij")
grid = np.stack([X, Y, np.zeros_like(X)], -1).astype(np.float32)
normals = np.zeros_like(grid)
normals[..., 2] = 1.0
cd.sensor_xyz = np.array([-0.5, 0.0, 0.25], np.float32)
cd.laser_xyz = np.array([-0.5, 0.0, 0.25], np.float32)
cd.sensor_grid_xyz, cd.laser_grid_xyz = grid, grid.copy()
cd.sensor_grid_normals, cd.laser_grid_normals = normals, normals.copy()
cd.sensor_grid_format = cd.laser_grid_format = GridFormat.X_Y_3
cd.delta_t, cd.t_start = np.float32(0.01), np.float32(1.2)
cd.t_accounts_first_and_last_bounces = False
cd.scene_info = {"original_format": "HDF5_TAL", "note": "fixture for nlosbench, written by y-tal 0.20.0"}
tal.io.write_capture(sys.argv[1], cd)
back = tal.io.read_capture(sys.argv[1])
print({k: getattr(v, "shape", v) for k, v in back.as_dict().items()}, "confocal:", back.is_confocal())
