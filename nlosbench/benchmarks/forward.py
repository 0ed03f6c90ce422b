"""Forward-model benchmarks on cornell_ball, side by side in one process:

- overhead: ForwardModel.render vs raw `mi.render` on the same scene, spp and seeds (ratio = raw/ours
  throughput; target ≥ 0.9, i.e. ≤ 10 % overhead);
- FD gradient variance with common random numbers vs independent seeds at equal render count
  (total derivative of the image w.r.t. ball position; ratio = var_independent / var_crn);
- AD (prb_projective) variance and cost per gradient relative to one forward render.

And on pi_hallway at 40×30 and 160×120 (reduced: 16×12 and 40×30 at max_depth 3, render_overhead at 16×12):

- frozen_render: ForwardModel.render through the frozen `mi.render` vs the traced one, same model,
  θ moving every call (ratio = traced / frozen seconds per render; > 1: freezing pays);
- render_overhead: ForwardModel.render (passes of the backend's pass size, frozen) vs one raw
  `mi.render` of all samples at 8192 spp (ratio = ours / raw throughput; target ≥ 0.95).
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


def _thetas(model, n: int) -> list[list[float]]:
    """n distinct θ spread over Θ (golden-ratio sequence), so every render moves the scene."""
    lo, hi = model.params.lower, model.params.upper
    return [list(lo + (hi - lo) * ((0.5 + 0.618034 * k) % 1.0)) for k in range(n)]


def _row_common(model, spp: int, reps: int) -> dict:
    W, H = model.size
    return {"scene": model.name, "size": f"{W}x{H}", "backend": model.backend, "spp": spp, "reps": reps,
            "pass_samples": model.max_pass_samples, "passes": len(model._passes(spp, 0))}


def _frozen_render(model, spp: int, reps: int) -> dict:
    """Seconds per ForwardModel.render, frozen vs traced, interleaved on one model (θ differs every call)."""
    saved = model.freeze
    thetas = _thetas(model, 2 * reps + 4)
    try:
        for k, on in enumerate((True, True, False, False)):  # warm-up: first render, recording, compile
            model.freeze = on
            model.render(thetas[k], spp, derive(SEED, "bench-frozen-warmup", k))
        t = {True: 0.0, False: 0.0}
        for i in range(reps):
            for j, on in enumerate((True, False) if i % 2 == 0 else (False, True)):
                model.freeze = on
                start = time.perf_counter()
                model.render(thetas[4 + 2 * i + j], spp, derive(SEED, "bench-frozen", i))
                t[on] += time.perf_counter() - start
    finally:
        model.freeze = saved
    return {"bench": "frozen_render", **_row_common(model, spp, reps), "recordings": model._renderer.n_recordings,
            "frozen_s": t[True] / reps, "traced_s": t[False] / reps, "ratio": t[False] / t[True]}


def _render_overhead(model, spp: int, reps: int) -> dict:
    """ForwardModel.render (its passes) vs one raw mi.render of all spp, same θ and seeds; ours/raw throughput."""
    import mitsuba as mi

    theta = _thetas(model, 1)[0]
    pass_spp = max(s for s, _ in model._passes(spp, 0))
    warm = derive(SEED, "bench-render-overhead-warmup")
    model.render(theta, pass_spp, warm), model.render(theta, pass_spp, warm + 1)  # first render, recording
    np.asarray(mi.render(model.scene, spp=pass_spp, seed=warm))  # the raw kernel (spp is not baked into it)
    t = {"ours": 0.0, "raw": 0.0}
    for i in range(reps):  # alternating order, so a change in machine load hits both alike
        s = derive(SEED, "bench-render-overhead", i)
        for which in ("ours", "raw") if i % 2 == 0 else ("raw", "ours"):
            start = time.perf_counter()
            if which == "ours":
                model.render(theta, spp, s)
            else:
                np.asarray(mi.render(model.scene, spp=spp, seed=s))
            t[which] += time.perf_counter() - start
    t_ours, t_raw = t["ours"], t["raw"]
    return {"bench": "render_overhead", **_row_common(model, spp, reps), "ours_s": t_ours / reps,
            "raw_s": t_raw / reps, "ratio": t_raw / t_ours}


def hallway_rows(reduced: bool = False, overhead: bool = True) -> list[dict]:
    """frozen_render at two sizes and render_overhead at 8192 spp (see the module docstring)."""
    from .. import scenes

    sizes = [(16, 12), (40, 30)] if reduced else [(40, 30), (160, 120)]
    extra = {"max_depth": 3} if reduced else {}
    rows = []
    for k, (w, h) in enumerate(sizes):
        model = scenes.get("pi_hallway", defines={"width": w, "height": h, **extra})
        rows.append(_frozen_render(model, 4 if reduced else 64, 3 if reduced else (10 if k == 0 else 4)))
        if overhead and (not reduced or k == 0):
            rows.append(_render_overhead(model, 8192, 1))
    return rows


def run(reduced: bool = False) -> list[dict]:
    from .. import scenes

    model = scenes.get("cornell_ball", **({} if reduced else {"defines": {"res": 64}}))
    spp, reps = (16, 3) if reduced else (256, 20)
    ad = {"sppc": 4, "sppp": 4, "sppi": 0} if reduced else {}
    return [
        _overhead(model, spp, reps * 3),
        *_fd_variance(model, spp, reps),
        _ad_cost(model, spp, 2 if reduced else 5, ad),
        *hallway_rows(reduced),
    ]


if __name__ == "__main__":
    from . import main

    main(__name__)
