"""Gradient images ∂L/∂θ_j (H, W, C) from one backend at several seeds, with their cost.

A backend is a `GradientSettings`: AD (forward mode, `model.jvp`) with a Mitsuba integrator and its
options, or FD (central, step ξ, R rounds, with or without common random numbers). `backend(spec)`
builds one from a config mapping such as `{method: ad, integrator: prb_projective, sppi: 0}` or
`{method: fd, step: 0.01, rounds: 4, crn: true}`.

Mitsuba 3.9 note: the projective integrators' `sppc` / `sppp` / `sppi` (samples for the continuous,
primary-visibility and indirect-visibility terms) are overridden by the spp of each render, except
that 0 switches a term off; `guiding` (none / grid / octree) and `guiding_rounds` shape the indirect
term. With octree guiding a 32×32 pass takes ~20 s on 2 CPU cores (guiding construction), with
`guiding: none` ~1 s, and `sppi: 0` drops indirect visibility (shadows) altogether.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..forward.bindings import GEOMETRY_KINDS
from ..forward.gradients import GradientSettings, jacobian
from ..forward.mitsuba_model import AD_INTEGRATORS
from ..forward.model import ForwardModel
from .cost import Cost, measure

#: options a Mitsuba AD integrator accepts here (besides `type`)
AD_OPTIONS = ("max_depth", "rr_depth", "sppc", "sppp", "sppi", "guiding", "guiding_proj", "guiding_rounds")
FD_OPTIONS = ("step", "rounds", "crn")


def backend(spec: dict) -> GradientSettings:
    """GradientSettings from `{method: ad, integrator: ..., <AD options>}` (no integrator: the model's
    choice, e.g. exact autograd for the analytic toys) or `{method: fd, step, rounds, crn}`.

    Examples
    --------
    >>> s = nb.diagnostics.backend({"method": "fd", "step": 0.01, "rounds": 4, "crn": True})
    >>> s.method, s.step, s.rounds, s.crn
    ('fd', 0.01, 4, True)
    >>> nb.diagnostics.backend({"method": "ad", "integrator": "prb", "sppi": 0}).ad
    {'type': 'prb', 'sppi': 0}
    """
    spec = dict(spec)
    method = spec.pop("method", None)
    if method == "ad":
        integ = spec.pop("integrator", None)
        if integ is not None and integ not in AD_INTEGRATORS:
            raise ValueError(f"AD backend: integrator must be one of {list(AD_INTEGRATORS)}, got {integ!r}")
        bad = sorted(set(spec) - set(AD_OPTIONS))
        if bad:
            raise ValueError(f"AD backend: unknown option(s) {bad}; known: {list(AD_OPTIONS)}")
        return GradientSettings("ad", ad=({"type": integ} if integ else {}) | spec)
    if method == "fd":
        bad = sorted(set(spec) - set(FD_OPTIONS))
        if bad:
            raise ValueError(f"FD backend: unknown option(s) {bad}; known: {list(FD_OPTIONS)}")
        return GradientSettings("fd", **spec)
    raise ValueError(f"a backend needs method 'ad' or 'fd', got {method!r}")


def spec_of(settings: GradientSettings) -> dict:
    """The config mapping that `backend` turns back into `settings` (JSON-serialisable).

    Examples
    --------
    >>> spec = {"method": "ad", "integrator": "prb_projective", "sppi": 0}
    >>> nb.diagnostics.spec_of(nb.diagnostics.backend(spec)) == spec
    True
    """
    if settings.method == "fd":
        step = settings.step if np.isscalar(settings.step) else list(settings.step)
        return {"method": "fd", "step": step, "rounds": settings.rounds, "crn": settings.crn}
    ad = dict(settings.ad)
    integ = ad.pop("type", None)
    return {"method": "ad", **({"integrator": integ} if integ else {}), **ad}


def label(settings: GradientSettings) -> str:
    """A short unique name, e.g. `fd(ξ=0.01,R=4,crn)`, `ad:prb_projective(guiding=none,sppi=0)`,
    `mixed(ad[2]=ad:prb,fd(ξ=0.01,R=1,crn))` or `auto`.

    Examples
    --------
    >>> nb.diagnostics.label(nb.diagnostics.backend({"method": "fd", "step": 0.01, "rounds": 4, "crn": True}))
    'fd(ξ=0.01,R=4,crn)'
    """
    if settings.method == "auto":
        return "auto"
    if settings.method == "mixed":
        fd, ad = replace(settings, method="fd", ad_params=()), replace(settings, method="ad", ad_params=())
        return f"mixed(ad{list(settings.ad_params)}={label(ad)},{label(fd)})"
    if settings.method == "fd":
        step = "/".join(f"{x:g}" for x in np.atleast_1d(settings.step))
        return f"fd(ξ={step},R={settings.rounds},{'crn' if settings.crn else 'no-crn'})"
    opts = {k: v for k, v in settings.ad.items() if k != "type"}
    inner = ",".join(f"{k}={v}" for k, v in sorted(opts.items()))
    return f"ad:{settings.ad.get('type', 'auto')}" + (f"({inner})" if inner else "")


def _binding(model: ForwardModel, index: int):
    """(binding, primal max_depth) of parameter `index` of a Mitsuba model (also seen through
    `restrict`); (None, None) for models without scene bindings (the analytic toys)."""
    base, j = (model.base, model.index[index]) if hasattr(model, "base") else (model, index)
    binder = getattr(base, "binder", None)
    if binder is None:
        return None, None
    return binder.bindings[j], getattr(base, "ad_defaults", {}).get("max_depth")


def param_kind(model: ForwardModel, index: int) -> str | None:
    """Binding kind of parameter `index` (translate, path, radius, reflectance, radiance) or None.

    Examples
    --------
    >>> model = nb.scenes.get("cornell_ball", defines={"res": 8})
    >>> [nb.diagnostics.param_kind(model, j) for j in range(3)]
    ['translate', 'radius', 'reflectance']
    >>> nb.diagnostics.param_kind(nb.scenes.get("blob2d"), 0) is None  # an analytic toy has no scene bindings
    True
    """
    b, _ = _binding(model, index)
    return b.kind if b is not None else None


def applicable_integrators(model: ForwardModel, index: int) -> dict[str, str]:
    """AD integrators for parameter `index` → '' when applicable, else why not. Geometry moves
    silhouettes, which `prb` does not differentiate; `direct_projective` differentiates direct
    illumination only, so it matches the primal image only when the path depth is ≤ 2.

    Examples
    --------
    >>> model = nb.scenes.get("cornell_ball", defines={"res": 8})
    >>> why = nb.diagnostics.applicable_integrators(model, 0)  # ball_x moves a silhouette
    >>> why["prb_projective"], why["prb"]
    ('', 'ignores visibility changes (silhouettes, shadows) of a moving/resizing object')
    """
    b, depth = _binding(model, index)
    if b is None:
        return {}
    out = {name: "" for name in AD_INTEGRATORS}
    if b.kind in GEOMETRY_KINDS:
        out["prb"] = "ignores visibility changes (silhouettes, shadows) of a moving/resizing object"
    if depth is None or depth < 0 or depth > 2:
        out["direct_projective"] = f"direct illumination only; the primal path depth is {depth}"
    return out


@dataclass
class GradientRun:
    """S gradient images (S, H, W, C) float32 of one backend at one spp, one per seed, with the wall
    seconds and peak RSS increase of each, and the renders / AD passes they took.

    Examples
    --------
    >>> import numpy as np
    >>> fd = nb.diagnostics.backend({"method": "fd", "step": 0.01, "rounds": 1})
    >>> run = nb.diagnostics.gradient_images(nb.scenes.get("blob2d"), [0.5, 0.5], 1, fd, spp=4, seeds=[1, 2, 3])
    >>> run.images.shape, run.renders  # a central difference per seed: 2 renders each
    ((3, 24, 24, 1), 6)
    >>> run.seconds == float(np.median([c.seconds for c in run.costs[1:]]))  # the first seed's is a cold start
    True
    """

    images: np.ndarray
    seeds: list[int]
    costs: list[Cost] = field(default_factory=list)
    renders: int = 0
    grad_passes: int = 0

    @property
    def seconds(self) -> float:
        """Warm wall time per image: the median over seeds after the first (which includes JIT compilation)."""
        return warm([c.seconds for c in self.costs])

    @property
    def peak_bytes(self) -> int:
        """Warm peak RSS increase per image: the largest after the first (which includes compilation)."""
        return max((c.peak_bytes for c in self.costs[1:] or self.costs), default=0)


def warm(values: Sequence[float]) -> float:
    """Median of `values` without the first (a cold start) when there are at least two."""
    v = list(values)
    return float(np.median(v[1:] if len(v) > 1 else v))


def gradient_images(model: ForwardModel, theta, index: int, settings: GradientSettings, spp: int,
                    seeds: Sequence[int]) -> GradientRun:
    """∂L/∂θ_index by `settings` at `spp`, once per seed (seeds chosen by the caller, e.g. derived).

    Examples
    --------
    AD and FD agree on the analytic blob:

    >>> import numpy as np
    >>> model, specs = nb.scenes.get("blob2d"), ({"method": "ad"}, {"method": "fd", "step": 1e-4})
    >>> ad, fd = (nb.diagnostics.gradient_images(model, [0.5, 0.5], 0, nb.diagnostics.backend(spec), 4, [1, 2])
    ...           for spec in specs)
    >>> ad.images.shape, ad.grad_passes, fd.renders
    ((2, 24, 24, 1), 2, 4)
    >>> bool(np.allclose(ad.images, fd.images, atol=1e-3 * np.abs(ad.images).max()))
    True
    """
    before = model.stats.snapshot()
    imgs, costs = [], []
    for s in seeds:
        with measure() as c:
            imgs.append(jacobian(model, theta, spp, s, settings, indices=[index])[0].numpy())
        costs.append(c)
    used = model.stats.since(before)
    return GradientRun(np.stack(imgs), list(seeds), costs, used.renders, used.grad_passes)


def forward_cost(model: ForwardModel, theta, spp: int, seeds: Sequence[int]) -> Cost:
    """Warm cost of one forward render at `spp`: like GradientRun, median seconds and largest peak
    after the first seed.

    Examples
    --------
    >>> cost = nb.diagnostics.forward_cost(nb.scenes.get("blob2d"), [0.5, 0.5], spp=4, seeds=[1, 2, 3])
    >>> type(cost).__name__, cost.seconds > 0
    ('Cost', True)
    """
    costs = []
    for s in seeds:
        with measure() as c:
            model.render(theta, spp, s)
        costs.append(c)
    return Cost(warm([c.seconds for c in costs]), max(c.peak_bytes for c in costs[1:] or costs), costs[0].method)
