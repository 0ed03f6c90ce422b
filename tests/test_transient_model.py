"""The mitransient forward model (`forward.transient`): same-seed renders identical in one process, θ written
without a reload, the returns where the geometry puts them (scan point positions and optical path), the detector's
zero-mean-bin error on a real render, FD only. Skipped without the `transient` extra (mitransient)."""
import importlib.util

import numpy as np
import pytest
import torch

from nlosbench.forward.detector import Detected, Detector
from nlosbench.forward.mitsuba_model import MitsubaModel
from nlosbench.forward.transient import Capture, Hidden


def test_bad_set_ups_fail_in_one_line_before_anything_loads():
    with pytest.raises(ValueError, match=r"exhaustive capture of 64 × 64 laser points.* GiB per render"):
        Capture(capture_type="exhaustive", scan=(64, 64), bins=512)
    with pytest.raises(ValueError, match="laser_scan is for exhaustive captures"):
        Capture(laser_scan=(2, 2))
    assert Capture(capture_type="exhaustive", scan=(4, 2)).laser_scan == (4, 2)  # default: the scan grid
    assert "laser_scan" not in Capture().as_dict()  # the other captures' content keys are unchanged
    with pytest.raises(ValueError, match="bin_width"):
        Capture(bin_width=0.0)
    with pytest.raises(ValueError, match="center z must be > 0"):
        Hidden(center=(0, 0, -0.5))
    with pytest.raises(ValueError, match="type obj needs an existing `filename`"):
        Hidden(type="obj", filename="/nonexistent.obj")


@pytest.fixture(scope="module")
def model():
    if importlib.util.find_spec("mitransient") is None:  # importing it needs a Mitsuba variant set: only look
        pytest.skip("the transient extra is not installed (pip install 'nlosbench[transient]')")
    from nlosbench.forward.transient import transient_patch

    return transient_patch(scan=4, bins=96, bin_width=0.01, start=1.2)


def test_same_seed_renders_are_identical_and_theta_moves_without_reload(model):
    t = model.params.default
    loads = MitsubaModel.loads
    a = model.render(t, 64, 3)
    assert a.shape == (4, 4, 96, model.channels // 96) and model.channels in (96, 288)
    assert torch.equal(a, model.render(t, 64, 3))
    assert not torch.equal(a, model.render(t, 64, 4))
    moved = t.copy()
    moved[model.params.index("depth")] += 0.02
    assert not torch.equal(a, model.render(moved, 64, 3))
    assert torch.equal(a, model.render(t, 64, 3))  # back at θ: the same bits
    assert MitsubaModel.loads == loads
    assert model.content_key()["mitransient"] == "1.3.1"
    with pytest.raises(NotImplementedError, match="FD derivatives only"):
        model.jvp(t, 0, 4, 0)


def test_returns_arrive_where_the_geometry_puts_them(model):
    """A patch moved to (0.1, −0.15, 0.75) m: each scan point's mean optical path (counts-weighted bin centres)
    is 2‖p_ij − c‖ within 1.5 bins (a 10 cm patch spreads the path by a few mm); the earliest return is at the
    scan point nearest the patch (its position from `Capture.scan_points`)."""
    t = model.params.default.copy()
    t[model.params.index("x")], t[model.params.index("y")] = 0.1, -0.15
    L = model.render(t, 1024, 0).double().numpy().sum(axis=-1)  # (ny, nx, T)
    centres = 0.5 * (model.capture.bin_edges()[1:] + model.capture.bin_edges()[:-1])
    mean_path = (L * centres).sum(-1) / L.sum(-1)
    expect = 2 * np.linalg.norm(model.capture.scan_points() - np.array([0.1, -0.15, 0.75]), axis=-1)
    assert np.all(np.abs(mean_path - expect) < 1.5 * model.capture.bin_width), mean_path - expect
    assert np.unravel_index(np.argmin(mean_path), mean_path.shape) == np.unravel_index(np.argmin(expect),
                                                                                         expect.shape)


def test_a_detector_without_background_names_the_zero_bins(model):
    t = model.params.default
    with pytest.raises(ValueError, match=r"bins have zero mean .* set dark or ambient > 0"):
        Detected(model, Detector(bin_width=0.01, start=1.2, jitter_ps=20.0)).render(t, 16, 0)
    seen = Detected(model, Detector(bin_width=0.01, start=1.2, jitter_ps=20.0, dark=0.01)).render(t, 16, 0)
    assert float(seen.min()) == pytest.approx(0.01)


def test_an_exhaustive_capture_puts_each_laser_where_its_block_says():
    """An exhaustive capture, 2 × 2 laser points × 3 × 3 detector points, a patch moved to (0.15, −0.1, 0.75) m:
    image (2·3, 2·3, T, C), block (i, j) the laser on laser point (i, j); each (laser, detector) pair's mean optical
    path is ‖l − c‖ + ‖p − c‖ within 1.5 bins (l, p from `Capture.scan_points`), so laser and detector grids sit
    where the confocal one does; the same seed gives the same bits, and no two blocks are the same."""
    if importlib.util.find_spec("mitransient") is None:
        pytest.skip("the transient extra is not installed (pip install 'nlosbench[transient]')")
    from nlosbench.forward.transient import TransientModel

    cap = Capture(scan=(3, 3), laser_scan=(2, 2), bins=96, bin_width=0.01, start=1.2, capture_type="exhaustive")
    params = [{"name": n, "kind": "translate", "object": "hidden", "axis": a, "lower": -0.2, "upper": 0.2,
               "default": 0.0} for n, a in (("x", [1, 0, 0]), ("y", [0, 1, 0]))]
    model = TransientModel("exhaustive", cap, [Hidden(center=(0.0, 0.0, 0.75), size=0.05)], params)
    t = np.array([0.15, -0.1])
    img = model.render(t, 512, 0)
    assert img.shape[:3] == (6, 6, 96) and torch.equal(img, model.render(t, 512, 0))
    L = img.double().numpy().sum(axis=-1).reshape(2, 3, 2, 3, 96).swapaxes(1, 2)  # (ly, lx, ny, nx, T)
    centres = 0.5 * (cap.bin_edges()[1:] + cap.bin_edges()[:-1])
    mean_path = (L * centres).sum(-1) / L.sum(-1)
    c = np.array([0.15, -0.1, 0.75])
    lasers = np.linalg.norm(cap.scan_points(cap.laser_scan) - c, axis=-1)  # (ly, lx)
    detectors = np.linalg.norm(cap.scan_points() - c, axis=-1)  # (ny, nx)
    expect = lasers[:, :, None, None] + detectors[None, None]
    assert np.all(np.abs(mean_path - expect) < 1.5 * cap.bin_width), mean_path - expect
    blocks = L.reshape(4, -1)
    assert all(not np.array_equal(blocks[a], blocks[b]) for a in range(4) for b in range(a))
