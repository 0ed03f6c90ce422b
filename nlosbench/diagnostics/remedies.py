"""Remedies for artifact-prone AD gradients suggested by the paper, at a chosen total spp:

- mean-of-K:   K independent AD passes of spp/K each, averaged per pixel (the same estimator as one
               pass of spp, kept as the equal-cost baseline);
- median-of-K: the per-pixel median of those K ≥ 3 passes: robust to outliers that hit fewer than
               K/2 passes, biased where the per-pixel noise is skewed (the metrics show how much);
- visibility-boost: more samples where visibility changes, in sample space: the continuous term at
               spp (`sppp = sppi = 0`) plus the visibility terms alone (`sppc = 0`) at boost·spp.
               The derivative is the sum of the two, so this is unbiased; with boost = 1 it is the
               plain pass, to float rounding (both parts use the pass's seed; tested on real renders).

A pixel-space variant (a second pass only over pixels flagged as silhouette or outlier) needs a
cropped film; in Mitsuba 3.9 `prb_projective` gets the silhouette derivatives of a cropped film wrong
(a 12×12 crop of the 32×32 cornell_paper film around the red ball, d/d red_x, 8 × 64 spp: silhouette
pixels 5–10× smaller than in the full film's derivative), so it is not offered.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..forward.gradients import GradientSettings
from ..forward.model import ForwardModel
from ..seeds import derive
from .cost import Cost
from .images import GradientRun, gradient_images

#: the remedies `remedy_run` applies, by name (the module docstring says what each does)
REMEDIES = ("mean", "median", "visibility-boost")


def mean_of_k(passes) -> np.ndarray:
    """Per-pixel mean of K passes (K, H, W, C) → (H, W, C) float64.

    Examples
    --------
    >>> import numpy as np
    >>> passes = np.array([1.0, 2.0, 30.0]).reshape(3, 1, 1, 1)  # one pass hit by an outlier
    >>> float(nb.diagnostics.mean_of_k(passes)[0, 0, 0])
    11.0
    """
    return np.asarray(passes, dtype=np.float64).mean(axis=0)


def median_of_k(passes) -> np.ndarray:
    """Per-pixel median of K passes (K, H, W, C) → (H, W, C) float64.

    Examples
    --------
    >>> import numpy as np
    >>> passes = np.array([1.0, 2.0, 30.0]).reshape(3, 1, 1, 1)  # one pass hit by an outlier
    >>> float(nb.diagnostics.median_of_k(passes)[0, 0, 0])
    2.0
    """
    return np.median(np.asarray(passes, dtype=np.float64), axis=0)


def _sum_costs(costs: Sequence[Cost]) -> Cost:
    return Cost(sum(c.seconds for c in costs), max(c.peak_bytes for c in costs), costs[0].method)


def k_pass(model: ForwardModel, theta, index: int, settings: GradientSettings, spp: int, seeds: Sequence[int],
           k: int, how: str) -> GradientRun:
    """For each seed, `how` ('mean' or 'median') of K passes of spp // K samples (seeds derived
    from it): S images at the cost of about S·(one pass of spp)."""
    if settings.method != "ad":
        raise ValueError(f"the K-pass remedies apply to AD backends, got method {settings.method!r}")
    if how not in ("mean", "median"):
        raise ValueError(f"how must be 'mean' or 'median', got {how!r}")
    if k < (3 if how == "median" else 2) or spp // k < 1:
        raise ValueError(
            f"need K >= 2 (median: K >= 3, the median of 2 is their mean) and spp >= K, got K={k}, spp={spp}"
        )
    combine = mean_of_k if how == "mean" else median_of_k
    imgs, costs, renders, passes = [], [], 0, 0
    for s in seeds:
        run = gradient_images(model, theta, index, settings, spp // k, [derive(s, "remedy-pass", i) for i in range(k)])
        imgs.append(combine(run.images).astype(np.float32))
        costs.append(_sum_costs(run.costs))
        renders, passes = renders + run.renders, passes + run.grad_passes
    return GradientRun(np.stack(imgs), list(seeds), costs, renders, passes)


def visibility_boost(
    model: ForwardModel, theta, index: int, settings: GradientSettings, spp: int, seeds: Sequence[int], boost: int
) -> GradientRun:
    """For each seed: continuous derivative at spp plus visibility derivatives at boost·spp
    (projective integrators only)."""
    if settings.method != "ad" or settings.ad.get("type") not in ("prb_projective", "direct_projective"):
        raise ValueError(
            f"visibility-boost needs a projective AD backend (prb_projective or direct_projective), got {settings}"
        )
    if boost < 1:
        raise ValueError(f"boost must be >= 1, got {boost}")
    cont = replace(settings, ad={**settings.ad, "sppp": 0, "sppi": 0})
    vis = replace(settings, ad={**settings.ad, "sppc": 0})
    a = gradient_images(model, theta, index, cont, spp, seeds)
    b = gradient_images(model, theta, index, vis, boost * spp, seeds)
    costs = [_sum_costs([x, y]) for x, y in zip(a.costs, b.costs, strict=True)]
    return GradientRun(a.images + b.images, list(seeds), costs, a.renders + b.renders, a.grad_passes + b.grad_passes)


def remedy_run(
    model: ForwardModel,
    theta,
    index: int,
    settings: GradientSettings,
    spp: int,
    seeds: Sequence[int],
    name: str,
    k: int = 4,
    boost: int = 4,
) -> GradientRun:
    """Dispatch on a remedy name in REMEDIES.

    Examples
    --------
    On the analytic blob (exact AD) the median of K passes is the plain gradient:

    >>> import numpy as np
    >>> model, ad = nb.scenes.get("blob2d"), nb.diagnostics.backend({"method": "ad"})
    >>> run = nb.diagnostics.remedy_run(model, [0.5, 0.5], 0, ad, spp=8, seeds=[1, 2], name="median", k=3)
    >>> plain = nb.diagnostics.gradient_images(model, [0.5, 0.5], 0, ad, spp=8, seeds=[1])
    >>> run.images.shape, bool(np.allclose(run.images[0], plain.images[0]))
    ((2, 24, 24, 1), True)
    >>> nb.diagnostics.remedy_run(model, [0.5, 0.5], 0, ad, spp=8, seeds=[1], name="visibility-boost")
    Traceback (most recent call last):
    ValueError: visibility-boost needs a projective AD backend (prb_projective or direct_projective), got ...
    """
    if name in ("mean", "median"):
        return k_pass(model, theta, index, settings, spp, seeds, k, name)
    if name == "visibility-boost":
        return visibility_boost(model, theta, index, settings, spp, seeds, boost)
    raise ValueError(f"unknown remedy {name!r}; known: {list(REMEDIES)}")
