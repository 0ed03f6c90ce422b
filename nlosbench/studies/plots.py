"""The studies' figures (matplotlib, Agg), each drawn from saved tables only."""
from __future__ import annotations

import math
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..io import read_csv, read_exr, save_figure
from ..tradeoff import pareto_front
from .plotstyle import (
    NOT_LIMIT,
    OPEN,
    interval,
    legend_below,
    noise_text,
    note,
    off_scale,
    rms_axis,
    symlog_ticks,
    theta_text,
    view,
)
from .tables import BOUND_TITLES, cell, mse_units


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def bound_curves_plot(rows: list[dict], path: Path, los_until: float | None = None, parameter: str = "θ",
                      units: str = "units", zzb: dict | None = None, zzb_notes: dict | None = None,
                      quoted: list[dict] | None = None) -> Path:
    """bounds.png: `bounds_figure` saved as PNG."""
    fig = bounds_figure(rows, los_until, parameter, units, zzb, zzb_notes, quoted)
    return save_figure(fig, path, dpi=120, bbox_inches="tight")


def bounds_figure(rows: list[dict], los_until: float | None = None, parameter: str = "θ", units: str = "units",
                  zzb: dict | None = None, zzb_notes: dict | None = None, quoted: list[dict] | None = None):
    """A figure: `draw_bound_curves` on one panel with an RMS-error axis and the legend below it."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 5.4))
    draw_bound_curves(ax, rows, los_until, parameter, units, zzb, zzb_notes, quoted)
    rms_axis(ax, units, log10_axis=True)
    ax.grid(alpha=0.3)
    noises = list(dict.fromkeys(r["noise"] for r in rows))
    names = [name for _, name, _, _ in CURVE_KINDS]

    def order(label: str) -> tuple:  # per noise model: the HCR's entries, the CRLB's, then the others
        noise = next((k for k, v in enumerate(noises) if v in label), len(noises))
        kind = next((k for k, v in enumerate(names) if label.startswith(f"{v}:")), len(names))
        return noise, kind, "point, bars" not in label

    legend_below(ax, order=order)
    fig.tight_layout()
    return fig


#: how the interval bounds of a curve are drawn: (kind, name, point marker, line style of the points' line)
CURVE_KINDS = (("hcr", "HCR", "o", "-"), ("crlb", "CRLB", "s", "--"))


def draw_bound_curves(ax, rows: list[dict], los_until: float | None = None, parameter: str = "θ",
                      units: str = "units", zzb: dict | None = None, zzb_notes: dict | None = None,
                      quoted: list[dict] | None = None) -> None:
    """log10 bound vs θ from bound-service rows (theta_<parameter>, log10_<kind>, <kind>_point, _lower, _upper,
    optional <kind>_<end>_note per noise): per noise model the HCR interval and the CRLB interval
    (`plotstyle.interval`), each its point on a line (HCR solid, CRLB dashed) with a bar to its finite ends, the two
    side by side at each θ (so no bound's end stands against another's point); a point is filled where both its ends
    are confidence limits and hollow where one is not (a note; `interval_artists`), an open end (±∞) is an arrow
    from the point to the frame; the paper's HCR_Neff (dotted) and Barankin (dash-dot) where present; `zzb`
    {noise: log10} adds the ZZB over Θ as a level line (dotted where `zzb_notes` {noise: reason} says its lower end
    is not a confidence limit). The y-range follows the two intervals' finite points and ends and the ZZB; values
    more than `plotstyle.REACH` decades beyond are marked by an arrow at the frame's edge. `quoted` (rows of the
    bounds at the quoted θ, precise.csv) adds per noise the HCR (◆, nudged left of the curve's bars) and CRLB (■,
    nudged right) points there with bars to their finite ends. Every drawn element has its legend label, nothing
    else has."""
    series = defaultdict(list)
    for r in rows:
        series[r["noise"]].append(r)
    zzb = {k: v for k, v in (zzb or {}).items() if np.isfinite(v)}
    kinds = [k for k in CURVE_KINDS if any(r.get(f"log10_{k[0]}") not in ("", None) for r in rows)]
    core, others = [], list(zzb.values())
    for rs in series.values():
        core += [v for r in rs for k in kinds for v in interval(r, k[0])]
        others += [cell(r.get(k)) for r in rs for k in ("log10_hcr_neff", "log10_barankin")]
    bottom, top = view(core, others)
    ax.set_ylim(bottom, top)
    xs = np.unique([float(r[f"theta_{parameter}"]) for r in rows])
    slots = len(series) * len(kinds)
    width = 0.5 * (float(np.diff(xs).min()) if len(xs) > 1 else 1.0) / max(slots, 1)
    slot = 0
    for i, (noise, rs) in enumerate(series.items()):
        x = np.array([float(r[f"theta_{parameter}"]) for r in rs])
        color = f"C{i}"
        for j, (kind, name, marker, style) in enumerate(kinds):
            shift = (i * len(kinds) + j - (slots - 1) / 2) * width
            interval_artists(ax, rs, x + shift, kind, name, noise_text(noise), marker, style, color)
        for key, style, name, lw in (("log10_hcr_neff", ":", "HCR_Neff (paper)", 0.9),
                                     ("log10_barankin", "-.", "Barankin", 1.0)):
            if rs and rs[0].get(key) not in ("", None):
                y = np.array([cell(r[key]) for r in rs])
                inside = off_scale(ax, x, y, bottom, top, f"{name}, {noise_text(noise)}", units, color, slot)
                slot += int(not inside.all())
                if (inside & np.isfinite(y)).any():
                    ax.plot(x, np.where(inside, y, np.nan), style, color=color, lw=lw,
                            label=f"{name}, {noise_text(noise)}")
        name = f"ZZB over Θ (Bayesian MSE), {noise_text(noise)}"
        if noise in zzb and off_scale(ax, x[len(x) // 2:][:1], np.array([zzb[noise]]), bottom, top, name, units, color,
                                      slot).all():
            bad = (zzb_notes or {}).get(noise, "")
            ax.axhline(zzb[noise], color=color, lw=0.8, ls=(0, (1, 3)) if bad else (0, (6, 2, 1, 2)),
                       label=f"{name}: lower end {NOT_LIMIT}" if bad else name)
    names = list(series)
    # HCR left, CRLB right of the quoted θ, clear of the curve's own bars there (within ±width·slots/2 of a grid θ)
    nudge = max(0.006 * (xs.max() - xs.min()), width * (slots / 2 + 1)) if len(xs) else 0.0
    for kind, marker, name, side in (("hcr", "D", "HCR", -1), ("crlb", "s", "CRLB", 1)):
        for noise in dict.fromkeys(r["noise"] for r in quoted or []):
            rs = [r for r in quoted if r["noise"] == noise and r.get(f"{kind}_point") not in ("", None)]
            if not rs:
                continue
            x = np.array([float(r[f"theta_{parameter}"]) for r in rs]) + side * nudge
            y, lo, up = (np.array([cell(r[f"{kind}_{e}"]) for r in rs]) for e in ("point", "lower", "upper"))
            ok = np.isfinite(y)  # an infinite point (no resolved information) has no place on the axis; its table
            if not ok.any():
                continue
            x, y, lo, up = x[ok], y[ok], lo[ok], up[ok]
            bars = np.stack([np.where(np.isfinite(lo), y - lo, 0.0), np.where(np.isfinite(up), up - y, 0.0)])
            color = f"C{names.index(noise)}" if noise in names else "k"
            ax.errorbar(x, y, yerr=bars, fmt=marker, ms=5, capsize=3, color=color, mec="k", mew=0.6,
                        label=f"{name} at the quoted θ (point, ends), {noise_text(noise)}")
    if los_until is not None:
        ax.axvline(float(los_until), color="gray", lw=0.8)
        below = top - 0.04 * (top - bottom)  # under the arrowheads of open ends
        ax.text(float(los_until), below, " NLOS →", va="top", ha="left", fontsize=8, color="gray")
        ax.text(float(los_until), below, "← LOS ", va="top", ha="right", fontsize=8, color="gray")
    ax.set_xlabel(f"θ = {parameter} [{units}]")
    ax.set_ylabel(f"log10 bound [{units}²]")


def interval_artists(ax, rows: list[dict], x: np.ndarray, kind: str, name: str, noise: str, marker: str,
                     style: str, color) -> None:
    """One interval bound `kind` (titled `name`) of a curve under `noise` at the θ `x` (G,) (set ax's y-limits
    first): its finite points on a line of `style` with bars to their finite ends, `marker` filled where both ends
    are confidence limits (an error-bar container); hollow markers where an end is not one (its note); per open side
    (+∞ upper, −∞ lower: 0) one line of arrows from each such point to the frame (segments apart by NaN, an
    arrowhead ^ / v at the frame). Each with its legend label."""
    y, lo, up = (np.array(v) for v in zip(*(interval(r, kind) for r in rows), strict=True))
    ok = np.isfinite(y)
    if not ok.any():
        return
    limits = np.array([not note(r, kind, "lower") and not note(r, kind, "upper") for r in rows])
    level = cell(rows[0].get(f"{kind}_level"))
    ends = f"one-sided {level:.0%} ends" if np.isfinite(level) else "ends"
    yo, lo_ok, up_ok = y[ok], lo[ok], up[ok]
    bars = np.stack([np.where(np.isfinite(lo_ok), yo - lo_ok, 0.0), np.where(np.isfinite(up_ok), up_ok - yo, 0.0)])
    ax.errorbar(x[ok], yo, yerr=bars, fmt=marker + style, ms=4, lw=1.0, elinewidth=0.8, capsize=1.5,
                color=color, markevery=[int(k) for k in np.flatnonzero(limits[ok])],
                label=f"{name}: point, bars to its {ends}, {noise}")
    if (ok & ~limits).any():
        ax.plot(x[ok & ~limits], y[ok & ~limits], marker, ls="none", ms=5, mfc="none", mew=1.0, color=color,
                label=f"{name}: an end {NOT_LIMIT} (hollow), {noise}")
    bottom, top = ax.get_ylim()
    inset = 0.015 * (top - bottom)
    for side, end, edge, head in (("upper", up, top - inset, "^"), ("lower", lo, bottom + inset, "v")):
        opened = np.flatnonzero(ok & np.isinf(end))
        if len(opened):
            xs = np.repeat(x[opened], 3)
            ys = np.column_stack([y[opened], np.full(len(opened), edge), np.full(len(opened), np.nan)]).ravel()
            ax.plot(xs, ys, ":", marker=head, markevery=slice(1, None, 3), ms=4, lw=0.7, color=color,
                    label=f"{name}: {side} end open ({'∞' if side == 'upper' else '0'}), arrow to the frame, {noise}")


def finish(fig, ax, path: Path, dpi: int = 120) -> Path:
    """Grid, legend, tight layout; save as PNG and close the figure."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=dpi)
    return path


def fisher_figure(out: Path, labels: list[str], names: list[str], where: dict[str, str] | None = None,
                  noise: str = "", units: list[str] | None = None, pooled: bool = False) -> Path:
    """fisher_maps.png: one row per point: the RGB render, then the unbiased per-pixel FI map of each
    parameter under `noise` (the first noise model; negative where rendering noise outweighs the signal) on a
    symmetric log scale (linear within the 90th percentile of |FI| / 100), from the saved EXRs; each panel is
    titled with the point's label, θ (`where`: label → "θ = …") and the noise model, each colour bar in
    1/units² of its parameter. `pooled` adds per parameter the pooled map (`bounds.pooling`, from
    `{label}_noise0_pooled_{name}.exr`, `..._cells_...exr` and pooled_cells.csv): each drawn cell's FI per pixel
    on a log scale, hatched where its limits on the estimation rounds include 0, grey where masked."""
    from matplotlib.colors import SymLogNorm
    from matplotlib.ticker import FixedLocator

    plt = _plt()
    cols = 1 + len(names) * (2 if pooled else 1)
    units = units or [f"({n} unit)" for n in names]
    cells = read_csv(out / "pooled_cells.csv") if pooled else []
    fig, axes = plt.subplots(len(labels), cols, figsize=(4.2 * cols, 3.3 * len(labels) + (0.5 if pooled else 0)),
                             squeeze=False)
    for r, label in enumerate(labels):
        at = f"{label}, {(where or {}).get(label, 'θ not recorded')}"
        rgb = read_exr(out / f"{label}_rgb.exr")
        if rgb.shape[-1] != 3:  # one channel, or a transient image's T·C values per scan point: their sum, in grey
            rgb = rgb.sum(axis=-1)
        axes[r, 0].imshow(np.clip(rgb / max(np.percentile(rgb, 99), 1e-12), 0, 1) ** (1 / 2.2),
                          cmap="gray" if rgb.ndim == 2 else None)
        axes[r, 0].set_title(f"{at}\nrender (tone-mapped)", fontsize=8)
        for c, name in enumerate(names, start=1):
            fi = read_exr(out / f"{label}_noise0_fisher_{name}.exr")[..., 0].astype(np.float64)
            top = float(np.abs(fi).max()) or 1.0
            lin = max(float(np.percentile(np.abs(fi), 90)) / 100, top * 1e-8)
            im = axes[r, c].imshow(fi, cmap="RdBu_r", norm=SymLogNorm(lin, vmin=-top, vmax=top, base=10))
            axes[r, c].set_title(f"{at}\nunbiased FI per pixel for {name}, {noise_text(noise)}", fontsize=8)
            bar = fig.colorbar(im, ax=axes[r, c], fraction=0.046, pad=0.04)
            bar.ax.yaxis.set_major_locator(FixedLocator(symlog_ticks(lin, top)))
            bar.ax.yaxis.set_minor_locator(FixedLocator([]))
            bar.set_label(f"FI per pixel [1/{units[c - 1]}²]", fontsize=8)
            if pooled:
                mine = [row for row in cells if row["label"] == label and row["param"] == name
                        and row["noise"] == noise]
                _pooled_panel(fig, axes[r, c + len(names)], out, label, name, mine, units[c - 1],
                              f"{at}\npooled FI for {name}, {noise}")
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
        for side in a.spines.values():
            side.set_visible(False)
    for a in axes[:, 0]:
        a.set_axis_off()
    for a in axes[:, 1:1 + len(names)].ravel():
        a.set_axis_off()
    if pooled:
        from matplotlib.patches import Patch

        fig.legend(handles=[Patch(facecolor="0.82", edgecolor="0.5", label="masked: not resolved on the rounds "
                                                                          "that chose the cells"),
                            Patch(facecolor="white", edgecolor="k", hatch="///",
                                  label="drawn cell whose interval on the other rounds includes 0")],
                   loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06 if pooled else 0, 1, 1))
    save_figure(fig, out / "fisher_maps.png", dpi=110)
    return out / "fisher_maps.png"


def _pooled_panel(fig, ax, out: Path, label: str, name: str, rows: list[dict], unit: str, title: str) -> None:
    """One pooled map: drawn cells' FI per pixel (log colour scale), hatched where not resolved on the estimation
    rounds (or not positive), grey where masked; the title says how many cells were drawn and resolved. No map
    file (the point's rounds were too few to pool): a panel that says so."""
    from matplotlib.colors import LogNorm

    path = out / f"{label}_noise0_pooled_{name}.exr"
    if not path.exists():  # a precision look with 3 fresh FD rounds: too few to split into selection and estimation
        ax.set_axis_off()
        ax.set_title(title, fontsize=8)
        ax.text(0.5, 0.5, "no pooled map:\nfewer than 4 FD rounds", transform=ax.transAxes, ha="center",
                va="center", fontsize=9)
        return
    dens = read_exr(path)[..., 0].astype(np.float64)
    lab = read_exr(out / f"{label}_noise0_cells_{name}.exr")[..., 0].astype(np.int64)
    resolved = np.zeros(lab.max() + 1, dtype=bool)
    for row in rows:
        resolved[int(row["cell"])] = str(row["resolved"]).lower() == "true"
    drawn = np.isfinite(dens)
    unresolved = drawn & (~resolved[lab] | ~(dens > 0))
    ax.set_facecolor("0.82")
    show = np.where(drawn & (dens > 0), dens, np.nan)
    n_drawn = len({int(v) for v in lab[drawn]})
    n_res = len({int(v) for v in lab[drawn & ~unresolved]})
    ax.set_title(f"{title}\n{n_drawn} of {len(rows)} cells drawn, {n_res} resolved", fontsize=8)
    if np.isfinite(show).any():
        lo, hi = float(np.nanmin(show)), float(np.nanmax(show))
        im = ax.imshow(show, cmap="viridis", norm=LogNorm(lo, hi if hi > lo else lo * 10))
        bar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        bar.set_label(f"cell FI per pixel (cell total ÷ its pixels) [1/{unit}²]", fontsize=7)
    else:
        ax.imshow(np.full(lab.shape, np.nan), cmap="viridis")
        ax.text(0.5, 0.5, "no cell resolved", transform=ax.transAxes, ha="center", va="center", fontsize=9)
    if unresolved.any():
        ax.contourf(unresolved.astype(float), levels=[0.5, 1.5], colors="none", hatches=["///"])


def plot_mse(
    rows: list[dict], bound_rows: list[dict], bounds, names: list[str], units: list[str], noise_names: dict, path: Path
) -> Path:
    """mse_vs_theta.png: `mse_figure` saved as PNG."""
    fig = mse_figure(rows, bound_rows, bounds, names, units, noise_names)
    return save_figure(fig, path, dpi=110, bbox_inches="tight")


def mse_figure(rows: list[dict], bound_rows: list[dict], bounds, names: list[str], units: list[str],
               noise_names: dict):
    """A figure of the MSE (± SE) of every estimator and the bounds at each θ*, log scale, one panel per noise
    model (trials summary rows and bound-service rows; parameter names and units), with each estimator's
    predicted MSE (×: its linearised update's variance + the measured bias²) beside its MSE. Points only: θ* are
    separate experiments (e.g. one LOS, one NLOS), so nothing joins them. A bound is its quoted value (—) with its
    interval as a bar, an open upper end (∞) as ▲, an end that is not a confidence limit as a hollow marker;
    the y-range follows the MSEs and the bounds within 3 decades of them (others marked off scale)."""
    plt = _plt()
    noises = sorted({r["noise"] for r in rows})
    fig, axes = plt.subplots(1, len(noises), figsize=(6.4 * len(noises), 5.2), squeeze=False)
    xname = names[0] if len(names) == 1 else "θ* index"
    xkey = f"theta_{names[0]}" if len(names) == 1 else "theta_index"
    labels = list(dict.fromkeys(r["estimator"] for r in rows))
    thetas = sorted({float(r[xkey]) for r in rows})
    dx = 0.025 * ((thetas[-1] - thetas[0]) if len(thetas) > 1 else (abs(thetas[0]) or 1.0))
    shift = {k: (i - (len(labels) + len(bounds) - 1) / 2) * dx for i, k in enumerate(labels + list(bounds))}
    for ax, j in zip(axes[0], noises, strict=True):
        mine = [r for r in rows if r["noise"] == j and r["mse"] > 0]
        brs = [r for r in bound_rows if r["noise_index"] == j]
        core = [math.log10(v) for r in mine for v in (r["mse"], r["mse"] + r["mse_se"], r["mse"] - r["mse_se"],
                                                      r.get("mse_predicted", math.nan))
                if isinstance(v, float) and v > 0]
        others = [cell(r.get(k)) for r in brs for b in bounds for k in (f"log10_{b}", f"{b}_lower", f"{b}_upper")]
        bottom, top = view(core, others, reach=3.0)
        for i, label in enumerate(labels):
            rs = [r for r in mine if r["estimator"] == label]
            ax.errorbar([float(r[xkey]) + shift[label] for r in rs], [r["mse"] for r in rs],
                        yerr=[[min(r["mse_se"], 0.999 * r["mse"]) for r in rs], [r["mse_se"] for r in rs]],
                        fmt="o", ls="none", color=f"C{i}", capsize=3, label=f"MSE ± SE, {label}")
            pred = [(float(r[xkey]) + shift[label] + 0.4 * dx, r["mse_predicted"]) for r in rs
                    if isinstance(r.get("mse_predicted"), float) and r["mse_predicted"] > 0]
            if pred:
                ax.plot(*zip(*pred, strict=True), marker="x", ms=8, mew=2, ls="none", color=f"C{i}",
                        label=f"predicted MSE (var + bias²), {label}")
        for m, b in enumerate(bounds, start=len(labels)):
            _draw_bound(ax, brs, b, xkey, shift[b], f"C{m}", bottom, top, mse_units(units)[:-1])
        ax.set_yscale("log")
        ax.set_ylim(10.0 ** bottom, 10.0 ** top)
        ax.set_xticks(thetas)
        ax.set_xlabel(f"θ* ({xname}{', ' + units[0] if len(names) == 1 else ''})")
        ax.set_ylabel(f"MSE, bound [{mse_units(units)}]")
        ax.set_title(noise_text(noise_names[j]), fontsize=9)
        if len(set(units)) == 1:
            rms_axis(ax, units[0], log10_axis=False, of="(MSE, bound)")
        ax.grid(alpha=0.3)
        legend_below(ax, ncol=1)
    fig.tight_layout()
    return fig


def _draw_bound(ax, rows: list[dict], b: str, xkey: str, shift: float, color, bottom: float, top: float,
                units: str) -> None:
    """One bound kind at each θ*: its quoted value (—), its interval (bar, clipped to the view), ▲ for an open
    upper end, hollow ○ / ▽ for a lower / upper end that is not a confidence limit; values beyond
    [bottom, top] (log10) marked off scale."""
    name = BOUND_TITLES.get(b, b.upper())
    short = name.split(" (")[0]
    rs = [r for r in rows if np.isfinite(cell(r.get(f"log10_{b}")))]
    if not rs:
        return
    x = np.array([float(r[xkey]) + shift for r in rs])
    val, lo, up = (np.array([cell(r.get(k)) for r in rs]) for k in (f"log10_{b}", f"{b}_lower", f"{b}_upper"))
    inside = off_scale(ax, x, val, bottom, top, name, units, color, log10_axis=False)
    if inside.any():
        ax.plot(x[inside], 10.0 ** val[inside], "_", ms=14, mew=2, color=color, label=name)
    bar = np.isfinite(lo) & np.isfinite(up) & (up > lo)
    if bar.any():
        ax.vlines(x[bar], 10.0 ** np.clip(lo[bar], bottom, top), 10.0 ** np.clip(up[bar], bottom, top), color=color,
                  lw=1.5, alpha=0.6, label=f"{short}: interval (lower to upper end)")
    opened = np.isposinf(up) & inside
    if opened.any():
        ax.plot(x[opened], 10.0 ** val[opened], "^", ms=7, color=color, label=f"{short}: {OPEN}")
    for end, y, marker in (("lower", lo, "o"), ("upper", up, "v")):
        bad = np.array([bool(note(r, b, end)) for r in rs]) & np.isfinite(y) & (y >= bottom) & (y <= top)
        if bad.any():
            ax.plot(x[bad], 10.0 ** y[bad], marker, ms=8, mfc="none", color=color,
                    label=f"{short}: {end} end {NOT_LIMIT}")


def plot_speed(rows: list[dict], units: str, path: Path, bayes: bool = False) -> Path:
    """Speed against error: per estimator setting (and noise model), mean wall seconds and renders
    (+ AD passes) per trial against the MSE averaged over θ* (bayes: the Bayesian MSE) ± its SE, log–log,
    with each noise model's Pareto front (the settings no other one beats on both cost and MSE)."""
    plt = _plt()
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    several = len({r["noise"] for r in rows}) > 1
    key = "bayes_mse" if bayes else "mse"
    points: dict = defaultdict(list)  # noise → [(label, seconds, renders, mse, se)]
    for j, label in dict.fromkeys((r["noise"], r["estimator"]) for r in rows):
        rs = [r for r in rows if r["noise"] == j and r["estimator"] == label and r[key] > 0]
        if not rs:  # every fit failed (or hit θ* exactly): nothing to place on a log axis
            continue
        se = math.sqrt(sum(r[f"{key}_se"] ** 2 for r in rs)) / len(rs)
        points[j].append((label, float(np.mean([r["mean_seconds"] for r in rs])),
                          float(np.mean([r["mean_renders"] + r.get("mean_grad_passes", 0.0) for r in rs])),
                          float(np.mean([r[key] for r in rs])), se))
    for col, (ax, xl) in enumerate(zip(axes, ("wall seconds per trial", "renders + AD passes per trial"),
                                       strict=True)):
        seen = []
        for k, (j, pts) in enumerate(points.items()):
            x = [p[1 + col] for p in pts]
            y, ye = [p[3] for p in pts], [min(p[4], 0.999 * p[3]) for p in pts]  # keep the bar on a log axis
            seen += x
            ax.errorbar(x, y, yerr=[ye, [p[4] for p in pts]], fmt="o", color=f"C{k}", capsize=3,
                        label=f"noise {j}" if several else None)
            for p, xi in zip(pts, x, strict=True):
                ax.annotate(p[0], (xi, p[3]), fontsize=8, xytext=(4, 4), textcoords="offset points")
            front = pareto_front(x, y)
            if len(front) > 1:
                ax.step([x[i] for i in front], [y[i] for i in front], where="post", color=f"C{k}", alpha=0.5,
                        lw=1.2, label="Pareto front" + (f" (noise {j})" if several else ""))
        if seen and min(seen) > 0:  # a log axis needs positive data (cached renders count 0)
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlabel(xl)
        ax.set_ylabel(f"{'Bayesian MSE' if bayes else 'MSE'} averaged over θ* ± SE [{units}]")
        ax.xaxis.set_minor_formatter(NullFormatter())
        if seen and min(seen) > 0 and units.endswith("²") and not units.startswith("mixed"):
            rms_axis(ax, units[:-1], log10_axis=False, of="MSE")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.suptitle("speed against error (one point per estimator setting)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path


def slug(s: str) -> str:
    """A file-name-safe lower-case version of `s` (runs of other characters → '_')."""
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_").lower()


def inexact_plots(study_dir: Path, results: dict) -> list[Path]:
    """PNG plots from the saved CSVs: HCR vs θ* with the interval shaded (per noise); λ̃^(N) vs Δ per
    level with λ̂, and the HCR functional from λ̃^(N_eff) and λ̂, at the θ* with the widest and the
    narrowest interval (sup near Δ = 0 vs away from it, as in the paper); the decay check."""
    plt = _plt()
    hrows, lrows = read_csv(study_dir / "hcr.csv"), read_csv(study_dir / "lambda.csv")
    par = f"{results['parameter']} [{results['units']}]"
    paths = []
    for noise in dict.fromkeys(r["noise"] for r in hrows):
        rs = [r for r in hrows if r["noise"] == noise]
        x = np.array([cell(r["theta"]) for r in rs])
        ge, gh = (np.array([cell(r[k]) for r in rs]) for k in ("log10_hcr_neff", "log10_hcr_hat"))
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.fill_between(x, np.minimum(ge, gh), np.maximum(ge, gh), color="C0", alpha=0.25, label="[HCR_Neff, HCR-hat]")
        for key, col, name in (
            ("neff", "C3", f"HCR_Neff (N_eff = {results['n_eff']})"),
            ("hat", "k", f"HCR-hat (λ̂ from {len(results['levels'])} levels)"),
        ):
            lo_, hi_ = (np.array([cell(r[f"ci_{key}_{s}"]) for r in rs]) for s in ("lo", "hi"))
            if np.isfinite(lo_).any():
                ax.fill_between(
                    x,
                    np.where(np.isfinite(lo_), lo_, np.nan),
                    np.where(np.isfinite(hi_), hi_, np.nan),
                    color=col,
                    alpha=0.12,
                    label=f"{name.split(' ')[0]}: {results['confidence']:.0%} bootstrap CI",
                )
            ax.plot(x, ge if key == "neff" else gh, "-o", ms=3, color=col, label=name)
        un = np.array([r["unresolved_hat"] == "True" for r in rs])
        if un.any():
            ax.plot(x[un], gh[un], "x", color="C1", ms=8, label="HCR-hat unresolved (some λ̂ ≤ 0)")
        ax.set_xlabel(f"θ* = {par}")
        ax.set_ylabel(f"log10 bound [{results['units']}²]")
        ax.set_title(f"HCR interval from inexact renders, {noise_text(noise)}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        paths.append(study_dir / f"hcr_vs_theta_{slug(noise)}.png")
        save_figure(fig, paths[-1], dpi=120)

        width = np.array([cell(r["width_decades"]) for r in rs])
        picks = (
            {"widest": int(np.nanargmax(width)), "narrowest": int(np.nanargmin(width))}
            if np.isfinite(width).any()
            else {}
        )
        for tag, i in picks.items():
            th = rs[i]["theta"]
            paths.append(
                _lambda_plot(
                    plt,
                    [r for r in lrows if r["noise"] == noise and r["theta"] == th],
                    results,
                    study_dir / f"lambda_{slug(noise)}_{tag}.png",
                    f"{noise_text(noise)}, θ* = {cell(th):g} ({tag} interval: {width[i]:.3g} decades)",
                )
            )
    if (study_dir / "decay.csv").exists():
        paths.append(_decay_plot(plt, study_dir, results))
    return paths


def _lambda_plot(plt, rows: list[dict], results: dict, path: Path, title: str) -> Path:
    d = np.array([cell(r["delta"]) for r in rows])
    o = np.argsort(d)
    d = d[o]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    cmap = plt.get_cmap("viridis")
    k = len(results["levels"])
    for i, n in enumerate(results["levels"]):
        a1.plot(
            d,
            np.array([cell(r[f"lam_l{i}"]) for r in rows])[o],
            ".-",
            lw=0.8,
            color=cmap(i / max(k - 1, 1)),
            label=f"λ̃, N = {n}" if i in (0, k - 1) else None,
        )
    a1.plot(
        d, np.array([cell(r["lam_neff"]) for r in rows])[o], "-", color="C3", label=f"λ̃, N_eff = {results['n_eff']}"
    )
    lam_hat = np.array([cell(r["lam_hat"]) for r in rows])[o]
    a1.plot(d, np.where(lam_hat > 0, lam_hat, np.nan), "-", color="k", lw=1.5, label="λ̂ (fit, N → ∞)")
    bad = lam_hat <= 0
    if bad.any():
        a1.plot(
            d[bad],
            np.full(bad.sum(), np.nanmin(np.where(lam_hat > 0, lam_hat, np.nan)) if (~bad).any() else 1.0),
            "v",
            color="C1",
            label="λ̂ ≤ 0 (unresolved)",
        )
    a1.set_yscale("log")
    a1.set_xlabel(f"Δ [{results['units']}]")
    a1.set_ylabel("λ")
    a1.legend(fontsize=7)
    a1.grid(alpha=0.3)
    for key, col, name in (("log10_f_neff", "C3", "from λ̃^(N_eff)"), ("log10_f_hat", "k", "from λ̂")):
        f = np.array([cell(r[key]) for r in rows])[o]
        a2.plot(d, np.where(np.isfinite(f), f, np.nan), "-o", ms=3, color=col, label=name)
    a2.set_xlabel(f"Δ [{results['units']}]")
    a2.set_ylabel(f"log10 Δ²/(exp λ − 1) [{results['units']}²]")
    a2.legend(fontsize=7)
    a2.grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    return path


def _decay_plot(plt, study_dir: Path, results: dict) -> Path:
    dc = read_csv(study_dir / "decay.csv")
    hist = read_csv(study_dir / "decay_popt.csv")
    gam = read_csv(study_dir / "decay_gamma.csv")
    dec = results["decay"]
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(12, 3.6))
    a1.plot([cell(r["p"]) for r in dc], [cell(r["fit_error"]) for r in dc], "-")
    a1.set_yscale("log")
    a1.set_xlabel("p")
    a1.set_ylabel("mean relative fit error ‖γ − C N^−p‖²/‖γ‖²")
    a2.bar(
        [cell(r["p_opt"]) for r in hist],
        [int(r["count"]) for r in hist],
        width=max(1e-3, float(np.diff([cell(r["p"]) for r in dc[:2]])[0])),
        color="C0",
    )
    a2.axvline(1.0, color="gray", lw=0.8)
    a2.set_xlabel(f"p_opt (median {dec['p']:.3f}, {dec['n_weights']} weightings)")
    a2.set_ylabel("count")
    n = np.array([cell(r["spp"]) for r in gam])
    a3.loglog(n, [cell(r["gamma"]) for r in gam], "o", label="γ(N), one weighting")
    a3.loglog(n, dec["c_example"] * n ** -dec["p"], "-", label=f"C N^−{dec['p']:.3f}")
    a3.set_xlabel("spp per render N")
    a3.legend(fontsize=7)
    for a in (a1, a2, a3):
        a.grid(alpha=0.3)
    fig.suptitle("rendering-noise decay check: Σ W Var L̃^(N) = C N^−p?", fontsize=9)
    fig.tight_layout()
    path = study_dir / "decay.png"
    save_figure(fig, path, dpi=120)
    return path


def fidelity_plots(study_dir: Path, results: dict) -> None:
    """The fidelity study's fidelity.png (a panel per knob) and, with a depth sweep, depth.png."""
    knobs = {k: s for k, s in results["knobs"].items() if k != "prune"}
    if knobs:
        _knob_plot(knobs, results, study_dir / "fidelity.png")
    if results["depth"] is not None:
        _depth_plot(read_csv(study_dir / "fidelity.csv"), results, study_dir / "depth.png")


def _knob_plot(knobs: dict, results: dict, path: Path) -> Path:
    """Per knob: relative bound error against cost (log-log), with its joint confidence limits as a bar
    (clipped to the panel); errors of 0 drawn at the bottom edge (▼), errors ≥ 100 (10⁴ %) or ∞ at the top
    edge (▲)."""
    plt = _plt()
    from matplotlib.ticker import FuncFormatter, LogLocator

    tol = results["tolerance"]
    fig, axes = plt.subplots(1, len(knobs), figsize=(4 * len(knobs), 3.6), squeeze=False)
    for ax, (knob, s) in zip(axes[0], knobs.items(), strict=True):
        shown = [p["error"] for p in s["points"] if 0 < p["error"] < 100]
        floor, top = tol / 100, max([tol * 10] + [2 * e for e in shown])
        for p in s["points"]:
            e = p["error"]
            y, marker = (floor, "v") if e == 0 else ((top, "^") if e >= 100 else (e, "o"))
            lo, hi = p.get("lower", math.nan), p.get("upper", math.nan)
            if not math.isnan(hi) and hi > 0:
                ax.plot([p["cost"]] * 2, [min(max(lo, floor), top), min(hi, top)], "-", lw=1, color="0.6")
            ax.loglog(p["cost"], y, marker, color="C3" if p["value"] == s["reference"] else "C0")
            ax.annotate(str(p["value"]), (p["cost"], y), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.axhline(tol, ls="--", color="gray", lw=0.8)
        ax.minorticks_off()  # few plain tick labels: mathtext and minor ticks make the plot slow
        for axis, subs in ((ax.xaxis, (1.0, 2.0, 5.0)), (ax.yaxis, (1.0,))):
            axis.set_major_locator(LogLocator(subs=subs, numticks=8))
            axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_xlabel("cost [s]" if results["cost"] == "seconds" else "cost [pixel-samples]")
        ax.set_title(f"{knob} (reference {s['reference']}: red)", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(f"relative bound error (- - tolerance {tol:g}; ▼ 0, ▲ ≥ 100)", fontsize=8)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.16, top=0.9, wspace=0.3)
    save_figure(fig, path, dpi=110)
    return path


def _depth_plot(rows: list[dict], results: dict, path: Path) -> Path:
    """Median log10 HCR (solid, min–max band) and CRLB (dashed) over the NLOS θ against path depth, with an
    RMS-error axis."""
    plt = _plt()
    lu = results["los_until"]
    depth_rows = [
        r
        for r in rows
        if r["knob"] == "max_depth" and (lu is None or float(r["theta"]) > lu or results["depth"]["all_points"])
    ]
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for i, noise in enumerate(results["noises"]):
        by = defaultdict(lambda: ([], []))
        for r in depth_rows:
            if r["noise"] == noise:
                by[int(r["value"])][0].append(float(r["log10_hcr"]))
                by[int(r["value"])][1].append(float(r["log10_crlb"]))
        d = sorted(by)
        fin = [np.array([v for v in by[k][0] if math.isfinite(v)] or [np.nan]) for k in d]
        ax.plot(d, [np.median(f) for f in fin], "o-", color=f"C{i}", label=f"HCR, {noise_text(noise)}")
        ax.fill_between(d, [f.min() for f in fin], [f.max() for f in fin], color=f"C{i}", alpha=0.15,
                        label=f"HCR min – max over the θ, {noise_text(noise)}")
        crlb = [np.median([v for v in by[k][1] if math.isfinite(v)] or [np.nan]) for k in d]
        ax.plot(d, crlb, "s--", color=f"C{i}", label=f"CRLB, {noise_text(noise)}")
    ax.set_xticks(d)
    ax.set_xlabel("max_depth (1: emitters seen directly, 2: direct light, ...)")
    units = results.get("units", "units")
    ax.set_ylabel(f"log10 bound, NLOS θ [{units}²]")
    rms_axis(ax, units, log10_axis=True)
    return finish(fig, ax, path)


def _vec_label(v) -> str:
    return "(" + ", ".join(f"{float(x):g}" for x in v) + ")"


def heat_maps(rows: list[dict], out: Path, summary: dict, column: str = "mean_fisher") -> list[Path]:
    """One PNG per noise model: log10 of the mean per-pixel FI of each parameter over the offset grid
    (axis 0 across, axis 1 up, in cm, like the paper's figure) from `column` (mean_fisher: unbiased,
    heatmap_noise{k}.png; plugin_mean_fisher: the plug-in, heatmap_plugin_noise{k}.png); infinite, missing or
    non-positive cells are blank."""
    plt = _plt()
    num, step = summary["num"], summary["step"]
    half = (num - 1) / 2 * step * 100
    ext = [-half - step * 50, half + step * 50, -half - step * 50, half + step * 50]
    paths = []
    for k, noise in enumerate(summary["noises"]):
        names = summary["params"]
        fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 4), squeeze=False)
        for p, name in enumerate(names):
            grid = np.full((num, num), np.nan)
            for r in rows:
                v = float(r[column])
                if r["noise"] == noise and r["param"] == name and math.isfinite(v) and v > 0:
                    grid[int(r["i"]), int(r["j"])] = math.log10(v)
            im = axes[0, p].imshow(grid.T, origin="lower", extent=ext, cmap="viridis", interpolation="nearest")
            kind = "plug-in FI" if column == "plugin_mean_fisher" else "FI"
            axes[0, p].set_title(f"{kind} for {name}", fontsize=9)
            axes[0, p].set_xlabel(f"camera offset along {_vec_label(summary['axes'][0])} [cm]")
            axes[0, p].set_ylabel(f"camera offset along {_vec_label(summary['axes'][1])} [cm]")
            fig.colorbar(
                im, ax=axes[0, p], fraction=0.046, pad=0.04, label=f"log10 mean FI per pixel [1/{summary['units'][p]}²]"
            )
        at = f"{theta_text(names, summary['theta'], summary['units'])}, " if "theta" in summary else ""
        fig.suptitle(f"{at}{noise_text(noise)}", fontsize=10)  # once for the panels: theirs would overlap
        fig.tight_layout()
        path = out / (f"heatmap_plugin_noise{k}.png" if column == "plugin_mean_fisher" else f"heatmap_noise{k}.png")
        save_figure(fig, path, dpi=120)
        paths.append(path)
    return paths


def profile_plot(curves: dict, out: Path, summary: dict) -> Path:
    """profiles.png: per parameter, log10 mean FI along the map's first axis, the median over the second axis with its
    10–90 % band, one colour per noise model; curves[(noise, param)] = (u0 (n0,) [m], quantiles (3, n0))."""
    plt = _plt()
    names = summary["params"]
    fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 3.6), squeeze=False)
    for p, name in enumerate(names):
        ax = axes[0, p]
        for noise in summary["noises"]:
            u0, q = curves[noise, name]
            line, = ax.plot(u0 * 100, q[1], marker=".", label=noise_text(noise))
            ax.fill_between(u0 * 100, q[0], q[2], color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel(f"camera offset along {_vec_label(summary['axes'][0])} [cm]")
        ax.set_ylabel(f"log10 mean FI per pixel [1/{summary['units'][p]}²]")
        ax.set_title(f"{name}: median over {_vec_label(summary['axes'][1])} (band 10–90 %)", fontsize=9)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "profiles.png"
    save_figure(fig, path, dpi=120)
    return path
