"""The real Mitsuba forward model on cornell_ball: determinism, seeds, no reloads, passes, errors, AD vs FD."""
import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.forward import GradientSettings, fd_jacobian
from nlosbench.forward.mitsuba_model import WAVEFRONT_LIMIT, MitsubaModel, split_spp

THETA = [0.0, 0.3, 0.8]


def test_same_arguments_same_image_bit_for_bit(cornell):
    a = cornell.render(THETA, 64, 5)
    cornell.render([0.2, 0.25, 0.5], 64, 5)  # move away and back
    b = cornell.render(THETA, 64, 5)
    assert a.shape == (32, 32, 3) and a.dtype == torch.float32
    assert torch.equal(a, b)


def test_a_moved_mesh_gives_the_same_image_at_the_same_arguments():
    """pi_hallway's teapot is a mesh whose vertices move with θ, so Mitsuba recomputes its vertex normals and
    rebuilds its acceleration structure at every new θ. Done in parallel, that varied in the last bit from
    call to call: 0.91 m rendered again after other θ gave 2 of 3600 pixels different in about a third of
    the runs (2–3 of 11 returns per run). The update now runs on one thread; 12 returns must all be
    bit-identical to the first render."""
    model = nb.scenes.get("pi_hallway", defines={"width": 40, "height": 30, "max_depth": 3})
    first = model.render([0.91], 64, 5)
    for k in range(12):
        model.render([1.2 + 0.01 * k], 16, 1)
        assert torch.equal(model.render([0.91], 64, 5), first), k


def test_non_power_of_two_spp_is_deterministic(cornell):
    assert torch.equal(cornell.render(THETA, 96, 1), cornell.render(THETA, 96, 1))


def test_different_seeds_give_independent_noise(cornell):
    ref = torch.stack([cornell.render(THETA, 64, s) for s in range(100, 108)]).mean(0)
    e1 = cornell.render(THETA, 16, 1) - ref
    e2 = cornell.render(THETA, 16, 2) - ref
    corr = torch.corrcoef(torch.stack([e1.flatten(), e2.flatten()]))[0, 1]
    # both errors share ref's small error (64·8 spp vs 16 spp: ≈ 3 % of the variance), so |corr| ≪ 1
    assert abs(float(corr)) < 0.15, float(corr)
    assert not torch.equal(e1, e2)


def test_moving_object_never_reloads_scene(cornell):
    loads, scene = MitsubaModel.loads, cornell.scene
    imgs = [cornell.render([x, 0.3, 0.8], 16, 0) for x in (-0.3, 0.0, 0.3)]
    assert MitsubaModel.loads == loads and cornell.scene is scene
    # the ball moved: the left and right positions differ where the ball was
    assert float((imgs[0] - imgs[2]).abs().mean()) > 0.01


def test_radius_and_colour_change_the_image(cornell):
    base = cornell.render(THETA, 32, 0)
    bigger = cornell.render([0.0, 0.4, 0.8], 32, 0)
    less_red = cornell.render([0.0, 0.3, 0.2], 32, 0)
    assert float(bigger.sum()) != float(base.sum())
    # lowering the red reflectance lowers red far more than green
    d = (base - less_red).sum(dim=(0, 1))
    assert d[0] > 5 * abs(d[1])


def test_split_spp_into_power_of_two_passes_under_the_wavefront_limit():
    passes = split_spp(3072, 256 * 512, 1 << 24)
    assert sum(passes) == 3072 and all(p & (p - 1) == 0 for p in passes)
    big = split_spp(2 ** 20, 512 * 512, 2 ** 40)  # 2.7e11 pixel-samples
    assert sum(big) == 2 ** 20 and all(p * 512 * 512 < WAVEFRONT_LIMIT for p in big) and len(big) > 1


def test_more_samples_than_a_pass_uses_distinct_seeds(cornell):
    saved, cornell.max_pass_samples = cornell.max_pass_samples, 32 * 32 * 16  # force passes of 16 spp
    try:
        passes = cornell._passes(64, 3)
        assert [s for s, _ in passes] == [16] * 4 and len({sd for _, sd in passes}) == 4
        img = cornell.render(THETA, 64, 3)
    finally:
        cornell.max_pass_samples = saved
    one = cornell.render(THETA, 64, 3)
    # same estimator, different random numbers: close in mean, not identical
    assert not torch.equal(img, one)
    assert abs(float(img.mean() - one.mean())) < 0.02 * float(one.mean())


@pytest.mark.parametrize("theta, spp, seed, msg", [
    ([0.0, 0.3], 16, 0, "must have 3"),
    ([0.9, 0.3, 0.8], 16, 0, "ball_x=0.9 outside"),
    (THETA, 0, 0, "spp must be a positive integer"),
    (THETA, 16, -1, "seed must be a non-negative"),
])
def test_bad_inputs(cornell, theta, spp, seed, msg):
    with pytest.raises(ValueError, match=msg):
        cornell.render(theta, spp, seed)


def test_unknown_scene_suggests_a_name():
    with pytest.raises(nb.scenes.SpecError, match="did you mean 'cornell_ball'"):
        nb.scenes.get("cornel_ball")


def test_bad_scene_spec(tmp_path):
    """A spec naming a missing XML file, or a binding to a shape the XML lacks: a SpecError (a ConfigError: the
    CLI's exit 2) naming the spec."""
    spec = tmp_path / "s.yaml"
    spec.write_text("file: missing.xml\nparams:\n  - {name: a, kind: radius, object: ball, lower: 0.1, upper: 0.2, "
                    "default: 0.1}\n")
    with pytest.raises(nb.scenes.SpecError, match="missing.xml"):
        nb.scenes.get(str(spec))
    xml = nb.scenes.SCENE_DIR / "cornell_ball.xml"
    spec.write_text(f"file: {xml}\nparams:\n  - {{name: a, kind: translate, object: nosuch, axis: [1,0,0], "
                    "lower: 0, upper: 1, default: 0}\n")
    with pytest.raises(ValueError, match="no movable shape with id 'nosuch'"):
        nb.scenes.get(str(spec))


def test_nan_render_raises_naming_scene_theta_spp_seed(cornell):
    """A NaN reflectance on the walls reaches the image on every supported Mitsuba (a NaN light radiance
    does not before 3.9.0: docs/versions.md), and the render error names scene, θ, spp and seed."""
    import mitsuba as mi

    key = "white.reflectance.value"
    saved = mi.Color3f(cornell._params[key])
    cornell._params[key] = mi.Color3f(float("nan"), 0.5, 0.5)
    cornell._params.update()
    try:
        with pytest.raises(nb.RenderError, match=r"cornell_ball.*ball_x.*spp=16, seed=4"):
            cornell.render([0.01, 0.3, 0.8], 16, 4)
    finally:
        cornell._params[key] = saved
        cornell._params.update()


def test_ad_and_fd_agree_on_colour_total_derivative(cornell):
    """d(Σ image)/d(ball_red): AD (prb, forward mode) vs central FD with common random numbers."""
    j = cornell.params.index("ball_red")
    fd = fd_jacobian(cornell, THETA, 512, 11, GradientSettings(step=0.05), indices=[j]).double().sum()
    ad = np.mean([float(cornell.jvp(THETA, j, 512, s).double().sum()) for s in (1, 2)])
    assert abs(ad - float(fd)) < 0.05 * abs(float(fd)), (ad, float(fd))
    # reverse mode gives the same total derivative as forward mode (grad_out = ones)
    rev = cornell.vjp(THETA, torch.ones(32, 32, 3), 512, 1, indices=[j])[j]  # `prb`, as the forward-mode pass
    assert abs(rev - float(fd)) < 0.05 * abs(float(fd))


def test_restricted_colour_gradient_uses_prb(cornell):
    """A colour-only restriction of a scene that also has geometry parameters needs no projective AD."""
    r = cornell.restrict(["ball_red"])
    cornell._ad_cache.clear()
    g = r.vjp([0.8], torch.ones(32, 32, 3), 64, 1)
    assert g.shape == (1,) and np.isfinite(g).all()
    assert [dict(k)["type"] for k in cornell._ad_cache] == ["prb"]


def test_an_ad_pass_leaves_its_scene_untracked_so_another_models_forward_ad_runs():
    """After a reverse-mode pass on one model, forward-mode AD on a second model of the same scene in the same
    process used to stop in Dr.Jit ("tried to forward-propagate derivatives across edge … outside of the current
    dr.isolate_grad() scope"): the first scene still held grad-enabled values. Now no scene value stays tracked
    after `vjp` or `jvp`, and the second model's derivative image is the one it renders alone (bit for bit)."""
    import drjit as dr

    first = nb.scenes.get("cornell_ball")
    first.restrict(["ball_red"]).vjp([0.8], torch.ones(32, 32, 3), 16, 1)
    assert not any(dr.grad_enabled(v) for _, v in first._params.items() if dr.is_array_v(v))
    second = nb.scenes.get("cornell_ball").restrict(["ball_red"])
    J = second.jvp([0.8], 0, 16, 0, type="prb")
    assert torch.isfinite(J).all() and torch.equal(J, second.jvp([0.8], 0, 16, 0, type="prb"))
    assert not any(dr.grad_enabled(v) for _, v in second.base._params.items() if dr.is_array_v(v))


def test_non_box_pixel_filter_warns_that_renders_are_not_bit_reproducible(tmp_path):
    src = (nb.scenes.SCENE_DIR / "cornell_ball.xml").read_text()
    assert '<rfilter type="box"/>' in src
    (tmp_path / "g.xml").write_text(src.replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>'))
    spec = tmp_path / "g.yaml"
    spec.write_text("file: g.xml\nparams:\n  - {name: x, kind: translate, object: ball, axis: [1, 0, 0], "
                    "lower: -0.3, upper: 0.3, default: 0}\n")
    with pytest.warns(UserWarning, match="GaussianFilter is not a box filter"):
        nb.scenes.get(str(spec), defines={"res": 8})
