"""Noise models: observations Y of an image with mean radiance L (independent pixels).

Every model implements sampling, the negative log-likelihood, the χ² exponent
λ with χ²(p_L1 ‖ p_L0) = exp(λ) − 1 (the HCR bound's divergence), the Barankin Gram exponent
log E_L0[ℓ_i ℓ_j] (ℓ = likelihood ratio p_Li / p_L0) and the per-pixel Fisher information.
Divergences and information are float64 and use direct differences L1 − L0.

The two built-in models are *quadratic*: all three quantities are Σ_ω w(L0)·(·)(·) for a per-pixel
weight w (AWGN: 1/σ², Poisson: scale/L0). A new model (e.g. Poisson + Gaussian read noise)
subclasses `NoiseModel` (or `QuadraticNoise` when its χ² exponent has that form) and registers
itself with `@register("name")`, or is installed as a plug-in: an entry point in the group
`nlosbench.noise` (name → the class), which `get` loads on first use. `get(name, **kw)` builds it; a config
names it as `noise: [{model: NAME, options: {...}}]`.

The bounds from replicated renders (the bound service) need a quadratic model: `bounds_refusal` says why
another model is refused. A quadratic model declares `signal_dependent` (default True): whether its weight
w(L0) depends on the mean image; the bound service then takes w from a render of θ independent of the
replicates it weights (a weight from the same renders would correlate with the U-statistics).
"""
from __future__ import annotations

import difflib
import importlib.metadata
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from .binning import check_bin


def to_float64(x, what: str = "input") -> torch.Tensor:
    """`x` (tensor, numpy array or memmap, any float dtype) as a float64 torch tensor (same device).

    Parameters
    ----------
    x : torch.Tensor or array_like
        The values (a tensor is detached).
    what : str, default "input"
        Its name, for the error message.

    Returns
    -------
    torch.Tensor
        `x` as float64, same shape.

    Raises
    ------
    ValueError
        If `x` is not numeric.

    Examples
    --------
    >>> import numpy as np
    >>> nb.noise.to_float64(np.array([0.1, 0.2], dtype=np.float32)).dtype
    torch.float64
    >>> nb.noise.to_float64("bright", "L")
    Traceback (most recent call last):
    ValueError: L: not a numeric array (could not convert string to float: 'bright')
    """
    if isinstance(x, torch.Tensor):
        return x.detach().to(torch.float64)
    try:
        return torch.as_tensor(np.asarray(x, dtype=np.float64))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: not a numeric array ({e})") from None


def check_finite(x: torch.Tensor, what: str) -> None:
    """Raise ValueError naming `what` if `x` holds NaN or ±Inf.

    Parameters
    ----------
    x : torch.Tensor
        The values to check.
    what : str
        Their name, for the message (which also counts the NaN and Inf values and gives the first index).

    Raises
    ------
    ValueError
        If `x` holds NaN or ±Inf.

    Examples
    --------
    >>> import torch
    >>> nb.noise.check_finite(torch.tensor([1.0, float("nan"), float("inf")]), "L")
    Traceback (most recent call last):
    ValueError: L contains 1 NaN and 1 Inf values (first at index (1,))
    """
    bad = ~torch.isfinite(x)
    if bool(bad.any()):
        n_nan = int(torch.isnan(x).sum())
        first = tuple(int(i) for i in torch.nonzero(bad)[0]) if x.ndim else ()
        raise ValueError(f"{what} contains {n_nan} NaN and {int(bad.sum()) - n_nan} Inf values "
                         f"(first at index {first})")


class NoiseModel(ABC):
    """Observation model Y ~ p_L for an image of mean radiance L (shape *S, pixels independent).

    Subclasses implement `sample`, `nll`, `chi2_exponent`, `gram_exponent` and `fisher`, and register
    themselves with `register`.

    Examples
    --------
    A model from the registry, used as a study uses it:

    >>> import torch
    >>> noise = nb.noise.get("poisson", scale=50.0)
    >>> isinstance(noise, nb.noise.NoiseModel), noise.signal_dependent
    (True, True)
    >>> L = torch.full((2, 2), 0.5)
    >>> y = noise.sample(L, torch.Generator().manual_seed(0))
    >>> bool(((50 * y).round() - 50 * y).abs().max() < 1e-4)  # photon counts, reported in radiance units
    True
    >>> float(noise.fisher(L, torch.ones(2, 2)).sum())  # 4 pixels of scale / L
    400.0
    """

    name: ClassVar[str] = ""
    #: chi2_exponent(L0, L1) == chi2_exponent(L1, L0) for every pair (pairwise λ then computes half)
    symmetric: ClassVar[bool] = False
    #: whether a quadratic model's weight w(L0) depends on L0: the bound service then computes w from an
    #: independent render of each θ (one render more per θ). False only for a weight that is the same for every
    #: image (AWGN).
    signal_dependent: ClassVar[bool] = True

    def validate(self, L: torch.Tensor, what: str) -> None:
        """Raise ValueError naming `what` if `L` is not a valid mean image (default: finite).

        Parameters
        ----------
        L : torch.Tensor
            A mean image (*S), radiance units.
        what : str
            Its name, for the message.

        Raises
        ------
        ValueError
            If `L` is not a valid mean of this model.
        """
        check_finite(L, what)

    @abstractmethod
    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """One noisy observation y of the image L, same shape and dtype, in radiance units.

        Parameters
        ----------
        L : torch.Tensor
            The mean image (*S), radiance units.
        generator : torch.Generator
            The random source.

        Returns
        -------
        torch.Tensor
            y, shaped and typed like L.
        """

    @abstractmethod
    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """−log p_L(y) up to an L-independent constant: float64 scalar, differentiable in L.

        Parameters
        ----------
        y : torch.Tensor or array_like
            An observation (*S), radiance units.
        L : torch.Tensor
            The mean image (*S), radiance units.

        Returns
        -------
        torch.Tensor
            The negative log-likelihood, float64 0-dim.
        """

    @abstractmethod
    def chi2_exponent(self, L0, L1, check: bool = True) -> torch.Tensor:
        """λ = log(1 + χ²(p_L1 ‖ p_L0)), float64 ≥ 0 (+inf allowed).

        Parameters
        ----------
        L0 : torch.Tensor or array_like
            The reference mean image (*S), radiance units.
        L1 : torch.Tensor or array_like
            The alternative mean image(s) (*B, *S).
        check : bool, default True
            Validate the inputs; False skips it (for callers that validated once already).

        Returns
        -------
        torch.Tensor
            λ of shape (*B), float64 (0-dim without batch dims).
        """

    @abstractmethod
    def gram_exponent(self, L0, Li, Lj) -> torch.Tensor:
        """log E_L0[ℓ_i ℓ_j] with ℓ = p_L / p_L0: Li (A, *S) or (*S), Lj (B, *S) or (*S) → (A, B)
        (batch dims dropped where absent). The diagonal i = j equals `chi2_exponent`.

        Parameters
        ----------
        L0 : torch.Tensor or array_like
            The reference mean image (*S), radiance units.
        Li : torch.Tensor or array_like
            Mean images (A, *S) or (*S).
        Lj : torch.Tensor or array_like
            Mean images (B, *S) or (*S).

        Returns
        -------
        torch.Tensor
            The Gram exponents (A, B), float64 (+inf allowed).
        """

    @abstractmethod
    def fisher(self, L, dL) -> torch.Tensor:
        """Per-pixel Fisher information, float64. dL = ∂L/∂θ with the shape of L → (*S);
        dL of shape (P, *S) → (P, P, *S).

        Parameters
        ----------
        L : torch.Tensor or array_like
            The mean image (*S), radiance units.
        dL : torch.Tensor or array_like
            ∂L/∂θ, (*S) for one parameter or (P, *S), radiance units per parameter unit.

        Returns
        -------
        torch.Tensor
            The information per pixel, float64 (*S) or (P, P, *S); summed over pixels it is the Fisher
            matrix.
        """

    def variance(self, L) -> torch.Tensor:
        """Per-pixel variance of an observation of the image L (radiance², float64, broadcastable to L). The
        default, 1 / (Fisher information per unit dL²), is exact for exponential families in their mean
        (AWGN, Poisson); a model where it is not overrides this.

        Parameters
        ----------
        L : torch.Tensor
            The clean image (*S), radiance.

        Returns
        -------
        torch.Tensor
            The per-pixel variance, float64: σ² for AWGN, L/scale for Poisson.
        """
        L = to_float64(L, "L")
        return 1.0 / self.fisher(L, torch.ones_like(L))

    def binned(self, b: int) -> NoiseModel:
        """The model of one b×b-binned pixel whose value is the mean of the block's b² independent
        observations (radiance units; see `nlosbench.binning`). Models that support binning override this.

        Parameters
        ----------
        b : int
            The bin size per side.

        Returns
        -------
        NoiseModel
            The binned pixel's noise model.

        Raises
        ------
        NotImplementedError
            If the model does not define binning.
        """
        raise NotImplementedError(f"noise model {type(self).__name__} does not define binned(b)")

    def _inputs(self, check: bool, **arrays) -> list[torch.Tensor]:
        out = [to_float64(a, k) for k, a in arrays.items()]
        if check:
            for k, a in zip(arrays, out, strict=True):
                self.validate(a, k)
        return out


class QuadraticNoise(NoiseModel):
    """Models with λ = Σ_ω w(L0)(L1 − L0)², log E[ℓ_i ℓ_j] = Σ_ω w(L0)(Li − L0)(Lj − L0) and
    per-pixel Fisher information w(L)(∂L/∂θ)². A pixel with infinite weight contributes 0 where the
    difference (or derivative) is 0 and +inf otherwise — never NaN. Subclasses implement `weight` and
    declare `signal_dependent`.

    Examples
    --------
    Shot and read noise as a Gaussian of variance L/scale + read², a model the bound service can use:

    >>> import torch
    >>> class ShotRead(nb.noise.QuadraticNoise):
    ...     def __init__(self, scale, read):
    ...         self.scale, self.read = scale, read
    ...     def variance(self, L):
    ...         return L.clamp(min=0) / self.scale + self.read**2
    ...     def weight(self, L0):
    ...         return 1 / self.variance(L0)
    ...     def sample(self, L, generator):
    ...         return L + self.variance(L).sqrt() * torch.randn(L.shape, generator=generator, dtype=L.dtype)
    ...     def nll(self, y, L):
    ...         v = self.variance(L.double())
    ...         return 0.5 * ((y - L) ** 2 / v + v.log()).sum()
    >>> noise = ShotRead(scale=64.0, read=0.125)
    >>> L0 = torch.ones(4)
    >>> noise.chi2_exponent(L0, L0 + 0.125)  # 4 pixels of 0.125² / (1/64 + 0.125²)
    tensor(2., dtype=torch.float64)
    >>> nb.noise.bounds_refusal(noise), noise.signal_dependent
    ('', True)
    """

    @abstractmethod
    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        """Per-pixel weight w(L0) ≥ 0, float64, broadcastable to L0 (+inf allowed).

        Parameters
        ----------
        L0 : torch.Tensor
            The mean image (*S), float64, radiance units.

        Returns
        -------
        torch.Tensor
            w(L0), float64, broadcastable to L0, in 1 / radiance².
        """

    def _flat_weight(self, L0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(finite weight with 0 at infinite entries, mask of infinite entries), both flat (N,)."""
        w = self.weight(L0).expand(L0.shape).reshape(-1)
        inf = torch.isinf(w)
        return torch.where(inf, torch.zeros_like(w), w), inf

    def chi2_exponent(self, L0, L1, check: bool = True) -> torch.Tensor:
        """λ = Σ_ω w(L0)(L1 − L0)², float64 ≥ 0 (+inf where an infinite weight meets a difference).

        Parameters
        ----------
        L0 : torch.Tensor or array_like
            The reference mean image (*S), radiance units.
        L1 : torch.Tensor or array_like
            The alternative mean image(s) (*B, *S).
        check : bool, default True
            Validate the inputs; False skips it (for callers that validated once already).

        Returns
        -------
        torch.Tensor
            λ of shape (*B), float64 (0-dim without batch dims).
        """
        L0, L1 = self._inputs(check, L0=L0, L1=L1)
        D, batch = _differences(L0, L1, "L1")
        wf, inf = self._flat_weight(L0)
        hit = (D[:, inf] != 0).any(dim=1) if bool(inf.any()) else None
        lam = D.square_() @ wf
        if hit is not None:
            lam[hit] = math.inf
        return lam.reshape(batch)

    def gram_exponent(self, L0, Li, Lj) -> torch.Tensor:
        """log E_L0[ℓ_i ℓ_j] = Σ_ω w(L0)(Li − L0)(Lj − L0): Li (A, *S) or (*S), Lj (B, *S) or (*S) → (A, B)
        (batch dims dropped where absent).

        Parameters
        ----------
        L0 : torch.Tensor or array_like
            The reference mean image (*S), radiance units.
        Li : torch.Tensor or array_like
            Mean images (A, *S) or (*S).
        Lj : torch.Tensor or array_like
            Mean images (B, *S) or (*S).

        Returns
        -------
        torch.Tensor
            The Gram exponents (A, B), float64 (+inf allowed).
        """
        L0, Li, Lj = self._inputs(True, L0=L0, Li=Li, Lj=Lj)
        Di, bi = _differences(L0, Li, "Li")
        Dj, bj = _differences(L0, Lj, "Lj")
        wf, inf = self._flat_weight(L0)
        g = (Di * wf) @ Dj.T
        if bool(inf.any()):
            hit = (Di[:, inf] != 0).to(torch.float64) @ (Dj[:, inf] != 0).to(torch.float64).T
            g[hit > 0] = math.inf
        return g.reshape(bi + bj)

    def fisher(self, L, dL) -> torch.Tensor:
        """Per-pixel Fisher information w(L) ∂L/∂θ_i ∂L/∂θ_j, float64 (0 where the derivative is 0).

        Parameters
        ----------
        L : torch.Tensor or array_like
            The mean image (*S), radiance units.
        dL : torch.Tensor or array_like
            ∂L/∂θ, (*S) for one parameter or (P, *S), radiance units per parameter unit.

        Returns
        -------
        torch.Tensor
            The information per pixel, float64 (*S) or (P, P, *S).
        """
        (L,) = self._inputs(True, L=L)
        dL = to_float64(dL, "dL")
        check_finite(dL, "dL")
        if dL.shape == L.shape:
            return self.fisher(L, dL[None])[0, 0]
        if dL.shape[1:] != L.shape:
            raise ValueError(f"dL must have shape {tuple(L.shape)} or (P, {tuple(L.shape)}), "
                             f"got {tuple(dL.shape)}")
        prod = dL[:, None] * dL[None, :]
        return torch.where(prod == 0, torch.zeros_like(prod), prod * self.weight(L))


def _differences(L0: torch.Tensor, L1: torch.Tensor, what: str) -> tuple[torch.Tensor, tuple]:
    """Direct differences L1 − L0 flattened to (B, N) and the batch shape of L1."""
    nb = L1.ndim - L0.ndim
    if nb < 0 or tuple(L1.shape[nb:]) != tuple(L0.shape):
        raise ValueError(f"{what} must have shape (*batch, {tuple(L0.shape)}), got {tuple(L1.shape)}")
    batch = tuple(L1.shape[:nb])
    return (L1 - L0).reshape(math.prod(batch), -1), batch


_REGISTRY: dict[str, type[NoiseModel]] = {}
ENTRY_POINT_GROUP = "nlosbench.noise"
"""The entry-point group of noise-model plug-ins: name = "package.module:Class" (a NoiseModel subclass)."""


def register(name: str) -> Callable[[type[NoiseModel]], type[NoiseModel]]:
    """Class decorator adding a NoiseModel subclass to the registry under `name`.

    Parameters
    ----------
    name : str
        The name `get` builds it by (also set as the class's `name`).

    Returns
    -------
    callable
        The decorator; it returns the class unchanged.

    Examples
    --------
    >>> @nb.noise.register("awgn-variance")
    ... class AWGNVariance(nb.noise.AWGN):
    ...     "AWGN given by its variance."
    ...     def __init__(self, variance):
    ...         super().__init__(sigma=variance**0.5)
    >>> nb.noise.get("awgn-variance", variance=0.25), AWGNVariance.name
    (AWGNVariance(sigma=0.5), 'awgn-variance')
    """

    def deco(cls: type[NoiseModel]) -> type[NoiseModel]:
        if not (isinstance(cls, type) and issubclass(cls, NoiseModel)):
            raise TypeError(f"{cls!r} is not a NoiseModel subclass")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return deco


def _entry_points() -> dict:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def model_class(name: str) -> type[NoiseModel]:
    """The class registered under `name`, loading an installed plug-in (entry-point group `nlosbench.noise`)
    on first use.

    Parameters
    ----------
    name : str
        A noise model's name (see `available`).

    Returns
    -------
    type
        The NoiseModel subclass.

    Raises
    ------
    ValueError
        If no model has that name (with a close match), or a plug-in is not a NoiseModel subclass.
    ImportError
        If the plug-in fails to import.

    Examples
    --------
    >>> nb.noise.model_class("poisson") is nb.noise.Poisson
    True
    >>> nb.noise.model_class("poison")
    Traceback (most recent call last):
    ValueError: unknown noise model 'poison'; did you mean 'poisson'? (available: ...)
    """
    if name in _REGISTRY:
        return _REGISTRY[name]
    eps = _entry_points()
    if name not in eps:
        close = difflib.get_close_matches(name, available(), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown noise model {name!r}{hint} (available: {', '.join(available())})")
    try:
        cls = eps[name].load()
    except Exception as e:  # noqa: BLE001 - any import failure of a plug-in is reported with its source
        raise ImportError(f"noise plug-in {name!r} ({eps[name].value}, entry-point group {ENTRY_POINT_GROUP!r}) "
                          f"failed to load: {type(e).__name__}: {e}") from e
    if not (isinstance(cls, type) and issubclass(cls, NoiseModel)):
        raise ValueError(f"noise plug-in {name!r} ({eps[name].value}) is {cls!r}, not a NoiseModel subclass")
    return register(name)(cls)


def get(name: str, **kw) -> NoiseModel:
    """Build the noise model `name` with keyword parameters, e.g. get("awgn", sigma=0.1).

    Parameters
    ----------
    name : str
        A registered name or an installed plug-in (see `available`).
    **kw
        The model's parameters (e.g. sigma for "awgn", scale for "poisson").

    Returns
    -------
    NoiseModel
        The model.

    Raises
    ------
    ValueError
        If no model has that name, or its parameters are refused.

    Examples
    --------
    >>> nb.noise.get("awgn", sigma=0.1)
    AWGN(sigma=0.1)
    """
    cls = model_class(name)
    try:
        return cls(**kw)
    except TypeError as e:
        raise ValueError(f"noise model {name!r}: bad parameters {sorted(kw)}: {e}") from None


def available() -> list[str]:
    """Names of the registered noise models and the installed plug-ins.

    Returns
    -------
    list of str
        The names, sorted.

    Examples
    --------
    >>> {"awgn", "poisson"} <= set(nb.noise.available())
    True
    """
    return sorted(set(_REGISTRY) | set(_entry_points()))


def bounds_refusal(model: NoiseModel) -> str:
    """Why the bounds from replicated renders cannot use `model` ("" when they can).

    Parameters
    ----------
    model : NoiseModel
        The noise model.

    Returns
    -------
    str
        The reason, or "" for a QuadraticNoise.

    Examples
    --------
    >>> nb.noise.bounds_refusal(nb.noise.AWGN(sigma=0.1))
    ''
    """
    if isinstance(model, QuadraticNoise):
        return ""
    return (f"{type(model).__name__} is not a QuadraticNoise: the bounds from replicated renders need a χ² exponent "
            "that is a quadratic form in the image difference, λ = Σ w(L0)·(L1 − L0)² per pixel (unbiased as a "
            "U-statistic over replicates); subclass QuadraticNoise and give its weight w, or use awgn / poisson")


@register("awgn")
@dataclass(frozen=True)
class AWGN(QuadraticNoise):
    """Additive white Gaussian noise Y = L + ε, ε ~ N(0, σ²), σ in radiance units.

    Parameters
    ----------
    sigma : float
        σ, the noise's standard deviation in radiance units (finite, > 0).

    Examples
    --------
    λ = ‖L1 − L0‖² / σ² for each alternative image:

    >>> import torch
    >>> noise = nb.noise.AWGN(sigma=0.5)
    >>> L0 = torch.zeros(2, 2)
    >>> noise.chi2_exponent(L0, torch.stack([L0, L0 + 0.5]))
    tensor([0., 4.], dtype=torch.float64)
    """

    sigma: float
    symmetric: ClassVar[bool] = True  # λ = ‖L1 − L0‖² / σ²
    signal_dependent: ClassVar[bool] = False  # w = 1/σ² for every image

    def __post_init__(self):
        if not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"AWGN sigma must be finite and > 0, got {self.sigma}")

    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        """w = 1/σ², the same for every pixel.

        Parameters
        ----------
        L0 : torch.Tensor
            The mean image (its device is used).

        Returns
        -------
        torch.Tensor
            1/σ², float64 0-dim.
        """
        return torch.tensor(1.0 / self.sigma**2, dtype=torch.float64, device=L0.device)

    def binned(self, b: int) -> AWGN:
        """Mean of b² pixels with independent N(0, σ²) noise: σ/b (the block's sum carries b·σ).

        Parameters
        ----------
        b : int
            The bin size per side.

        Returns
        -------
        AWGN
            AWGN with σ/b.
        """
        return AWGN(self.sigma / check_bin(b))

    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """y = L + σε, ε standard normal per pixel.

        Parameters
        ----------
        L : torch.Tensor
            The mean image (*S), radiance units; finite.
        generator : torch.Generator
            The random source.

        Returns
        -------
        torch.Tensor
            y, shaped and typed like L.
        """
        check_finite(L, "L")
        eps = torch.randn(L.shape, generator=generator, dtype=L.dtype, device=L.device)
        return L + self.sigma * eps

    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """Σ (y − L)² / (2σ²).

        Parameters
        ----------
        y : torch.Tensor or array_like
            An observation (*S), radiance units.
        L : torch.Tensor
            The mean image (*S), radiance units.

        Returns
        -------
        torch.Tensor
            The negative log-likelihood up to a constant, float64 0-dim, differentiable in L.
        """
        r = (torch.as_tensor(y).to(torch.float64) - L.to(torch.float64)) / self.sigma
        return 0.5 * (r * r).sum()


@register("poisson")
@dataclass(frozen=True)
class Poisson(QuadraticNoise):
    """Photon counts K ~ Poisson(scale·L); `scale` = expected photons per unit radiance.

    Observations are reported in radiance units, y = K / scale (so E[y] = L, Var[y] = L / scale).
    The bound depends on `scale`: λ = scale·Σ(L1 − L0)²/L0 (exact for Poisson).

    Parameters
    ----------
    scale : float
        Expected photons per unit radiance (finite, > 0).

    Examples
    --------
    >>> import torch
    >>> nb.noise.Poisson(scale=100.0).chi2_exponent(torch.ones(4), torch.full((4,), 1.5))
    tensor(100., dtype=torch.float64)
    """

    scale: float

    def __post_init__(self):
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"Poisson scale must be finite and > 0, got {self.scale}")

    def validate(self, L: torch.Tensor, what: str) -> None:
        """Raise ValueError naming `what` unless `L` is finite and ≥ 0.

        Parameters
        ----------
        L : torch.Tensor
            A mean image (*S), radiance units.
        what : str
            Its name, for the message.

        Raises
        ------
        ValueError
            If `L` holds NaN, Inf or negative values.
        """
        check_finite(L, what)
        neg = int((L < 0).sum())
        if neg:
            raise ValueError(f"{what} has {neg} negative values; a Poisson mean must be >= 0")

    def weight(self, L0: torch.Tensor) -> torch.Tensor:
        """w(L0) = scale / L0 (+inf where L0 = 0).

        Parameters
        ----------
        L0 : torch.Tensor
            The mean image (*S), float64, radiance units.

        Returns
        -------
        torch.Tensor
            w, float64 (*S).
        """
        return self.scale / L0  # +inf where L0 = 0

    def binned(self, b: int) -> Poisson:
        """Counts of b² pixels summed (a b² larger pixel): Poisson(scale·Σ L) = b²·scale photons per unit
        of the block's mean radiance.

        Parameters
        ----------
        b : int
            The bin size per side.

        Returns
        -------
        Poisson
            Poisson with scale·b².
        """
        return Poisson(self.scale * check_bin(b) ** 2)

    def sample(self, L: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """y = K / scale with counts K ~ Poisson(scale·L) per pixel.

        Parameters
        ----------
        L : torch.Tensor
            The mean image (*S), radiance units; finite, ≥ 0.
        generator : torch.Generator
            The random source.

        Returns
        -------
        torch.Tensor
            y, shaped and typed like L, in radiance units.
        """
        self.validate(L, "L")
        counts = torch.poisson(self.scale * L.to(torch.float64), generator=generator)
        return (counts / self.scale).to(L.dtype)

    def nll(self, y: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
        """scale·Σ (L − y·log L), i.e. −log p up to a constant; y = 0 pixels add scale·L even at
        L = 0 (finite value and gradient), y > 0 at L = 0 gives +inf.

        Parameters
        ----------
        y : torch.Tensor or array_like
            An observation (*S), radiance units (counts / scale).
        L : torch.Tensor
            The mean image (*S), radiance units.

        Returns
        -------
        torch.Tensor
            The negative log-likelihood up to a constant, float64 0-dim, differentiable in L.
        """
        y = torch.as_tensor(y).to(torch.float64)
        L = L.to(torch.float64)
        safe = torch.where(y > 0, L, torch.ones_like(L))
        return self.scale * (L - y * torch.log(safe)).sum()
