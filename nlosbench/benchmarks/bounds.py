"""Benchmark of the bound computations on synthetic renders (no renderer needed).

(a) HCR curve over a G-point grid through `pairwise_lambda` against a naive loop calling `hcr()`
    for every θ* (same numbers asserted, time ratio reported);
(b) pairwise-λ throughput: GB/s of image data compared, i.e. G² × (bytes of one render) / time;
(c) `interval_width`: the HCR interval at one θ* on the Π hallway from the bound service (4 replicate sets,
    a test grid over Θ and small offsets), with common random numbers against independent seeds at equal
    render budget: each width in decades (upper − lower end; inf when the upper end is open) and `ratio` =
    the common-seed interval's factor 10^width (the paper's intervals are within about 2×). Full mode: NLOS
    (θ* = 1.3 m) at 40 × 30 with information-equivalent AWGN σ = 0.025; reduced: blob2d with synthetic
    rendering noise.

Run: `python -m nlosbench.benchmarks.bounds [--reduced]` (a table, then one JSON line per row).
"""
from __future__ import annotations

import time

import numpy as np
import torch

from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService, hcr, hcr_curve, pairwise_lambda
from nlosbench.noise import AWGN
from nlosbench.scenes import build


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


def interval_width(spec: dict, label: str, theta: float, sigma: float, spp: int, replicates: int = 4,
                   test_grid: int = 12, fd_step: float = 0.01, seed: int = 7) -> dict:
    """The HCR interval at a scalar θ* of the model `spec` with common against independent seeds."""
    model = build(spec)
    out = {}
    for seeds in ("common", "independent"):
        svc = BoundService(RenderBank(model, seed=seed), [AWGN(sigma)])
        t0 = time.perf_counter()
        (pt,) = svc.at([[theta]], spp, ("hcr",), seeds, replicates, test_grid, 3, fd_step)
        b = pt.bounds["hcr"]
        out[seeds] = (b.lower, b.upper, b.upper - b.lower, time.perf_counter() - t0, b.terms)
    (cl, cu, cw, cs, ct), (il, iu, iw, is_, it) = out["common"], out["independent"]
    return dict(bench="interval_width", scene=label, theta=theta, sigma=sigma, spp=spp,
                replicates=replicates, common_lower=cl, common_upper=cu, common_width_decades=cw,
                independent_lower=il, independent_upper=iu, independent_width_decades=iw, common_terms=ct,
                independent_terms=it, seconds_each=(cs + is_) / 2, ratio=10.0 ** cw)


def run(reduced: bool = False) -> list[dict]:
    """Run the benchmarks; returns one dict per result row."""
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
        interval_width({"name": "blob2d", "options": {"width": 0.15, "render_noise": 0.3}, "params": ["x"]},
                       "blob2d x (render_noise 0.3)", 0.5, 0.3, 16, test_grid=7, fd_step=0.01) if reduced else
        interval_width({"name": "pi_hallway", "options": {"defines": {"width": 40, "height": 30}}},
                       "pi_hallway 40×30 NLOS", 1.3, 0.025, 512),
    ]


if __name__ == "__main__":
    from . import main

    main(__name__)
