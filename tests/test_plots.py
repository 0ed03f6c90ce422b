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
    assert f"HCR interval (lower to upper end), {NOISE}" in labels  # the band has its entry
    noted = any(note(r, "hcr", e) for r in rs for e in ("lower", "upper"))  # the service's own notes (FD step)
    assert any(NOT_LIMIT in t for t in labels) == noted
    assert any(OPEN in t for t in labels) == any(math.isinf(r["hcr_upper"]) for r in rs)
    legend = ax.get_legend().get_window_extent(fig.canvas.get_renderer())
    assert legend.y1 < ax.get_window_extent(fig.canvas.get_renderer()).y0  # below the data, not over it
    _plt().close(fig)


def test_an_open_upper_end_is_a_marker_and_no_band_reaches_the_frame(rows):
    rs = [dict(r) for r in rows[0]]
    rs[6]["hcr_upper"] = math.inf
    fig = bounds_figure(rs, parameter="edge", units="m")
    ax = fig.axes[0]
    opened = [a for a in ax.lines if OPEN in a.get_label()]
    assert len(opened) == 1 and list(opened[0].get_xdata()) == [pytest.approx(rs[6]["theta_edge"])]
    assert opened[0].get_ydata()[0] == pytest.approx(rs[6]["log10_hcr"])
    finite = max(r["hcr_upper"] for r in rs if math.isfinite(r["hcr_upper"]))
    for band in (c for c in ax.collections if "interval" in c.get_label()):
        assert np.nanmax(_ydata(band)) <= finite + 1e-9 < ax.get_ylim()[1]
    assert OPEN in {t.get_text().split(", ")[0].removeprefix("HCR ") for t in ax.get_legend().get_texts()}
    _plt().close(fig)


def test_an_end_that_is_not_a_confidence_limit_is_drawn_apart_and_old_tables_read_as_valid(rows):
    rs = [{k: v for k, v in r.items() if not k.endswith("_note")} for r in rows[0]]  # a table without notes: valid
    fig = bounds_figure(rs, parameter="edge", units="m")
    assert not any(NOT_LIMIT in a.get_label() for a in fig.axes[0].lines)
    _plt().close(fig)
    rs[2]["hcr_lower_note"] = "not a confidence limit: FD step not converged (F ×1.46 from ξ to ξ/2)"
    rs[3]["hcr_lower_note"] = ""
    fig = bounds_figure(rs, parameter="edge", units="m")
    marked = [a for a in fig.axes[0].lines if NOT_LIMIT in a.get_label()]
    assert len(marked) == 1 and "lower end" in marked[0].get_label()
    assert list(marked[0].get_xdata()) == [pytest.approx(rs[2]["theta_edge"])]
    assert marked[0].get_markerfacecolor() == "none"  # hollow: set apart from the valid ends
    _plt().close(fig)
    level = rs[0]["log10_hcr"] + 0.3
    for notes, expect in (({NOISE: "not a confidence limit: upper limit of the distance not resolved"}, 1), ({}, 0)):
        fig = bounds_figure(rs, parameter="edge", units="m", zzb={NOISE: level}, zzb_notes=notes)
        zzb = [a for a in fig.axes[0].lines if a.get_label().startswith("ZZB")]
        assert len(zzb) == 1 and zzb[0].get_ydata()[0] == pytest.approx(level)
        assert zzb[0].get_label().endswith(NOT_LIMIT) == bool(expect)
        _plt().close(fig)


def test_values_decades_away_are_marked_off_scale_and_do_not_stretch_the_axis(rows):
    rs, zzb = rows
    assert min(r["log10_hcr_neff"] for r in rs) < -100 and zzb < -20  # the toy's paper HCR_Neff and ZZB are far off
    fig = bounds_figure(rs, parameter="edge", units="m", zzb={NOISE: zzb})
    ax = fig.axes[0]
    bottom, top = ax.get_ylim()
    data = [v for r in rs for v in (r["log10_hcr"], r["hcr_upper"], r["log10_crlb"])]
    assert bottom > min(data) - 1 and top < max(data) + 1
    off = [a for a in ax.lines if "off scale" in a.get_label()]
    assert {a.get_label().split(":")[0] for a in off} == {f"HCR_Neff (paper), {NOISE}",
                                                          f"ZZB over Θ (Bayesian MSE), {NOISE}"}
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
