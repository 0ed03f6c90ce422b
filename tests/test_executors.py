"""Executors: a spawned process pool loads the real Mitsuba scene once per worker and renders bit for
bit what this process renders; trials through the pool and through Dask (LocalCluster) give exactly
the records of a serial run, each worker having built its model once."""
import importlib.util
import os

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench import executors
from nlosbench.executors import DaskExecutor, LocalPoolExecutor, SerialExecutor
from nlosbench.forward import GradientSettings
from nlosbench.montecarlo import LOG_NAME, Setting, make_trials, run_trials

CORNELL = {"name": "cornell_ball", "params": ["ball_x"]}
BLOB = {"name": "blob2d", "options": {"width": 0.15, "render_noise": 0.05}}


def render_task(model, x):
    """Runs in a worker: (item, pid, models built in that process, Mitsuba scene loads there, image)."""
    from nlosbench.forward.mitsuba_model import MitsubaModel

    return x, os.getpid(), executors.builds, MitsubaModel.loads, model.render([x], 16, 7)


def test_pool_workers_load_the_scene_once_and_render_bit_identically(cornell):
    xs = [-0.3, -0.2, -0.1, 0.0, 0.1, 0.2]
    with LocalPoolExecutor(CORNELL, workers=2) as pool:
        out = sorted(pool.imap_unordered(render_task, xs), key=lambda r: r[0])
    assert [r[0] for r in out] == xs
    assert {r[1] for r in out} - {os.getpid()} == {r[1] for r in out}  # all in other processes
    assert all(r[2] == 1 and r[3] == 1 for r in out)  # one model, one scene load per worker
    ball_x = cornell.restrict(["ball_x"])
    for x, *_, img in out:
        assert torch.equal(img, ball_x.render([x], 16, 7))


def probe_task(model, x):
    """Runs in a worker: (process id, models built in that process)."""
    return os.getpid(), executors.builds


def _trials():
    model = nb.scenes.get(BLOB["name"], **BLOB["options"])
    noise = nb.noise.AWGN(0.05)
    theta = np.array([[0.4, 0.6], [0.55, 0.45]])
    cleans = {i: model.render(t, 256, i) for i, t in enumerate(theta)}
    settings = [Setting("mle-adam", {"iterations": 25, "spp": 16}, gradient=GradientSettings("ad")),
                Setting("gauss-newton", {"spp": 16, "iterations": 6})]  # 6 renders per iteration
    return model, make_trials(theta, 3, settings, {0: noise}, cleans, seed=9)


def _comparable(records):
    return sorted(({k: v for k, v in r.items() if k != "seconds"} for r in records),
                  key=lambda r: (r["theta_index"], r["trial"], r["estimator"]))


HAS_DASK = importlib.util.find_spec("distributed") is not None
needs_dask = pytest.mark.skipif(not HAS_DASK, reason="dask.distributed is not installed (the optional 'dask' extra)")


@pytest.mark.parametrize("make", [lambda: LocalPoolExecutor(BLOB, workers=2),
                                  pytest.param(lambda: DaskExecutor(BLOB, workers=2),
                                               marks=[needs_dask, pytest.mark.slow])],
                         ids=["pool", "dask"])
def test_trials_through_workers_match_a_serial_run(tmp_path, make):
    model, trials = _trials()
    serial = run_trials(SerialExecutor(model), trials, tmp_path / "serial" / LOG_NAME)
    with make() as ex:
        remote = run_trials(ex, trials, tmp_path / "remote" / LOG_NAME)
        probes = list(ex.imap_unordered(probe_task, range(4)))
    assert len(remote) == len(trials) == 12
    assert _comparable(remote) == _comparable(serial)
    assert all(pid != os.getpid() and builds == 1 for pid, builds in probes)  # one model per worker process


def test_create_from_the_run_config(cornell):
    assert isinstance(executors.create({"type": "serial"}, CORNELL, model=cornell), SerialExecutor)
    pool = executors.create({"type": "local", "workers": 3}, CORNELL)
    assert isinstance(pool, LocalPoolExecutor) and pool.workers == 3 and pool.threads >= 1
    if HAS_DASK:
        assert isinstance(executors.create({"type": "dask", "workers": 2, "address": None}, CORNELL), DaskExecutor)
    else:
        with pytest.raises(ImportError, match=r"pip install 'nlosbench\[dask\]'"):
            executors.create({"type": "dask", "workers": 2, "address": None}, CORNELL)
    with pytest.raises(ValueError, match="unknown executor type 'mpi'"):
        executors.create({"type": "mpi"}, CORNELL)
    for make in (LocalPoolExecutor, DaskExecutor) if HAS_DASK else (LocalPoolExecutor,):
        with pytest.raises(ValueError, match="workers must be a positive integer"):
            make(CORNELL, workers=0)


def test_serial_executor_uses_the_given_model_without_loading():
    model = nb.scenes.get("edge1d")
    before = executors.builds
    out = list(SerialExecutor(model).imap_unordered(lambda m, x: m.render([x], 1, 0).sum().item(), [0.2, 0.8]))
    assert executors.builds == before and out[0] > out[1]
