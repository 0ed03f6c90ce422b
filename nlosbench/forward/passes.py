"""How one primal render of `spp` samples per pixel runs: split into passes, each rendered by a
`drjit.freeze`d `mi.render` (or traced, where freezing is off).

Passes. A render is split into power-of-two spp passes (largest first), each with its own seed
`derive(seed, "pass", i)`; the image is their spp-weighted mean, accumulated in float64. The pass
size (pixel-samples per pass) is chosen per backend by `pass_samples`:

  llvm (CPU)   2**20  Python sees Ctrl-C (KeyboardInterrupt) only when `mi.render` returns, i.e.
                      between passes, so a pass must be short: 2**20 pixel-samples took 1.4–1.7 s
                      for cornell_ball and ≈ 2.4 s for pi_hallway (max_depth 8: 2.3 µs per
                      pixel-sample) on 2 shared cores;
                      SIGINT stopped a 2**17-spp render within 2–3 s (2**24-sample passes: 27 s).
                      The per-pass cost (a frozen replay, a copy and a float64 add) is milliseconds.
  cuda (GPU)   2**30  a quarter of Dr.Jit's wavefront limit (2**32): 8192 spp up to 360 × 360 pixels
                      is one pass, so at the benchmark sizes a render is the same single call as raw
                      `mi.render`. Not measured on a GPU yet: `python -m nlosbench.benchmarks.forward`
                      prints ours / raw (render_overhead) on whatever backend it runs on.

The split is a pure function of (spp, pixels, pass size), so with the box filter the same (θ, spp,
seed) gives the same image bit for bit on the CPU; a different pass size splits differently and
changes the image (the pass size is therefore part of `MitsubaModel.content_key`).

Freezing. `FrozenRender` wraps `mi.render(scene, spp=s, seed=UInt32)` in `drjit.freeze`: the scene is
a traversed input (its variables may change between calls), the seed an opaque UInt32, the pass spp `s`
a Python int. The θ → scene update (`SceneBinder.apply` + `params.update()`) stays *outside* the frozen
function, for two reasons: `params.update()` rebuilds the ray-tracing acceleration structure on the host
(Embree; OptiX on CUDA), which Dr.Jit cannot record — freezing the update replays the recording's BVH
(measured on LLVM: frozen images at other θ off by up to 0.13 while traced ones moved the object) —
and the `path` binding picks its polyline segment in Python from θ's value, which a recording would
bake in. With the update outside, every binding kind (translate, path, radius, reflectance, radiance)
renders through the frozen function, and the θ write is a few small traced kernels.

Re-recording (see `dr.freeze`'s docstring) happens on:
  - a pass spp not seen before (part of the recording's key; power-of-two passes keep this to at most
    log2(pass size / pixels) + 1 recordings per model);
  - a change in the layout of the scene's variables: the first render of a scene allocates the film's
    storage (so that render runs traced, not recorded), and the first AD pass (`vjp`/`jvp`) leaves the
    scene with more state — one or two re-recordings, once; then AD and primal renders alternate freely;
  - a scene variable changing type, size or AD status, or a *literal* changing value (`auto_opaque`
    makes it opaque at a second recording; `MitsubaModel` writes θ as opaque values, so moving θ does
    not record);
  - another scene object.
`FrozenRender.limit` bounds the recordings kept (least recently used is dropped).

Switch: `MitsubaModel(..., freeze=False)`, `model.freeze = False`, or the environment variable
NLOSBENCH_FREEZE=0 renders every pass traced (for debugging). On LLVM both paths give bit-identical
images (tests/test_frozen_render.py); on CUDA they agree within float32 atomic-accumulation noise
(tolerance stated there). A recording that raises (e.g. an integrator that cannot be frozen) warns once
and falls back to the traced path for that model.
"""
from __future__ import annotations

import os
import warnings

from .. import interrupts

WAVEFRONT_LIMIT = 2 ** 32
#: pixel-samples per pass by Dr.Jit backend (see the module docstring for how they were chosen)
PASS_SAMPLES = {"llvm": 2 ** 20, "cuda": 2 ** 30}
#: environment variable that turns freezing off when set to 0 / false / no / off
FREEZE_ENV = "NLOSBENCH_FREEZE"


def backend_of(variant: str) -> str:
    """'cuda' or 'llvm' for a Mitsuba variant name such as 'llvm_ad_rgb'."""
    for b in PASS_SAMPLES:
        if variant.startswith(b):
            return b
    raise ValueError(f"variant {variant!r} is neither a CUDA nor an LLVM variant")


def pass_samples(variant: str, cap: int | None = None) -> int:
    """Pixel-samples per pass for `variant`'s backend, at most `cap` (a user's limit, e.g. memory)."""
    policy = PASS_SAMPLES[backend_of(variant)]
    return policy if cap is None else max(1, min(int(cap), policy))


def split_spp(spp: int, pixels: int, max_pass_samples: int) -> list[int]:
    """spp split into power-of-two passes of at most max_pass_samples pixel-samples (largest first)."""
    limit = min(max_pass_samples, WAVEFRONT_LIMIT - 1)
    cap = 1 << max(0, (limit // max(pixels, 1)).bit_length() - 1)
    if pixels * cap > limit and cap > 1:
        cap >>= 1
    passes = [cap] * (spp // cap)
    rest = spp % cap
    passes += [1 << b for b in range(rest.bit_length() - 1, -1, -1) if rest >> b & 1]
    return passes


def freeze_default(option: bool | None = None) -> bool:
    """Whether to freeze: `option` if given, else $NLOSBENCH_FREEZE (default on)."""
    if option is not None:
        return bool(option)
    return os.environ.get(FREEZE_ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def _render_pass(scene, seed, spp: int):
    """The frozen body: one `mi.render` of the scene's own sensor and integrator → TensorXf (H, W, C)."""
    import mitsuba as mi

    return mi.render(scene, spp=spp, seed=seed)


class FrozenRender:
    """`mi.render(scene, spp, seed)` through `drjit.freeze` (one recording per pass spp), or traced.

    `enabled` False renders traced. A recording that raises turns this instance off with a warning.
    """

    def __init__(self, enabled: bool = True, limit: int = 32, label: str = ""):
        import drjit as dr

        self.enabled = bool(enabled)
        self.limit = int(limit)
        self.label = label
        self._warm = None  # the scene rendered at least once (traced) by this instance
        # warn_after: every new pass spp records legitimately, so only warn well above that
        self._frozen = dr.freeze(_render_pass, limit=self.limit, warn_after=2 * self.limit)

    @property
    def n_recordings(self) -> int:
        """Recordings made so far (traces of the render body)."""
        return int(self._frozen.n_recordings)

    def __call__(self, scene, spp: int, seed: int):
        """TensorXf (H, W, C): one pass of `spp` samples per pixel with 32-bit `seed`."""
        import drjit as dr
        import mitsuba as mi

        if not self.enabled or scene is not self._warm:
            # the first render of a scene allocates its film storage, which changes what the frozen function
            # sees as its input: rendering it traced saves a recording that would be used once
            img = mi.render(scene, spp=spp, seed=seed)
            self._warm = scene if self.enabled else self._warm
            return img
        try:
            img = self._frozen(scene, dr.opaque(mi.UInt32, seed), int(spp))
            dr.eval(img)
            return img
        except Exception as e:  # noqa: BLE001 - any recording failure: render traced from now on
            interrupt = interrupts.interrupt_in(e)
            if interrupt is not None:  # Ctrl-C inside the frozen call: Dr.Jit wraps it in a RuntimeError
                raise interrupt from None
            self.enabled = False
            self._frozen.clear()
            warnings.warn(f"{self.label}: the frozen render failed ({type(e).__name__}: {e}); rendering traced "
                          "from now on", RuntimeWarning, stacklevel=2)
            return mi.render(scene, spp=spp, seed=seed)
