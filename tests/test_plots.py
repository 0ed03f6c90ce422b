"""Figures a newcomer reads without help: the bounds plot's legend names exactly the drawn elements, an open
upper end is a marker (no band to the frame), an end that is not a confidence limit is drawn apart, values
decades away are marked off scale instead of stretching the axis, an RMS axis in the parameter's units, no
line joins separate θ* in the trials plot; reports print an open end as ∞. Rows come from the bound service
on the analytic edge1d toy (a few cells then set to an open end or a note, as newer service versions write)."""
import math

import numpy as np
import pytest
from matplotlib.colors import SymLogNorm

import nlosbench as nb
from nlosbench.bank import RenderBank
from nlosbench.bounds import BoundService
from nlosbench.studies.plots import _plt, bounds_figure, mse_figure
from nlosbench.studies.plotstyle import NOT_LIMIT, OPEN, note, symlog_ticks
from nlosbench.studies.tables import fmt, fmt_end

NOISE = "AWGN(sigma=0.05)"
WORDS = "AWGN, σ = 0.05"  # how a legend names it


@pytest.fixture(scope="module")
def rows():
    model = nb.scenes.get("edge1d")
    curve = BoundService(RenderBank(model), [nb.noise.AWGN(0.05)], 0.95).curve(np.linspace(0.3, 0.7, 9), 16)
    return [p.row(model.params.names) for p in curve.points], curve.zzb[0].log10


def drawn(ax) -> list:
    """The data artists on the axes (lines and filled areas with data; grid lines are not among them), an
    error bar's parts as its container (which carries their label)."""
    parts = {id(c): k for k, box in enumerate(ax.containers) for c in box.get_children()}
    loose = [a for a in ax.lines + ax.collections if id(a) not in parts and len(np.atleast_1d(_ydata(a)))]
    return loose + list(ax.containers)


def _ydata(a):
    if hasattr(a, "get_ydata"):
        return a.get_ydata()
    return np.concatenate([p.vertices[:, 1] for p in a.get_paths()]) if a.get_paths() else []


def test_the_legend_names_every_drawn_element_and_nothing_else(rows):
    rs, _ = rows
    fig = bounds_figure(rs, parameter="edge", units="m")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert len(labels) == len(set(labels))
    assert set(labels) == {a.get_label() for a in drawn(ax)}
    assert all(not a.get_label().startswith("_") for a in drawn(ax))
    assert f"HCR: point, bars to its one-sided 95% ends, {WORDS}" in labels  # each interval has its entry
    assert f"CRLB: point, bars to its one-sided 95% ends, {WORDS}" in labels
    noted = any(note(r, "hcr", e) for r in rs for e in ("lower", "upper"))  # the service's own notes (FD step)
    assert any(NOT_LIMIT in t for t in labels) == noted
    assert any(OPEN in t for t in labels) == any(math.isinf(r[f"{k}_upper"]) for r in rs for k in ("hcr", "crlb"))
    legend = ax.get_legend().get_window_extent(fig.canvas.get_renderer())
    assert legend.y1 < ax.get_window_extent(fig.canvas.get_renderer()).y0  # below the data, not over it
    _plt().close(fig)


def _row(noise: str, theta: float, hcr: tuple, crlb: tuple, notes: dict | None = None) -> dict:
    """A bounds.csv row (as read back: text cells) with the HCR's and CRLB's (point, lower, upper) log10 and notes
    {column: text}."""
    row = {"noise": noise, "theta_x": str(theta)}
    for kind, (point, lower, upper) in (("hcr", hcr), ("crlb", crlb)):
        row |= {f"log10_{kind}": str(lower), f"{kind}_point": str(point), f"{kind}_lower": str(lower),
                f"{kind}_upper": str(upper), f"{kind}_level": "0.95", f"{kind}_lower_note": "",
                f"{kind}_upper_note": ""}
    return row | (notes or {})


A, B = "AWGN(sigma=0.05)", "Poisson(scale=300.0)"
A_WORDS, B_WORDS = "AWGN, σ = 0.05", "Poisson, scale = 300"  # as the legend names them
FD = "not a confidence limit: FD step not converged (F ×1.5 from ξ to ξ/2)"
SYNTHETIC = [  # θ 0.1 resolved; 0.2: A's HCR upper end open; 0.3: A's lower ends not limits; B's CRLB open at 0.2
    _row(A, 0.1, (-4.0, -4.2, -3.8), (-4.1, -4.3, -3.9)),
    _row(A, 0.2, (-3.5, -3.7, math.inf), (-3.6, -3.8, -3.4)),
    _row(A, 0.3, (-3.0, -3.3, -2.8), (-3.1, -3.3, -2.9), {"hcr_lower_note": FD, "crlb_lower_note": FD}),
    _row(A, 0.4, (-2.5, -2.7, -2.3), (-2.6, -2.8, -2.4)),
    _row(B, 0.1, (-4.5, -4.7, -4.3), (-4.6, -4.8, -4.4)),
    _row(B, 0.2, (-4.0, -4.2, -3.8), (-4.1, -4.3, math.inf)),
    _row(B, 0.3, (-3.5, -3.7, -3.3), (-3.6, -3.8, -3.4)),
    _row(B, 0.4, (-3.0, -3.2, -2.8), (-3.1, -3.3, -2.9)),
]


def test_each_interval_is_its_own_bar_open_ends_are_arrows_and_non_limits_hollow():
    """A synthetic curve (2 noise models × 4 θ): every interval is an error bar from its own lower to its own upper
    end around its own point (the HCR and the CRLB side by side, never at one x), filled markers exactly at the
    points whose ends are both confidence limits, hollow ones exactly where an end carries a note (A's HCR and CRLB at
    0.3), and an arrow from the point to the top frame for each open upper end (A's HCR and B's CRLB at 0.2)."""
    from nlosbench.studies.plotstyle import interval

    fig = bounds_figure(SYNTHETIC, parameter="x", units="m")
    ax = fig.axes[0]
    bottom, top = ax.get_ylim()
    xs = {}
    for box in ax.containers:
        name = box.get_label().split(": point")[0]
        noise = next(n for n, words in ((A, A_WORDS), (B, B_WORDS)) if box.get_label().endswith(words))
        rs = [r for r in SYNTHETIC if r["noise"] == noise]
        line = box.lines[0]
        x = line.get_xdata()
        xs[name, noise] = x
        assert np.allclose(x - [float(r["theta_x"]) for r in rs], x[0] - 0.1) and abs(x[0] - 0.1) < 0.05
        ends = [interval(r, name.lower()) for r in rs]
        assert np.allclose(line.get_ydata(), [e[0] for e in ends])
        for seg, (point, lower, upper) in zip(box.lines[2][0].get_segments(), ends, strict=True):
            assert np.allclose(seg[:, 1], [lower, upper if math.isfinite(upper) else point])
        filled = [k for k, r in enumerate(rs) if not r[f"{name.lower()}_lower_note"]]
        assert line.get_markevery() == filled
    assert len(xs) == 4 and len({round(v[0], 9) for v in xs.values()}) == 4  # four bars apart at each θ
    hollow = {a.get_label(): a.get_xdata() for a in ax.lines if a.get_markerfacecolor() == "none"}
    assert set(hollow) == {f"{kind}: an end {NOT_LIMIT} (hollow), {A_WORDS}" for kind in ("HCR", "CRLB")}
    assert all(len(x) == 1 for x in hollow.values())
    arrows = {a.get_label(): a for a in ax.lines if "arrow to the frame" in a.get_label()}
    assert set(arrows) == {f"HCR: {OPEN}, arrow to the frame, {A_WORDS}",
                           f"CRLB: {OPEN}, arrow to the frame, {B_WORDS}"}
    for label, a in arrows.items():
        y = a.get_ydata()
        assert len(y) == 3 and np.isnan(y[2]) and top - 0.02 * (top - bottom) < y[1] < top  # one arrow, to the frame
        assert y[0] == pytest.approx(-3.5 if label.startswith("HCR") else -4.1)  # from the point
    _plt().close(fig)


def test_the_caption_counts_the_resolved_points_and_what_the_rest_would_cost():
    """The report's lines under the synthetic curve: 2 of 4 resolved for A, 3 of 4 for B (split at `los_until`: A 1 of
    2 on each side, B 1 of 2 and 2 of 2); without a precision target the rest get no cost but the way to have one
    predicted; with records at the quoted θ (A's 0.2 unmet, 1e8 extra pixel-samples, 0.3 met, and 0.4, resolved on
    the curve, unmet with 2e8 more; B's 0.2 predicted never to meet it, 0.4 met, 0.3 not quoted) the line counts
    every quoted θ, sums the extra, times it at the measured rate (10 ns per pixel-sample: 3e8 → 3 s), names what no
    number of sets meets and the unresolved θ not quoted; with the curve's own prediction instead, the median and
    the largest count of fresh sets of the whole grid and those that need a finer step."""
    from nlosbench.studies.bounds import resolution

    lines = resolution(SYNTHETIC, "x", [], None, 0.95)
    assert "about 5% of the ends may miss" in lines[0]
    assert lines[2].startswith("- AWGN, σ = 0.05: 2 of 4 points resolved; the other 2: no cost predicted")
    assert lines[3].startswith("- Poisson, scale = 300: 3 of 4 points resolved; the other 1: no cost predicted")
    lines = resolution(SYNTHETIC, "x", [], None, 0.95, los_until=0.25)  # line of sight: θ 0.1, 0.2
    assert lines[2].startswith("- AWGN, σ = 0.05: 2 of 4 points resolved (line of sight 1 of 2, beyond the corner 1 "
                               "of 2);")
    assert lines[3].startswith("- Poisson, scale = 300: 3 of 4 points resolved (line of sight 1 of 2, beyond the "
                               "corner 2 of 2);")

    def rec(noise, theta, met, extra):
        return {"noise": noise, "theta": {"x": theta}, "target": 0.25, "met": met, "extra_pixel_samples": extra}

    recs = [rec(A, 0.1, True, 0.0), rec(A, 0.2, False, 1e8), rec(A, 0.3, True, 0.0), rec(A, 0.4, False, 2e8),
            rec(B, 0.2, False, math.inf), rec(B, 0.4, True, 0.0)]
    lines = resolution(SYNTHETIC, "x", recs, 1e-8, 0.95)
    assert lines[2] == ("- AWGN, σ = 0.05: 2 of 4 points resolved; at the 4 quoted θ, 2 met ±25 %, 2 would need ≈ "
                        "3e+08 more pixel-samples (each θ's prediction, summed, ≈ 3 s on this machine at its measured "
                        "10 ns per pixel-sample)."), lines[2]
    assert lines[3].startswith("- Poisson, scale = 300: 3 of 4 points resolved; at the 2 quoted θ, 1 met ±25 %, 1 are "
                               "predicted to need more than any number of replicate sets"), lines[3]
    recs = [rec(B, 0.4, True, 0.0)]  # B's unresolved 0.2 not quoted
    assert resolution(SYNTHETIC, "x", recs, 1e-8, 0.95)[3] == (
        "- Poisson, scale = 300: 3 of 4 points resolved; at the 1 quoted θ, 1 met ±25 %; 1 unresolved θ not quoted "
        "(no prediction).")
    # the curve's own prediction (no quoted θ): A's 0.2, 0.3 and 0.4 need 8, 32 and 16 fresh sets of the whole grid (1e8
    # pixel-samples each), B's 0.2 a finer FD step; the cost of half of A's is the median count's, of all the largest's
    def own(noise, theta, sets, finer_step=False):
        return {"noise": noise, "theta": {"x": theta}, "target": 0.25, "met": False, "extra_sets": sets,
                "extra_pixel_samples": sets * 1e8, "note": "", "finer_step": finer_step}

    pred = [own(A, 0.2, 8.0), own(A, 0.3, 32.0), own(A, 0.4, 16.0), own(B, 0.2, math.inf, finer_step=True)]
    lines = resolution(SYNTHETIC, "x", [], 1e-8, 0.95, predicted=pred)
    assert lines[2] == ("- AWGN, σ = 0.05: 2 of 4 points resolved; what ±25 % would cost, predicted from the curve's "
                        "own sets (nothing rendered for it): 3 of the 4 θ miss it; 3 would meet it with fresh "
                        "replicate sets of the whole grid, one set serving every θ (from 8 sets): half of them with 16 "
                        "sets, 1.6e+09 pixel-samples, ≈ 16 s, all 3 with 32 sets, 3.2e+09 pixel-samples, ≈ 32 s on "
                        "this machine at its measured 10 ns per pixel-sample."), lines[2]
    assert lines[3].endswith("1 of the 4 θ miss it; 1 need a finer FD step than the grid's (F still rises at it: an "
                             "edge), which a `precision` target quotes through the bound service's `at`."), lines[3]


def test_values_decades_away_are_marked_off_scale_and_do_not_stretch_the_axis(rows):
    rs, zzb = rows
    assert min(r["log10_hcr_neff"] for r in rs) < -100 and zzb < -20  # the toy's paper HCR_Neff and ZZB are far off
    fig = bounds_figure(rs, parameter="edge", units="m", zzb={NOISE: zzb})
    ax = fig.axes[0]
    bottom, top = ax.get_ylim()
    data = [v for r in rs for v in (r["log10_hcr"], r["hcr_upper"], r["log10_crlb"])]
    assert bottom > min(data) - 1 and top < max(data) + 1
    off = [a for a in ax.lines if "off scale" in a.get_label()]
    assert {a.get_label().split(":")[0] for a in off} == {f"HCR_Neff (paper), {WORDS}",
                                                          f"ZZB over Θ (Bayesian MSE), {WORDS}"}
    for a in off:
        assert bottom < min(a.get_ydata()) and max(a.get_ydata()) < bottom + 0.1 * (top - bottom)  # just inside
    assert not any(np.allclose(a.get_ydata(), bottom) for a in ax.lines)  # nothing drawn on the bottom frame
    _plt().close(fig)


def test_an_rms_axis_in_the_parameters_units_stands_beside_the_bound_axis(rows):
    fig = bounds_figure(rows[0], parameter="edge", units="m")
    fig.canvas.draw()
    sec = fig.axes[0].child_axes[0]
    ticks = [t.get_text() for t in sec.get_yticklabels() if t.get_text()]
    assert len(ticks) >= 3 and all(t.endswith(("mm", "µm", "cm")) for t in ticks)
    for t, y in zip(sec.get_yticklabels(), sec.get_yticks(), strict=True):  # each label names √(10^y) m
        value, unit = t.get_text().split()
        scale = {"cm": 1e-2, "mm": 1e-3, "µm": 1e-6}[unit]
        assert float(value) * scale == pytest.approx(10.0 ** y, rel=1e-2)
    _plt().close(fig)


def test_the_trials_plot_joins_no_theta_and_keeps_a_far_bound_off_the_axis(rows):
    rs = rows[0]
    b = [dict(rs[1], theta_index=0, noise_index=0), dict(rs[7], theta_index=1, noise_index=0, hcr_upper=math.inf)]
    summary = [{"noise": 0, "theta_index": i, "theta_edge": r["theta_edge"], "estimator": "mle", "mse": 3 * 10 ** r[
        "log10_hcr"], "mse_se": 10 ** r["log10_hcr"]} for i, r in enumerate(b)]
    fig = mse_figure(summary, b, ["hcr", "crlb", "hcr_neff"], ["edge"], ["m"], {0: NOISE})
    ax = fig.axes[0]
    for line in ax.lines:  # markers only: two θ* are two experiments
        assert len(line.get_xdata()) < 2 or line.get_linestyle() == "None", line.get_label()
    assert ax.get_ylim()[0] > 1e-12  # HCR_Neff (1e-400 and below) is marked, not shown
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(lab.startswith("HCR_Neff: off scale") for lab in labels) and f"HCR: {OPEN}" in labels
    assert set(labels) == {a.get_label() for a in drawn(ax)}
    _plt().close(fig)


def test_colour_bar_ticks_on_a_symlog_scale_do_not_overlap():
    plt = _plt()
    fig, ax = plt.subplots(figsize=(3, 3))
    lin, top = 3e-2, 4e4
    im = ax.imshow(np.linspace(-top, top, 64).reshape(8, 8), norm=SymLogNorm(lin, vmin=-top, vmax=top), cmap="RdBu_r")
    bar = fig.colorbar(im, ax=ax)
    bar.set_ticks(symlog_ticks(lin, top))
    fig.canvas.draw()
    boxes = sorted((t.get_window_extent() for t in bar.ax.get_yticklabels() if t.get_text()), key=lambda b: b.y0)
    assert len(boxes) >= 5
    assert all(a.y1 <= b.y0 for a, b in zip(boxes, boxes[1:], strict=False))
    plt.close(fig)


def test_an_open_end_prints_as_infinity_and_a_missing_one_as_a_dash():
    assert fmt_end(math.inf) == fmt_end("inf") == "∞"
    assert fmt_end(-math.inf) == "0"
    assert fmt_end(None) == fmt_end("") == fmt_end(math.nan) == "–"
    assert fmt_end(-3.0) == "0.001"
    assert fmt(math.inf) == "∞" and fmt(math.nan) == "–" and fmt(0.5) == "0.5"  # e.g. an MSE's open upper limit
