"""Benchmark of the bound computations on synthetic renders (no renderer needed).

(a) HCR curve over a G-point grid through `pairwise_lambda` against a naive loop calling `hcr()`
    for every θ* (same numbers asserted, time ratio reported);
(b) pairwise-λ throughput: GB/s of image data compared, i.e. G² × (bytes of one render) / time.

Run: `python -m nlosbench.benchmarks.bounds [--reduced]` (a table, then one JSON line per row).
"""
from __future__ import annotations

import time

import numpy as np
import torch

from nlosbench.bounds import hcr, hcr_curve, pairwise_lambda
from nlosbench.noise import AWGN


def _renders(thetas: np.ndarray, shape: tuple[int, int, int]) -> torch.Tensor:
    """(G, H, W, C) float32: a bright blob moving along x over a textured floor."""
    H, W, C = shape
    y, x = torch.meshgrid(torch.linspace(0, 1, H), torch.linspace(0, 1, W), indexing="ij")
    floor = 0.2 + 0.05 * torch.sin(40 * x) * torch.cos(30 * y)
    t = torch.as_tensor(thetas, dtype=torch.float32)[:, None, None]
    blob = torch.exp(-((x - t) ** 2 + (y - 0.5) ** 2) / 0.01)
    tint = torch.linspace(1.0, 0.5, C)
    return ((floor + blob)[..., None] * tint).contiguous()


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def run(reduced: bool = False) -> list[dict]:
    """Run both benchmarks; returns one dict per result row."""
    G, shape = (48, (32, 64, 3)) if reduced else (160, (64, 128, 3))
    thetas = np.linspace(0.2, 0.8, G)
    R = _renders(thetas, shape)
    noise = AWGN(sigma=0.1)

    curve, t_grid = _timed(lambda: hcr_curve(R, thetas, noise))

    def naive():
        idx = np.arange(G)
        return np.array([hcr(R[i], R[idx != i], thetas[idx != i] - thetas[i], noise).log10
                         for i in range(G)])

    naive_log10, t_naive = _timed(naive)
    diff = float(np.max(np.abs(curve.log10 - naive_log10)))
    if not diff <= 1e-9:
        raise AssertionError(f"HCR curve differs from per-θ* hcr(): max |Δlog10| = {diff:g}")

    _, t_pair = _timed(lambda: pairwise_lambda(R, noise))
    image_bytes = R[0].numel() * R.element_size()
    return [
        dict(bench="hcr_curve", G=G, image=list(shape), grid_s=t_grid, naive_s=t_naive,
             ratio=t_naive / t_grid, max_abs_log10_diff=diff),
        dict(bench="pairwise_lambda", G=G, image=list(shape), seconds=t_pair,
             gb_per_s=G * G * image_bytes / t_pair / 1e9, pairs_per_s=G * G / t_pair),
    ]


if __name__ == "__main__":
    from . import main

    main(__name__)
