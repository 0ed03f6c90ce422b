"""Per-pixel Fisher information images: where in the picture the information about θ_j lives."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from nlosbench.bounds.hcr import as_numpy
from nlosbench.noise import NoiseModel, to_float64


def fisher_maps(L, J, noise: NoiseModel, reduce: str = "sum") -> np.ndarray:
    """Fisher information of each parameter per pixel → (P, H, W) float64, 1/(parameter units)².

    The per-channel information w(L)·(∂L/∂θ_j)² is summed (`reduce="sum"`: the map sums to F_jj) or
    averaged (`"mean"`) over channels.

    Parameters
    ----------
    L : torch.Tensor or array_like of shape (H, W, C) or (H, W)
        The noise-free image, radiance units.
    J : torch.Tensor or array_like of shape (P, H, W, C), (P, H, W) or the shape of L
        J = ∂L/∂θ, one image per parameter (the shape of L: P = 1).
    noise : NoiseModel
        The observation model (its per-pixel Fisher information).
    reduce : {"sum", "mean"}, optional
        How the channels are combined.

    Returns
    -------
    ndarray of shape (P, H, W)
        The information about each θ_j per pixel, float64, 1/(parameter units)².

    Examples
    --------
    >>> import torch
    >>> L = torch.ones(2, 2, 3)
    >>> m = nb.bounds.fisher_maps(L, 0.5 * L, nb.noise.AWGN(0.5))
    >>> m.shape, float(m.sum())
    ((1, 2, 2), 12.0)
    """
    if reduce not in ("sum", "mean"):
        raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
    L = to_float64(L)
    J = to_float64(J)
    if J.shape == L.shape:
        J = J[None]
    if L.ndim == 2:
        L, J = L[..., None], J[..., None]
    if L.ndim != 3 or J.shape[1:] != L.shape:
        raise ValueError(f"expected L (H, W, C) and J (P, H, W, C), got {tuple(L.shape)}, {tuple(J.shape)}")
    maps = np.stack([as_numpy(noise.fisher(L, Jp)) for Jp in J])
    return maps.sum(axis=-1) if reduce == "sum" else maps.mean(axis=-1)


def save_fisher_maps(maps: np.ndarray, names: Sequence[str], outdir: str | Path, prefix: str = "fisher",
                     units: Sequence[str] | None = None, where: str = "") -> list[Path]:
    """Write each map (P, H, W) as `{prefix}_{name}.exr` (float32 data) and a log-scale PNG.

    Each PNG is titled with the parameter and `where` (e.g. "θ = 0.79 m, AWGN(sigma=0.025)"), its colour
    bar in 1/units² of the parameter.

    Parameters
    ----------
    maps : ndarray of shape (P, H, W)
        Per-pixel Fisher information, e.g. from `fisher_maps`, 1/(parameter units)².
    names : sequence of str
        One name per parameter (P), used in the file names and titles.
    outdir : str or Path
        The folder written to.
    prefix : str, optional
        The file-name prefix.
    units : sequence of str, optional
        The unit of each parameter, for the colour bar (default: "(name unit)").
    where : str, optional
        A second title line saying where the maps were taken ("" for none).

    Returns
    -------
    list of Path
        The written paths, an EXR and a PNG per parameter.

    Examples
    --------
    >>> import tempfile
    >>> import numpy as np
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     paths = nb.bounds.save_fisher_maps(np.ones((1, 4, 4)), ["x"], tmp, where="θ = 0.5 m")
    ...     names = sorted(p.name for p in paths)
    >>> names
    ['fisher_x.exr', 'fisher_x.png']
    """
    from nlosbench import io

    maps = as_numpy(maps)
    if maps.ndim != 3 or len(names) != maps.shape[0]:
        raise ValueError(f"need maps (P, H, W) and P names, got {maps.shape} and {len(names)} names")
    outdir = Path(outdir)
    paths = []
    for m, name, unit in zip(maps, names, units or [f"({n} unit)" for n in names], strict=True):
        paths.append(io.write_exr(outdir / f"{prefix}_{name}.exr", m))
        paths.append(io.write_png(outdir / f"{prefix}_{name}.png", m, log=bool(np.all(m >= 0)),
                                  symmetric=bool(np.any(m < 0)),
                                  title=f"Fisher information per pixel: {name}" + (f"\n{where}" if where else ""),
                                  cbar_label=f"FI per pixel [1/{unit}²]"))
    return paths
