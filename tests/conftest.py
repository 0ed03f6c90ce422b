"""Shared fixtures. Mitsuba scenes load once per test session (scene loads are the slow part): once per worker
process under `make test`'s `pytest -n 2 --dist loadgroup` (pytest-xdist), whose scheduler is defined here."""
import functools
import os
import re
from pathlib import Path

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


#: a test file that defines a fixture of one of these scopes is one unit of work under `--dist loadgroup`
_SHARED_SCOPE = re.compile(r"""scope\s*=\s*["'](?:module|class|package)["']""")


@functools.cache
def _shares_fixtures(path: Path) -> bool:
    try:
        return bool(_SHARED_SCOPE.search(path.read_text(encoding="utf-8")))
    except OSError:  # not a file (a doctest's module, say): keep its tests together
        return True


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """`make test` runs `pytest -n 2 --dist loadgroup`, scheduled here: a test file that defines a module- or
    class-scoped fixture is one unit of work, run by one worker (the fixture is made once, and whatever it writes
    to a fixed place, such as the own-scene run in $NLOSBENCH_OWN_SCENE_OUT, is written by one process); every
    other test is a unit of its own, handed to whichever worker is free, so that no long file holds the run up.
    Units go out largest first. (pytest-xdist's `xdist_group` marks do not reach its scheduler under pytest 9.2,
    which reads a test's id from elsewhere, so the grouping is decided here, from the file.)"""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    root = Path(config.rootpath)

    class FileOrTest(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return path if _shares_fixtures(root / path) else nodeid

    return FileOrTest(config, log)


def pytest_configure(config):
    """Under `pytest -n N` with N ≥ 2 (`make test`) each worker process computes on one thread, torch's and Dr.Jit's:
    N processes with a thread per core each oversubscribe the cores (measured on 2 cores, one run each: a CPU-bound
    part of the suite, U-statistics and planners, 95 → 74 s; a render-bound part 107 → 100 s)."""
    if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
        import torch

        torch.set_num_threads(1)
        dr.set_thread_count(1)
