"""Analytic forward models in torch: exact images and exact gradients, the ground truth for tests.

Optional synthetic rendering noise mimics a Monte Carlo renderer: L̃ = L + ε with
ε ~ N(0, render_noise² · L / N^p) per pixel, N = spp, p = `render_noise_power` (1 for a path tracer),
independent across seeds. With render_noise = 0 the image is exact for every spp and seed.
`render_noise_dist` "t3" draws ε heavy-tailed instead: Student's t with 3 degrees of freedom scaled to the same
variance (t/√3; kurtosis infinite), as a renderer's rare bright paths make it; "gauss" (the default) is the
normal draw above, unchanged. `render_noise_channels` "shared" draws one standard variate per pixel for all its
channels (ε_c = z·√Var_c: the channels' errors fully correlated, as a path tracer's channels share their light
paths — 0.76–0.998 measured on the Π hallway); "independent" (the default) draws one per value. Any of these can
make a pixel negative where L is below a few SDs of ε, which no renderer does and Poisson noise cannot take as a
mean: `render_noise_clip` renders max(L̃, 0) instead (biased up where it clips; a run refuses Poisson noise with
rendering noise unless it is on).
"""
from __future__ import annotations

from abc import abstractmethod

import numpy as np
import torch

from ..params import Param, ParamSpace
from ..seeds import derive
from .model import ForwardModel

#: synthetic rendering-noise distributions (unit variance before scaling)
NOISE_DISTS = ("gauss", "t3")
#: how a pixel's channels draw their synthetic rendering noise
NOISE_CHANNELS = ("independent", "shared")


class AnalyticModel(ForwardModel):
    """Base for closed-form models: subclasses give `clean(θ)` as a differentiable torch function."""

    def __init__(self, name: str, params: ParamSpace, render_noise: float = 0.0,
                 render_noise_power: float = 1.0, cache=None, render_noise_dist: str = "gauss",
                 render_noise_channels: str = "independent", render_noise_clip: bool = False):
        super().__init__(name, params, cache)
        if render_noise < 0:
            raise ValueError(f"render_noise must be >= 0, got {render_noise}")
        if render_noise_dist not in NOISE_DISTS:
            raise ValueError(f"render_noise_dist must be one of {list(NOISE_DISTS)}, got {render_noise_dist!r}")
        self.render_noise = float(render_noise)
        self.render_noise_power = float(render_noise_power)
        if render_noise_channels not in NOISE_CHANNELS:
            raise ValueError(f"render_noise_channels must be one of {list(NOISE_CHANNELS)}, "
                             f"got {render_noise_channels!r}")
        self.render_noise_dist = render_noise_dist
        self.render_noise_channels = render_noise_channels
        self.render_noise_clip = bool(render_noise_clip)
        self.exact = self.render_noise == 0.0
        self._channels: int | None = None

    @property
    def channels(self) -> int:
        """C of `clean(θ)`'s image (H, W, C), read once from the default θ."""
        if self._channels is None:
            with torch.no_grad():
                self._channels = int(self.clean(torch.as_tensor(self.params.default, dtype=torch.float64)).shape[-1])
        return self._channels

    @abstractmethod
    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        """Noise-free image (H, W, C) float64 from θ float64 (P,), differentiable in θ."""

    def noise_variance(self, L: torch.Tensor, spp: int) -> torch.Tensor:
        """Per-pixel variance of the synthetic rendering error at `spp` samples (float64)."""
        return self.render_noise ** 2 * L.clamp_min(0) / float(spp) ** self.render_noise_power

    def _noisy(self, theta: torch.Tensor, spp: int, seed: int) -> torch.Tensor:
        L = self.clean(theta)
        if self.exact:
            return L
        g = torch.Generator().manual_seed(derive(seed, "analytic-render-noise"))
        shape = tuple(L.shape[:-1]) + (1,) if self.render_noise_channels == "shared" else tuple(L.shape)
        z = torch.randn(shape, generator=g, dtype=torch.float64)
        if self.render_noise_dist == "t3":  # t₃ = z / √(χ²₃/3) has variance 3: divided by √3, unit variance
            chi2 = (torch.randn((3,) + shape, generator=g, dtype=torch.float64) ** 2).sum(dim=0)
            z = z / chi2.sqrt()
        out = L + z * self.noise_variance(L, spp).sqrt()
        return out.clamp_min(0.0) if self.render_noise_clip else out

    def _render(self, theta: np.ndarray, spp: int, seed: int) -> torch.Tensor:
        with torch.no_grad():
            return self._noisy(torch.as_tensor(theta, dtype=torch.float64), spp, seed).float()

    def jvp(self, theta, index: int, spp: int = 1, seed: int = 0, **ad) -> torch.Tensor:
        # reverse mode twice: g(w) = Jᵀw is linear in w, so ∂g_index/∂w is J's column `index`. The same numbers as
        # torch's forward mode (torch.func.jvp), which runs add/sub through Python reference ops: on blob2d
        # (24 × 24) 0.25 ms a column against 1.6 ms
        with torch.enable_grad():
            t = torch.as_tensor(self.params.validate(theta), dtype=torch.float64).requires_grad_(True)
            out = self._noisy(t, spp, seed)
            w = torch.zeros_like(out, requires_grad=True)
            (g,) = torch.autograd.grad(out, t, w, create_graph=True)
            (d,) = torch.autograd.grad(g[index], w)
        self.stats.grad_passes += 1
        return d.float()

    def vjp(self, theta, grad_out: torch.Tensor, spp: int = 1, seed: int = 0, indices=None, **ad) -> np.ndarray:
        with torch.enable_grad():  # also when called from an autograd Function's backward
            t = torch.as_tensor(self.params.validate(theta), dtype=torch.float64).requires_grad_(True)
            (g,) = torch.autograd.grad(self._noisy(t, spp, seed), t, grad_out.to(torch.float64))
        self.stats.grad_passes += 1
        return g.numpy()

    def content_key(self) -> dict:
        # the default draws and no clipping are left out, so keys made before the options existed stay valid
        return {"model": type(self).__name__, **{k: v for k, v in vars(self).items()
                                                 if isinstance(v, (int, float, str, tuple)) and not k.startswith("_")
                                                 and (k, v) not in (("render_noise_dist", "gauss"),
                                                                    ("render_noise_channels", "independent"),
                                                                    ("render_noise_clip", False),
                                                                    ("free_albedo", False))}}


class Blob2D(AnalyticModel):
    """A Gaussian spot at θ = (x, y) metres on a size×size image plane spanning [0, 1]² m, plus a
    constant background: L(u) = background + amplitude · exp(−‖u − θ‖² / (2 width²)). One channel."""

    def __init__(self, size: int = 24, width: float = 0.08, amplitude: float = 1.0,
                 background: float = 0.1, **kw):
        params = ParamSpace([Param("x", 0.2, 0.8, 0.5, "m", "spot centre, horizontal"),
                             Param("y", 0.2, 0.8, 0.5, "m", "spot centre, vertical")])
        super().__init__("blob2d", params, **kw)
        self.size, self.width, self.amplitude, self.background = (
            int(size),
            float(width),
            float(amplitude),
            float(background),
        )
        c = (torch.arange(self.size, dtype=torch.float64) + 0.5) / self.size
        self._v, self._u = torch.meshgrid(c, c, indexing="ij")

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        r2 = (self._u - theta[0]) ** 2 + (self._v - theta[1]) ** 2
        return (self.background + self.amplitude * torch.exp(-r2 / (2 * self.width**2)))[..., None]


class Edge1D(AnalyticModel):
    """A hard shadow edge at θ metres on a 1-D strip of `pixels` pixels spanning [0, 1] m: the region
    x > θ is lit. Pixel i integrates its area: L_i = background + amplitude · coverage_i(θ), so L is
    piecewise linear in θ with kinks where the edge crosses pixel boundaries. Image (1, pixels, 1)."""

    def __init__(self, pixels: int = 64, amplitude: float = 1.0, background: float = 0.2, **kw):
        params = ParamSpace([Param("edge", 0.1, 0.9, 0.5, "m", "shadow edge position")])
        super().__init__("edge1d", params, **kw)
        self.pixels, self.amplitude, self.background = int(pixels), float(amplitude), float(background)
        self._right = torch.arange(1, self.pixels + 1, dtype=torch.float64) / self.pixels

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        coverage = ((self._right - theta[0]) * self.pixels).clamp(0.0, 1.0)
        return (self.background + self.amplitude * coverage)[None, :, None]


class SpotRGB(AnalyticModel):
    """A coloured Gaussian spot at x = θ metres (y = 0.5 m) on a size×size image plane spanning [0, 1]² m, RGB:
    L_c(u) = background + amplitude_c · exp(−‖u − (θ, 0.5)‖² / (2 width²)). Its synthetic rendering noise is
    shared by a pixel's three channels by default (`render_noise_channels` "shared"), as a path tracer's is: the
    toy on which standard errors must group a pixel's channels. Image (size, size, 3)."""

    def __init__(self, size: int = 16, width: float = 0.12, amplitude=(1.0, 0.6, 0.3), background: float = 0.1,
                 render_noise_channels: str = "shared", **kw):
        params = ParamSpace([Param("x", 0.2, 0.8, 0.5, "m", "spot centre, horizontal")])
        super().__init__("spot_rgb", params, render_noise_channels=render_noise_channels, **kw)
        if len(amplitude) != 3:
            raise ValueError(f"amplitude needs one value per channel (3), got {amplitude!r}")
        self.size, self.width, self.background = int(size), float(width), float(background)
        self.amplitude = tuple(float(a) for a in amplitude)
        c = (torch.arange(self.size, dtype=torch.float64) + 0.5) / self.size
        self._v, self._u = torch.meshgrid(c, c, indexing="ij")
        self._amp = torch.tensor(self.amplitude, dtype=torch.float64)

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        r2 = (self._u - theta[0]) ** 2 + (self._v - 0.5) ** 2
        return self.background + self._amp * torch.exp(-r2 / (2 * self.width**2))[..., None]


class TransientPoint(AnalyticModel):
    """A point reflector at θ = (x, y, depth) metres behind a relay wall, scanned confocally: the analytic
    transient toy, with its Fisher information in closed form (`fisher`).

    The wall is the plane z = 0; its scan points p_ij form a scan×scan grid of pitch `wall / scan` centred on
    the origin (i along y, j along x); the reflector sits at (x, y, depth), depth > 0. A laser pulse at p_ij
    returns to p_ij after the optical path d_ij = 2‖θ − p_ij‖ (the wall-to-laser and wall-to-detector legs
    excluded, as y-tal's t_accounts_first_and_last_bounces = False), spread by a Gaussian temporal response
    of standard deviation σ = `jitter_ps` · c (optical path). Bin k collects optical paths in
    [start + k·bin_width, start + (k+1)·bin_width) metres. Expected counts per bin (the image is in counts:
    use `nb.noise.Poisson(scale=1.0)`):

        μ_ijk(θ) = background + A_ij(θ) · [Φ((e_k+1 − d_ij)/σ) − Φ((e_k − d_ij)/σ)],
        A_ij(θ) = photons · albedo · ‖θ − p_ij‖⁻⁴ / Σ_ij ‖θ₀ − p_ij‖⁻⁴,

    θ₀ the default point, so that `photons` is the expected signal count of a whole capture at θ₀ (albedo 1)
    and the radiometric r⁻⁴ fall-off moves with θ. With `free_albedo` the albedo (dimensionless, in [0.1, 10],
    default `albedo`) is a fourth parameter, θ = (x, y, depth, albedo): a nuisance parameter for the position
    (equivalently an unknown laser power, which scales A the same way). `background` (dark counts plus ambient
    light, counts per bin, > 0) keeps every bin's information finite. Image (scan, scan, T, 1) float32; a scan
    point's T·1 values share their rendering noise's paths (`channels`).
    """

    def __init__(self, scan: int = 4, wall: float = 1.0, bins: int = 96, bin_width: float = 0.006,
                 start: float = 1.4, jitter_ps: float = 30.0, photons: float = 1e5, background: float = 0.5,
                 albedo: float = 1.0, free_albedo: bool = False, **kw):
        ps = [Param("x", -0.3, 0.3, 0.05, "m", "reflector position along the wall's x"),
              Param("y", -0.3, 0.3, -0.03, "m", "reflector position along the wall's y"),
              Param("depth", 0.5, 1.0, 0.75, "m", "reflector distance from the wall")]
        if free_albedo:
            if not 0.1 <= albedo <= 10.0:
                raise ValueError(f"albedo must be in [0.1, 10] with free_albedo, got {albedo!r}")
            ps.append(Param("albedo", 0.1, 10.0, float(albedo), "", "reflector albedo (× the budget's)"))
        super().__init__("transient_point", ParamSpace(ps), **kw)
        self.free_albedo = bool(free_albedo)
        for name, v in (("scan", scan), ("bins", bins)):
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        for name, v in (("wall", wall), ("bin_width", bin_width), ("jitter_ps", jitter_ps), ("photons", photons),
                        ("background", background), ("albedo", albedo)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        self.scan, self.wall, self.bins, self.bin_width, self.start = int(scan), float(wall), int(bins), \
            float(bin_width), float(start)
        self.jitter_ps, self.photons, self.background, self.albedo = float(jitter_ps), float(photons), \
            float(background), float(albedo)
        from .detector import ps_to_m

        self.sigma = ps_to_m(self.jitter_ps)  # metres of optical path
        c = (np.arange(self.scan) + 0.5) / self.scan * self.wall - self.wall / 2
        py, px = np.meshgrid(c, c, indexing="ij")
        self.points = np.stack([px, py, np.zeros_like(px)], axis=-1)  # (scan, scan, 3): p_ij, metres
        self.edges = self.start + self.bin_width * np.arange(self.bins + 1)  # (T + 1,) metres of optical path
        self._norm = float((np.linalg.norm(self.params.default[:3] - self.points, axis=-1) ** -4.0).sum())

    @property
    def channels(self) -> int:
        """T·C = bins: the values per scan point that share path samples."""
        return self.bins

    def clean(self, theta: torch.Tensor) -> torch.Tensor:
        p = torch.as_tensor(self.points)
        r = torch.linalg.vector_norm(theta[:3] - p, dim=-1)  # (scan, scan)
        amp = self.photons * (theta[3] if self.free_albedo else self.albedo) * r ** -4.0 / self._norm
        u = (torch.as_tensor(self.edges) - 2.0 * r[..., None]) / self.sigma  # (scan, scan, T + 1)
        cdf = torch.special.ndtr(u)
        return (self.background + amp[..., None] * (cdf[..., 1:] - cdf[..., :-1]))[..., None]

    def fisher(self, theta, summed: bool = False) -> np.ndarray:
        """The exact Fisher information matrix (P, P) of θ for Poisson counts at θ, float64 (1/m² for the position;
        P = 3, or 4 with `free_albedo`: the albedo's entries per unit albedo): F = Σ_ijk ∇μ_ijk ∇μ_ijkᵀ / μ_ijk, with
        ∇μ written out by hand (numpy; independent of `clean`'s autograd) from ∂d/∂θ = 2(θ − p)/r,
        ∂A/∂θ = −4A(θ − p)/r², ∂Φ(u)/∂d = −φ(u)/σ and ∂A/∂albedo = A/albedo. `summed`: of a detector without
        timing, which counts Σ_k μ_ijk per scan point."""
        from scipy.special import ndtr

        t = self.params.validate(theta)
        albedo = t[3] if self.free_albedo else self.albedo
        diff = t[:3] - self.points  # (scan, scan, 3)
        r = np.linalg.norm(diff, axis=-1)
        amp = self.photons * albedo * r ** -4.0 / self._norm
        u = (self.edges - 2.0 * r[..., None]) / self.sigma
        phi = np.exp(-0.5 * u * u) / np.sqrt(2 * np.pi)
        mass = np.diff(ndtr(u), axis=-1)  # (scan, scan, T)
        dmass_dd = -np.diff(phi, axis=-1) / self.sigma
        mu = self.background + amp[..., None] * mass
        grad = (-4.0 * amp[..., None, None] * diff[..., None, :] / (r ** 2)[..., None, None] * mass[..., None]
                + amp[..., None, None] * dmass_dd[..., None] * (2.0 * diff / r[..., None])[..., None, :])
        if self.free_albedo:
            grad = np.concatenate([grad, (amp[..., None] * mass / albedo)[..., None]], axis=-1)
        if summed:
            mu, grad = mu.sum(axis=2, keepdims=True), grad.sum(axis=2, keepdims=True)
        return np.einsum("ijka,ijkb->ab", grad / mu[..., None], grad)

    def crlb(self, theta, names=None) -> float:
        """tr F⁻¹ over the parameters `names` (all of them by default; m² for the position), the others unknown
        too."""
        idx = list(range(self.params.dim)) if names is None else [self.params.index(n) for n in names]
        return float(np.trace(np.linalg.inv(self.fisher(theta))[np.ix_(idx, idx)]))
