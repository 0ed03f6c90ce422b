"""One result row per (parameter, backend, remedy, spp): artifact metrics, cost relative to a forward
render, error of the total derivative, and the time needed to reach a target error.

Time to target: for an unbiased estimator the squared error falls as 1/spp, i.e. as 1/time, so a
configuration with error e after t seconds reaches error e* after t·(e/e*)² seconds. A configuration
whose total derivative disagrees with the reference (biased) never does: +inf.
"""
from __future__ import annotations

import numpy as np

from ..forward.gradients import GradientSettings
from ..forward.model import ForwardModel
from ..seeds import derive
from .cost import Cost
from .images import GradientRun, gradient_images
from .metrics import THRESHOLD, Reference, summarize

MIB = float(1 << 20)
#: below this a forward render's peak memory is allocator noise (Dr.Jit's symbolic loops keep the path
#: state in registers: a 32×32, 64-spp render of cornell_paper adds < 0.1 MiB), so no ratio is formed
MIN_FORWARD_PEAK = 1 << 20


def fd_reference(model: ForwardModel, theta, index: int, spp: int, rounds: int, step: float, seed: int) -> Reference:
    """High-spp FD reference: `rounds` independent central-difference images (common random numbers
    within each), mean and per-pixel standard error."""
    if rounds < 2:
        raise ValueError(f"a reference needs at least 2 rounds for its standard error, got {rounds}")
    run = gradient_images(model, theta, index, GradientSettings("fd", step=step), spp,
                          [derive(seed, "reference-round", r) for r in range(rounds)])
    return Reference.from_stack(run.images, center="mean")


def result_row(run: GradientRun, ref: Reference, forward: Cost, target_rel_error: float,
               threshold: float = THRESHOLD, min_area: int = 1) -> dict:
    """Metrics (see metrics.summarize) plus seconds and peak MiB per gradient, their ratios to one
    forward render at the same spp (memory: NaN when the render's peak is under MIN_FORWARD_PEAK),
    RMSE of the per-seed total derivative against the reference (and relative to |reference total|),
    and the seconds to reach `target_rel_error`."""
    if not target_rel_error > 0:
        raise ValueError(f"target_rel_error must be > 0, got {target_rel_error}")
    row = summarize(run.images, ref, threshold, min_area)
    totals = np.asarray(run.images, dtype=np.float64).sum(axis=(1, 2, 3))
    err = float(np.sqrt(np.mean((totals - ref.total) ** 2)))
    rel = err / abs(ref.total) if ref.total != 0 else float("inf")
    unbiased = bool(row.get("agrees", True))
    row.update(
        seconds=run.seconds, time_ratio=run.seconds / forward.seconds if forward.seconds > 0 else float("nan"),
        peak_mib=run.peak_bytes / MIB,
        memory_ratio=run.peak_bytes / forward.peak_bytes if forward.peak_bytes >= MIN_FORWARD_PEAK else float("nan"),
        renders=run.renders, grad_passes=run.grad_passes, total_rmse=err, rel_total_error=rel,
        cost_to_target=run.seconds * (rel / target_rel_error) ** 2 if unbiased and np.isfinite(rel) else float("inf"))
    return row
