"""Study `gradients`: which gradient to trust for each parameter, and what it costs.

For every parameter: gradient images from each backend (FD with and without common random numbers,
every applicable AD integrator) at each spp level and seed; remedies (mean / median of K AD passes,
more samples on the visibility terms) at the highest spp; artifact metrics against a high-spp FD
reference (or, with `reference: null`, against the per-pixel median of the FD seeds); time and
peak memory relative to a forward render; a verdict per parameter (`verdicts.json`, which
`nlosbench.diagnostics.choose_backend` reads for `grad="auto"`) and the paper-style figure.

Files: summary.csv (one row per parameter × backend × remedy × spp), seeds.csv (one per image),
verdicts.json, gradient_grid.png, images/*.exr (seed 0 of each configuration, and the references).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..diagnostics import (
    REMEDIES,
    Reference,
    applicable_integrators,
    backend,
    forward_cost,
    gradient_images,
    image_metrics,
    judge,
    label,
    load_verdicts,
    outlier_mask,
    outlier_scores,
    param_kind,
    remedy_run,
    save_verdicts,
    spec_of,
)
from ..diagnostics.evaluate import fd_reference, result_row
from ..diagnostics.figures import gradient_grid
from ..diagnostics.metrics import THRESHOLD, spp_trend
from ..forward.gradients import GradientSettings
from ..forward.mitsuba_model import AD_INTEGRATORS
from ..io import read_csv, write_csv, write_exr
from ..schema import ConfigError, Field
from .context import RunContext
from .estimate import AD_PASS_RENDERS, Estimate, pixels

NAME = "gradients"
SCHEMA = {
    "params": Field(list, None, "parameters to differentiate (default: all of the scene's)", items=str, nullable=True),
    "at": Field(dict, {}, "θ where gradients are taken, by parameter name (default: the scene's values)"),
    "spp": Field(list, [64, 256], "spp levels of the gradient images", items=int),
    "seeds": Field(int, 4, "independent seeds per backend and spp (>= 2: confidence intervals need them)"),
    "backends": Field(list, None, "gradient backends, e.g. [{method: fd, step: 0.01, rounds: 1, crn: true}, "
                      "{method: ad, integrator: prb_projective, sppi: 0}]; default: FD with and without CRN "
                      "and every applicable AD integrator with `ad_options`", items=dict, nullable=True),
    "ad_options": Field(dict, {"guiding": "none"}, "options of the default projective AD backends "
                        "(Mitsuba's octree guiding costs ~20 s per 32×32 pass on 2 cores)"),
    "fd_step": Field(float, 0.01, "FD step ξ of the default FD backends and of the reference (parameter units)"),
    "reference": Field({"spp": Field(int, 1024, "spp of each reference FD render"),
                        "rounds": Field(int, 4, "independent FD rounds averaged (>= 2)")}, nullable=True,
                       help="high-spp FD reference; null: the per-pixel median of the FD (CRN) seeds"),
    "remedies": Field({"names": Field(list, list(REMEDIES), "remedies to measure", items=str),
                       "k": Field(int, 4, "passes of the mean/median-of-K remedies (spp/K each; median: K >= 3)"),
                       "boost": Field(int, 4, "visibility-boost: spp multiplier of the visibility terms")}),
    "threshold": Field(float, THRESHOLD, "outlier score threshold"),
    "min_area": Field(int, 1, "smallest outlier cluster counted (pixels)"),
    "target_rel_error": Field(float, 0.05, "target error of the total derivative relative to the reference's"),
    "save_images": Field(bool, True, "write the gradient images as EXR"),
}


def _backends(ctx: RunContext, cfg: dict, index: int) -> list[tuple[GradientSettings, str]]:
    """(settings, why not applicable or '') for parameter `index`; FD with CRN first (the control)."""
    if cfg["backends"] is not None:
        found = [backend(b) for b in cfg["backends"]]
        why = applicable_integrators(ctx.model, index)
        return sorted([(s, why.get(s.ad.get("type"), "") if s.method == "ad" else "") for s in found],
                      key=lambda x: not (x[0].method == "fd" and x[0].crn))
    out = [
        (GradientSettings("fd", step=cfg["fd_step"]), ""),
        (GradientSettings("fd", step=cfg["fd_step"], crn=False), ""),
    ]
    applicable = applicable_integrators(ctx.model, index)
    if not applicable:  # a model without scene bindings: its own (exact) derivative
        return out + [(GradientSettings("ad"), "")]
    for name in AD_INTEGRATORS:
        if not applicable[name]:
            opts = cfg["ad_options"] if name != "prb" else {}
            out.append((backend({"method": "ad", "integrator": name, **opts}), ""))
    return out


@dataclass(frozen=True)
class Plan:
    """Parameters to differentiate, θ (P,), the sorted spp levels, and per parameter the backends
    (settings, why not applicable or '')."""

    names: list
    theta: np.ndarray
    spps: list
    backends: dict


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError naming the key for what the schema cannot see
    (parameter names, θ inside Θ, positive spp / seeds >= 2 / reference, backends that parse, known remedies).
    Renders nothing."""
    sid = cfg.get("id") or NAME
    model = ctx.model
    names = cfg["params"] or list(model.params.names)
    for i, n in enumerate(names):
        if n not in model.params.names:
            raise ConfigError(f"{sid}.params[{i}]",
                              f"unknown parameter {n!r}; this model has {list(model.params.names)}")
    theta = model.params.default.copy()
    for k, v in cfg["at"].items():
        if k not in model.params.names:
            raise ConfigError(f"{sid}.at.{k}", f"unknown parameter; this model has {list(model.params.names)}")
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise ConfigError(f"{sid}.at.{k}", f"expected a number, got {type(v).__name__} {v!r}")
        theta[model.params.index(k)] = v
    try:
        theta = model.params.validate(theta)
    except ValueError as e:
        raise ConfigError(f"{sid}.at", str(e)) from None
    if not cfg["spp"] or min(cfg["spp"]) < 1:
        raise ConfigError(f"{sid}.spp", f"expected a non-empty list of positive integers, got {cfg['spp']}")
    checks = {"seeds": (cfg["seeds"] >= 2, "an integer >= 2 (confidence intervals need them)"),
              "fd_step": (cfg["fd_step"] > 0, "a step > 0"),
              "threshold": (cfg["threshold"] > 0, "a number > 0"),
              "min_area": (cfg["min_area"] >= 1, "an integer >= 1"),
              "target_rel_error": (cfg["target_rel_error"] > 0, "a number > 0"),
              "remedies.k": (cfg["remedies"]["k"] >= 1, "an integer >= 1"),
              "remedies.boost": (cfg["remedies"]["boost"] >= 1, "an integer >= 1")}
    if cfg["reference"] is not None:
        checks["reference.spp"] = (cfg["reference"]["spp"] >= 1, "a positive integer")
        checks["reference.rounds"] = (cfg["reference"]["rounds"] >= 2, "an integer >= 2")
    for key, (ok, expected) in checks.items():
        if not ok:
            value = cfg
            for part in key.split("."):
                value = value[part]
            raise ConfigError(f"{sid}.{key}", f"expected {expected}, got {value!r}")
    unknown = sorted(set(cfg["remedies"]["names"]) - set(REMEDIES))
    if unknown:
        raise ConfigError(f"{sid}.remedies.names", f"unknown remedies {unknown}; known: {list(REMEDIES)}")
    try:
        backends = {n: _backends(ctx, cfg, model.params.index(n)) for n in names}
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{sid}.backends", str(e)) from None
    if cfg["reference"] is None and not any(s.method == "fd" and s.crn for s, _ in next(iter(backends.values()))):
        raise ConfigError(f"{sid}.reference", "null (the median of the FD seeds) needs an FD backend with crn: true")
    return Plan(names, theta, sorted(cfg["spp"]), backends)


def cost(ctx: RunContext, cfg: dict, p: Plan) -> Estimate:
    """Per parameter: 3 forward renders per spp level (the time baseline), the FD reference (rounds × 2
    renders at its spp), each backend at each spp × seeds (FD: 2 renders per round; AD: one pass, counted
    as AD_PASS_RENDERS renders), and each remedy of each AD backend at the top spp (K passes of spp/K; the
    visibility boost `boost`× the samples)."""
    px, S, top, ref = pixels(ctx.model), cfg["seeds"], max(p.spps), cfg["reference"]
    renders = samples = 0
    for n in p.names:
        renders += 3 * len(p.spps)
        samples += 3 * sum(p.spps)
        if ref:
            renders += 2 * ref["rounds"]
            samples += 2 * ref["rounds"] * ref["spp"]
        for s, why in p.backends[n]:
            per = 2 * s.rounds if s.method == "fd" else AD_PASS_RENDERS
            renders += per * S * len(p.spps)
            samples += per * S * sum(p.spps)
            if s.method == "ad" and not why and s.ad.get("type"):
                for rem in cfg["remedies"]["names"]:
                    if rem != "visibility-boost" or s.ad["type"] != "prb":
                        k = cfg["remedies"]["boost"] if rem == "visibility-boost" else 1
                        renders += AD_PASS_RENDERS * S * (cfg["remedies"]["k"] if rem != "visibility-boost" else 1)
                        samples += AD_PASS_RENDERS * S * top * k
    return Estimate(renders, samples * px, "AD passes counted as 4 renders each")


def run(ctx: RunContext, cfg: dict) -> dict:
    p = plan(ctx, cfg)
    model, out = ctx.model, ctx.study_dir(cfg)
    names, theta = p.names, p.theta
    spps, S, top = p.spps, cfg["seeds"], max(cfg["spp"])
    forward = {
        spp: forward_cost(model, theta, spp, [ctx.seed_for("gradients-forward", spp, s) for s in range(3)])
        for spp in spps
    }
    rows, seed_rows, images, masks, grid_rows = [], [], {}, {}, ["reference"]
    for j_name in names:
        j = model.params.index(j_name)
        ref_cfg = cfg["reference"]
        ref = (
            fd_reference(
                model, theta, j, ref_cfg["spp"], ref_cfg["rounds"], cfg["fd_step"], ctx.seed_for("gradients-ref", j)
            )
            if ref_cfg
            else None
        )
        if ref is not None:
            images[("reference", j_name, spps[0])] = ref.image
        configs = p.backends[j_name]
        todo = [(b, s, why, spp, "") for b, (s, why) in enumerate(configs) for spp in spps]
        todo += [
            (b, s, why, top, rem)
            for b, (s, why) in enumerate(configs)
            if s.method == "ad" and not why and s.ad.get("type")
            for rem in cfg["remedies"]["names"]
            if rem != "visibility-boost" or s.ad["type"] != "prb"
        ]
        fd_median: dict[int, Reference] = {}
        for b, settings, why, spp, remedy in ctx.progress(todo, total=len(todo), desc=f"gradients d/d{j_name}"):
            seeds = [ctx.seed_for("gradients", b, j, spp, s) for s in range(S)]
            if remedy:
                run_ = remedy_run(
                    model, theta, j, settings, spp, seeds, remedy, cfg["remedies"]["k"], cfg["remedies"]["boost"]
                )
            else:
                run_ = gradient_images(model, theta, j, settings, spp, seeds)
            is_control = settings.method == "fd" and settings.crn and not remedy
            if ref is None and is_control:
                fd_median[spp] = Reference.from_stack(run_.images, center="median")
            r_ = ref or fd_median.get(spp)
            if r_ is None:
                raise ValueError("gradients study with `reference: null` needs an FD backend with crn: true")
            lab = label(settings) + (f" + {remedy}" if remedy else "")
            row = {
                "param": j_name,
                "kind": param_kind(model, j) or "",
                "label": lab,
                "backend": label(settings),
                "method": settings.method,
                "crn": settings.crn if settings.method == "fd" else "",
                "remedy": remedy,
                "spp": spp,
                "applicable": why,
                "spec": json.dumps(spec_of(settings)),
                **result_row(run_, r_, forward[spp], cfg["target_rel_error"], cfg["threshold"], cfg["min_area"]),
            }
            rows.append(row)
            for m in image_metrics(run_.images, r_, cfg["threshold"], cfg["min_area"]):
                seed_rows.append({"param": j_name, "label": lab, "spp": spp, "seed": seeds[m["seed_index"]], **m})
            if not remedy:
                grid_rows += [label(settings)] if label(settings) not in grid_rows else []
                key = (label(settings), j_name, spp)
                images[key] = run_.images[0]
                masks[key] = outlier_mask(outlier_scores(run_.images, r_), cfg["threshold"], cfg["min_area"])[0]
        if ref is None:
            images[("reference", j_name, spps[0])] = fd_median[spps[0]].image
    if cfg["save_images"]:
        for (row_label, p, spp), img in images.items():
            write_exr(out / "images" / f"{p}__{_safe(row_label)}__{spp}spp.exr", img)
    _add_spp_trends(rows)
    write_csv(out / "summary.csv", rows)
    write_csv(out / "seeds.csv", seed_rows)
    verdicts = {n: judge(rows, n) for n in names}
    save_verdicts(out / "verdicts.json", verdicts)
    gradient_grid(
        images,
        masks,
        grid_rows,
        [(p, s) for p in names for s in spps],
        out / "gradient_grid.png",
        {n: model.params.units[model.params.index(n)] for n in names},
    )
    return {
        "params": names,
        "theta": dict(zip(model.params.names, theta.tolist(), strict=True)),
        "spp": spps,
        "seeds": S,
        "reference": (
            f"FD ξ={cfg['fd_step']:g}, {cfg['reference']['spp']} spp × {cfg['reference']['rounds']} rounds"
            if cfg["reference"]
            else "per-pixel median of the FD (CRN) seeds"
        ),
        "target_rel_error": cfg["target_rel_error"],
        "threshold": cfg["threshold"],
        "forward_seconds": {str(k): v.seconds for k, v in forward.items()},
        "forward_peak_mib": {str(k): v.peak_bytes / (1 << 20) for k, v in forward.items()},
        "verdicts": {n: v.text for n, v in verdicts.items()},
    }


def _add_spp_trends(rows: list[dict]) -> None:
    """Set `spp_trend` (none / fade / steady / grow: outlier pixels per image from the lowest to the
    highest spp, see metrics.spp_trend) on every plain (no remedy) row; '' with a single spp level."""
    by_config: dict = {}
    for r in rows:
        if not r["remedy"]:
            by_config.setdefault((r["param"], r["label"]), []).append(r)
    for group in by_config.values():
        lo, hi = min(group, key=lambda r: r["spp"]), max(group, key=lambda r: r["spp"])
        trend = spp_trend(lo["outlier_pixels_per_image"], hi["outlier_pixels_per_image"]) if hi is not lo else ""
        for r in group:
            r["spp_trend"] = trend
    for r in rows:
        r.setdefault("spp_trend", "")


def smoke(block: dict) -> dict:
    """A seconds-long copy: 2 seeds, spp levels 4 and 8 (one level stays one), a 32-spp × 2-round
    reference, K ≤ 4, boost = 2, and `guiding: none` for the projective AD backends (octree guiding costs
    ~20 s per pass on 2 cores whatever the image size)."""

    def unguided(spec: dict) -> dict:
        projective = spec.get("method") == "ad" and spec.get("integrator") in ("prb_projective", "direct_projective")
        return {**spec, "guiding": "none"} if projective else spec

    return {
        **block,
        "spp": [4, 8] if len(set(block["spp"])) > 1 else [8],
        "seeds": 2,
        "backends": None if block["backends"] is None else [unguided(b) for b in block["backends"]],
        "ad_options": {**block["ad_options"], "guiding": "none"},
        "reference": block["reference"] and {"spp": min(block["reference"]["spp"], 32), "rounds": 2},
        "remedies": {**block["remedies"], "k": min(block["remedies"]["k"], 4), "boost": 2},
    }


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_=." else "_" for c in name)


def _fmt(v, spec: str = ".3g") -> str:
    if v in ("", None):
        return ""
    x = float(v)
    return "∞" if math.isinf(x) else ("" if math.isnan(x) else format(x, spec))


def report(study_dir: Path, results: dict) -> str:
    rows = read_csv(study_dir / "summary.csv")
    verdicts = load_verdicts(study_dir)
    lines = [
        f"Gradients of {', '.join(results['params'])} at θ = {results['theta']}: each backend at "
        f"{', '.join(map(str, results['spp']))} spp, {results['seeds']} seeds; reference: {results['reference']}. "
        f"Outliers: score > {results['threshold']:g} (robust per-pixel z against the reference). "
        f"Time to target: seconds to reach a total-derivative error of {results['target_rel_error']:.0%} "
        "(∞: biased). One forward render takes "
        + ", ".join(
            f"{float(t):.3g} s ({float(results['forward_peak_mib'][k]):.3g} MiB peak) at {k} spp"
            for k, t in results["forward_seconds"].items()
        )
        + ".",
        "",
        f"![gradient images]({study_dir.name}/gradient_grid.png)",
        "",
        "| parameter | verdict | backend for grad=auto | cheapest to target |",
        "|---|---|---|---|",
    ]
    for n, v in verdicts.items():
        lines.append(f"| {n} | {v.text} | {label(v.settings())} | {v.cheapest or '—'} |")
    lines += [
        "",
        "Persistence: mean Jaccard overlap of the outlier masks across seeds (1: clusters stay put, 0: they "
        "move with the seed). Trend: outlier pixels from the lowest to the highest spp. × fwd memory: blank where "
        "a forward render's own peak is under 1 MiB (then only the absolute peak means something).",
        "",
        "| parameter | gradient | spp | clusters/img | outlier px/img | max cluster px | persistence | trend "
        "| total ± se | reference | agrees | pixel var | s/grad | × fwd time | peak MiB | × fwd memory "
        "| time to target [s] |",
        "|" + "---|" * 17,
    ]
    for r in rows:
        lines.append(
            f"| {r['param']} | {r['label']}{' (' + r['applicable'] + ')' if r['applicable'] else ''} | {r['spp']} "
            f"| {_fmt(r['clusters_per_image'])} | {_fmt(r['outlier_pixels_per_image'])} "
            f"| {r['max_cluster_area']} | {_fmt(r['persistence'], '.2f')} | {r.get('spp_trend', '')} "
            f"| {_fmt(r['total'], '.4g')} ± {_fmt(r['total_se'], '.2g')} | {_fmt(r['ref_total'], '.4g')} "
            f"| {r['agrees']} | {_fmt(r['pixel_var'])} | {_fmt(r['seconds'])} | {_fmt(r['time_ratio'])} "
            f"| {_fmt(r['peak_mib'])} | {_fmt(r['memory_ratio'])} | {_fmt(r['cost_to_target'])} |"
        )
    lines += ["", "Per-verdict evidence:"]
    lines += [f"- {n}: " + "; ".join(v.reasons) for n, v in verdicts.items()]
    return "\n".join(lines)
