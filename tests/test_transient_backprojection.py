"""The backprojection localiser (`estimators.backprojection`): its backprojection against a direct evaluation,
its peak on the analytic toy's noise-free captures (the discretisation error, stated tolerances), one-line errors."""
import numpy as np
import pytest

import nlosbench as nb
from nlosbench.estimators.backprojection import backproject
from nlosbench.forward.analytic import TransientPoint


def test_backprojection_reads_each_histogram_at_twice_the_distance():
    """One scan point, one count in bin k: B(v) is the tent of half-width one bin around bin k's centre, read at
    the optical path 2‖v − p‖ (linear interpolation between bin centres)."""
    edges = 1.0 + 0.01 * np.arange(11)
    y = np.zeros((1, 1, 10, 1))
    y[0, 0, 4, 0] = 1.0  # centre at 1.045 m of optical path
    p = np.zeros((1, 1, 3))
    r = np.array([1.045, 1.040, 1.050, 1.0475, 1.03]) / 2
    B = backproject(y, p, edges, np.c_[np.zeros(5), np.zeros(5), r])
    assert np.allclose(B, [1.0, 0.5, 0.5, 0.75, 0.0], atol=1e-9)


@pytest.mark.parametrize("theta", [[0.0537, -0.0213, 0.7466], [-0.1234, 0.0771, 0.6123]])
def test_the_peak_of_a_noise_free_capture_is_within_half_a_voxel(theta):
    """Noise-free toy captures (30 ps response, 6 mm bins), 1 cm voxels: the parabolic peak lies within half a
    voxel of θ in each coordinate (its discretisation error; measured ≤ 2 mm at 5 mm voxels)."""
    m = TransientPoint()
    t = np.array(theta)
    problem = nb.estimators.Problem(m, nb.noise.Poisson(1.0))
    est = nb.estimators.get("backprojection", voxel=0.01)
    e = est.fit(problem, m.render(t, 1, 0), rng=np.random.default_rng(0))
    assert np.all(np.abs(e.theta - t) < 0.005), e.theta - t
    assert e.renders == 0 and e.status == "converged"


def test_depth_alone_on_a_restricted_model():
    m = TransientPoint().restrict(["depth"], {"x": 0.05, "y": -0.03})
    problem = nb.estimators.Problem(m, nb.noise.Poisson(1.0))
    e = nb.estimators.get("backprojection", voxel=0.001).fit(problem, m.render([0.7433], 1, 0),
                                                            rng=np.random.default_rng(0))
    assert abs(e.theta[0] - 0.7433) < 5e-4, e.theta[0] - 0.7433


def test_bad_options_and_models_fail_in_one_line():
    with pytest.raises(ValueError, match="voxel"):
        nb.estimators.get("backprojection", voxel=0.0)
    with pytest.raises(ValueError, match="refine"):
        nb.estimators.get("backprojection", refine="cubic")
    problem = nb.estimators.Problem(nb.scenes.get("blob2d"), nb.noise.Poisson(1.0))
    with pytest.raises(ValueError, match="no known map from θ|not a confocal transient model"):
        nb.estimators.get("backprojection").fit(problem, np.ones((24, 24, 1)), rng=np.random.default_rng(0))
