"""Benchmark of the bound computations on synthetic renders (no renderer needed).

(a) HCR curve over a G-point grid through `pairwise_lambda` against a naive loop calling `hcr()`
    for every θ* (same numbers asserted, time ratio reported);
(b) pairwise-λ throughput: GB/s of image data compared, i.e. G² × (bytes of one render) / time;
(c) `interval_width`: the HCR interval at one θ* on the Π hallway from the bound service (4 replicate sets,
    a test grid over Θ and small offsets), with common random numbers against independent seeds at equal
    render budget: each width in decades (upper − lower end; inf when the upper end is open) and `ratio` =
    the common-seed interval's factor 10^width (the paper's intervals are within about 2×). Full mode: NLOS
    (θ* = 1.3 m) at 40 × 30 with information-equivalent AWGN σ = 0.025; reduced: blob2d with synthetic
    rendering noise;
(d) `precision_allocation`: the pixel-samples for which every θ of a grid gets its HCR and CRLB intervals within
    ±p, adaptively (`BoundService.at(precision=p)`: pilot sets everywhere, fresh sets, FD steps and tested Δ only
    where a θ misses) against a uniform plan (the same spp and replicate sets at every θ, raised over the ladder
    3, 4, 6, 8, 12, … until the worst θ meets p; each run counts the distinct renders it uses, through a shared
    disk cache so nothing renders twice). `ratio` = uniform / adaptive pixel-samples, for the same worst-θ
    precision (the uniform ends at the service's level, the adaptive ones with α spent along the looks). Full mode:
    the Π hallway at 40 × 30, AWGN σ = 0.025, three NLOS θ whose CRLB spans a decade (1.0, 1.3, 1.6 m), 512 spp, 4
    pilot sets, a 12-point test grid, p = 0.5 (the demo's 34-point grid at 96 spp and p = 0.25 would take hours on 2
    cores: its NLOS points alone need thousands of 96-spp sets by the service's own prediction); reduced: the Π hallway
    blob2d's x with synthetic rendering noise over 4 θ at p = 0.1 (nearly the same information at every θ: it
    keeps the code running; the gain is measured in full mode);
(e) `curve_allocation`: the same comparison for a decisive curve (`curve(precision=…)` quoting every grid θ, a target
    per θ, the grid's own points as the HCR's test points, FD from a large step halved per θ; `configs/
    decisive_curve.yaml`'s settings) against a uniform plan with the same settings: every θ gets R sets, R raised
    until every θ meets its target. Full mode: the Π hallway at 40 × 30, 6 θ beyond the corner (1.09–1.69 m) at
    512 spp, ±25 % up to 1.5 m and ±50 % beyond; reduced: blob2d's x on a 5-point grid (±5 % at three θ, ±30 %
    at two: measured 1.76× fewer pixel-samples).

Run: `python -m nlosbench.benchmarks.bounds [--reduced]` (a table, then one JSON line per row).
"""
from __future__ import annotations

import tempfile
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


def precision_allocation(spec: dict, label: str, thetas, sigma: float, spp: int, target: float, pilot: int = 3,
                         test_grid: int = 34, offsets: int = 1, fd_step: float = 0.03, max_halvings: int = 2,
                         step_tol: float = 0.1, max_sets: int = 256, seed: int = 0) -> dict:
    """Adaptive against uniform replicate sets for `target` at every θ of `thetas` (see the module docstring)."""
    from nlosbench.bounds.precision import ladder, reached
    from nlosbench.forward.cache import RenderCache

    model = build(spec)
    args = dict(want=("hcr", "crlb"), seeds="common", test_grid=test_grid, offsets=offsets, fd_step=fd_step,
                max_halvings=max_halvings, step_tol=step_tol)
    pts = [[t] for t in thetas]
    with tempfile.TemporaryDirectory() as root:
        store = RenderCache(root)
        t0 = time.perf_counter()
        bank = RenderBank(model, seed=seed, store=store)
        got = BoundService(bank, [AWGN(sigma)]).at(pts, spp, replicates=pilot, precision=target, **args)
        adaptive_s = time.perf_counter() - t0
        adaptive = got[0].precision.pixel_samples
        pixels = adaptive // max(bank.renders * spp, 1)
        adaptive_worst = max(p.precision.worst for p in got)
        uniform = uniform_sets = uniform_worst = None
        for R in ladder(max_sets, pilot - 1, least=3):
            b = RenderBank(model, seed=seed, store=store)
            res = BoundService(b, [AWGN(sigma)]).at(pts, spp, replicates=R, **args)
            worst = max(reached(p.bounds[k]) for p in res for k in ("hcr", "crlb"))
            uniform, uniform_sets, uniform_worst = b.renders * spp * pixels, R, worst
            if worst <= target:
                break
    met = uniform_worst <= target
    return dict(bench="precision_allocation", scene=label, thetas=len(thetas), spp=spp, target=target,
                pilot_sets=pilot, adaptive_pixel_samples=int(adaptive), adaptive_worst=adaptive_worst,
                adaptive_met=adaptive_worst <= target,
                adaptive_seconds=adaptive_s, uniform_pixel_samples=int(uniform), uniform_sets=uniform_sets,
                uniform_worst=uniform_worst, uniform_met=met,
                ratio=uniform / adaptive, ratio_is_lower_bound=not met)


def curve_allocation(spec: dict, label: str, grid, sigma: float, spp: int, targets, pilot: int = 3,
                     quote_step: float = 0.06, max_halvings: int = 2, step_tol: float = 0.1, max_sets: int = 256,
                     seed: int = 0) -> dict:
    """A decisive curve against the uniform plan (module docstring, (e)): `curve(precision=targets)` quoting every
    grid θ with the grid as its HCR test points, no axis offsets and FD from `quote_step`, against `at` on the same
    grid with the same settings and R sets at every θ, R raised over the ladder until every θ meets its target.
    Pixel-samples are the distinct renders each route's bank asked for (grid, stencils, weights) × spp × pixels."""
    from nlosbench.bounds.precision import ladder, reached
    from nlosbench.bounds.service import quote_test_grid
    from nlosbench.forward.cache import RenderCache
    from nlosbench.studies.estimate import pixels as image_pixels

    model = build(spec)
    grid = np.asarray(grid, dtype=np.float64)
    goal = np.broadcast_to(np.asarray(targets, dtype=np.float64), grid.shape)
    pixels = image_pixels(model)
    kw = dict(offsets=0, max_halvings=max_halvings, step_tol=step_tol)
    with tempfile.TemporaryDirectory() as root:
        store = RenderCache(root)
        t0 = time.perf_counter()
        bank = RenderBank(model, seed=seed, store=store)
        got = BoundService(bank, [AWGN(sigma)]).curve(grid, spp, "common", pilot, zzb=False, precision=goal,
                                                      quote_step=quote_step, **kw).precise
        adaptive_s = time.perf_counter() - t0
        adaptive = bank.renders * spp * pixels
        adaptive_met = sum(p.precision.met for p in got)
        uniform = uniform_sets = None
        uniform_met = 0
        for R in ladder(max_sets, pilot - 1, least=3):
            b = RenderBank(model, seed=seed, store=store)
            res = BoundService(b, [AWGN(sigma)]).at(grid[:, None], spp, ("hcr", "crlb"), "common", R,
                                                    quote_test_grid(model.params, grid), fd_step=quote_step, **kw)
            uniform_met = sum(max(reached(p.bounds[k]) for k in ("hcr", "crlb")) <= g
                              for p, g in zip(res, goal, strict=True))
            uniform, uniform_sets = b.renders * spp * pixels, R
            if uniform_met == len(grid):
                break
    return dict(bench="curve_allocation", scene=label, thetas=len(grid), spp=spp, targets=sorted(set(goal.tolist())),
                pilot_sets=pilot, adaptive_pixel_samples=int(adaptive), adaptive_met=int(adaptive_met),
                adaptive_seconds=adaptive_s, uniform_pixel_samples=int(uniform), uniform_sets=uniform_sets,
                uniform_met=int(uniform_met), ratio=uniform / adaptive,
                ratio_is_lower_bound=uniform_met < len(grid) or adaptive_met < len(grid))


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
        precision_allocation({"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]},
                             "blob2d x (render_noise 2), 4 θ", np.array([0.3, 0.45, 0.6, 0.75]), 0.3, 16, 0.1,
                             test_grid=3, fd_step=0.01, max_halvings=1, max_sets=64) if reduced else
        precision_allocation({"name": "pi_hallway", "options": {"defines": {"width": 40, "height": 30}}},
                             "pi_hallway 40×30, NLOS 1.0/1.3/1.6 m", np.array([1.0, 1.3, 1.6]), 0.025, 512, 0.5,
                             pilot=4, test_grid=12, fd_step=0.06, max_halvings=1),
        curve_allocation({"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]},
                         "blob2d x (render_noise 2), 5-point grid", np.linspace(0.2, 0.8, 5), 0.3, 16,
                         [0.05, 0.05, 0.05, 0.3, 0.3], quote_step=0.02, max_halvings=1, max_sets=64) if reduced else
        curve_allocation({"name": "pi_hallway", "options": {"defines": {"width": 40, "height": 30}}},
                         "pi_hallway 40×30, 6 θ over 1.09–1.69 m", np.linspace(1.09, 1.69, 6), 0.025, 512,
                         [0.25, 0.25, 0.25, 0.25, 0.5, 0.5], quote_step=0.06, max_halvings=2),
    ]


if __name__ == "__main__":
    from . import main

    main(__name__)
