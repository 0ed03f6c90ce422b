"""Precision on request for the studies that quote bounds at θ (`trials` at its θ*, `bounds` at `precision_at`,
`fisher-maps` at its points):
the shared config keys, their config-time check, the arguments they give the bound service, what a run keeps of
each point's `Precision` record, and the report's table. The stopping rule itself is the bound service's
(`bounds.precision`); nothing here computes a bound.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

from ..bounds.precision import CEILING, KINDS, ceiling
from ..schema import ConfigError, Field, integer_in, positive_integer, positive_number
from .estimate import Estimate, describe
from .tables import fmt, fmt_end

PRECISION = Field(positive_number, None, "target relative half-width p of every interval bound quoted at θ (HCR, "
                  "CRLB): the bound service adds fresh replicate render sets where an interval is wider than "
                  "1 ± p (α spent along the looks, so coverage survives the stopping); null: one fixed set of "
                  "`replicates`", nullable=True)
PRECISION_BUDGET = Field(positive_integer, None, "cap on the pixel-samples (spp × H × W × renders) the precise bounds "
                         f"may spend (needs `precision`); null: the default ceiling, {CEILING} × what their pilot "
                         "costs (the pilot included)", nullable=True)
LOOKS = Field(integer_in(1, 64), 2, "with `precision`: the pilot and at most looks − 1 fresh looks, each on "
              "replicate sets of its own; the pilot's ends at α/20, the fresh looks' share the rest (α = 1 − level); "
              "1: the pilot alone at the full level, with what meeting the target would cost")
#: the schema keys, as a study's SCHEMA takes them
KEYS = {"precision": PRECISION, "precision_budget": PRECISION_BUDGET, "looks": LOOKS}


def check(cfg: dict, sid: str, kinds: Sequence[str], sets: str = "replicates") -> None:
    """ConfigError naming the key: a budget without a precision; a precision without an interval bound among
    `kinds` (the bounds asked for) or with fewer than 3 replicate sets (confidence limits; `sets` names the key
    that counts them)."""
    if cfg["precision_budget"] is not None and cfg["precision"] is None:
        raise ConfigError(f"{sid}.precision_budget", "a budget needs a precision target; set `precision` or remove "
                                                     "`precision_budget`")
    if cfg["precision"] is None:
        return
    if not set(KINDS) & set(kinds):
        raise ConfigError(f"{sid}.precision", f"a precision target needs an interval bound ({', '.join(KINDS)}), "
                                              f"got {list(kinds)}")
    if cfg[sets] < 3:
        raise ConfigError(f"{sid}.{sets}", f"a precision target needs >= 3 {sets} (confidence limits), got "
                                           f"{cfg[sets]}")


def at_kwargs(cfg: dict) -> dict:
    """The precision keyword arguments of `BoundService.at`, `curve` and `fisher` from a validated block (precision,
    budget, looks)."""
    return {"precision": cfg["precision"], "budget": cfg["precision_budget"], "looks": cfg["looks"]}


def estimate(renders: int, samples: int, cfg: dict, spp: int, pixels: int, pilot: int, note: str = "") -> Estimate:
    """A study's Estimate from what it counts (renders, pixel-samples) and its precision target. The target's call is
    capped, its pilot included, at the `precision_budget` or without one at the default ceiling
    (`bounds.precision.ceiling`) of `pilot`, the pixel-samples the study counts for that pilot (every request it
    charges, rendered or shared); so its fresh looks add at most budget − pilot in renders of `spp` × `pixels`:
    `samples` is then a maximum and `least` what is spent without them. The note names a default ceiling."""
    if cfg.get("precision") is None:
        return Estimate(renders, samples, note)
    budget = cfg["precision_budget"]
    if budget is None:
        budget = ceiling(pilot)
        note = "; ".join(n for n in (note, f"precision: no precision_budget, so the default ceiling, {CEILING} × "
                                           f"the pilot's pixel-samples (≈ {pilot:.3g}): ≈ {budget:.3g}") if n)
    fresh = max(budget - pilot, 0)
    return Estimate(renders + fresh // (spp * pixels), samples + fresh, note, samples)


def smoke(block: dict) -> dict:
    """A smoke run keeps the target but a budget of 1 pixel-sample: the pilot and the plan, no fresh look."""
    return {**block, "precision_budget": 1} if block.get("precision") is not None else block


def records(points: Sequence, T: int, names: Sequence[str]) -> list[dict]:
    """What a run keeps (results.json) of each BoundPoint's `Precision`: noise, θ index, θ, per interval bound
    its log10 point and ends and the precision reached, and the record's target, met, looks, level, pixel-samples
    charged to the whole call (by request), this θ's own share (`Precision.own_pixel_samples`) and those rendered
    by this process, predicted extra sets and pixel-samples,
    note, and whether only a finer FD step would meet it (`finer_step`). [] without a precision target."""
    out = []
    for n, pt in enumerate(points):
        pr = pt.precision
        if pr is None:
            continue
        out.append({"noise_index": pt.noise_index, "noise": pt.noise, "theta_index": n % T,
                    "theta": {k: float(v) for k, v in zip(names, pt.theta, strict=True)},
                    "bounds": {k: {"point": pt.bounds[k].point, "lower": pt.bounds[k].lower,
                                   "upper": pt.bounds[k].upper, "reached": r} for k, r in pr.reached.items()},
                    "target": pr.target, "met": pr.met, "looks": pr.looks, "fresh_sets": pr.fresh_sets,
                    "level": pr.level, "pixel_samples": pr.pixel_samples, "own_pixel_samples": pr.own_pixel_samples,
                    "rendered_pixel_samples": pr.rendered, "extra_sets": pr.extra_sets,
                    "extra_pixel_samples": pr.extra_pixel_samples, "note": pr.note, "finer_step": pr.finer_step})
    return out


def _own(r: dict) -> str:
    """A record's own pixel-samples, "–" in a record kept before they were."""
    return f"{r['own_pixel_samples']:.3g}" if "own_pixel_samples" in r else "–"


def _extra(r: dict, seconds_per_sample: float | None) -> str:
    if r["met"]:
        return "–"
    x = r["extra_pixel_samples"]
    if not math.isfinite(x):
        return "none predicted to suffice"
    text = f"{fmt(float(r['extra_sets']), 3)} sets, {x:.3g} pixel-samples"
    return text + (f", ≈ {describe(x * seconds_per_sample)}" if seconds_per_sample else "")


def table(recs: list[dict], units: str, seconds_per_sample: float | None = None) -> list[str]:
    """Markdown: a row per (noise, θ, interval bound): the point and its ends (units²), the precision reached
    against the target, met, looks, the θ's own pixel-samples and the call's, and where unmet the predicted extra fresh
    sets and pixel-samples (and time at `seconds_per_sample`, the run's measured rate, when given), the note."""
    if not recs:
        return []
    lvl = f"{recs[0]['level']:.2%}"
    lines = [f"Target: every interval bound within ±{fmt(100 * recs[0]['target'], 3)} % (relative half-width, linear "
             f"units); each end a one-sided {lvl} limit (the level divided over the looks, so the reported interval "
             "keeps its coverage whatever look it stops at). Pixel-samples: first this θ's own, its replicate sets' "
             "renders over the pilot and every look (θ and its offsets or tested Δ, the FD stencils of each step "
             "rendered; not the test grid every θ shares; a render a neighbour's stencil shares, as common seeds "
             "make them, counted in each), then those the whole call asked for (every θ listed), charged whether "
             "rendered or served from a cache or store, so the budget decides the same way cold or warm (in "
             "brackets: what this run rendered); the predicted extra is what more fresh replicate sets the "
             "service's plan says the target needs" +
             ("" if seconds_per_sample else " (no time: this run has no measured render rate)") + ".", "",
             f"| noise | θ | bound | point [{lvl} ends] ({units}) | reached (target) | met | looks | pixel-samples | "
             "predicted extra | note |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        theta = ", ".join(fmt(v, 4) for v in r["theta"].values())
        for kind, b in r["bounds"].items():
            ends = f"{fmt_end(b['point'])} [{fmt_end(b['lower'])}, {fmt_end(b['upper'])}]"
            lines.append(f"| {r['noise']} | {theta} | {kind} | {ends} | ±{fmt(100 * b['reached'], 3)} % "
                         f"(±{fmt(100 * r['target'], 3)} %) | {'yes' if r['met'] else 'no'} | {r['looks']} | "
                         f"{_own(r)}; {r['pixel_samples']:.3g} ({r.get('rendered_pixel_samples', 0):.3g}) | "
                         f"{_extra(r, seconds_per_sample)} | {r['note']} |")
    return lines
