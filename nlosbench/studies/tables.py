"""Markdown helpers for study reports: number formats (also beyond float64's range) and the paper's
MLE-vs-bounds table."""
from __future__ import annotations

import math

import numpy as np


def cell(v) -> float:
    """A CSV cell as a float (NaN for an empty cell)."""
    return float(v) if v not in ("", None) else np.nan


def mse_units(units) -> str:
    """Units of the MSE of θ: the parameters' unit squared (or a note when they differ)."""
    return f"{units[0]}²" if len(set(units)) == 1 else "mixed units²"


def fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, float) and math.isinf(v):
        return "∞" if v > 0 else "−∞"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


BOUND_TITLES = {"hcr": "HCR (lower end)", "hcr_neff": "HCR_Neff", "hcr_hat": "HCR-hat", "crlb": "CRLB",
                "barankin": "Barankin"}


def fmt_log10(lg: float) -> str:
    """10**lg with 4 significant digits, also beyond float64's range (e.g. 1.3e-400); '–' when the
    bound is unavailable (log10 = ±inf; its reason is in the bounds table)."""
    if not math.isfinite(lg):
        return "–"
    if -300 < lg < 300:
        return f"{10.0 ** lg:.4g}"
    e = math.floor(lg)
    return f"{10.0 ** (lg - e):.4g}e{e:+d}"


def fmt_end(lg) -> str:
    """An interval end given as log10 (a float or a CSV cell): "∞" for an open end (+inf), "0" for an end at 0
    (−inf), "–" when it was not computed (NaN, empty or None), else as `fmt_log10`."""
    v = cell(lg) if isinstance(lg, str) or lg is None else float(lg)
    if math.isnan(v):
        return "–"
    if math.isinf(v):
        return "∞" if v > 0 else "0"
    return fmt_log10(v)


def paper_table(rows: list[dict], bound_rows: list[dict], bounds, params: list[str], units: list[str],
                noise: int) -> list[str]:
    """The paper's MLE-vs-HCR table for one noise model (index): θ*, the bounds, then MSE and Var of every
    estimator (units², 4 significant digits; an underflowed bound is written from its log10)."""
    labels = list(dict.fromkeys(r["estimator"] for r in rows))
    head = [f"θ* ({', '.join(units)})"] + [BOUND_TITLES[b] for b in bounds] + \
        [f"{m}({e})" for e in labels for m in ("MSE", "Var")]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    mine = [r for r in rows if r["noise"] == noise]
    for i in dict.fromkeys(r["theta_index"] for r in mine):
        first = next(r for r in mine if r["theta_index"] == i)
        b = next((b for b in bound_rows if b["noise_index"] == noise and b["theta_index"] == i), {})
        cells = [", ".join(fmt(first[f"theta_{n}"], 4) for n in params)]
        cells += [fmt_log10(float(b[f"log10_{k}"])) if b else "–" for k in bounds]
        for e in labels:
            r = next(r for r in mine if r["theta_index"] == i and r["estimator"] == e)
            cells += [fmt(r["mse"], 4), fmt(r["var"], 4)]
        out.append("| " + " | ".join(cells) + " |")
    return out
