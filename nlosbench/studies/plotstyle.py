"""The common style of the studies' figures: an RMS-error axis in the parameter's units beside a bound or
MSE axis, interval ends that are open or not confidence limits drawn as such, values decades away from
the data marked at the frame's edge instead of stretching the axis, and the legend outside the data."""
from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np

OPEN = "upper end open (∞)"
NOT_LIMIT = "not a confidence limit"
#: how far (decades) a secondary series may lie beyond the main data before it is drawn off scale
REACH = 1.0


def note(row: dict, kind: str, end: str) -> str:
    """Why the `end` ("lower" / "upper") of bound `kind` in a CSV row is not a confidence limit; "" when it
    is one (also for tables written before the `<kind>_<end>_note` columns existed)."""
    return (row.get(f"{kind}_{end}_note") or "").strip()


def interval(row: dict, kind: str) -> tuple[float, float, float]:
    """(point, lower, upper) log10 of the interval bound `kind` in a CSV row (NaN where absent; ±inf an open end);
    a table without `<kind>_point` / `_lower` columns (a bound without an interval) gives log10_<kind> for them, and
    without `<kind>_upper` an upper end of NaN (not known, so never resolved)."""
    def value(key: str, default: str | None = None) -> float:
        v = row.get(key, default)
        return float(v) if v not in ("", None) else math.nan

    lg = row.get(f"log10_{kind}")
    return value(f"{kind}_point", lg), value(f"{kind}_lower", lg), value(f"{kind}_upper")


def resolved(row: dict, kinds: Sequence[str] = ("hcr", "crlb")) -> bool:
    """Whether a CSV row's interval bounds among `kinds` (those it has) are resolved: a finite point and both ends
    finite confidence limits (no open end, no `<kind>_<end>_note`); False when it has none of them."""
    have = [k for k in kinds if row.get(f"log10_{k}") not in ("", None)]
    return bool(have) and all(np.isfinite(interval(row, k)).all() and not note(row, k, "lower")
                              and not note(row, k, "upper") for k in have)


def length(v: float, units: str) -> str:
    """A tick label for an RMS error `v` in `units` (metres with a metric prefix: 10 µm, 3 mm, 2 cm)."""
    if units == "m":
        for scale, name in ((1.0, "m"), (1e-2, "cm"), (1e-3, "mm"), (1e-6, "µm"), (1e-9, "nm")):
            if v >= scale * 0.999:
                return f"{v / scale:.3g} {name}"
    return f"{v:.3g}"


def _nice(lo: float, hi: float) -> list[float]:
    """Tick positions (log10) in [lo, hi]: 1·10^k, else also 2 and 5·10^k, else round linear steps, whichever
    first gives 3 ticks or more."""
    from matplotlib.ticker import MaxNLocator

    for mant in ((1,), (1, 2, 5)):
        ticks = [math.log10(m) + k for k in range(math.floor(lo) - 1, math.ceil(hi) + 1) for m in mant]
        ticks = [t for t in ticks if lo <= t <= hi]
        if len(ticks) >= 3:
            return ticks
    steps = MaxNLocator(4).tick_values(10.0 ** lo, 10.0 ** hi)
    return [math.log10(v) for v in steps if v > 0 and lo <= math.log10(v) <= hi]


def rms_axis(ax, units: str, log10_axis: bool, of: str = "bound"):
    """A right-hand axis with the RMS error √(`of`: bound or MSE) in `units` beside `ax`'s y-axis, which
    shows log10 of units² (`log10_axis`) or units² on a log scale (call it after the y-limits are set)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    if log10_axis:
        sec = ax.secondary_yaxis("right", functions=(lambda y: np.asarray(y) / 2, lambda r: 2 * np.asarray(r)))
        lo, hi = (v / 2 for v in ax.get_ylim())
        sec.yaxis.set_major_locator(FixedLocator(_nice(lo, hi)))
        sec.yaxis.set_major_formatter(FuncFormatter(lambda r, _: length(10.0 ** r, units)))
    else:
        sec = ax.secondary_yaxis("right", functions=(lambda y: np.sqrt(np.maximum(y, 0)), np.square))
        lo, hi = (math.log10(v) / 2 for v in ax.get_ylim())
        sec.yaxis.set_major_locator(FixedLocator([10.0 ** t for t in _nice(lo, hi)]))
        sec.yaxis.set_major_formatter(FuncFormatter(lambda r, _: length(r, units)))
    sec.yaxis.set_minor_locator(NullLocator())
    sec.set_ylabel(f"RMS error = √{of}" + ("" if units in ("m", "1", "") else f" [{units}]"))
    return sec


def view(core: Sequence[float], others: Sequence[float] = (), pad: float = 0.4, reach: float = REACH
         ) -> tuple[float, float]:
    """(bottom, top) of a log10 axis: the finite `core` values (the data and the bounds to quote) and the
    `others` within `reach` decades of them, with `pad` decades of margin."""
    core = np.asarray([v for v in core if np.isfinite(v)], dtype=float)
    if not core.size:
        return -10.0, 0.0
    lo, hi = core.min(), core.max()
    near = np.asarray([v for v in others if np.isfinite(v) and lo - reach <= v <= hi + reach], dtype=float)
    if near.size:
        lo, hi = min(lo, near.min()), max(hi, near.max())
    return lo - pad, hi + pad


def off_scale(ax, x: np.ndarray, lg: np.ndarray, bottom: float, top: float, name: str, units: str, color,
              slot: int = 0, log10_axis: bool = True) -> np.ndarray:
    """Mark the values of a series (log10 values `lg`) beyond [bottom, top] (log10) by arrowheads (▾ / ▴) just
    inside the frame's edge, labelled with the extreme value; `slot` stacks the marks of several series; the
    axis shows log10 values (`log10_axis`) or values on a log scale. Returns the in-range mask (draw there)."""
    fin = np.isfinite(lg)
    below, above = fin & (lg < bottom), fin & (lg > top)
    inset = 0.025 * (top - bottom) * (1 + 1.5 * slot)
    for mask, edge, extreme, marker, where in ((below, bottom + inset, np.min, 7, "below"),
                                               (above, top - inset, np.max, 6, "above")):
        if mask.any():
            v = float(extreme(lg[mask]))
            value = f"10^{v:.0f}" if abs(v) >= 3 else f"{10.0 ** v:.2g}"
            yy = np.full(int(mask.sum()), edge if log10_axis else 10.0 ** edge)
            ax.plot(x[mask], yy, marker=marker, ls="none", ms=6, color=color,
                    label=f"{name}: off scale, {'down' if where == 'below' else 'up'} to {value} {units}²")
    return ~(below | above)


def legend_below(ax, ncol: int = 2, order=None) -> None:
    """The legend under the axes (off the data), when anything is labelled; `order` (label → sort key) orders its
    entries (stable), None: as drawn."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        pairs = sorted(zip(handles, labels, strict=True), key=lambda p: order(p[1])) if order else list(
            zip(handles, labels, strict=True))
        ax.legend(*zip(*pairs, strict=True), fontsize=7, ncol=ncol, loc="upper center", bbox_to_anchor=(0.5, -0.16),
                  frameon=False)


def noise_text(noise: str) -> str:
    """A noise model for a title, in words: "AWGN(sigma=0.025)" → "AWGN, σ = 0.025"."""
    m = re.fullmatch(r"(\w+)\((.*)\)", noise)
    if not m:
        return noise
    args = [a.split("=", 1) for a in m[2].split(",") if "=" in a]

    def value(v: str) -> str:
        try:
            return f"{float(v):g}"
        except ValueError:
            return v.strip()

    return ", ".join([m[1], *(f"{ {'sigma': 'σ'}.get(k.strip(), k.strip())} = {value(v)}" for k, v in args)])


def theta_text(names: Sequence[str], values: Sequence[float], units: Sequence[str]) -> str:
    """θ for a title: "θ = 0.79 m" for one parameter, else "θ = (x 0.3 m, y 0.5 m)" (units '1': none)."""
    parts = [f"{float(v):.4g}" + ("" if u in ("1", "") else f" {u}") for v, u in zip(values, units, strict=True)]
    if len(parts) == 1:
        return f"θ = {parts[0]}"
    return "θ = (" + ", ".join(f"{n} {p}" for n, p in zip(names, parts, strict=True)) + ")"


def symlog_ticks(linthresh: float, top: float, per_side: int = 3) -> list[float]:
    """Colour-bar ticks for a SymLogNorm(linthresh) over [−top, top]: 0 and ±10^k from one decade above the
    linear range up to `top`, at most `per_side` on each side (so no two labels overlap)."""
    k0, k1 = math.ceil(math.log10(linthresh)) + 1, math.floor(math.log10(top)) if top > 0 else 0
    ks = list(range(k0, k1 + 1))
    ks = ks[::-1][::max(1, math.ceil(len(ks) / per_side))][::-1]
    return sorted([-(10.0 ** k) for k in ks] + [0.0] + [10.0 ** k for k in ks])
