"""Render work shared by studies, as executor tasks (module level, so worker processes can unpickle
them): `fn(model, item)` returns (tag, result, renders done in that process; cached renders count 0)."""
from __future__ import annotations

from ..executors import SerialExecutor
from ..forward.gradients import GradientSettings, fd_jacobian


def render_task(model, item: tuple) -> tuple:
    """item (tag, θ, spp, seed) → (tag, image (H, W, C) float32 tensor, renders)."""
    tag, theta, spp, seed = item
    before = model.stats.snapshot()
    img = model.render(theta, spp, seed)
    return tag, img, model.stats.since(before).renders


def jacobian_task(model, item: tuple) -> tuple:
    """item (tag, θ, spp, seed, ξ) → (tag, central-FD Jacobian (P, H, W, C) with CRN, renders)."""
    tag, theta, spp, seed, step = item
    before = model.stats.snapshot()
    jac = fd_jacobian(model, theta, spp, seed, GradientSettings(step=step))
    return tag, jac, model.stats.since(before).renders


def run_tasks(ctx, fn, items: list, desc: str, executor=None) -> tuple[dict, int]:
    """({tag: result}, renders done) of `fn` over `items` through `executor` (default: the run's, else
    serial in this process), with a progress bar. Results do not depend on the executor: every item
    carries its own seed."""
    executor = executor or ctx.executor or SerialExecutor(ctx.model)
    out, renders = {}, 0
    for tag, value, n in ctx.progress(executor.imap_unordered(fn, items), total=len(items), desc=desc):
        out[tag] = value
        renders += n
    return out, renders
