"""Pixel binning with the photon budget fixed: b×b blocks of sensor pixels read out as one pixel.

Model: the binned pixel's value is the mean of its block's b² independent pixel observations, in
radiance units (so a binned image is comparable with the full-resolution one). Its mean is the block's
mean radiance and its noise follows from the per-pixel model (`NoiseModel.binned(b)`):
AWGN σ per pixel → σ/b on the mean (the block's sum carries b·σ: each pixel read out separately);
Poisson → counts summed, i.e. the photons a b² larger pixel collects (scale·b² per unit mean radiance).
Where the image (and its change with θ) is constant within every block the binned observation is a
sufficient statistic and every bound is unchanged; otherwise information is lost (data processing),
so a bound from binned images is never below the full-resolution one.
"""
from __future__ import annotations

import numpy as np
import torch


def check_bin(b) -> int:
    """A binning factor b as an int ≥ 1, else ValueError."""
    if isinstance(b, bool) or not isinstance(b, (int, np.integer, float)) or not float(b).is_integer() or b < 1:
        raise ValueError(f"binning factor must be an integer >= 1, got {b!r}")
    return int(b)


def bin_image(x, b: int) -> np.ndarray:
    """Mean over b×b pixel blocks: x (..., H, W, C) (numpy or torch, any float dtype) → (..., H/b, W/b, C)
    float64. H and W must be multiples of b."""
    b = check_bin(b)
    a = x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)
    if a.ndim < 3:
        raise ValueError(f"bin_image needs an image (..., H, W, C), got shape {a.shape}")
    *lead, H, W, C = a.shape
    if H % b or W % b:
        raise ValueError(f"cannot bin a {H}×{W} image by b = {b}: height and width must be multiples of b")
    a = a.astype(np.float64, copy=False).reshape(*lead, H // b, b, W // b, b, C)
    return a.mean(axis=(-4, -2))
