"""Per-backend contracts of the Mitsuba forward model: determinism (LLVM bit for bit; CUDA within a
stated tolerance), the pass size policy, Ctrl-C between passes, and what the render key holds."""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import drjit as dr
import pytest
import torch

from nlosbench.forward.cache import render_key
from nlosbench.forward.passes import PASS_SAMPLES, WAVEFRONT_LIMIT, pass_samples, split_spp

THETA = [0.1, 0.25, 0.6]
#: CUDA accumulates samples with atomics, so identical renders differ in the last bits: |Δ| ≤ RTOL·|L| + ATOL
CUDA_RTOL, CUDA_ATOL = 1e-5, 1e-6
ROOT = Path(__file__).resolve().parents[1]


def _same(model, a: torch.Tensor, b: torch.Tensor) -> bool:
    if model.backend == "llvm":
        return torch.equal(a, b)
    return torch.allclose(a, b, rtol=CUDA_RTOL, atol=CUDA_ATOL)


@pytest.mark.parametrize("passes", [None, 32 * 32 * 16])  # the backend's pass size; forced 16-spp passes
def test_same_seed_same_image_per_backend(backend_model, passes):
    """LLVM: the box filter and power-of-two passes make a render bit-reproducible. CUDA: atomic
    accumulation order varies, so identical calls agree within CUDA_RTOL, CUDA_ATOL."""
    saved = backend_model.max_pass_samples
    if passes:
        backend_model.max_pass_samples = passes
    try:
        assert [s for s, _ in backend_model._passes(48, 7)] == ([32, 16] if passes is None else [16] * 3)
        a = backend_model.render(THETA, 48, 7)
        backend_model.render([0.3, 0.2, 0.9], 48, 7)  # move away and back
        b = backend_model.render(THETA, 48, 7)
        c = backend_model.render(THETA, 48, 8)
    finally:
        backend_model.max_pass_samples = saved
    assert _same(backend_model, a, b), float((a - b).abs().max())
    assert float((a - c).abs().max()) > 1e-3  # another seed is other noise


def test_pass_size_policy_per_backend():
    cpu, gpu = pass_samples("llvm_ad_rgb"), pass_samples("cuda_ad_rgb")
    assert cpu == PASS_SAMPLES["llvm"] <= 2 ** 21  # ≈ 1 µs per pixel-sample on 2 cores: Ctrl-C within seconds
    assert gpu == PASS_SAMPLES["cuda"] >= 2 ** 28 and gpu < WAVEFRONT_LIMIT
    # 8192 spp at pi_hallway's 160 × 120 is one GPU pass (the same single call as raw mi.render)
    assert split_spp(8192, 160 * 120, gpu) == [8192]
    cpu_passes = split_spp(8192, 160 * 120, cpu)
    assert sum(cpu_passes) == 8192 and all(p & (p - 1) == 0 and p * 160 * 120 <= cpu for p in cpu_passes)
    assert pass_samples("llvm_ad_rgb", 4096) == 4096 and pass_samples("llvm_ad_rgb", 2 ** 24) == cpu  # a cap
    with pytest.raises(ValueError, match="neither"):
        pass_samples("scalar_rgb")


def test_model_uses_its_backends_pass_size(cornell):
    # the registry still passes its old default (2**24) as a cap: the CPU policy is below it
    assert cornell.max_pass_samples == pass_samples(cornell.variant) == PASS_SAMPLES[cornell.backend]


def test_render_key_names_versions_integrator_and_pass_size(cornell):
    import mitsuba as mi

    key = cornell.content_key()
    assert key["mitsuba"] == mi.__version__ and key["drjit"] == dr.__version__
    assert key["max_pass_samples"] == cornell.max_pass_samples
    assert "PathIntegrator" in key["integrator"] and "max_depth = 4" in key["integrator"]
    before = render_key(model=key, theta=[repr(0.0)], spp=64, seed=1)
    saved, cornell.max_pass_samples = cornell.max_pass_samples, 2 ** 12
    try:
        after = render_key(model=cornell.content_key(), theta=[repr(0.0)], spp=64, seed=1)
    finally:
        cornell.max_pass_samples = saved
    assert before != after  # a different pass split is a different image


_INTERRUPTED_RENDER = """
import faulthandler, signal, time
faulthandler.register(signal.SIGUSR1, all_threads=True)  # the test dumps the stacks if this ever hangs
# a shell without job control starts background jobs with SIGINT ignored, and children inherit that;
# Python then installs no KeyboardInterrupt handler, so restore it: this test is about our passes
signal.signal(signal.SIGINT, signal.default_int_handler)
import nlosbench as nb
m = nb.scenes.get("cornell_ball")
m.render([0.0, 0.3, 0.8], 1024, 0)  # compile the pass kernel
print("rendering", len(m._passes(1 << 17, 1)), flush=True)
t = time.perf_counter()
m.render([0.0, 0.3, 0.8], 1 << 17, 1)  # 1.3e8 pixel-samples: minutes on 2 cores
print("done", time.perf_counter() - t, flush=True)
"""


@pytest.mark.skipif(os.name != "posix", reason="sends SIGINT")
def test_ctrl_c_stops_a_long_cpu_render_within_a_pass(cornell, tmp_path):
    """SIGINT to a process rendering 2**17 spp (minutes) ends it with KeyboardInterrupt after at most
    one pass (2**20 pixel-samples, about a second or two on 2 cores), far before the render ends."""
    if cornell.backend != "llvm":
        pytest.skip("the CPU pass size is what bounds the latency")
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err_file:  # a file, not a pipe: nothing can block on a full pipe
        proc = subprocess.Popen([sys.executable, "-c", _INTERRUPTED_RENDER], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=err_file, text=True)
    hung = False
    try:
        started = threading.Event()
        lines: list[str] = []

        def read():
            for line in proc.stdout:
                lines.append(line)
                started.set()

        threading.Thread(target=read, daemon=True).start()
        assert started.wait(120), err_path.read_text()[-3000:]
        assert lines[0].startswith("rendering") and int(lines[0].split()[1]) == 128  # 128 passes of 1024 spp
        time.sleep(2.0)  # mid-render
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            hung = True
            proc.send_signal(signal.SIGUSR1)  # Python stacks of every thread into stderr.txt
            time.sleep(2.0)
        latency = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = err_path.read_text()
    assert not hung, f"the process did not exit within 60 s of SIGINT; its stderr:\n{err[-6000:]}"
    assert "KeyboardInterrupt" in err, err[-2000:]
    assert not any(line.startswith("done") for line in lines)
    # one pass is ~1–2.5 s here; the old 2**24-sample passes took 20–40 s each
    assert latency < 10.0, f"Ctrl-C took {latency:.1f} s to stop the render"
