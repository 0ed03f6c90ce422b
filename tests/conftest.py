"""Shared fixtures. Mitsuba scenes load once per test session (scene loads are the slow part)."""
import drjit as dr
import numpy as np
import pytest

import nlosbench as nb


@pytest.fixture(scope="session")
def cornell():
    """The real 32×32 Mitsuba `cornell_ball` scene (llvm_ad_rgb on CPU)."""
    return nb.scenes.get("cornell_ball")


@pytest.fixture(params=["llvm", "cuda"])
def backend_model(request, cornell):
    """cornell_ball on the requested Dr.Jit backend (the session fixture where it already is)."""
    backend = request.param
    if backend == "cuda" and not dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("no CUDA device (dr.has_backend(dr.JitBackend.CUDA) is False)")
    if cornell.backend == backend:
        yield cornell
        return
    previous = nb.variant.select()
    try:
        yield nb.scenes.get("cornell_ball", variant=f"{backend}_ad_rgb")
    finally:
        nb.variant.select(previous)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True, scope="session")
def _rates_cache(tmp_path_factory):
    """Render rates measured for cost estimates go to a folder of this session, not ~/.cache (subprocesses
    inherit the variable)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg-cache")))
    yield
    mp.undo()
