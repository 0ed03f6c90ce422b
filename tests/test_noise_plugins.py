"""Noise models as entry-point plug-ins (group `nlosbench.noise`): listed, built by name, run from a config with
the weight taken from an independent render when it depends on the signal; one the bounds cannot use is refused
with the reason before anything is written."""
import importlib.metadata
import math
from pathlib import Path

import pytest

import nlosbench as nb
from nlosbench import noise
from nlosbench.cli import BAD_INPUT, main

PLUGINS = {"shot-read": "noise_plugins:ShotRead", "shot-read-fixed": "noise_plugins:ShotReadFixed",
           "laplace": "noise_plugins:Laplace", "not-a-model": "noise_plugins:NOT_A_MODEL"}
GRID = [0.3, 0.4, 0.5, 0.6, 0.7]


@pytest.fixture
def plugins(monkeypatch):
    """The test package's models installed as entry points (and dropped from the registry afterwards)."""
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "plugins"))
    eps = {n: importlib.metadata.EntryPoint(n, v, noise.ENTRY_POINT_GROUP) for n, v in PLUGINS.items()}
    monkeypatch.setattr(noise, "_entry_points", lambda: eps)
    monkeypatch.setattr(noise, "_REGISTRY", dict(noise._REGISTRY))


def config(model: str, options: dict) -> dict:
    return {"name": "plug", "scene": {"name": "blob2d", "params": ["x"]},
            "noise": [{"model": model, "options": options}], "executor": {"type": "serial"}, "keep_renders": False,
            "studies": [{"type": "bounds", "grid": {"start": GRID[0], "stop": GRID[-1], "num": len(GRID)}, "spp": 4,
                         "save_images": False, "zzb": False, "fd_step": 0.002}]}


def test_a_plugin_is_listed_and_built_by_name(plugins, capsys):
    assert {"shot-read", "laplace", "awgn"} <= set(noise.available())
    m = noise.get("shot-read", scale=100.0, read=0.1)
    assert type(m).__name__ == "ShotRead" and m.name == "shot-read" and noise.bounds_refusal(m) == ""
    assert main(["list", "noise"]) == 0
    out = capsys.readouterr().out
    assert "shot-read: Gaussian noise of variance read² + L/scale per pixel" in out
    assert "not-a-model: (fails to load: noise plug-in 'not-a-model' (noise_plugins:NOT_A_MODEL) is" in out


def test_a_signal_dependent_plugin_runs_from_a_config_with_an_independent_weight_render(plugins, tmp_path):
    opts = {"scale": 100.0, "read": 0.1}
    runs = {m: nb.run(config(m, opts), out=tmp_path / m) for m in ("shot-read", "shot-read-fixed")}
    renders = {m: r.summary["studies"]["00-bounds"]["results"]["renders"] for m, r in runs.items()}
    assert renders["shot-read"] - renders["shot-read-fixed"] == len(GRID)  # one weight render per grid θ
    # blob2d's images are exact, so the weight render is the image: the CRLB is 1 / Σ w(L)·(∂L/∂x)²
    t = runs["shot-read"].table("bounds")
    full, m = nb.scenes.get("blob2d"), noise.get("shot-read", **opts)
    for x, got in zip(t["theta_x"], t["log10_crlb"], strict=True):
        L, J = full.render([x, 0.5], 1, 0).double(), full.jvp([x, 0.5], 0).double()
        assert got == pytest.approx(-math.log10(float((m.weight(L) * J**2).sum())), abs=2e-3)


@pytest.mark.parametrize("model, options, message", [
    ("laplace", {"b": 0.1}, "noise[0].model: laplace cannot be used by the bounds: Laplace is not a QuadraticNoise: "
                            "the bounds from replicated renders need a χ² exponent that is a quadratic form in the "
                            "image difference"),
    ("shot-read", {"scale": 100.0}, "noise[0]: noise model 'shot-read': bad parameters ['scale']"),
    ("shot-reed", {}, "noise[0].model: expected one of awgn, laplace, not-a-model, poisson, shot-read, "
                      "shot-read-fixed"),
])
def test_a_model_the_bounds_cannot_use_is_refused_with_the_reason(plugins, tmp_path, capsys, model, options, message):
    import yaml

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(config(model, options)))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not (tmp_path / "run").exists()
