import numpy as np
import pytest
import torch

from nlosbench.params import Param, ParamSpace


def space():
    return ParamSpace([Param("x", -1.0, 1.0, 0.0), Param("r", 0.1, 0.5, 0.2)])


def test_validate_returns_float64_vector():
    t = space().validate(torch.tensor([0.5, 0.3], dtype=torch.float64))
    assert t.dtype == np.float64 and t.tolist() == [0.5, 0.3]


@pytest.mark.parametrize("theta, msg", [([0.0], "must have 2 value"), ([0.0, 0.2, 0.1], "must have 2 value"),
                                        ([np.nan, 0.2], "finite"), ([2.0, 0.2], "x=2 outside"),
                                        ([0.0, 0.05], "r=0.05 outside")])
def test_bad_theta_errors_name_the_problem(theta, msg):
    with pytest.raises(ValueError, match=msg):
        space().validate(theta)


def test_unknown_name_lists_known():
    with pytest.raises(KeyError, match=r"\['x', 'r'\]"):
        space().index("radius")


def test_bad_param_definitions():
    with pytest.raises(ValueError, match="lower < upper"):
        Param("a", 1.0, 0.0, 0.5)
    with pytest.raises(ValueError, match="default"):
        Param("a", 0.0, 1.0, 2.0)
    with pytest.raises(ValueError, match="duplicate"):
        ParamSpace([Param("a", 0, 1, 0), Param("a", 0, 1, 0)])


def test_uniform_samples_inside(rng):
    s = space()
    pts = np.array([s.sample_uniform(rng) for _ in range(200)])
    assert all(s.contains(p) for p in pts)
    assert pts[:, 0].min() < -0.8 and pts[:, 0].max() > 0.8


def test_grid_is_the_tensor_product_over_theta():
    g = space().grid(3)
    assert g.shape == (9, 2) and g.dtype == np.float64
    np.testing.assert_allclose(g[:3], [[-1.0, 0.1], [-1.0, 0.3], [-1.0, 0.5]], rtol=1e-15)  # last parameter fastest
    s = space()
    assert all(s.contains(t) for t in g) and (g.min(0) == s.lower).all() and (g.max(0) == s.upper).all()
