"""Dr.Jit's LLVM target: the pinned portable target reproduces a committed reference image bit for bit; the
render identity keys the render cache and refuses a resume on another machine; the target is one per process."""
import importlib.util
import json
import platform
from pathlib import Path

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench.executors import LocalPoolExecutor
from nlosbench.experiment import config, rundir
from nlosbench.forward import identity, llvm_target
from nlosbench.schema import ConfigError

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
_spec = importlib.util.spec_from_file_location("make_target_reference", ROOT / "scripts" / "make_target_reference.py")
MAKE = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(MAKE)  # the reference's spec and arguments
REF = MAKE.NAME


def _reference(folder: Path = DATA) -> tuple[np.ndarray, dict]:
    """(image, render identity) of the reference written to `folder` by scripts/make_target_reference.py."""
    return np.load(folder / f"{REF}.npy"), json.loads((folder / f"{REF}.json").read_text())


def _skip_unless_comparable(ref: dict) -> None:
    """Skip, saying why, where the reference cannot be expected to hold."""
    if platform.machine().lower() not in ("x86_64", "amd64") or not {"avx2", "fma"} <= llvm_target._cpu_flags():
        pytest.skip(f"the portable target needs x86-64 with AVX2 and FMA; this is {platform.machine()}")
    here = identity.render_identity()
    if here["libllvm"] != ref["libllvm"]:
        pytest.skip(f"the reference was rendered with libLLVM {ref['libllvm']}, Dr.Jit here loads "
                    f"{here['libllvm']}: LLVM versions compile the same IR differently")
    for lib in ("mitsuba", "drjit"):
        if here["versions"][lib] != ref["versions"][lib]:
            pytest.skip(f"the reference was rendered with {lib} {ref['versions'][lib]}, this is "
                        f"{here['versions'][lib]}")
    if here["host"] != ref["host"]:
        pytest.skip(f"the reference was rendered on a {ref['host']} CPU, this is {here['host']}: Embree (the mesh "
                    "intersector) picks its kernels by the CPU's ISA, which no target pins")


def reference_task(model, _):
    """Runs in a pool worker: (its render identity, the reference render)."""
    return model.content_key()["render"], model.render(MAKE.THETA, MAKE.SPP, MAKE.SEED).numpy()


def test_pool_worker_pinned_to_portable_renders_the_reference():
    """A spawned pool worker whose spec asks for the portable target pins it before its first kernel and renders
    pi_hallway 16×12 (64 spp, seed 3) to the same bits as the committed reference (made by
    scripts/make_target_reference.py on an AMD EPYC, LLVM CPU znver5, AVX-512)."""
    ref_img, ref = _reference()
    _skip_unless_comparable(ref)
    with LocalPoolExecutor(MAKE.SPEC, workers=1) as pool:
        [(got, img)] = list(pool.imap_unordered(reference_task, [0]))
    assert got["llvm_target"] == {"name": "portable", "cpu": llvm_target.PORTABLE.cpu, "features": "",
                                  "width": llvm_target.PORTABLE.width}
    assert img.dtype == ref_img.dtype and img.shape == ref_img.shape == (12, 16, 3)
    assert np.array_equal(img.view(np.uint32), ref_img.view(np.uint32))


@pytest.fixture(scope="module")
def hallway(tmp_path_factory):
    """pi_hallway 16×12 in this process (its target: the session's, native unless NLOSBENCH_LLVM_TARGET is
    set), with a render cache."""
    return nb.scenes.get(MAKE.SPEC["name"], **MAKE.SPEC["options"], cache=tmp_path_factory.mktemp("cache"))


def test_native_target_renders_other_bits(hallway):
    """Where the host's own target is not the portable one, the same render differs from the reference: the pin
    is what makes the reference reproducible (here: znver5 at width 16 → 448 of 576 values differ)."""
    ref_img, ref = _reference()
    _skip_unless_comparable(ref)
    target = llvm_target.current()
    if hallway.llvm_target == "portable" or (target.cpu, target.width) == (llvm_target.PORTABLE.cpu,
                                                                           llvm_target.PORTABLE.width):
        pytest.skip(f"this process renders with the portable target already ({target.cpu}, width {target.width})")
    img = hallway.render(MAKE.THETA, spp=MAKE.SPP, seed=MAKE.SEED).numpy()
    assert not np.array_equal(img.view(np.uint32), ref_img.view(np.uint32))
    np.testing.assert_allclose(img, ref_img, atol=0.02)  # the same image up to Monte Carlo path changes


def test_cache_entry_is_not_served_to_another_render_identity(hallway, monkeypatch):
    """A render cached under this machine's identity is a miss for another (here: another LLVM target)."""
    first = hallway.render([1.0], spp=4, seed=7)
    hits = hallway.cache.hits
    assert torch.equal(hallway.render([1.0], spp=4, seed=7), first) and hallway.cache.hits == hits + 1
    other = {**identity.render_identity(), "llvm_target": {"name": "portable", "cpu": "x86-64-v3", "features": "",
                                                            "width": 4}}
    monkeypatch.setattr("nlosbench.forward.mitsuba_model.render_identity", lambda: other)
    misses = hallway.cache.misses
    hallway.render([1.0], spp=4, seed=7)
    assert hallway.cache.misses == misses + 1


@pytest.mark.parametrize("restricted", [False, True])
def test_resume_on_another_machine_is_refused_naming_it(tmp_path, restricted):
    """A run folder whose fingerprint holds another render identity refuses the resume, naming the component
    (also when the model is a restriction of the scene, whose key nests the scene's)."""
    key = {"scene": "abc", "render": {"llvm_target": {"name": "native", "cpu": "znver5", "width": 16},
                                      "libllvm": "19.1.7"}}
    wrap = (lambda k: {"base": k, "index": [0], "fixed": [0.0]}) if restricted else (lambda k: k)
    cfg = {"name": "x", "seed": 0}
    rundir.write_fingerprint(tmp_path, rundir.fingerprint(cfg, wrap(key), {}))
    rundir.check(tmp_path, rundir.fingerprint(cfg, wrap(key), {}), resume=True)  # the same machine: fine
    moved = {**key, "render": {**key["render"], "llvm_target": {"name": "native", "cpu": "skylake-avx512",
                                                                "width": 16}}}
    with pytest.raises(rundir.RunFolderError, match=r"rendered with render\.llvm_target\.cpu = 'znver5', this "
                                                    r"process has 'skylake-avx512'") as e:
        rundir.check(tmp_path, rundir.fingerprint(cfg, wrap(moved), {}), resume=True)
    assert "\n" not in str(e.value)


def test_resume_of_a_run_without_a_render_identity_is_refused(tmp_path):
    """A folder whose fingerprint predates the render identity cannot show it was rendered here: refused."""
    cfg, key = {"name": "x", "seed": 0}, {"scene": "abc"}
    rundir.write_fingerprint(tmp_path, rundir.fingerprint(cfg, key, {}))
    with pytest.raises(rundir.RunFolderError, match="rendered with render = '<absent>'"):
        rundir.check(tmp_path, rundir.fingerprint(cfg, {**key, "render": identity.render_identity()}, {}), resume=True)


def test_target_is_fixed_once_per_process():
    """A process renders with one target: asking for the other after the first is refused (kernels compiled for
    the first would mix with the second)."""
    first = llvm_target.pin()
    assert llvm_target.pin(first) == first
    other = "portable" if first == "native" else "native"
    with pytest.raises(llvm_target.TargetError, match="already"):
        llvm_target.pin(other)


def test_unknown_target_is_bad_input(monkeypatch):
    with pytest.raises(ValueError, match="expected one of native, portable"):
        llvm_target.requested("avx2")
    monkeypatch.setenv(llvm_target.ENV, "fast")
    with pytest.raises(ValueError, match="NLOSBENCH_LLVM_TARGET is 'fast'"):
        llvm_target.requested()
    raw = {"scene": {"name": "pi_hallway", "llvm_target": "fast"}, "studies": []}
    with pytest.raises(ConfigError, match="scene.llvm_target"):
        config.resolve(raw)
