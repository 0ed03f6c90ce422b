"""Artifact metrics for gradient images ∂L/∂θ_j (H, W, C): outlier scores, clusters, persistence
across seeds, total-derivative agreement with a reference, per-pixel variance.

Outlier score of seed s at pixel ω (max over channels c):

    z_s(ω) = |g_s(ω) − ref(ω)| / σ(ω),   σ(ω) = sqrt( max(spread(ω), floor)² + se_ref(ω)² )

spread(ω) is the robust spread of the S seeds at that pixel (1.4826 · median |g_s − median_s g|,
robust while an outlier hits fewer than half the seeds), maximised over the 3×3 neighbourhood so it
follows the larger legitimate noise at silhouettes; floor is the same statistic pooled over all
pixels, and at least RELATIVE_FLOOR × the reference's signal (Monte Carlo gradient noise is sparse:
most seeds of most pixels can be exactly 0, which would make any non-zero value infinitely
significant); se_ref is the reference's per-pixel standard error. A bias that persists in every
seed keeps spread small while |g − ref| is large, so it is flagged too. Pixels with z > threshold are
outliers; 8-connected outlier pixels form clusters.
All statistics are float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, stats

#: 1.4826 · MAD estimates σ for Gaussian data
MAD_TO_SD = 1.4826
#: default outlier threshold on z: Gaussian noise with σ jumping 10× across one-pixel silhouettes,
#: 8 seeds, reached z ≈ 5 at most in 737,280 pixel-scores (tests/test_diagnostics.py)
THRESHOLD = 8.0
#: σ is at least this fraction of the reference's signal (99th percentile of |ref|, all channels)
RELATIVE_FLOOR = 0.02
_EIGHT = np.ones((3, 3), dtype=bool)


def as_stack(images) -> np.ndarray:
    """Gradient images as float64 (S, H, W, C); a single (H, W, C) image becomes S = 1."""
    a = np.asarray(images.detach().cpu() if hasattr(images, "detach") else images, dtype=np.float64)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4:
        raise ValueError(f"expected gradient images (S, H, W, C) or (H, W, C), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"gradient images contain {int((~np.isfinite(a)).sum())} NaN/Inf values")
    return a


def robust_scale(x: np.ndarray, axis=None) -> np.ndarray:
    """1.4826 · median |x − median x| along `axis` (all elements when None); float64."""
    x = np.asarray(x, dtype=np.float64)
    med = np.median(x, axis=axis, keepdims=True)
    return MAD_TO_SD * np.median(np.abs(x - med), axis=axis)


@dataclass
class Reference:
    """What a gradient image is compared with: an image (H, W, C), its per-pixel standard error, and
    the total derivative Σ_ω ∂L/∂θ with its standard error. All float64.

    Examples
    --------
    Three rounds of a reference gradient: 1, 2 and 3 in every pixel:

    >>> import numpy as np
    >>> ref = nb.diagnostics.Reference.from_stack(np.stack([np.full((2, 2, 1), v) for v in (1.0, 2.0, 3.0)]))
    >>> float(ref.image[0, 0, 0]), ref.total, round(ref.total_se, 3), ref.n  # totals 4, 8, 12: SE 4/√3
    (2.0, 8.0, 2.309, 3)
    """

    image: np.ndarray
    stderr: np.ndarray
    total: float
    total_se: float
    n: int
    center: str

    @classmethod
    def from_stack(cls, images, center: str = "mean") -> Reference:
        """From R independent estimates (R, H, W, C): e.g. R rounds of a high-spp FD gradient
        (center="mean"), or the seeds of one backend when no reference is affordable
        (center="median": robust to outliers in a minority of seeds)."""
        a = as_stack(images)
        R = a.shape[0]
        totals = a.sum(axis=(1, 2, 3))
        if center == "mean":
            img = a.mean(0)
            se = a.std(0, ddof=1) / np.sqrt(R) if R > 1 else np.zeros_like(img)
        elif center == "median":
            img = np.median(a, 0)
            # the median of R samples has standard error ≈ 1.2533 σ/√R for Gaussian noise
            se = 1.2533 * robust_scale(a, axis=0) / np.sqrt(R) if R > 1 else np.zeros_like(img)
        else:
            raise ValueError(f"center must be 'mean' or 'median', got {center!r}")
        total_se = float(totals.std(ddof=1) / np.sqrt(R)) if R > 1 else float("nan")
        return cls(img, se, float(totals.mean()), total_se, R, center)


def outlier_scores(images, ref: Reference) -> np.ndarray:
    """z scores (S, H, W) float64 of S images of one backend against `ref` (see module docstring).

    Examples
    --------
    One pixel of one seed off by 1 where the reference is 1 everywhere (σ floored at 2 % of the signal):

    >>> import numpy as np
    >>> g = np.ones((4, 8, 8, 1))
    >>> g[0, 3, 3] = 2.0
    >>> z = nb.diagnostics.outlier_scores(g, nb.diagnostics.Reference.from_stack(np.ones((4, 8, 8, 1))))
    >>> z.shape, round(float(z[0, 3, 3]), 6), float(z[1:].max())
    ((4, 8, 8), 50.0, 0.0)
    """
    a = as_stack(images)
    if a.shape[1:] != ref.image.shape:
        raise ValueError(f"images {a.shape[1:]} and reference {ref.image.shape} differ in shape")
    dev = a - np.median(a, axis=0)
    spread = MAD_TO_SD * np.median(np.abs(dev), axis=0)
    # a few seeds give a noisy spread: take the largest of each 3×3 neighbourhood, so a pixel on a
    # one-pixel-wide silhouette whose own few seeds happen to agree still gets the silhouette's σ
    spread = ndimage.maximum_filter(spread, size=(3, 3, 1), mode="nearest")
    floor = np.maximum(
        robust_scale(dev if a.shape[0] > 1 else a - ref.image, axis=(0, 1, 2)),  # (C,)
        RELATIVE_FLOOR * np.percentile(np.abs(ref.image), 99),
    )
    sigma = np.sqrt(np.maximum(spread, floor) ** 2 + ref.stderr**2)
    r = np.abs(a - ref.image)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sigma > 0, r / sigma, np.where(r > 0, np.inf, 0.0))
    return z.max(axis=-1)


@dataclass
class Cluster:
    """A connected (8-neighbour) group of outlier pixels: area in pixels, bounding box
    (row0, row1, col0, col1, end-exclusive), centroid (row, col) and its largest score."""

    area: int
    bbox: tuple[int, int, int, int]
    centroid: tuple[float, float]
    peak: float


def clusters(z: np.ndarray, threshold: float = THRESHOLD, min_area: int = 1) -> list[Cluster]:
    """Clusters of pixels with score z (H, W) above `threshold`, largest first; smaller than
    `min_area` pixels are dropped.

    Examples
    --------
    >>> import numpy as np
    >>> z = np.zeros((8, 8))
    >>> z[2:4, 5:7], z[7, 0] = 20.0, 9.0
    >>> [(c.area, c.bbox, c.peak) for c in nb.diagnostics.clusters(z)]
    [(4, (2, 4, 5, 7), 20.0), (1, (7, 8, 0, 1), 9.0)]
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"expected a score image (H, W), got shape {z.shape}")
    labels, n = ndimage.label(z > threshold, structure=_EIGHT)
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        inside = labels[sl] == k
        area = int(inside.sum())
        if area < min_area:
            continue
        rows, cols = np.nonzero(inside)
        out.append(
            Cluster(
                area,
                (sl[0].start, sl[0].stop, sl[1].start, sl[1].stop),
                (float(rows.mean() + sl[0].start), float(cols.mean() + sl[1].start)),
                float(z[sl][inside].max()),
            )
        )
    return sorted(out, key=lambda c: -c.area)


def outlier_mask(z: np.ndarray, threshold: float = THRESHOLD, min_area: int = 1) -> np.ndarray:
    """Boolean (…, H, W): pixels in clusters of at least `min_area` outliers.

    Examples
    --------
    >>> import numpy as np
    >>> z = np.zeros((8, 8))
    >>> z[2:4, 5:7], z[7, 0] = 20.0, 9.0
    >>> int(nb.diagnostics.outlier_mask(z).sum()), int(nb.diagnostics.outlier_mask(z, min_area=2).sum())
    (5, 4)
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim == 3:
        return np.stack([outlier_mask(zi, threshold, min_area) for zi in z])
    labels, _ = ndimage.label(z > threshold, structure=_EIGHT)
    if min_area <= 1:
        return labels > 0
    sizes = np.bincount(labels.ravel())
    keep = sizes >= min_area
    keep[0] = False
    return keep[labels]


def persistence(masks: np.ndarray, dilate: int = 1) -> float:
    """Mean Jaccard overlap of the outlier masks (S, H, W) over all pairs of seeds, each dilated by
    `dilate` pixels: ≈1 when clusters stay in place across seeds, ≈0 when they move. NaN when fewer
    than two seeds have outliers.

    Examples
    --------
    >>> import numpy as np
    >>> masks = np.zeros((2, 8, 8), dtype=bool)
    >>> masks[:, 2:4, 2:4] = True
    >>> nb.diagnostics.persistence(masks)  # the same cluster in both seeds
    1.0
    >>> masks[1] = np.roll(masks[1], 4, axis=1)
    >>> nb.diagnostics.persistence(masks)  # it moved
    0.0
    """
    m = np.asarray(masks, dtype=bool)
    if dilate > 0:
        m = np.stack([ndimage.binary_dilation(x, structure=_EIGHT, iterations=dilate) for x in m])
    hit = [i for i in range(len(m)) if m[i].any()]
    if len(hit) < 2:
        return float("nan")
    j = [
        np.logical_and(m[a], m[b]).sum() / np.logical_or(m[a], m[b]).sum()
        for i, a in enumerate(hit)
        for b in hit[i + 1 :]
    ]
    return float(np.mean(j))


@dataclass
class Agreement:
    """Total derivative T = Σ_ω ∂L/∂θ of a backend (mean over S seeds) against the reference:
    difference, its confidence interval (Welch t, level `level`) and whether 0 lies inside."""

    total: float
    total_se: float
    ref_total: float
    ref_se: float
    diff: float
    ci_low: float
    ci_high: float
    agrees: bool
    level: float


def total_agreement(images, ref: Reference, level: float = 0.95) -> Agreement:
    """Does the backend's total derivative agree with the reference's within a `level` CI?
    Needs ≥ 2 seeds (their spread is the backend's uncertainty).

    Examples
    --------
    A backend 10 % too high in every pixel, against an exact reference of 1:

    >>> import numpy as np
    >>> ref = nb.diagnostics.Reference.from_stack(np.ones((4, 8, 8, 1)))
    >>> g = 1.1 + 0.01 * np.random.default_rng(0).standard_normal((4, 8, 8, 1))
    >>> ag = nb.diagnostics.total_agreement(g, ref)
    >>> ag.agrees, round(ag.diff, 1)
    (False, 6.4)
    """
    a = as_stack(images)
    S = a.shape[0]
    if S < 2:
        raise ValueError("a confidence interval on the total derivative needs at least 2 seeds")
    totals = a.sum(axis=(1, 2, 3))
    m, v = float(totals.mean()), float(totals.var(ddof=1) / S)
    vr = ref.total_se**2 if np.isfinite(ref.total_se) else 0.0
    var = v + vr
    # Welch–Satterthwaite degrees of freedom
    dof = var**2 / (v**2 / (S - 1) + (vr**2 / (ref.n - 1) if ref.n > 1 and vr > 0 else 0.0)) if var > 0 else S - 1
    half = float(stats.t.ppf(0.5 + level / 2, dof)) * np.sqrt(var)
    d = m - ref.total
    return Agreement(
        m,
        float(np.sqrt(v)),
        ref.total,
        float(np.sqrt(vr)),
        d,
        d - half,
        d + half,
        bool(d - half <= 0 <= d + half),
        level,
    )


def image_metrics(images, ref: Reference, threshold: float = THRESHOLD, min_area: int = 1) -> list[dict]:
    """One dict per seed: outlier pixels, clusters (count, total and largest area), largest score,
    total derivative, RMSE against the reference image.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.ones((4, 8, 8, 1))
    >>> g[0, 3, 3] = 2.0
    >>> rows = nb.diagnostics.image_metrics(g, nb.diagnostics.Reference.from_stack(np.ones((4, 8, 8, 1))))
    >>> [(r["outlier_pixels"], r["clusters"]) for r in rows]
    [(1, 1), (0, 0), (0, 0), (0, 0)]
    """
    a = as_stack(images)
    return _seed_rows(a, outlier_scores(a, ref), ref, threshold, min_area)


def _seed_rows(a: np.ndarray, z: np.ndarray, ref: Reference, threshold: float, min_area: int) -> list[dict]:
    """image_metrics from the stack a (S, H, W, C) and its scores z (S, H, W)."""
    rows = []
    for s in range(a.shape[0]):
        cl = clusters(z[s], threshold, min_area)
        rows.append(
            {
                "seed_index": s,
                "outlier_pixels": int(sum(c.area for c in cl)),
                "clusters": len(cl),
                "max_cluster_area": max((c.area for c in cl), default=0),
                "max_score": float(z[s].max()),
                "total": float(a[s].sum()),
                "rmse": float(np.sqrt(np.mean((a[s] - ref.image) ** 2))),
            }
        )
    return rows


def summarize(images, ref: Reference, threshold: float = THRESHOLD, min_area: int = 1, level: float = 0.95) -> dict:
    """Metrics of S seeds of one backend: mean clusters and outlier pixels per image, persistence,
    total-derivative agreement, mean per-pixel variance across seeds, image RMSE.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.ones((4, 8, 8, 1))
    >>> g[0, 3, 3] = 2.0
    >>> s = nb.diagnostics.summarize(g, nb.diagnostics.Reference.from_stack(np.ones((4, 8, 8, 1))))
    >>> s["outlier_pixels_per_image"], s["agrees"]  # one outlier pixel in four seeds; the totals still agree
    (0.25, True)
    """
    a = as_stack(images)
    z = outlier_scores(a, ref)
    per = _seed_rows(a, z, ref, threshold, min_area)
    masks = outlier_mask(z, threshold, min_area)
    out = {
        "seeds": a.shape[0],
        "clusters_per_image": float(np.mean([r["clusters"] for r in per])),
        "outlier_pixels_per_image": float(np.mean([r["outlier_pixels"] for r in per])),
        "max_cluster_area": max(r["max_cluster_area"] for r in per),
        "max_score": max(r["max_score"] for r in per),
        "persistence": persistence(masks),
        "pixel_var": float(a.var(0, ddof=1).mean()) if a.shape[0] > 1 else float("nan"),
        "rmse": float(np.sqrt(np.mean((a - ref.image) ** 2))),
    }
    if a.shape[0] > 1:
        ag = total_agreement(a, ref, level)
        out.update(
            total=ag.total,
            total_se=ag.total_se,
            ref_total=ag.ref_total,
            ref_se=ag.ref_se,
            diff=ag.diff,
            ci_low=ag.ci_low,
            ci_high=ag.ci_high,
            agrees=ag.agrees,
        )
    return out


def spp_trend(outliers_low: float, outliers_high: float, tol: float = 0.5) -> str:
    """'grow', 'fade' or 'steady': how the outlier area per image changes from low to high spp
    (relative change beyond `tol`); 'none' when neither level has outliers."""
    if outliers_low == 0 and outliers_high == 0:
        return "none"
    if outliers_high > (1 + tol) * outliers_low:
        return "grow"
    if outliers_high < (1 - tol) * outliers_low:
        return "fade"
    return "steady"
