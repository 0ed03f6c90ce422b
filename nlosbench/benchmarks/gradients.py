"""Benchmark: error of the total derivative Σ_ω ∂L/∂θ against wall time, for the red ball's position
and radius on the paper's Cornell box (`cornell_paper`): FD with and without common random numbers,
AD with each integrator, and the AD remedies (mean / median of K = 4 passes, visibility boost ×4).

Each row: seconds per gradient image (warm: median over seeds after the first) and its `ratio` to
one forward render at the same spp, timed just before it in this process; the peak RSS per gradient
(see diagnostics.cost: a forward render's own peak is < 1 MiB here, so no ratio is formed); the
RMSE of the per-seed total derivative relative to a high-spp FD reference; outlier pixels per image;
whether the total agrees with the reference (95 % CI); and the seconds to reach a 5 % total-derivative
error (t·(e/0.05)², ∞ when biased). Full mode: 32×32, 64 spp, 8 seeds (2 for Mitsuba's default octree
guiding, ~40 s a pass on 2 cores), reference 8192 spp × 4 rounds: about 10 minutes on 2 shared cores.

Run: `python -m nlosbench.benchmarks.gradients [--reduced]`.
"""
from __future__ import annotations

import nlosbench as nb
from nlosbench.diagnostics import backend, forward_cost, gradient_images, label, remedy_run
from nlosbench.diagnostics.evaluate import fd_reference, result_row
from nlosbench.seeds import derive

SEED = 2024
TARGET = 0.05


def _configs(reduced: bool) -> list[tuple[dict, str, int]]:
    """(backend spec, remedy or '', seeds) per measured configuration."""
    cheap = {"method": "ad", "integrator": "prb_projective", "guiding": "none"}
    fds = [{"method": "fd", "step": 0.01, "crn": True}, {"method": "fd", "step": 0.01, "crn": False}]
    if reduced:
        return [(b, "", 2) for b in fds + [{**cheap, "sppi": 0}]] + [({**cheap, "sppi": 0}, "median", 2)]
    ads = [
        {"method": "ad", "integrator": "prb"},
        {"method": "ad", "integrator": "direct_projective", "guiding": "none"},
        cheap,
        {**cheap, "sppi": 0},
    ]
    return (
        [(b, "", 8) for b in fds + ads]
        + [({"method": "ad", "integrator": "prb_projective"}, "", 2)]
        + [(cheap, r, 8) for r in ("mean", "median", "visibility-boost")]
    )


def run(reduced: bool = False) -> list[dict]:
    """One row per (parameter, gradient configuration); see the module docstring."""
    res, spp, ref_spp, ref_rounds = (16, 16, 64, 2) if reduced else (32, 64, 8192, 4)
    params = ["red_x"] if reduced else ["red_x", "red_radius"]
    model = nb.scenes.get("cornell_paper", defines={"res": res})
    theta = model.params.default
    rows = []
    for name in params:
        j = model.params.index(name)
        ref = fd_reference(model, theta, j, ref_spp, ref_rounds, 0.01, derive(SEED, "bench-ref", j))
        for b, (spec, remedy, seeds) in enumerate(_configs(reduced)):
            settings = backend(spec)
            # the forward render is re-timed beside each configuration, so a shared machine's load cancels in the ratio
            fwd = forward_cost(model, theta, spp, [derive(SEED, "bench-forward", j, b, s) for s in range(4)])
            sd = [derive(SEED, "bench", j, b, s) for s in range(seeds)]
            run_ = (
                remedy_run(model, theta, j, settings, spp, sd, remedy)
                if remedy
                else gradient_images(model, theta, j, settings, spp, sd)
            )
            r = result_row(run_, ref, fwd, TARGET)
            rows.append(
                {
                    "bench": "gradients",
                    "param": name,
                    "gradient": label(settings) + (f" + {remedy}" if remedy else ""),
                    "res": res,
                    "spp": spp,
                    "seeds": seeds,
                    "seconds": r["seconds"],
                    "ratio": r["time_ratio"],
                    "forward_s": fwd.seconds,
                    "rel_total_error": r["rel_total_error"],
                    "image_rmse": r["rmse"],
                    "outlier_px": r["outlier_pixels_per_image"],
                    "agrees": r["agrees"],
                    "time_to_5pct_s": r["cost_to_target"],
                    "peak_mib": r["peak_mib"],
                    "ref_total": ref.total,
                    "ref_total_se": ref.total_se,
                }
            )
    return rows


if __name__ == "__main__":
    from nlosbench.benchmarks import main

    main(__name__)
