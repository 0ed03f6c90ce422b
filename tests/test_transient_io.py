"""y-tal's HDF5 capture layout (`capture_io`): the fixture written by y-tal 0.20.0 itself
(tests/data/ytal_confocal.hdf5, from tests/data/make_ytal_fixture.py) is read with its keys, shapes and values and
sets up a transient scene; a capture written by nlosbench has the fixture's keys, dtypes and shapes and reads back
to the same image and geometry; bad input fails in one line before a file is written."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

h5py = pytest.importorskip("h5py", reason="the transient extra is not installed (pip install 'nlosbench[transient]')")

from nlosbench.capture_io import KEYS, CaptureFile, CaptureFileError, read_ytal, write_ytal  # noqa: E402
from nlosbench.forward.transient import Capture  # noqa: E402

FIXTURE = Path(__file__).parent / "data" / "ytal_confocal.hdf5"


def _layout(path):
    """{key: (shape, dtype str, enum mapping or None)} of an HDF5 file."""
    with h5py.File(path, "r") as f:
        return {k: (f[k].shape, str(f[k].dtype), h5py.check_enum_dtype(f[k].dtype)) for k in f}


def test_the_ytal_fixture_reads_with_its_keys_shapes_and_values():
    cf = read_ytal(FIXTURE)
    assert set(_layout(FIXTURE)) == set(KEYS)
    assert cf.H.shape == (16, 3, 2) and cf.H_format == "T_Sx_Sy" and cf.is_confocal()
    assert cf.sensor_grid_xyz.shape == (3, 2, 3) and cf.delta_t == pytest.approx(0.01)
    assert cf.t_start == pytest.approx(1.2)
    assert not cf.t_accounts_first_and_last_bounces and "y-tal 0.20.0" in cf.scene_info["note"]
    assert cf.image().shape == (2, 3, 16, 1) and cf.image()[1, 2, 5, 0] == cf.H[5, 2, 1]


def test_the_ytal_fixture_sets_up_a_scene():
    cap = Capture.from_file(FIXTURE)
    assert cap.scan == (3, 2) and cap.bins == 16 and cap.bin_width == pytest.approx(0.01)
    assert cap.start == pytest.approx(1.2) and cap.wall == pytest.approx((1.2, 1.0))
    assert np.allclose(cap.scan_points().transpose(1, 0, 2), read_ytal(FIXTURE).sensor_grid_xyz, atol=1e-6)
    assert cap.laser_origin == pytest.approx((-0.5, 0.0, 0.25))
    if importlib.util.find_spec("mitransient") is not None:
        from nlosbench.forward.transient import Hidden, TransientModel

        m = TransientModel("from_ytal", cap, [Hidden(center=(0.0, 0.0, 0.7))],
                           [{"name": "z", "kind": "translate", "object": "hidden", "axis": [0, 0, 1], "lower": -0.1,
                             "upper": 0.1, "default": 0.0}])
        assert m.render(m.params.default, 16, 0).shape[:3] == (2, 3, 16)


def test_a_written_capture_has_ytals_layout_and_reads_back(tmp_path):
    cap = Capture(scan=(4, 3), bins=8, bin_width=0.02, start=1.0, wall=(0.8, 0.6))
    img = np.random.default_rng(0).uniform(size=(3, 4, 8, 3)).astype(np.float32)
    out = write_ytal(tmp_path / "c.hdf5", cap.to_file(img, {"scene": "test"}))
    ours, theirs = _layout(out), _layout(FIXTURE)
    assert set(ours) == set(theirs)
    for k in theirs:  # dtypes and enums as y-tal writes them; shapes the same up to the grid's size
        assert ours[k][1:] == theirs[k][1:], k
        assert (ours[k][0] is None) == (theirs[k][0] is None) and len(ours[k][0] or ()) == len(theirs[k][0] or ()), k
    back = read_ytal(out)
    assert back.H.shape == (8, 4, 3)
    assert np.allclose(back.image()[..., 0], img.sum(-1), rtol=1e-6)
    got = Capture.from_file(back)  # float32 in the file: equal to 1e-6
    assert got.scan == cap.scan and got.bins == cap.bins and got.capture_type == cap.capture_type
    for k in ("bin_width", "start", "wall", "laser_origin", "sensor_origin"):
        assert getattr(got, k) == pytest.approx(getattr(cap, k), rel=1e-6, abs=1e-7), k


def test_bad_captures_fail_in_one_line_before_writing(tmp_path):
    cap = Capture(scan=(4, 3), bins=8)
    with pytest.raises(CaptureFileError, match=r"scan_points must be \(scan_y, scan_x, 3\)"):
        write_ytal(tmp_path / "x.hdf5", cap.to_file(np.zeros((4, 3, 8))))  # scan axes swapped
    assert not (tmp_path / "x.hdf5").exists()
    (tmp_path / "bad.hdf5").write_text("not hdf5")
    with pytest.raises(CaptureFileError, match="not an HDF5 file"):
        read_ytal(tmp_path / "bad.hdf5")
    with pytest.raises(CaptureFileError, match="delta_t"):
        CaptureFile(H=np.zeros((2, 2, 2)), sensor_grid_xyz=np.zeros((2, 2, 3)), laser_grid_xyz=np.zeros((2, 2, 3)),
                    delta_t=0.0, t_start=0.0)
    with pytest.raises(ValueError, match="not confocal"):
        Capture.from_file(CaptureFile(H=np.zeros((2, 2, 2)), sensor_grid_xyz=np.zeros((2, 2, 3)),
                                      laser_grid_xyz=np.ones(3), delta_t=0.01, t_start=0.0))
