"""The paper-style figure: a grid of gradient images (rows: backends; columns: parameter × spp) with a
symmetric colour scale shared by every image of one parameter, outlier clusters outlined."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from ..io import save_figure


def gradient_grid(images: dict, masks: dict, rows: list[str], columns: list[tuple[str, int]], path: str | Path,
                  units: dict[str, str] | None = None, reference: str = "reference") -> Path:
    """Save the grid to `path` (PNG).

    images: {(row, param, spp): (H, W, C)} gradient images (shown as the sum over channels);
    masks: {(row, param, spp): (H, W) bool} outlier pixels (each 8-connected cluster is boxed);
    rows: backend labels top to bottom; columns: (param, spp) left to right; units: param → units.
    The colour scale of a parameter is ±max |reference image| when the row `reference` has one
    (larger values saturate, as outliers should), else ±(99.5th percentile of all its images).
    Missing cells stay blank."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    def img2d(key):
        return np.asarray(images[key], dtype=np.float64).sum(axis=-1)

    scale = {}
    for param in {key[1] for key in images}:
        refs = [img2d(k) for k in images if k[1] == param and k[0] == reference]
        pool = refs or [img2d(k) for k in images if k[1] == param]
        scale[param] = float(np.abs(refs[0]).max()) if refs else float(np.percentile(np.abs(np.stack(pool)), 99.5))
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(2.2 * len(columns) + 0.8, 2.2 * len(rows) + 0.6),
                             squeeze=False)
    shown = {}
    for i, row in enumerate(rows):
        for k, (param, spp) in enumerate(columns):
            ax = axes[i, k]
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"{param}, {spp} spp", fontsize=8)
            if k == 0:
                ax.set_ylabel(row, fontsize=6, rotation=0, ha="right", va="center")
            key = (row, param, spp)
            if key not in images:
                ax.set_frame_on(False)
                continue
            v = scale[param] or 1.0
            shown[param] = ax.imshow(img2d(key), cmap="RdBu_r", vmin=-v, vmax=v, interpolation="nearest")
            labels, _ = ndimage.label(masks.get(key, np.zeros((1, 1), bool)), structure=np.ones((3, 3), bool))
            for sl in ndimage.find_objects(labels):
                r, c = sl
                ax.add_patch(Rectangle((c.start - 0.5, r.start - 0.5), c.stop - c.start, r.stop - r.start,
                                       fill=False, edgecolor="lime", linewidth=1.0))
    for param, im in shown.items():
        cols = [k for k, (p, _) in enumerate(columns) if p == param]
        u = (units or {}).get(param, "")
        fig.colorbar(im, ax=axes[:, cols].ravel().tolist(), location="bottom", fraction=0.03, pad=0.02,
                     shrink=0.9, label=f"Σ_RGB ∂L/∂{param}" + (f" [1/{u}]" if u and u != "1" else ""))
    path = Path(path)
    save_figure(fig, path, dpi=110, bbox_inches="tight")
    return path
