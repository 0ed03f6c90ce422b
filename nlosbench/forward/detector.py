"""What a time-resolved detector (a SPAD with a time-to-digital converter) makes of a transient render, applied
after rendering: temporal response, time gate, photon budget, dark counts, ambient background and the direct wall
return. `Detected(model, detector)` is the forward model a bound or an estimator sees.

For an image L (scan_y, scan_x, T, C) on bins of `bin_width` metres of optical path from `start` metres, the
expected counts per bin are

    μ = gain · g ⊙ (h ⊛ L) + g ⊙ (dark + ambient) + wall_return · [the bin holding optical path 0, if gated in],

h the temporal response (a Gaussian jitter of σ = jitter_ps, bin-integrated, or a measured response), ⊛ along
T with zeros outside the rendered window (render a window a few σ wider than the gate), g the gate (1 for bins
whose centre lies in [gate[0], gate[1]) metres of optical path, else 0: a gated-off bin counts nothing). `gain`
is counts per unit image value (laser power × exposure × efficiency); `for_budget` sets it so that a reference
image gives a stated number of signal photons per capture. A detector without timing (`timing=False`) reports
the gated bins summed, (scan_y, scan_x, 1, C), with its background summed over them and the wall return
counted when optical path 0 is gated in (an ungated detector collects it: it carries no information about the
hidden scene but adds Poisson noise).

Counts are Poisson and independent per bin: use `nb.noise.Poisson(scale=1.0)` on these images. Everything but
the background is linear in L, so derivatives (FD differences, Jacobians, `jvp`) go through `apply_linear`: the
same response, gate and gain, no background. A bin with zero mean and a non-zero derivative has infinite Poisson
information: with dark + ambient = 0 `Detected.render` refuses images with zero gated bins and `check` names
the bins of an (L, J) pair.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from .model import ForwardModel

#: the speed of light, m/s (optical path = c · time)
C_LIGHT = 299_792_458.0
#: a Gaussian response is cut at this many standard deviations
TRUNCATE = 5.0


def ps_to_m(ps: float) -> float:
    """Optical path (m) travelled in `ps` picoseconds."""
    return float(ps) * 1e-12 * C_LIGHT


#: the FD step rule of a transient bound: the step's arrival shift (optical path) at most this fraction of σ
STEP_FRACTION = 0.5


def max_fd_step(sigma: float, rate: float = 2.0, fraction: float = STEP_FRACTION) -> float:
    """The largest FD step ξ (parameter units) for a transient Fisher information: the step's arrival shift
    rate·ξ (metres of optical path; rate = 2 for a translation of the object, d = 2‖θ − p‖) is at most `fraction`
    of the Gaussian temporal response's σ (metres of optical path, the jitters combined in quadrature).

    Why σ and not the bin width: a bin's mean as a function of the arrival path is the response integrated over
    the bin, whose flanks at the bin edges are σ wide whatever the bin width, so a coarse bin does not relax the
    step; a fine one does not tighten it. And why a rule at all: under Poisson counts with little background the
    central difference over a shift comparable to σ *overestimates* F (the pulse's tails, weighted by 1/μ): on the
    analytic toy F_ξ/F = 1.09 at a shift of σ and 2.6 at 2σ (30 ps, 6 mm bins), so the CRLB comes out too low,
    and `bounds.fd_step`'s halving rule, which halves ξ only while F rises, cannot see it (F falls towards its
    limit as ξ shrinks). At a shift of σ/2 the same toy gives |F_ξ/F − 1| ≤ 0.8 % for bins up to 2σ wide (and
    2.8 % for bins 13σ wide; `tests/test_transient_fd_step.py`); the halving rule then settles what remains.

    Parameters
    ----------
    sigma : float
        The temporal response's standard deviation, metres of optical path (> 0).
    rate : float, optional
        The largest rate of change of the arrival path with θ, metres of optical path per parameter unit (> 0).
    fraction : float, optional
        The largest shift allowed, in units of σ (> 0).

    Returns
    -------
    float
        ξ_max = fraction · σ / rate, parameter units.

    Raises
    ------
    ValueError
        If σ is 0 (raw bins, no temporal response: the Fisher information is not defined) or an input is not a
        finite positive number.
    """
    if sigma == 0:
        raise ValueError("no temporal response (σ = 0): the transient Fisher information of raw bins is not defined; "
                         "give the detector a jitter")
    for name, v in (("sigma", sigma), ("rate", rate), ("fraction", fraction)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    return fraction * sigma / rate


@dataclass(frozen=True)
class Detector:
    """A detector model (see the module docstring); lengths in metres of optical path, counts per bin.

    Parameters
    ----------
    bin_width : float
        Width of the image's time bins, metres of optical path.
    start : float, optional
        Optical path at the start of bin 0, metres.
    jitter_ps : float, optional
        Standard deviation of a Gaussian temporal response, picoseconds (0: none).
    response : tuple of float, optional
        A measured response instead, one value per bin from shift `response_shift` bins on (normalised to sum 1).
    response_shift : int, optional
        The shift (bins) of the response's first value.
    gate : (float, float), optional
        The optical path window [lo, hi) counted, metres; None: every bin.
    dark, ambient : float, optional
        Dark counts and ambient background per bin and scan point (≥ 0).
    gain : float, optional
        Expected counts per unit image value (> 0).
    wall_return : float, optional
        Expected counts of the direct wall return per scan point, at optical path 0 (≥ 0).
    timing : bool, optional
        False: a detector without timing, the gated bins summed.
    """

    bin_width: float
    start: float = 0.0
    jitter_ps: float = 0.0
    response: tuple | None = None
    response_shift: int = 0
    gate: tuple | None = None
    dark: float = 0.0
    ambient: float = 0.0
    gain: float = 1.0
    wall_return: float = 0.0
    timing: bool = True

    def __post_init__(self):
        if not (math.isfinite(self.bin_width) and self.bin_width > 0):
            raise ValueError(f"detector bin_width must be finite and > 0 (metres), got {self.bin_width!r}")
        if not math.isfinite(self.start):
            raise ValueError(f"detector start must be finite (metres of optical path), got {self.start!r}")
        for name in ("jitter_ps", "dark", "ambient", "wall_return"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"detector {name} must be finite and >= 0, got {v!r}")
        if not (math.isfinite(self.gain) and self.gain > 0):
            raise ValueError(f"detector gain must be finite and > 0 (counts per unit image value), got {self.gain!r}")
        if self.response is not None:
            h = np.asarray(self.response, dtype=np.float64)
            if self.jitter_ps:
                raise ValueError("detector: give jitter_ps or a measured response, not both")
            if h.ndim != 1 or h.size == 0 or not np.all(np.isfinite(h)) or np.any(h < 0) or h.sum() <= 0:
                raise ValueError("detector response must be a non-empty list of finite values >= 0 with a positive sum")
            object.__setattr__(self, "response", tuple(float(x) for x in h / h.sum()))
        if self.gate is not None:
            lo, hi = (float(x) for x in self.gate)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"detector gate must be (lo, hi) metres of optical path, lo < hi, got {self.gate!r}")
            object.__setattr__(self, "gate", (lo, hi))

    # -- the parts ---------------------------------------------------------------------------------------
    @property
    def background(self) -> float:
        """Dark counts plus ambient background per bin and scan point."""
        return float(self.dark + self.ambient)

    def kernel(self) -> tuple[np.ndarray, int]:
        """(h, first shift): the temporal response per bin, float64 summing to 1, h[m] for a shift of m + first
        bins. A Gaussian of σ = jitter_ps is integrated over each bin ([s − ½, s + ½) bin widths), cut at
        ±5σ; no response: ([1], 0)."""
        if self.response is not None:
            return np.asarray(self.response), int(self.response_shift)
        if self.jitter_ps == 0:
            return np.ones(1), 0
        from scipy.special import ndtr

        s = ps_to_m(self.jitter_ps) / self.bin_width  # σ in bins
        half = max(1, math.ceil(TRUNCATE * s))
        edges = (np.arange(-half, half + 2) - 0.5) / s
        h = np.diff(ndtr(edges))
        return h / h.sum(), -half

    def gate_mask(self, T: int) -> np.ndarray:
        """1.0 for the bins (T,) whose centre lies in the gate, else 0.0."""
        centres = self.start + (np.arange(T) + 0.5) * self.bin_width
        if self.gate is None:
            return np.ones(T)
        return ((centres >= self.gate[0]) & (centres < self.gate[1])).astype(np.float64)

    def _wall_bin(self, T: int) -> int | None:
        """The bin holding optical path 0 when it is gated in (None otherwise; -1: before the window, counted
        only without timing)."""
        if self.gate is not None and not (self.gate[0] <= 0.0 < self.gate[1]):
            return None
        k = math.floor((0.0 - self.start) / self.bin_width)
        return k if 0 <= k < T else -1

    @staticmethod
    def _check(L: np.ndarray, what: str) -> np.ndarray:
        L = np.asarray(L, dtype=np.float64)
        if L.ndim != 4:
            raise ValueError(f"{what} must be (scan_y, scan_x, T, C), got shape {L.shape}")
        return L

    def convolve(self, L) -> np.ndarray:
        """h ⊛ L along T (axis 2), zeros outside the window; float64, shape unchanged."""
        L = self._check(L, "image")
        h, first = self.kernel()
        T = L.shape[2]
        out = np.zeros_like(L)
        for m, w in enumerate(h):
            s = first + m
            if abs(s) < T:
                if s >= 0:
                    out[:, :, s:] += w * L[:, :, : T - s]
                else:
                    out[:, :, : T + s] += w * L[:, :, -s:]
        return out

    def correlate(self, G) -> np.ndarray:
        """The adjoint of `convolve`: ⟨G, h ⊛ L⟩ = ⟨h ⋆ G, L⟩."""
        G = self._check(G, "cotangent")
        h, first = self.kernel()
        T = G.shape[2]
        out = np.zeros_like(G)
        for m, w in enumerate(h):
            s = first + m
            if abs(s) < T:
                if s >= 0:
                    out[:, :, : T - s] += w * G[:, :, s:]
                else:
                    out[:, :, -s:] += w * G[:, :, : T + s]
        return out

    # -- images --------------------------------------------------------------------------------------------
    def apply_linear(self, L) -> np.ndarray:
        """gain · g ⊙ (h ⊛ L) (no background): for derivatives and differences. (scan_y, scan_x, T, C) →
        the same shape, or (scan_y, scan_x, 1, C) without timing; float64."""
        L = self._check(L, "image")
        out = self.gain * self.convolve(L) * self.gate_mask(L.shape[2])[:, None]
        return out if self.timing else out.sum(axis=2, keepdims=True)

    def apply(self, L) -> np.ndarray:
        """Expected counts per bin (see the module docstring), float64."""
        L = self._check(L, "image")
        T = L.shape[2]
        g = self.gate_mask(T)
        out = self.gain * self.convolve(L) * g[:, None] + self.background * g[:, None]
        k = self._wall_bin(T)
        if not self.timing:
            out = out.sum(axis=2, keepdims=True)
            return out + (self.wall_return if k is not None else 0.0)
        if k is not None and k >= 0:
            out[:, :, k] += self.wall_return
        return out

    def adjoint(self, G, T: int | None = None) -> np.ndarray:
        """The adjoint of `apply_linear`: a cotangent G on the detector's image → one on the render
        (scan_y, scan_x, T, C), float64. Without timing G is (scan_y, scan_x, 1, C) and T must be given."""
        G = self._check(G, "cotangent")
        if not self.timing:
            if T is None:
                raise ValueError("the adjoint of a detector without timing needs the render's bins T")
            G = np.repeat(G, T, axis=2)
        return self.gain * self.correlate(G * self.gate_mask(G.shape[2])[:, None])

    def check(self, mean, derivative) -> None:
        """ValueError naming the bins whose mean is 0 while their derivative is not (infinite Poisson
        information), for a detector image `mean` and a derivative image of the same shape (counts per unit)."""
        mu, d = np.asarray(mean, dtype=np.float64), np.asarray(derivative, dtype=np.float64)
        if mu.shape != d.shape:
            raise ValueError(f"mean {mu.shape} and derivative {d.shape} differ in shape")
        bad = np.argwhere((mu == 0) & (d != 0))
        if len(bad):
            first = [tuple(b) for b in bad[:3].tolist()]
            raise ValueError(f"{len(bad)} bins have zero mean but a non-zero derivative (infinite Poisson "
                             f"information), first (scan_y, scan_x, bin, channel): {first}; set dark or ambient > 0")

    @classmethod
    def for_budget(cls, photons: float, reference, **options) -> Detector:
        """A detector whose gain makes `reference` (an image (scan_y, scan_x, T, C), e.g. a high-spp render at
        θ*) give `photons` expected signal counts per capture after its response and gate (background and wall
        return not included). The gain is then fixed: other θ give other totals, as a fixed laser power and
        exposure would."""
        if not (math.isfinite(photons) and photons > 0):
            raise ValueError(f"photons must be finite and > 0, got {photons!r}")
        unit = cls(**{**options, "gain": 1.0, "timing": True})
        total = float(unit.apply_linear(reference).sum())
        if not total > 0:
            raise ValueError("the reference image has no signal inside the gate: no photon budget can be set from it")
        return cls(**{**options, "gain": photons / total})

    @classmethod
    def from_file(cls, path, bin_width: float, **options) -> Detector:
        """A detector with a measured response: a text file of two columns, time (ps) and response (any
        units), resampled onto the bins (linear interpolation at each bin's centre shift; t = 0 is no delay)."""
        data = np.loadtxt(Path(path), ndmin=2)
        if data.shape[1] != 2 or len(data) < 2 or np.any(np.diff(data[:, 0]) <= 0):
            raise ValueError(f"{path}: expected two columns (time in ps, increasing; response)")
        t = data[:, 0] * 1e-12 * C_LIGHT / bin_width  # in bins
        first, last = math.ceil(t[0]), math.floor(t[-1])
        if last < first:
            raise ValueError(f"{path}: the response spans less than one bin of {bin_width} m")
        shifts = np.arange(first, last + 1)
        h = np.interp(shifts, t, data[:, 1])
        return cls(bin_width=bin_width, response=tuple(h), response_shift=int(first), **options)

    def as_dict(self) -> dict:
        return asdict(self)


def time_bins(model: ForwardModel) -> int:
    """T of a transient model's images: its capture's bins (`TransientModel`) or `bins` (`TransientPoint`),
    looked up through wrappers (`Restricted`, `Detected`)."""
    m = model
    while m is not None:
        if getattr(m, "capture", None) is not None:
            return int(m.capture.bins)
        if isinstance(getattr(m, "bins", None), int):
            return int(m.bins)
        m = getattr(m, "base", None)
    raise ValueError(f"{model!r} is not a transient model (no capture or bins)")


class Detected(ForwardModel):
    """`base` (images (scan_y, scan_x, T, C)) seen through `detector`: renders are expected counts per bin
    (`Detector.apply`), derivatives go through `Detector.apply_linear`. Renders, derivatives and stats go to the
    base model (its cache too); θ and Θ are the base's.

    Parameters
    ----------
    base : ForwardModel
        A transient model (`TransientModel`, or the analytic `TransientPoint`).
    detector : Detector
        The detector; its bins must be the base's.
    """

    def __init__(self, base: ForwardModel, detector: Detector):
        self.base, self.detector = base, detector
        super().__init__(f"{base.name}-detected", base.params, None)
        self.stats = base.stats
        self.exact = base.exact

    @property
    def channels(self) -> int:
        """A scan point's values that share path samples: the base's (T·C), or C without timing."""
        return self.base.channels if self.detector.timing else self.base.channels // time_bins(self.base)

    def _counts(self, img: torch.Tensor, linear: bool) -> torch.Tensor:
        f = self.detector.apply_linear if linear else self.detector.apply
        return torch.from_numpy(f(img.numpy()).astype(np.float32))

    def render(self, theta, spp: int, seed: int) -> torch.Tensor:
        """Expected counts (scan_y, scan_x, T, C) float32 (T = 1 without timing) of the base's render."""
        out = self._counts(self.base.render(theta, spp, seed), linear=False)
        if self.detector.background == 0:
            zero = np.argwhere(out.numpy() == 0)
            if len(zero):
                first = [tuple(z) for z in zero[:3].tolist()]
                raise ValueError(f"scene {self.name!r}: {len(zero)} bins have zero mean at spp={spp}, seed={seed} "
                                 f"(first (scan_y, scan_x, bin, channel): {first}); with no "
                                 "dark counts or background their Poisson information is infinite wherever their "
                                 "derivative is not zero: set dark or ambient > 0")
        return out

    def _render(self, theta, spp, seed):  # render() is delegated whole, with the base's cache
        raise NotImplementedError

    def jvp(self, theta, index: int, spp: int, seed: int, **ad) -> torch.Tensor:
        return self._counts(self.base.jvp(theta, index, spp, seed, **ad), linear=True)

    def vjp(self, theta, grad_out, spp: int, seed: int, indices=None, **ad) -> np.ndarray:
        back = self.detector.adjoint(np.asarray(grad_out, dtype=np.float64), time_bins(self.base))
        return self.base.vjp(theta, torch.from_numpy(back.astype(np.float32)), spp, seed, indices=indices, **ad)

    def content_key(self) -> dict:
        return {"base": self.base.content_key(), "detector": self.detector.as_dict()}
