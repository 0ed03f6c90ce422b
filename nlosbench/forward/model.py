"""ForwardModel: θ ↦ image L_θ (H, W, C) float32, rendered with `spp` samples per pixel and a seed.

Subclasses implement `_render` (the image), `jvp` (derivative image along one parameter, by AD or
exactly) and `vjp` (gradient of ⟨grad_out, L_θ⟩ w.r.t. θ). This base class validates inputs, counts
renders and time, checks for NaN/Inf, and consults the optional on-disk cache.
"""
from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import torch

from ..binning import bin_image, check_bin
from ..params import ParamSpace
from .cache import RenderCache, render_key


class RenderError(RuntimeError):
    """A render produced NaN or Inf; the message names scene, θ, spp and seed.

    Examples
    --------
    >>> import torch
    >>> toy = nb.scenes.get("edge1d")
    >>> toy._render = lambda theta, spp, seed: torch.full((1, 4, 1), float("nan"))  # a renderer gone wrong
    >>> toy.render([0.5], spp=4, seed=7)
    Traceback (most recent call last):
    nlosbench.forward.model.RenderError: render of scene 'edge1d' has 4 NaN/Inf value(s) at θ={'edge': 0.5}, ...
    """


@dataclass
class RenderStats:
    """Work done by a model: primal renders, derivative passes, pixel samples and wall seconds."""

    renders: int = 0
    grad_passes: int = 0
    samples: int = 0
    seconds: float = 0.0

    def snapshot(self) -> RenderStats:
        return RenderStats(self.renders, self.grad_passes, self.samples, self.seconds)

    def __add__(self, o: RenderStats) -> RenderStats:
        return RenderStats(self.renders + o.renders, self.grad_passes + o.grad_passes, self.samples + o.samples,
                           self.seconds + o.seconds)

    def since(self, before: RenderStats) -> RenderStats:
        return RenderStats(self.renders - before.renders, self.grad_passes - before.grad_passes,
                           self.samples - before.samples, self.seconds - before.seconds)


def check_spp_seed(spp: int, seed: int) -> tuple[int, int]:
    if isinstance(spp, bool) or int(spp) != spp or spp < 1:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(spp), int(seed)


class ForwardModel(ABC):
    """A scene with a parameter space. `render(θ, spp, seed)` gives the same image for the same
    arguments and independent rendering noise for different seeds.

    Parameters
    ----------
    name : str
        The scene's name (in messages, keys and records).
    params : ParamSpace
        The parameter space Θ; θ vectors follow its order and units.
    cache : RenderCache, str, os.PathLike or None, optional
        An on-disk render cache, or the folder of one; None renders every time.

    Examples
    --------
    A model of your own: an exact 1 × 8 ramp whose slope is θ:

    >>> import numpy as np, torch
    >>> class Ramp(nb.ForwardModel):
    ...     exact, channels = True, 1
    ...     def __init__(self):
    ...         super().__init__("ramp", nb.ParamSpace([nb.Param("slope", 0.0, 2.0, 1.0, units="1")]))
    ...     def _render(self, theta, spp, seed):
    ...         return float(theta[0]) * self.jvp(theta, 0, spp, seed)
    ...     def jvp(self, theta, index, spp, seed, **ad):
    ...         return torch.linspace(0, 1, 8).reshape(1, 8, 1)
    ...     def vjp(self, theta, grad_out, spp, seed, indices=None, **ad):
    ...         return np.array([float((grad_out * self.jvp(theta, 0, spp, seed)).sum())])
    ...     def content_key(self):
    ...         return {"scene": "ramp"}
    >>> model = Ramp()
    >>> model.render([0.5], spp=1, seed=0).shape, model.stats.renders
    (torch.Size([1, 8, 1]), 1)
    >>> model.render([3.0], spp=1, seed=0)
    Traceback (most recent call last):
    ValueError: θ out of range: slope=3 outside [0, 2] 1
    """

    name: str
    params: ParamSpace
    #: True when the image has no rendering noise (then spp and seed do not change it)
    exact: bool = False

    def __init__(self, name: str, params: ParamSpace, cache: RenderCache | str | None = None):
        self.name = name
        self.params = params
        self.cache = RenderCache(cache) if isinstance(cache, (str, bytes)) or hasattr(cache, "__fspath__") else cache
        self.stats = RenderStats()

    @property
    def channels(self) -> int:
        """C, the values per pixel of an image (H, W, C). A pixel's C values come from the same light paths, so
        their rendering errors are correlated: every standard error over images sums them before it treats
        pixels as independent (`bounds.ustat`). Subclasses say how many their images have."""
        raise NotImplementedError(f"{type(self).__name__} does not say how many channels its images have")

    # -- subclass contract -------------------------------------------------------------------
    @abstractmethod
    def _render(self, theta: np.ndarray, spp: int, seed: int) -> torch.Tensor:
        """Image (H, W, C) float32 for a validated θ (float64 (P,))."""

    @abstractmethod
    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        """∂L/∂θ_index as an image (H, W, C) float32 (forward-mode AD, or exact).

        Parameters
        ----------
        theta : array_like
            θ, P values in parameter units.
        index : int
            The component of θ to differentiate along.
        spp : int
            Samples per pixel of the derivative render.
        seed : int
            Render seed (non-negative).
        **ad
            Options for the AD integrator (e.g. type, max_depth).

        Returns
        -------
        torch.Tensor
            The derivative image (H, W, C) float32, in image units per parameter unit.
        """

    @abstractmethod
    def vjp(self, theta, grad_out: torch.Tensor, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        """Σ_ω grad_out(ω) ∂L(ω)/∂θ as float64 (P,) (reverse-mode AD, or exact); `indices` names the
        components the caller needs (a model may use it to pick a cheaper method; all P are returned).

        Parameters
        ----------
        theta : array_like
            θ, P values in parameter units.
        grad_out : torch.Tensor
            The image-space cotangent, shaped like the image (H, W, C).
        spp : int
            Samples per pixel of the derivative render.
        seed : int
            Render seed (non-negative).
        indices : sequence of int, optional
            The components of θ the caller needs; None: all.
        **ad
            Options for the AD integrator (e.g. type, max_depth).

        Returns
        -------
        numpy.ndarray
            The gradient, float64 (P,), per parameter unit.
        """

    @abstractmethod
    def content_key(self) -> dict:
        """What defines this model's images besides (θ, spp, seed): scene hash, variant, settings."""

    # -- shared behaviour --------------------------------------------------------------------
    def render(self, theta, spp: int, seed: int) -> torch.Tensor:
        """L_θ as a float32 tensor (H, W, C); θ in the units of `params` (metres for positions).

        Validated, counted in `stats`, checked for NaN/Inf and read from or written to the cache.

        Parameters
        ----------
        theta : array_like or torch.Tensor
            θ, P values in parameter units, inside Θ.
        spp : int
            Samples per pixel (≥ 1).
        seed : int
            Render seed (≥ 0); the same arguments give the same image.

        Returns
        -------
        torch.Tensor
            The image (H, W, C) float32.

        Raises
        ------
        RenderError
            If the image has NaN or Inf values.

        Examples
        --------
        >>> model = nb.scenes.get("blob2d")
        >>> model.render(model.params.default, spp=4, seed=0).shape
        torch.Size([24, 24, 1])
        """
        t = self.params.validate(theta)
        spp, seed = check_spp_seed(spp, seed)
        key = None
        if self.cache is not None:
            key = render_key(model=self.content_key(), theta=[repr(float(v)) for v in t], spp=spp, seed=seed)
            hit = self.cache.get(key)
            if hit is not None:
                return hit
        start = time.perf_counter()
        img = self._render(t, spp, seed)
        self.stats.seconds += time.perf_counter() - start
        self.stats.renders += 1
        self.stats.samples += spp * int(np.prod(img.shape[:2]))
        self.check_finite(img, t, spp, seed, what="render")
        if key is not None:
            self.cache.put(key, img)
        return img

    def check_finite(self, img: torch.Tensor, theta, spp: int, seed: int, what: str) -> None:
        """RenderError unless `img` is finite; the message names the scene, θ, spp and seed.

        Parameters
        ----------
        img : torch.Tensor
            The image (or derivative image) to check.
        theta : array_like
            θ it was rendered at, in parameter units.
        spp : int
            Its samples per pixel.
        seed : int
            Its render seed.
        what : str
            What was rendered, for the message (e.g. "render", "jvp").

        Raises
        ------
        RenderError
            If `img` has NaN or Inf values.
        """
        if not bool(torch.isfinite(img).all()):
            n = int((~torch.isfinite(img)).sum())
            raise RenderError(
                f"{what} of scene {self.name!r} has {n} NaN/Inf value(s) at "
                f"θ={dict(zip(self.params.names, np.asarray(theta).tolist(), strict=True))}, spp={spp}, seed={seed}"
            )

    def restrict(self, names, fixed: dict | None = None) -> ForwardModel:
        """This model seen through parameters `names` only; the others held at `fixed` or their defaults.

        Parameters
        ----------
        names : sequence of str
            The parameters left free, in the restricted θ's order.
        fixed : dict, optional
            {name: value} for held parameters, in parameter units; the others at their defaults.

        Returns
        -------
        ForwardModel
            A model of θ restricted to `names`; renders and stats go to this model.
        """
        return Restricted(self, names, fixed)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self.params!r})"


class Restricted(ForwardModel):
    """`base` seen through the parameters `names` only; the rest stay at `fixed` (default: defaults).

    Renders, derivatives and stats go to the base model (one scene load, one render counter)."""

    def __init__(self, base: ForwardModel, names, fixed: dict | None = None):
        self.base = base
        self.index = [base.params.index(n) for n in names]
        full = base.params.default.copy()
        for k, v in (fixed or {}).items():
            full[base.params.index(k)] = v
        self.full = base.params.validate(full)
        super().__init__(base.name, base.params.subset(names), None)
        self.stats = base.stats
        self.exact = base.exact

    @property
    def channels(self) -> int:
        return self.base.channels

    def expand(self, theta) -> np.ndarray:
        """Full θ (float64) from the restricted θ."""
        t = self.full.copy()
        t[self.index] = self.params.validate(theta)
        return t

    def render(self, theta, spp: int, seed: int) -> torch.Tensor:
        return self.base.render(self.expand(theta), spp, seed)

    def _render(self, theta, spp, seed):  # render() is delegated whole, with the base's cache
        raise NotImplementedError

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        return self.base.jvp(self.expand(theta), self.index[index], spp, seed, **ad)

    def vjp(self, theta, grad_out, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        wanted = self.index if indices is None else [self.index[j] for j in indices]
        return self.base.vjp(self.expand(theta), grad_out, spp, seed, indices=wanted, **ad)[self.index]

    def content_key(self) -> dict:
        return {"base": self.base.content_key(), "index": self.index, "fixed": self.full.tolist()}


class Binned(ForwardModel):
    """`base` seen by a sensor b× coarser per side at a fixed photon budget: `render(θ, spp, seed)` is the
    b×b block mean of `base.render(θ, spp // b², seed)` — the spp samples of one coarse pixel spread over
    its b² fine pixels — an image (H/b, W/b, C). Derivatives are binned the same way; spp must be a
    multiple of b², and H, W multiples of b. Renders, derivatives and stats go to the base model."""

    def __init__(self, base: ForwardModel, b: int):
        self.base, self.b = base, check_bin(b)
        super().__init__(f"{base.name}-bin{self.b}", base.params, None)
        self.stats = base.stats
        self.exact = base.exact

    @property
    def channels(self) -> int:
        return self.base.channels

    def _fine_spp(self, spp: int) -> int:
        spp, _ = check_spp_seed(spp, 0)
        if spp % (self.b * self.b):
            raise ValueError(
                f"a {self.b}×{self.b}-binned sensor needs spp divisible by b² = {self.b * self.b}, got {spp}"
            )
        return spp // (self.b * self.b)

    def _bin(self, img: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(bin_image(img, self.b).astype(np.float32))

    def render(self, theta, spp: int, seed: int) -> torch.Tensor:
        return self._bin(self.base.render(theta, self._fine_spp(spp), seed))

    def _render(self, theta, spp, seed):  # render() is delegated whole, with the base's cache
        raise NotImplementedError

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        return self._bin(self.base.jvp(theta, index, self._fine_spp(spp), seed, **ad))

    def vjp(self, theta, grad_out, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        """⟨grad_out, binned L⟩ = ⟨grad_out spread over each block / b², L⟩."""
        fine = grad_out.repeat_interleave(self.b, dim=0).repeat_interleave(self.b, dim=1) / (self.b * self.b)
        return self.base.vjp(theta, fine, self._fine_spp(spp), seed, indices=indices, **ad)

    def content_key(self) -> dict:
        return {"base": self.base.content_key(), "bin": self.b}
