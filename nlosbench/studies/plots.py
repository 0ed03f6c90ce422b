"""Plots shared by studies (matplotlib, Agg): bound curves on a log scale with LOS/NLOS marked."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def bound_curves_plot(rows: list[dict], path: Path, los_until: float | None = None, xlabel: str = "θ",
                      units: str = "units") -> Path:
    """log10 bound vs θ: one solid line (HCR) and, where present, dashed CRLB and dotted Barankin per noise."""
    plt = _plt()
    series = defaultdict(list)
    for r in rows:
        series[r["noise"]].append(r)
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, (noise, rs) in enumerate(series.items()):
        x = [float(r["theta"]) for r in rs]
        color = f"C{i}"
        ax.plot(x, [float(r["log10_hcr"]) for r in rs], "-", color=color, label=f"HCR, {noise}")
        for key, style, name in (("log10_crlb", "--", "CRLB"), ("log10_barankin", ":", "Barankin")):
            if rs and key in rs[0] and rs[0][key] not in ("", None):
                ax.plot(x, [float(r[key]) for r in rs], style, color=color, label=f"{name}, {noise}")
    if los_until is not None:
        ax.axvline(float(los_until), color="gray", lw=0.8)
        ax.text(float(los_until), ax.get_ylim()[1], " NLOS →", va="top", ha="left", fontsize=8, color="gray")
        ax.text(float(los_until), ax.get_ylim()[1], "← LOS ", va="top", ha="right", fontsize=8, color="gray")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"log10 bound [{units}²]")
    return finish(fig, ax, path)


def finish(fig, ax, path: Path, dpi: int = 120) -> Path:
    """Grid, legend, tight layout; save as PNG and close the figure."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return path
