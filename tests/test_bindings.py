"""θ bindings on the real cornell_ball scene: a polyline path, emitter radiance, the variant error."""
import numpy as np
import pytest
import torch
import yaml

import nlosbench as nb
from nlosbench import variant

XML = nb.scenes.SCENE_DIR / "cornell_ball.xml"


@pytest.fixture(scope="module")
def path_model(tmp_path_factory):
    spec = {
        "file": str(XML),
        "params": [
            {
                "name": "s",
                "kind": "path",
                "object": "ball",
                "points": [[-0.4, -0.6, 0.1], [0.0, -0.6, 0.1], [0.0, -0.2, 0.1]],
            },
            {
                "name": "light",
                "kind": "radiance",
                "key": "light.emitter.radiance.value",
                "lower": 0.1,
                "upper": 2.0,
                "default": 1.0,
            },
        ],
    }
    spec["params"][0]["default"] = 0.4
    p = tmp_path_factory.mktemp("spec") / "path.yaml"
    p.write_text(yaml.safe_dump(spec))
    return nb.scenes.get(str(p))


def test_path_bounds_default_to_its_arc_length(path_model):
    assert path_model.params.lower[0] == 0.0 and path_model.params.upper[0] == pytest.approx(0.8)


def test_path_places_ball_centre_on_the_polyline(path_model):
    import mitsuba as mi

    for s, centre in ((0.0, [-0.4, -0.6, 0.1]), (0.3, [-0.1, -0.6, 0.1]), (0.6, [0.0, -0.4, 0.1])):
        path_model.render([s, 1.0], 4, 0)
        m = np.array(mi.Transform4f(path_model._params["ball.to_world"]).matrix).reshape(4, 4)
        assert np.allclose(m[:3, 3], centre, atol=1e-6), (s, m[:3, 3])
        assert np.allclose(np.diag(m)[:3], 0.3, atol=1e-6)  # radius unchanged


def test_fd_across_a_path_corner_is_continuous(path_model):
    """At the corner (s = 0.4) the two one-segment derivatives differ in direction; the central FD
    stencil straddles both, and its image stays finite and non-zero."""
    fd = nb.forward.fd_jacobian(path_model, [0.4, 1.0], 64, 1, nb.GradientSettings(step=0.02), indices=[0])
    assert bool(torch.isfinite(fd).all()) and float(fd.abs().sum()) > 0


def test_radiance_scales_the_image_linearly(path_model):
    a = path_model.render([0.4, 1.0], 16, 3).double()
    b = path_model.render([0.4, 2.0], 16, 3).double()
    # same seed, light twice as bright: every pixel doubles (the light is the only emitter)
    assert torch.allclose(b, 2 * a, rtol=1e-4, atol=1e-6)


def test_unknown_variant_names_the_problem(monkeypatch):
    with pytest.raises(variant.VariantError, match="no_such_variant: not in this Mitsuba build"):
        variant.select("no_such_variant")


def test_old_libllvm_is_refused_with_the_fix(monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-14.so")
    assert "libLLVM 14" in variant._llvm_problem() and "crashes Dr.Jit" in variant._llvm_problem()
    assert "apt-get install libllvm19" in variant._FIX
