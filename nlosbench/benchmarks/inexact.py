"""Benchmark of the inexact-rendering interval at equal render budget.

(a) Synthetic toy (blob2d with rendering noise S²L/N, AWGN, true HCR from the clean images; the sup
    sits at the smallest Δ, NLOS-like): for a few budgets N_eff (up to the paper's 65536), over
    repeated runs, the width of [HCR_Neff, HCR-hat] and the error of each end against the truth
    (log10). The paper's design: 10 levels N = b·2 … b·11 with b = N_eff/64 (Σ N ≈ N_eff), each
    level (and N_eff) as R = 8 replicates of N/8 spp (4 in reduced mode) — the same statistics as
    one render at N — so the half-sample bootstrap can widen the ends: `coverage` is how often the
    raw interval holds the truth, `coverage_ci` how often [HCR_Neff CI low, HCR-hat CI high] (90 %)
    does.
    `ratio` = RMS error of HCR-hat / RMS error of HCR_Neff.
(b) cornell_ball (real Mitsuba): renders/s and samples/s of a k-level render set against one N_eff
    render set of the same samples per image; `ratio` = time of the k levels / time of N_eff (the
    per-render overhead of splitting the budget).

Run: `python -m nlosbench.benchmarks.inexact [--reduced]` (a table, then one JSON line per row).
"""
from __future__ import annotations

import time

import numpy as np
import torch

from ..bank import RenderBank
from ..bounds.hcr import hcr_from_lambda
from ..bounds.inexact import inexact_hcr
from ..noise import AWGN
from ..seeds import derive

S_RENDER = 0.15
DX = np.array([0.0025, 0.005, 0.01, 0.02, 0.04, 0.08, -0.0025, -0.005, -0.01, -0.02, -0.04, -0.08])


def _paper_levels(n_eff: int) -> list[int]:
    return [n_eff // 64 * i for i in range(2, 12)]


def _toy(n_eff: int, reps: int, replicates: int = 8, bootstrap: int = 100) -> dict:
    from .. import scenes

    model = scenes.get("blob2d", render_noise=S_RENDER)
    theta = np.array([0.5, 0.5])
    pts = np.vstack([theta, theta + np.stack([DX, 0 * DX], 1)])
    noise = AWGN(1.0)
    clean = torch.stack([model.clean(torch.as_tensor(p)) for p in pts])
    true = hcr_from_lambda(noise.chi2_exponent(clean[0], clean[1:]), DX).log10
    levels = _paper_levels(n_eff)
    ends = np.empty((reps, 5))
    for rep in range(reps):
        X = RenderBank(model, seed=rep).levels_at(pts, levels, replicates, "levels")
        Xe = RenderBank(model, seed=rep).levels_at(pts, [n_eff], replicates, "n-eff")
        r = inexact_hcr(X[:, :, 0], X[:, :, 1:], DX, levels, noise, Xe[0, :, 0], Xe[0, :, 1:], n_eff,
                        bootstrap=bootstrap, seed=derive(rep, "bench-inexact-bootstrap"))
        ends[rep] = r.hcr_neff.log10, r.hcr_hat.log10, r.hcr_hat.unresolved, r.ci_neff[0], r.ci_hat[1]
    neff, hat, unres = ends[:, 0] - true, ends[:, 1] - true, ends[:, 2].astype(bool)
    ok = ~unres
    rms_neff, rms_hat = float(np.sqrt(np.mean(neff**2))), float(np.sqrt(np.mean(hat[ok] ** 2)))
    return dict(bench="toy_interval", n_eff=n_eff, levels=f"{levels[0]}..{levels[-1]} (k={len(levels)})",
                samples_levels=sum(levels), replicates=replicates, reps=reps, true_log10=float(true),
                width_decades=float(np.mean(ends[ok, 1] - ends[ok, 0])), bias_neff=float(neff.mean()),
                rms_neff=rms_neff, bias_hat=float(hat[ok].mean()), rms_hat=rms_hat,
                unresolved=float(unres.mean()), neff_below=float(np.mean(neff <= 0)),
                coverage=float(np.mean((neff <= 0) & ((hat >= 0) | unres))),
                coverage_ci=float(np.mean((ends[:, 3] <= true) & (ends[:, 4] >= true))), ratio=rms_hat / rms_neff)


def _cornell(levels: list[int], n_eff: int, points: list[float]) -> dict:
    from .. import scenes

    model = scenes.get("cornell_ball").restrict(["ball_x"])
    model.render(points[:1], 4, 0)  # warm up (kernel compilation) outside the timings
    timings = {}
    for name, lv, purpose in (("levels", levels, "levels"), ("n_eff", [n_eff], "n-eff")):
        before = model.stats.snapshot()
        t0 = time.perf_counter()
        RenderBank(model, seed=1).levels_at(points, lv, 1, purpose)
        dt = time.perf_counter() - t0
        timings[name] = (dt, model.stats.since(before))
    (t_lv, s_lv), (t_eff, s_eff) = timings["levels"], timings["n_eff"]
    return dict(bench="cornell_render_sets", k=len(levels), levels=f"{levels[0]}..{levels[-1]}", n_eff=n_eff,
                points=len(points), levels_s=t_lv, n_eff_s=t_eff, levels_renders_per_s=s_lv.renders / t_lv,
                n_eff_renders_per_s=s_eff.renders / t_eff, levels_msamples_per_s=s_lv.samples / t_lv / 1e6,
                n_eff_msamples_per_s=s_eff.samples / t_eff / 1e6, ratio=t_lv / t_eff)


def run(reduced: bool = False) -> list[dict]:
    """Toy interval rows (one per budget) and the cornell_ball timing row."""
    budgets, reps, R = ([1024], 6, 4) if reduced else ([1024, 4096, 16384, 65536], 40, 8)
    rows = [_toy(b, reps, R) for b in budgets]
    if reduced:
        rows.append(_cornell([8, 16], 24, [0.0, 0.1]))
    else:
        rows.append(_cornell(_paper_levels(1024), 1024, [-0.2, -0.1, 0.0, 0.1, 0.2]))
    return rows


if __name__ == "__main__":
    from . import main

    main(__name__)
