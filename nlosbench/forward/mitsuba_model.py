"""MitsubaModel: a Mitsuba 3 scene, loaded once, whose parameters θ are written with
`mi.traverse` + `params.update()` (never a reload), rendered with `mi.render`.

Passes: a render of spp samples is split into passes whose spp are powers of two (at most
`max_pass_samples` pixel-samples each: the backend's policy in `passes.PASS_SAMPLES`, capped by the
constructor option, and never more than 2³² — Dr.Jit's wavefront limit), each with its own seed
derived from (seed, pass index); the image is their spp-weighted mean. With the box pixel filter each
sample lands in one pixel, and power-of-two passes keep Dr.Jit's parallel accumulation order fixed, so
on the CPU the same (θ, spp, seed) gives the same image bit for bit (CUDA: within float32 atomic noise).

Frozen path: θ is written to the scene traced (`SceneBinder.apply`, which rebuilds the acceleration
structure), then each pass runs through a `drjit.freeze`d `mi.render` (`passes.FrozenRender`): one
recording per distinct pass spp, replayed for every θ and seed. `freeze=False` or NLOSBENCH_FREEZE=0
turns it off. What is frozen, what re-records and why the scene update is not frozen: `passes.py`.
"""
from __future__ import annotations

import contextlib
import re
import warnings
from pathlib import Path

import numpy as np
import torch

from .. import interrupts
from .. import variant as _variant
from ..params import ParamSpace
from ..seeds import derive
from . import llvm_target as _llvm_target
from .bindings import GEOMETRY_KINDS, Binding, SceneBinder
from .identity import render_identity
from .model import ForwardModel, check_spp_seed
from .passes import WAVEFRONT_LIMIT, FrozenRender, backend_of, freeze_default, pass_samples, split_spp
from .scene_files import content_hash

__all__ = ["MitsubaModel", "SceneError", "WAVEFRONT_LIMIT", "split_spp", "pruned_xml", "AD_INTEGRATORS"]

#: AD integrators by the kind of parameter: geometry needs the visibility-aware projective ones
AD_INTEGRATORS = ("prb", "direct_projective", "prb_projective")


class SceneError(ValueError):
    """A scene file that Mitsuba cannot load (invalid XML, unknown plugin, missing asset); one line."""


def _first_line(e: Exception) -> str:
    """The message of a Mitsuba error without its source location prefix ('[parser.cpp:1087] ')."""
    text = (str(e).strip().splitlines() or [type(e).__name__])[0]
    return re.sub(r"^\[[\w.]+:\d+\]\s*", "", text)


def pruned_xml(scene_file: Path, remove: list[str]) -> str:
    """The XML of `scene_file` without the elements whose `id` is in `remove` (anywhere in the tree),
    relative `filename` references made absolute so the string loads like the file. ValueError names
    ids the file does not have."""
    import xml.etree.ElementTree as ET

    # comments go first: Mitsuba's parser accepts "--" inside them (our ASCII maps), expat does not
    try:
        root = ET.fromstring(re.sub(r"<!--.*?-->", "", scene_file.read_text(), flags=re.S))
    except ET.ParseError as e:
        raise SceneError(f"scene file {scene_file} is not valid XML: {e}") from None
    ids = {e.get("id"): e for e in root.iter() if e.get("id")}
    missing = [r for r in remove if r not in ids]
    if missing:
        raise ValueError(f"scene file {scene_file.name} has no element with id {missing} to remove "
                         f"(ids: {', '.join(sorted(ids))})")
    parent = {c: p for p in root.iter() for c in p}
    for r in remove:
        parent[ids[r]].remove(ids[r])
    for e in root.iter():
        key = "filename" if e.tag == "include" else ("value" if e.get("name") == "filename" else None)
        if key and e.get(key) and "$" not in e.get(key) and not Path(e.get(key)).is_absolute():
            e.set(key, str(scene_file.parent / e.get(key)))
    return ET.tostring(root, encoding="unicode")


class MitsubaModel(ForwardModel):
    """A Mitsuba scene file plus parameter bindings (see `bindings.py`).

    max_pass_samples: a cap (pixel-samples per pass) below the backend's pass size
    (`passes.PASS_SAMPLES`: 2**20 on the CPU, 2**30 on CUDA); None = the backend's. The effective value
    is the attribute `max_pass_samples` and is part of `content_key`.
    freeze: render passes through a `drjit.freeze`d `mi.render` (default: on unless the environment
    variable NLOSBENCH_FREEZE=0); False renders every pass traced, for debugging. Same images either way
    on the CPU (bit for bit).
    llvm_target: Dr.Jit's LLVM code-generation target for this process, 'native' or 'portable' (default: the
    one already fixed in this process, else $NLOSBENCH_LLVM_TARGET, else native); fixed once per process
    (`llvm_target.pin`): a model asking for another one later raises TargetError.

    Examples
    --------
    The Cornell box of scenes/ at 8 × 8 pixels, θ the ball's offset along x:

    >>> from nlosbench.forward.mitsuba_model import MitsubaModel
    >>> ball_x = {"name": "ball_x", "kind": "translate", "object": "ball", "axis": [1, 0, 0],
    ...           "lower": -0.4, "upper": 0.4, "default": 0.0}
    >>> model = MitsubaModel("box", "scenes/cornell_ball.xml", [ball_x], defines={"res": 8, "max_depth": 3})
    >>> loads = MitsubaModel.loads
    >>> left, right = (model.render([x], spp=4, seed=0) for x in (-0.2, 0.2))
    >>> left.shape, model.size, bool((left != right).any())
    (torch.Size([8, 8, 3]), (8, 8), True)
    >>> MitsubaModel.loads == loads  # moving the ball updates the loaded scene, never reloads it
    True
    """

    #: scene loads in this process, across all models (tests check that θ changes never reload)
    loads = 0

    def __init__(self, name: str, scene_file: str | Path, params: list[dict], variant: str | None = None,
                 defines: dict | None = None, ad_integrator: dict | None = None,
                 max_pass_samples: int | None = None, cache=None, remove: list[str] | None = None,
                 freeze: bool | None = None, llvm_target: str | None = None):
        self.scene_file = Path(scene_file)
        if not self.scene_file.is_file():
            raise FileNotFoundError(f"scene {name!r}: scene file {self.scene_file} does not exist")
        self.defines = {k: v for k, v in (defines or {}).items()}
        self.remove = list(remove or [])  # element ids dropped from the scene file before loading
        with interrupts.deferred():  # Dr.Jit's and Mitsuba's imports and the scene load are not cut by a Ctrl-C
            self.llvm_target = _llvm_target.pin(llvm_target)  # before Mitsuba runs its first kernel
            self.variant = _variant.select(variant)
            self.scene = self._load(name)
        import mitsuba as mi

        MitsubaModel.loads += 1
        self._params = mi.traverse(self.scene)
        bindings = [Binding.from_spec(p) for p in params]
        self.binder = SceneBinder(self._params, bindings)
        super().__init__(name, ParamSpace([b.param for b in bindings]), cache)
        self.max_pass_samples = pass_samples(self.variant, max_pass_samples)
        film = self.scene.sensors()[0].film()
        self.size = tuple(int(v) for v in film.crop_size())  # (W, H)
        self._channels = int(film.base_channels_count())  # the developed image's C (RGB: 3, mono: 1)
        if not str(film.rfilter()).startswith("BoxFilter"):
            warnings.warn(f"scene {name!r}: pixel filter {str(film.rfilter()).split('[')[0]} is not a box filter; "
                          "Dr.Jit's multi-threaded splatting then makes renders differ slightly between identical "
                          "calls (we measured 6e-4 with a Gaussian filter), so FD with common random numbers and "
                          "resumed runs are not bit-reproducible. Use <rfilter type=\"box\"/> in the film.",
                          stacklevel=2)
        # AD integrators default to the primal integrator's path depth, so AD and FD differentiate the same image
        self.ad_defaults = dict(ad_integrator or {})
        for opt in ("max_depth", "rr_depth"):
            found = re.search(rf"{opt} = (-?\d+)", str(self.scene.integrator()))
            if found:
                self.ad_defaults.setdefault(opt, int(found.group(1)))
        self._ad_cache: dict = {}
        self._applied: np.ndarray | None = None
        # every file the scene loads (includes and $-named meshes too), as Mitsuba's parser finds them
        self._hash = content_hash(self.scene_file, {k: str(v) for k, v in self.defines.items()}, self.variant)
        self._renderer = FrozenRender(freeze_default(freeze), label=f"scene {name!r}")

    def _load(self, name: str):
        """The Mitsuba scene from the scene file (without `remove`'s elements); SceneError when it does not load.
        optimize=False: merging meshes orders shapes and emitters differently in each process, which breaks
        "same (θ, spp, seed) → same image" across worker processes."""
        import mitsuba as mi

        try:
            if self.remove:
                return mi.load_string(pruned_xml(self.scene_file, self.remove), optimize=False, **self.defines)
            return mi.load_file(str(self.scene_file), optimize=False, **self.defines)
        except RuntimeError as e:  # Mitsuba's parser: invalid XML, unknown plugin, missing asset, bad define
            stop = interrupts.interrupt_in(e)
            if stop is not None:
                raise stop from None
            raise SceneError(f"scene {name!r}: {self.scene_file} does not load: {_first_line(e)}") from None

    @property
    def channels(self) -> int:
        """C of the film's developed image: 3 for RGB variants, 1 for mono ones (alpha included where the film
        has one). A path sample adds to every channel of its pixel."""
        return self._channels

    @property
    def freeze(self) -> bool:
        """Whether primal passes render through the frozen function (settable; see `passes.py`)."""
        return self._renderer.enabled

    @freeze.setter
    def freeze(self, on: bool) -> None:
        self._renderer.enabled = bool(on)

    @property
    def backend(self) -> str:
        """'llvm' (CPU) or 'cuda' (GPU): the Dr.Jit backend of this model's variant."""
        return backend_of(self.variant)

    # -- θ → scene ----------------------------------------------------------------------------
    def _apply(self, theta: np.ndarray) -> None:
        if self._applied is not None and np.array_equal(self._applied, theta):
            return
        import drjit as dr
        import mitsuba as mi

        # opaque θ: the scene holds evaluated values (not literals), so a new θ never re-records the frozen render
        values = [dr.opaque(mi.Float, float(v)) for v in theta]
        if self.backend == "llvm":
            # the update on one thread: in parallel, recomputing a moved mesh's vertex normals (and its
            # acceleration structure) varied in the last bit of a few values from call to call, so the same
            # (θ, spp, seed) gave images differing in 2 of 3600 pixels in a third of runs (pi_hallway's teapot)
            threads = dr.thread_count()
            dr.set_thread_count(1)
            try:
                self.binder.apply(self._params, values)
            finally:
                dr.set_thread_count(threads)
        else:
            self.binder.apply(self._params, values)
        self._applied = theta.copy()

    def _passes(self, spp: int, seed: int):
        W, H = self.size
        return [(s, derive(seed, "pass", i)) for i, s in enumerate(split_spp(spp, W * H, self.max_pass_samples))]

    def _render(self, theta: np.ndarray, spp: int, seed: int) -> torch.Tensor:
        """Image (H, W, C) float32: θ written traced, then the passes (frozen unless `freeze` is off).
        Ctrl-C takes effect between passes (Python raises KeyboardInterrupt when `mi.render` returns)."""
        self._apply(theta)
        passes = self._passes(spp, seed)
        if len(passes) == 1:
            return torch.from_numpy(np.asarray(self._renderer(self.scene, spp, passes[0][1])))
        acc = 0.0
        for s, pass_seed in passes:
            acc = acc + np.asarray(self._renderer(self.scene, s, pass_seed), dtype=np.float64) * (s / spp)
        return torch.from_numpy(acc.astype(np.float32))

    # -- AD ------------------------------------------------------------------------------------
    def ad_integrator(self, indices=None, **options):
        """A (cached) Mitsuba AD integrator: `type` in prb / direct_projective / prb_projective, plus
        its options (max_depth, sppc, sppp, sppi, guiding, ...). Without a `type`, parameters `indices`
        (default all) that move geometry get `prb_projective` (visibility-aware), others `prb`."""
        import mitsuba as mi

        opts = {**self.ad_defaults, **options}
        if "type" not in opts:
            kinds = [self.binder.bindings[j].kind for j in (range(len(self.params)) if indices is None else indices)]
            opts["type"] = "prb_projective" if any(k in GEOMETRY_KINDS for k in kinds) else "prb"
        if opts.get("type") not in AD_INTEGRATORS:
            raise ValueError(f"AD integrator must be one of {list(AD_INTEGRATORS)}, got {opts.get('type')!r}")
        key = tuple(sorted(opts.items()))
        if key not in self._ad_cache:
            integ = mi.load_dict(opts)
            # our scenes keep moving objects inside the view; scenes where they leave it set sample_border
            if hasattr(integ, "sample_border_warning"):
                integ.sample_border_warning = False
            self._ad_cache[key] = integ
        return self._ad_cache[key]

    @contextlib.contextmanager
    def _untracked_after(self, theta: np.ndarray):
        """Leave the scene holding θ untracked after AD passes, however they end: a scene left with grad-enabled
        values breaks another scene's forward-mode AD in the same process (Dr.Jit: "tried to forward-propagate
        derivatives across edge … outside of the current dr.isolate_grad() scope", measured after a `vjp`)."""
        try:
            yield
        finally:
            self._apply(theta)

    def _ad_pass(self, theta: np.ndarray, spp: int, seed: int, pass_seed_index: int, integrator, grad_index=None):
        """Render one AD pass with θ tracked; returns (image, θ variables)."""
        import drjit as dr
        import mitsuba as mi

        th = [mi.Float(float(v)) for v in theta]
        for j, t in enumerate(th):
            if grad_index is None or j == grad_index:
                dr.enable_grad(t)
        self.binder.apply(self._params, th)
        self._applied = None  # the scene now holds tracked values: `_untracked_after` re-applies θ
        img = mi.render(self.scene, self._params, integrator=integrator, spp=spp,
                        seed=derive(seed, "pass", pass_seed_index),
                        seed_grad=derive(seed, "seed_grad", pass_seed_index))
        return img, th

    def vjp(self, theta, grad_out: torch.Tensor, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        """As ForwardModel.vjp; `indices` (default all) are the parameters whose gradient is wanted,
        so a colour-only gradient gets `prb` even when other parameters move geometry."""
        import drjit as dr
        import mitsuba as mi

        t = self.params.validate(theta)
        spp, seed = check_spp_seed(spp, seed)
        integ = self.ad_integrator(indices, **ad)
        go = np.ascontiguousarray(grad_out.detach().cpu().numpy(), dtype=np.float32)
        total = np.zeros(len(t))
        with self._untracked_after(t):
            for i, (s, _) in enumerate(self._passes(spp, seed)):
                img, th = self._ad_pass(t, s, seed, i, integ)
                dr.backward(img * mi.TensorXf(go * (s / spp)))
                total += np.array([float(dr.grad(x)[0]) for x in th])
                self.stats.grad_passes += 1
        self.check_finite(torch.from_numpy(total), t, spp, seed, what="AD gradient")
        return total

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        import drjit as dr

        t = self.params.validate(theta)
        spp, seed = check_spp_seed(spp, seed)
        integ = self.ad_integrator([index], **ad)
        acc = None
        with self._untracked_after(t):
            for i, (s, _) in enumerate(self._passes(spp, seed)):
                img, th = self._ad_pass(t, s, seed, i, integ, grad_index=index)
                dr.forward(th[index])
                d = np.asarray(dr.grad(img), dtype=np.float64) * (s / spp)
                acc = d if acc is None else acc + d
                self.stats.grad_passes += 1
        out = torch.from_numpy(acc.astype(np.float32))
        self.check_finite(out, t, spp, seed, what=f"AD derivative image d/d{self.params.names[index]}")
        return out

    def content_key(self) -> dict:
        """Everything besides (θ, spp, seed) that changes an image: scene content (a hash over every file the
        scene loads, `scene_files.content_hash`), defines, removed
        ids, variant, the primal integrator's settings, the bindings, the pass size (it decides the pass
        split, hence the random numbers), the Mitsuba and Dr.Jit versions, and under `render` what else decides
        the bits (`identity.render_identity`: the LLVM target, libLLVM, the host's ISA). Freezing is not in it:
        the frozen and traced paths give the same image (bit for bit on the CPU)."""
        import drjit as dr
        import mitsuba as mi

        key = {"scene": self._hash, "defines": self.defines, "variant": self.variant,
               "integrator": str(self.scene.integrator()), "params": [repr(b) for b in self.binder.bindings],
               "max_pass_samples": self.max_pass_samples, "mitsuba": mi.__version__, "drjit": dr.__version__,
               "render": render_identity()}
        return {**key, "remove": self.remove} if self.remove else key
