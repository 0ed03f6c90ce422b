"""Forward-model benchmarks on cornell_ball, side by side in one process:

- overhead: ForwardModel.render vs raw `mi.render` on the same scene, spp and seeds (ratio = raw/ours
  throughput; target ≥ 0.9, i.e. ≤ 10 % overhead);
- FD gradient variance with common random numbers vs independent seeds at equal render count
  (total derivative of the image w.r.t. ball position; ratio = var_independent / var_crn);
- AD (prb_projective) variance and cost per gradient relative to one forward render.
"""
from __future__ import annotations

import time

import numpy as np

from ..seeds import derive

THETA = [0.0, 0.3, 0.8]
SEED = 2024


def _overhead(model, spp: int, reps: int) -> dict:
    import mitsuba as mi

    warmup = derive(SEED, "bench-overhead-warmup")
    model.render(THETA, spp, warmup), mi.render(model.scene, spp=spp, seed=warmup)  # compile both
    t_ours = t_raw = 0.0
    for i in range(reps):  # interleaved, so machine noise hits both alike
        s = derive(SEED, "bench-overhead", i)
        t = time.perf_counter()
        model.render(THETA, spp, s)
        t_ours += time.perf_counter() - t
        t = time.perf_counter()
        np.asarray(mi.render(model.scene, spp=spp, seed=s))
        t_raw += time.perf_counter() - t
    return {"bench": "forward_overhead", "spp": spp, "reps": reps, "ours_s": t_ours / reps, "raw_s": t_raw / reps,
            "ratio": t_raw / t_ours}


def _fd_variance(model, spp: int, reps: int) -> list[dict]:
    from ..forward.gradients import GradientSettings, fd_jacobian

    j = model.params.index("ball_x")
    out = {}
    for crn in (True, False):
        s = GradientSettings(step=0.02, crn=crn)
        vals = [float(fd_jacobian(model, THETA, spp, derive(SEED, "bench-fd", r), s, indices=[j]).double().sum())
                for r in range(reps)]
        out[crn] = (np.var(vals, ddof=1), np.mean(vals))
    return [{"bench": "fd_crn_vs_independent", "spp": spp, "reps": reps, "renders_per_gradient": 2,
             "var_crn": out[True][0], "var_independent": out[False][0], "mean_crn": out[True][1],
             "mean_independent": out[False][1], "ratio": out[False][0] / out[True][0]}]


def _ad_cost(model, spp: int, reps: int, ad: dict) -> dict:
    j = model.params.index("ball_x")
    model.jvp(THETA, j, spp, derive(SEED, "bench-ad-warmup"), **ad)  # compile
    t = time.perf_counter()
    vals = [float(model.jvp(THETA, j, spp, derive(SEED, "bench-ad", r), **ad).double().sum()) for r in range(reps)]
    t_ad = (time.perf_counter() - t) / reps
    t = time.perf_counter()
    for r in range(reps):
        model.render(THETA, spp, derive(SEED, "bench-ad-forward", r))
    t_fwd = (time.perf_counter() - t) / reps
    return {
        "bench": "ad_prb_projective",
        "spp": spp,
        "reps": reps,
        "ad": str(ad),
        "var_ad": float(np.var(vals, ddof=1)),
        "mean_ad": float(np.mean(vals)),
        "ad_s": t_ad,
        "forward_s": t_fwd,
        "ratio": t_ad / t_fwd,
    }


def run(reduced: bool = False) -> list[dict]:
    from .. import scenes

    model = scenes.get("cornell_ball", **({} if reduced else {"defines": {"res": 64}}))
    spp, reps = (16, 3) if reduced else (256, 20)
    ad = {"sppc": 4, "sppp": 4, "sppi": 0} if reduced else {}
    return [
        _overhead(model, spp, reps * 3),
        *_fd_variance(model, spp, reps),
        _ad_cost(model, spp, 2 if reduced else 5, ad),
    ]


if __name__ == "__main__":
    from . import main

    main(__name__)
