"""Per-pixel Fisher information maps: consistency with the Fisher matrix, shapes, files."""
import numpy as np
import pytest
import torch

from nlosbench import bounds as B
from nlosbench.noise import AWGN, Poisson


@pytest.mark.parametrize("model", [AWGN(0.2), Poisson(30.0)])
def test_maps_sum_to_fisher_diagonal(model):
    g = torch.Generator().manual_seed(0)
    L = 0.1 + torch.rand(12, 16, 3, generator=g)
    J = torch.randn(2, 12, 16, 3, generator=g)
    J[1, :6] = 0.0  # θ1 only informs the bottom half
    maps = B.fisher_maps(L, J, model)
    F = B.fisher_matrix(L, J, model)
    assert maps.shape == (2, 12, 16) and maps.dtype == np.float64 and (maps >= 0).all()
    np.testing.assert_allclose(maps.sum(axis=(1, 2)), np.diag(F), rtol=1e-12)
    assert (maps[1, :6] == 0).all() and (maps[1, 6:] > 0).any()
    np.testing.assert_allclose(B.fisher_maps(L, J, model, reduce="mean"), maps / 3, rtol=1e-15)
    one = B.fisher_maps(L, J[0], model)  # scalar θ
    np.testing.assert_array_equal(one, maps[:1])
    gray = B.fisher_maps(L[..., 0], J[:, ..., 0], model)  # (H, W) images
    np.testing.assert_allclose(gray.sum(axis=(1, 2)), np.diag(B.fisher_matrix(L[..., 0], J[:, ..., 0], model)),
                               rtol=1e-12)
    with pytest.raises(ValueError, match="reduce"):
        B.fisher_maps(L, J, model, reduce="max")


def test_save_fisher_maps(tmp_path):
    from nlosbench.io import read_exr

    L = 0.5 + torch.rand(8, 10, 3)
    J = torch.randn(2, 8, 10, 3)
    maps = B.fisher_maps(L, J, AWGN(0.1))
    paths = B.save_fisher_maps(maps, ["x", "radius"], tmp_path / "fi", prefix="ball")
    names = sorted(p.name for p in paths)
    assert names == ["ball_radius.exr", "ball_radius.png", "ball_x.exr", "ball_x.png"]
    assert all(p.stat().st_size > 0 for p in paths)
    back = read_exr(tmp_path / "fi" / "ball_radius.exr")
    np.testing.assert_allclose(back[..., 0], maps[1], rtol=1e-6)  # float32 storage
    with pytest.raises(ValueError):
        B.save_fisher_maps(maps, ["x"], tmp_path)
