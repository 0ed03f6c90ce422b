"""The frozen render path (`drjit.freeze`d `mi.render`, nlosbench/forward/passes.py): same images as the
traced path, one recording per pass spp, the θ → scene update (geometry included) stays correct, the
switch turns it off."""
import warnings

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.forward import passes
from nlosbench.forward.mitsuba_model import MitsubaModel

#: θ sequences that move geometry (ball_x, ball_radius) and colour (ball_red) between renders
THETAS = [[0.0, 0.3, 0.8], [0.25, 0.2, 0.3], [-0.3, 0.4, 0.9], [0.1, 0.15, 0.05]]
#: CUDA accumulates samples with atomics, so identical renders differ in the last bits: |Δ| ≤ RTOL·|L| + ATOL
CUDA_RTOL, CUDA_ATOL = 1e-5, 1e-6


def _frozen_and_traced(model, thetas, spp, seed):
    """Images of `thetas` rendered first all frozen, then all traced (so each frozen render follows a
    frozen render at another θ: a recording that baked in the scene would show)."""
    saved = model.freeze
    try:
        model.freeze = True
        frozen = [model.render(t, spp, seed) for t in thetas]
        model.freeze = False
        traced = [model.render(t, spp, seed) for t in thetas]
    finally:
        model.freeze = saved
    return frozen, traced


def test_frozen_equals_traced_per_backend(backend_model):
    """LLVM: bit for bit. CUDA: within the stated atomic-accumulation tolerance."""
    frozen, traced = _frozen_and_traced(backend_model, THETAS, 32, 9)
    assert not torch.equal(frozen[0], frozen[1])  # the θ changes do change the image
    for f, t in zip(frozen, traced, strict=True):
        if backend_model.backend == "llvm":
            assert torch.equal(f, t), float((f - t).abs().max())
        else:
            assert torch.allclose(f, t, rtol=CUDA_RTOL, atol=CUDA_ATOL), float((f - t).abs().max())


def test_frozen_equals_traced_with_several_passes(cornell):
    """Non-power-of-two spp and a small pass size: every pass replays with its own seed."""
    saved = cornell.max_pass_samples
    cornell.max_pass_samples = 32 * 32 * 8  # passes of 8 spp: 40 = 8·5
    try:
        assert [s for s, _ in cornell._passes(40, 3)] == [8] * 5
        frozen, traced = _frozen_and_traced(cornell, THETAS[:2], 40, 3)
        frozen96, traced96 = _frozen_and_traced(cornell, THETAS[2:], 12, 3)  # passes 8 + 4
    finally:
        cornell.max_pass_samples = saved
    for f, t in zip(frozen + frozen96, traced + traced96, strict=True):
        assert torch.equal(f, t)


def test_new_theta_and_seed_replay_without_recording():
    """One recording per pass spp: θ (geometry and colour) and the seed are inputs, not baked in. A model of its own:
    the session's cornell has recorded whichever pass spp other tests in the same process rendered before (13 spp is
    passes of 8, 4 and 1: one new recording there after the several-passes test, three on a fresh model)."""
    model = nb.scenes.get("cornell_ball")
    model.render(THETAS[0], 16, 1)  # traced: the first render allocates the film
    model.render(THETAS[1], 16, 0)  # the first recording at 16 spp
    n = model._renderer.n_recordings
    imgs = [model.render(t, 16, s) for s, t in enumerate(THETAS, start=2)]
    assert model._renderer.n_recordings == n
    assert len({float(i.sum()) for i in imgs}) == len(imgs)
    assert [s for s, _ in model._passes(32, 1)] == [32]
    model.render(THETAS[0], 32, 1)  # one pass, of an spp not seen before: one recording
    assert model._renderer.n_recordings == n + 1


def test_primal_render_after_ad_passes_is_unchanged_and_stops_recording(cornell):
    """An AD pass leaves gradient-tracked values (and AD integrator state) in the scene; the next primal
    render rewrites plain θ, gives the same image, and after one AD/primal cycle no longer records."""
    j = cornell.params.index("ball_red")
    before = cornell.render(THETAS[1], 16, 4)
    counts = []
    for _ in range(3):
        cornell.vjp(THETAS[1], torch.ones(32, 32, 3), 4, 1, indices=[j])
        assert torch.equal(cornell.render(THETAS[1], 16, 4), before)
        cornell.render(THETAS[2], 16, 5)
        counts.append(cornell._renderer.n_recordings)
    assert counts[1] == counts[2], counts


def test_path_binding_renders_frozen_like_traced(tmp_path):
    """`path` picks its polyline segment in Python from θ's value: that runs traced, before the frozen
    render, so positions on different segments are still right."""
    spec = tmp_path / "path.yaml"
    spec.write_text(f"file: {nb.scenes.SCENE_DIR / 'cornell_ball.xml'}\nparams:\n"
                    "  - {name: s, kind: path, object: ball, points: [[-0.4, 0, 0], [0.3, 0, 0], [0.3, 0.4, 0]], "
                    "lower: 0, upper: 1.1, default: 0.2}\n")
    model = nb.scenes.get(str(spec))
    thetas = [[0.1], [0.9], [0.5], [1.05]]  # segments 0, 1, 0, 1
    frozen, traced = _frozen_and_traced(model, thetas, 16, 2)
    assert model._renderer.n_recordings == 1
    for f, t in zip(frozen, traced, strict=True):
        assert torch.equal(f, t)
    assert not torch.equal(frozen[1], frozen[3])


def test_switch_off_by_option_and_environment(monkeypatch):
    assert passes.freeze_default(None) and not passes.freeze_default(False)
    for off in ("0", "false", "off"):
        monkeypatch.setenv(passes.FREEZE_ENV, off)
        assert not passes.freeze_default(None)
        assert passes.freeze_default(True)  # an explicit option wins over the environment
    model = nb.scenes.get("cornell_ball")  # built while NLOSBENCH_FREEZE=off
    assert not model.freeze
    model.render(THETAS[0], 8, 0)
    assert model._renderer.n_recordings == 0  # traced: nothing recorded
    monkeypatch.delenv(passes.FREEZE_ENV)
    assert nb.scenes.get("cornell_ball").freeze
    x = {"name": "x", "kind": "translate", "object": "ball", "axis": [1, 0, 0], "lower": -0.3, "upper": 0.3,
         "default": 0.0}
    assert not MitsubaModel("c", nb.scenes.SCENE_DIR / "cornell_ball.xml", [x], freeze=False).freeze


def test_a_failing_recording_falls_back_to_traced_with_a_warning(cornell, monkeypatch):
    renderer = passes.FrozenRender(True, label="scene 'x'")

    def broken(*args, **kwargs):
        raise RuntimeError("cannot record this")

    monkeypatch.setattr(renderer, "_frozen", type("F", (), {"__call__": broken, "clear": lambda self: None,
                                                            "n_recordings": 0})())
    cornell._apply(np.asarray(THETAS[0], dtype=np.float64))
    renderer(cornell.scene, 8, 4)  # the first render of a scene is traced (see FrozenRender)
    with pytest.warns(RuntimeWarning, match="scene 'x': the frozen render failed.*cannot record this"):
        img = renderer(cornell.scene, 8, 5)
    assert not renderer.enabled
    import mitsuba as mi

    assert np.array_equal(np.asarray(img), np.asarray(mi.render(cornell.scene, spp=8, seed=5)))


def test_ctrl_c_inside_the_frozen_render_is_a_keyboard_interrupt_not_a_fallback(cornell):
    """Dr.Jit re-raises what a frozen function's recording raised as a RuntimeError caused by it; a Ctrl-C there
    (a real `drjit.freeze` whose body raises KeyboardInterrupt) comes out as KeyboardInterrupt and leaves the
    frozen path on. Before, it was taken for a failed recording: a warning, and the render went on traced (a
    Ctrl-C test then waited a minute for a render that no longer stopped)."""
    import drjit as dr

    renderer = passes.FrozenRender(True, label="scene 'x'")

    def interrupted(scene, seed, spp):
        raise KeyboardInterrupt

    renderer._frozen = dr.freeze(interrupted)
    cornell._apply(np.asarray(THETAS[0], dtype=np.float64))
    renderer(cornell.scene, 8, 4)  # the first render of a scene is traced (see FrozenRender)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(KeyboardInterrupt):
            renderer(cornell.scene, 8, 5)
    assert renderer.enabled
