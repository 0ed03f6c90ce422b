"""Study `viewpoint-search`: the camera offset with the smallest A-optimal score tr F̂⁻¹ of θ, found by Bayesian
optimisation, confirmed with fresh renders, and the best pair of cameras.

A view is a camera offset x = (x₀, x₁) [m] along two world axes, the camera re-aimed at a fixed `target`
(`camera.CameraRig`, as in the `viewpoints` grid). Its score is the bound service's CRLB of θ, tr F̂⁻¹ (units²),
from the unbiased Fisher matrix F̂ (P × P) over `fd_rounds` ≥ 3 independent FD rounds (`bounds.cameras_crlb`),
with one-sided limits and the jackknife SE of its log10 (`camera.log_se`). Views are compared at one FD step ξ, as
in the grid: the score is that of the model smoothed by ξ (flag "fd-smoothed"), the same quantity as the grid's, so
its ends are confidence limits of it and a search's view compares with a grid's view.

1. Search: `bayesopt.Search` minimises log10 tr F̂⁻¹ of one noise model over the offset `box`: a Sobol design
   (nothing from a grid), then `qLogNoisyExpectedImprovement` batches with each evaluation's SE as its known
   noise; it returns the evaluated view with the lowest posterior mean. A separate study, not a mode of
   `viewpoints`: its keys (box, evaluations, batches, confirmations) and its records differ from the grid's, and
   the two share the camera through `camera`.
2. Confirmation: the returned view, the standard view (offset 0) and, with a `grid`, that grid's best view are
   re-rendered with fresh seeds (purpose "viewpoint-confirm", never used by the search or the grid) at
   `confirm_rounds` rounds; their reported scores and limits come from those renders only.
3. Pair: Fisher matrices of independent cameras add, so from the evaluations' F̂ (and the grid's, with `grid`)
   the pair of views minimising tr (F̂_a + F̂_b)⁻¹ is chosen with no new render (`camera.best_pair`), then both
   views are rendered afresh and the pair's score and limits come from the joint rounds.

Every evaluation and confirmation is an executor task; finished ones are appended to search.jsonl (a
`records.RecordLog`), so a resumed run re-asks the same offsets (seeded) and renders only what is missing.
Needs the optional extra `search` (BoTorch).
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import read_csv, save_figure, write_csv
from ..records import RecordLog
from ..schema import ConfigError, Field
from . import bayesopt
from .camera import VIEW_KEYS, CameraRig, best_pair, score_cells, unit_axes, view_scores, viewpoint_information
from .context import RunContext, theta_at
from .estimate import Estimate, pixels
from .plots import _plt, noise_text

NAME = "viewpoint-search"
SCHEMA = {
    "at": Field(list, None, "θ (one value per studied parameter) whose A-optimal score is minimised (default: the "
                "parameters' defaults)", items=float, nullable=True),
    "box": Field(list, [[-0.381, 0.381], [-0.381, 0.381]], "[low, high] offsets [m] along each axis (paper: ±38.1 cm)",
                 items=Field(list, items=float)),
    **VIEW_KEYS,
    "fd_rounds": Field(int, 3, "independent FD rounds per evaluation (>= 3: a standard error)"),
    "reduce": Field(str, "mean", "combine the RGB channels of the Fisher maps by", choices=("sum", "mean")),
    "noise": Field(int, 0, "index of the noise model whose score the search minimises"),
    "initial": Field(int, 8, "views of the Sobol design before the first model-guided batch (>= 2)"),
    "evaluations": Field(int, 24, "views the search evaluates in all (>= initial)"),
    "batch": Field(int, 1, "views per model-guided batch (evaluated in parallel by the executor)"),
    "confirm_rounds": Field(int, 6, "independent FD rounds of each confirmation's fresh renders (>= 3)"),
    "pair": Field(bool, True, "choose the best pair of cameras and confirm it"),
    "max_pairs": Field(int, 5000, "exhaustive pair search up to this many pairs, greedy beyond"),
    "grid": Field(str, None, "id of a `viewpoints` study earlier in this run (same θ, axes, target, FD step, reduce, "
                  "fd_rounds >= 3): its best view is confirmed too, its views join the pair's candidates and its map "
                  "is drawn under the search's path", nullable=True),
    "grid_from": Field(str, None, "instead of `grid`: the folder of an earlier run (e.g. "
                       "results/paper_hallway_viewpoint_map; relative to the working directory) whose one `viewpoints` "
                       "study is used as `grid` is, checked to match this run's scene and noise models too",
                       nullable=True),
}
GRID_KEYS = ("at", "axes", "target", "fd_step", "reduce")
#: what is confirmed with fresh renders; the index in this tuple seeds its renders (purpose "viewpoint-confirm")
CONFIRMED = ("search", "standard", "grid-best", "pair")


def check(block: dict, path: str) -> None:
    """Config-time check: BoTorch (the extra `search`) is installed."""
    try:
        bayesopt.botorch_modules()
    except ImportError as e:
        raise ConfigError(path, str(e)) from None


@dataclass(frozen=True)
class Plan:
    """θ (P,), the box (2, 2) [m], the unit axes (2, 3), the camera's target (3,); the grid's block, the path of its
    viewpoints.csv and its label (the study id, or the earlier run's folder), None without a grid; `fingerprint`:
    the earlier run's map (its SHA-256), so a resume after it changed is refused."""

    theta: np.ndarray
    box: np.ndarray
    axes: np.ndarray
    target: np.ndarray
    grid: dict | None
    grid_csv: Path | None
    grid_label: str | None
    fingerprint: dict | None


def plan(ctx: RunContext, cfg: dict) -> Plan:
    """The study's plan from its validated block; ConfigError naming the key for what the schema cannot see.
    Renders nothing."""
    sid = cfg.get("id") or NAME
    m = ctx.model
    theta = theta_at(ctx, cfg, sid)
    checks = [("spp", cfg["spp"] >= 1, "a positive integer"), ("fd_step", cfg["fd_step"] > 0, "a step > 0"),
              ("fd_rounds", cfg["fd_rounds"] >= 3, "an integer >= 3 (a standard error needs 3 rounds)"),
              ("confirm_rounds", cfg["confirm_rounds"] >= 3, "an integer >= 3"),
              ("noise", 0 <= cfg["noise"] < len(ctx.noises), f"an index into the {len(ctx.noises)} noise model(s)"),
              ("initial", cfg["initial"] >= 2, "an integer >= 2"),
              ("evaluations", cfg["evaluations"] >= max(cfg["initial"], 2), "an integer >= initial"),
              ("batch", cfg["batch"] >= 1, "a positive integer"),
              ("max_pairs", cfg["max_pairs"] >= 1, "an integer >= 1")]
    for key, ok, want in checks:
        if not ok:
            raise ConfigError(f"{sid}.{key}", f"expected {want}, got {cfg[key]!r}")
    for key, call in (("box", lambda: bayesopt.check_box(cfg["box"])), ("axes", lambda: unit_axes(cfg["axes"]))):
        try:
            call()
        except ValueError as e:
            raise ConfigError(f"{sid}.{key}", str(e)) from None
    box = bayesopt.check_box(cfg["box"])
    if box.shape != (2, 2) or not np.all((box[:, 0] <= 0) & (box[:, 1] >= 0)):
        raise ConfigError(f"{sid}.box", f"expected two [low, high] pairs around the standard view (low <= 0 <= high), "
                                        f"got {cfg['box']!r}")
    try:
        target = CameraRig(m, cfg["target"]).target
    except ValueError as e:
        raise ConfigError(f"{sid}.target" if cfg["target"] is not None or "hits nothing" in str(e) else sid,
                          str(e)) from None
    if cfg["grid"] is not None and cfg["grid_from"] is not None:
        raise ConfigError(f"{sid}.grid_from", "give `grid` (a study of this run) or `grid_from` (an earlier run), "
                                              "not both")
    if cfg["grid_from"] is not None:
        g, csv = _grid_from(ctx, cfg, sid)
        label, fp = cfg["grid_from"], {"grid_sha256": hashlib.sha256(csv.read_bytes()).hexdigest()}
    else:
        g, label, fp = _grid_block(ctx, cfg, sid), cfg["grid"], None
        csv = None if g is None else ctx.dir / g["id"] / "viewpoints.csv"
    return Plan(theta, box, unit_axes(cfg["axes"]), target, g, csv, label, fp)


def _matching(g: dict, cfg: dict, path: str, what: str) -> None:
    """ConfigError unless the grid's block `g` matches this search in GRID_KEYS and has fd_rounds >= 3."""
    differ = [k for k in GRID_KEYS if g[k] != cfg[k]] + (["fd_rounds"] if g["fd_rounds"] < 3 else [])
    if differ:
        raise ConfigError(path, f"the grid {what} must match this search in {', '.join(GRID_KEYS)} and have "
                                f"fd_rounds >= 3; it differs in {', '.join(differ)}")


def run_study(where: Path, kind: str) -> tuple[dict, dict, Path]:
    """The config of the run in folder `where` (its config.yaml, which a run writes resolved: every default, every
    study's id), its one study of type `kind` and that study's folder; ValueError (one line) otherwise."""
    import yaml

    try:
        cfg = yaml.safe_load((Path(where) / "config.yaml").read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ValueError(f"{where} is not a finished run's folder ({e})") from None
    blocks = [b for b in cfg.get("studies", []) if b["type"] == kind]
    if len(blocks) != 1:
        raise ValueError(f"{where} has {len(blocks)} `{kind}` studies; one is needed")
    return cfg, blocks[0], Path(where) / blocks[0]["id"]


def _grid_from(ctx: RunContext, cfg: dict, sid: str) -> tuple[dict, Path]:
    """The one `viewpoints` block of the run in `grid_from` and its viewpoints.csv, checked to match this run's scene
    and noise models and this search."""
    where, key = cfg["grid_from"], f"{sid}.grid_from"
    try:
        other, g, folder = run_study(where, "viewpoints")
    except ValueError as e:
        raise ConfigError(key, str(e)) from None
    differ = [part for part in ("scene", "noise") if other[part] != ctx.config[part]]
    if differ:
        raise ConfigError(key, f"{where} was run with another {' and '.join(differ)}: its views are not this "
                               "run's")
    _matching(g, cfg, key, repr(str(where)))
    csv = folder / "viewpoints.csv"
    if not csv.is_file():
        raise ConfigError(key, f"{csv} is missing (is the run finished?)")
    return g, csv


def _grid_block(ctx: RunContext, cfg: dict, sid: str) -> dict | None:
    """The `viewpoints` block named by `grid`, checked to be earlier in the run and to match."""
    if cfg["grid"] is None:
        return None
    blocks = ctx.config.get("studies", [])
    ids = [b.get("id") for b in blocks]
    here = ids.index(cfg.get("id")) if cfg.get("id") in ids else len(blocks)
    found = [b for b in blocks[:here] if b.get("id") == cfg["grid"] and b["type"] == "viewpoints"]
    if not found:
        raise ConfigError(f"{sid}.grid", f"no `viewpoints` study with id {cfg['grid']!r} before this one "
                                         f"(ids: {', '.join(str(i) for i in ids[:here]) or 'none'})")
    _matching(found[0], cfg, f"{sid}.grid", repr(cfg["grid"]))
    return found[0]


def _views_per_confirmation(cfg: dict) -> int:
    """Views rendered afresh: the search's, the standard one, the grid's best (with a grid), the pair's two."""
    return 2 + (cfg["grid"] is not None or cfg["grid_from"] is not None) + 2 * cfg["pair"]


def cost(ctx: RunContext, cfg: dict, p: dict) -> Estimate:
    """`evaluations` views × (a render + `fd_rounds` FD rounds of 2P renders), and the confirmations' fresh views
    × (a render + `confirm_rounds` rounds)."""
    per = lambda rounds: 1 + 2 * ctx.model.params.dim * rounds
    renders = cfg["evaluations"] * per(cfg["fd_rounds"]) + _views_per_confirmation(cfg) * per(cfg["confirm_rounds"])
    return Estimate(renders, renders * cfg["spp"] * pixels(ctx.model))


def _views_task(model, item: dict) -> tuple:
    """Executor task (module level, picklable): one or two views rendered with their own seeds → (tag, record,
    renders): per view and noise F̂ (P, P) and the score's (point, lower, upper, log SE, lower note, flags); with
    two views the pair's joint score too (their Fisher matrices add)."""
    before = model.stats.snapshot()
    rig = CameraRig(model, item["target"])
    group = model.channels
    points, views = [], []
    for offset, seed in zip(item["offsets"], item["seeds"], strict=True):
        with rig.at(np.asarray(offset) @ np.asarray(item["axes"])):
            fp = viewpoint_information(model, item["theta"], item["spp"], seed, item["fd_step"], item["rounds"],
                                       item["noises"], item["reduce"], smoothed=True)
        points.append(fp)
        views.append(view_scores([fp], item["noises"], group, smoothed=True))
    rec = {"tag": item["tag"], "offsets": item["offsets"], "views": views,
           "joint": view_scores(points, item["noises"], group, smoothed=True) if len(points) > 1 else None}
    rec["renders"] = model.stats.since(before).renders
    return item["tag"], rec, rec["renders"]


def run(ctx: RunContext, cfg: dict) -> dict:
    p = plan(ctx, cfg)
    out = ctx.study_dir(cfg)
    names = list(ctx.model.params.names)
    log = RecordLog(out / "search.jsonl")
    if not ctx.resume:
        log.reset()
    done = {rec["tag"]: rec for rec in log.read()}
    base = {"target": p.target.tolist(), "axes": p.axes.tolist(), "theta": p.theta.tolist(),
            "spp": cfg["spp"], "fd_step": cfg["fd_step"], "noises": ctx.noises, "reduce": cfg["reduce"]}

    def render(items: list[dict], desc: str) -> list[dict]:
        todo = [it for it in items if it["tag"] not in done]
        with log:
            for tag, rec in ctx.bank.map(_views_task, todo, desc):
                log.append(rec)
                done[tag] = rec
        for it in items:
            if not np.allclose(done[it["tag"]]["offsets"], it["offsets"], rtol=0, atol=1e-12):
                raise ValueError(f"{log.path}: the record of {it['tag']} is at {done[it['tag']]['offsets']}, this run "
                                 f"asks {it['offsets']} (another search); run again without --resume")
        return [done[it["tag"]] for it in items]

    k = cfg["noise"]
    search = bayesopt.Search(p.box, cfg["initial"], ctx.seed_for("viewpoint-search"))
    while len(search) < cfg["evaluations"]:
        X, phase = search.ask(min(cfg["batch"], cfg["evaluations"] - len(search)))
        n0 = len(search)
        recs = render([{**base, "tag": f"evaluation-{n0 + i}", "offsets": [x.tolist()], "rounds": cfg["fd_rounds"],
                        "seeds": [ctx.seed_for("viewpoint-search", n0 + i)]} for i, x in enumerate(X)],
                      f"viewpoint search ({phase})")
        search.tell(X, [r["views"][0][k]["log10"] for r in recs], [r["views"][0][k]["log_se"] for r in recs], phase)
    evaluations = [done[f"evaluation-{n}"] for n in range(cfg["evaluations"])]
    phases = search.phase
    resolved = bool(np.isfinite(search.y).any())  # else no view has a positive definite F̂: nothing to return
    found, post_mean, post_sd = search.recommend() if resolved else (None, math.nan, math.nan)

    # candidates for the pair: the evaluations' views, then the grid's
    cand_x = [e["offsets"][0] for e in evaluations]
    cand_F = [np.array(e["views"][0][k]["F"]) for e in evaluations]
    grid_best = None
    if p.grid_csv is not None:
        gx, gF, gbest = _grid_views(p.grid_csv, str(ctx.noises[k]), names)
        cand_x, cand_F, grid_best = cand_x + gx, cand_F + gF, gx[gbest]
    confirm = ([("search", [found.tolist()])] if resolved else []) + [("standard", [[0.0, 0.0]])]
    if grid_best is not None:
        confirm.append(("grid-best", [grid_best]))
    pair = None
    if cfg["pair"]:
        a, b, predicted, method = best_pair(np.stack(cand_F), cfg["max_pairs"])
        pair = {"views": [cand_x[a], cand_x[b]], "indices": [a, b], "predicted_log10": _log10(predicted),
                "method": method, "candidates": len(cand_x)}
        if math.isfinite(predicted):  # else no pair's summed F̂ is positive definite: nothing to confirm
            confirm.append(("pair", pair["views"]))
    items = [{**base, "tag": f"confirm-{label}", "offsets": offs, "rounds": cfg["confirm_rounds"],
              "seeds": [ctx.seed_for("viewpoint-confirm", CONFIRMED.index(label), v) for v in range(len(offs))]}
             for label, offs in confirm]
    confirmed = {label: rec for (label, _), rec in zip(confirm, render(items, "confirmations"), strict=True)}

    write_csv(out / "evaluations.csv", [
        {"n": n, "phase": phases[n], "offset_0": e["offsets"][0][0], "offset_1": e["offsets"][0][1],
         "noise": str(noise), **score_cells(e["views"][0][j], names)}
        for n, e in enumerate(evaluations) for j, noise in enumerate(ctx.noises)])
    rows = []
    for label, rec in confirmed.items():
        parts = [(f"{label}" + (f" view {v}" if len(rec["views"]) > 1 else ""), [off], rec["views"][v])
                 for v, off in enumerate(rec["offsets"])]
        if rec["joint"] is not None:
            parts.append((label, rec["offsets"], rec["joint"]))
        for what, offs, scores in parts:
            for j, noise in enumerate(ctx.noises):
                rows.append({"confirm": what, "offsets": ";".join(f"{o[0]:.6g} {o[1]:.6g}" for o in offs),
                             "noise": str(noise), **score_cells(scores[j], names)})
    write_csv(out / "confirmed.csv", rows)
    return {
        "theta": p.theta.tolist(), "params": names, "units": list(ctx.model.params.units),
        "noises": [str(n) for n in ctx.noises], "noise": k, "box": p.box.tolist(), "axes": cfg["axes"],
        "target": p.target.tolist(), "spp": cfg["spp"], "fd_rounds": cfg["fd_rounds"],
        "confirm_rounds": cfg["confirm_rounds"], "evaluations": cfg["evaluations"], "initial": cfg["initial"],
        "batch": cfg["batch"], "found": None if found is None else found.tolist(),
        "posterior_log10": post_mean, "posterior_sd": post_sd,
        "pair": pair, "grid": p.grid_label, "grid_from": cfg["grid_from"] is not None,
        # the grid's map for the report's plot: in this run (relative to its folder) or an earlier run's (as given)
        "grid_csv": None if p.grid_csv is None else str(p.grid_csv if cfg["grid_from"] else p.grid_csv.relative_to(
            ctx.dir)),
        "renders": sum(r["renders"] for r in done.values()),
        "pixel_samples": sum(r["renders"] for r in done.values()) * cfg["spp"] * pixels(ctx.model),
    }


def _log10(v: float) -> float:
    return math.log10(v) if v > 0 else -math.inf


def _grid_views(path: Path, noise: str, names: list[str]) -> tuple[list, list, int]:
    """A `viewpoints` grid's views for one noise model: offsets [[x₀, x₁]] [m], F̂ (P, P) each, and the index of
    the view with the lowest point score."""
    rows = [r for r in read_csv(path) if r["noise"] == noise and r["param"] == names[0]]
    if not rows or "log10_score" not in rows[0]:
        raise ValueError(f"{path} has no Fisher matrices for noise {noise!r}")
    xs, Fs, scores = [], [], []
    for r in rows:
        F = np.empty((len(names), len(names)))
        for i, a in enumerate(names):
            for j, b in enumerate(names[i:], start=i):
                F[i, j] = F[j, i] = float(r[f"fisher_{a}_{b}"])
        xs.append([float(r["offset_0"]), float(r["offset_1"])])
        Fs.append(F)
        scores.append(float(r["log10_score"]))
    return xs, Fs, int(np.nanargmin(np.where(np.isfinite(scores), scores, np.nan)))


def smoke(block: dict) -> dict:
    # an earlier run's map (grid_from) was made at the full scene, which a smoke run shrinks: the smoke searches alone
    return {**block, "spp": min(block["spp"], 16), "fd_rounds": 3, "confirm_rounds": 3, "initial": 3,
            "evaluations": 4, "batch": 1, "grid_from": None}


def report(study_dir: Path, results: dict) -> str:
    path = _path_plot(study_dir, results)
    k = results["noise"]
    noise = results["noises"][k]
    units = f"{results['units'][0]}²" if len(set(results["units"])) == 1 else "each θ_j's units²"
    lo, hi = np.array(results["box"]).T * 100
    lines = [
        f"Bayesian optimisation of the A-optimal score tr F̂⁻¹ of θ = {results['theta']} over camera offsets "
        f"[{lo[0]:.3g}, {hi[0]:.3g}] × [{lo[1]:.3g}, {hi[1]:.3g}] cm along {results['axes']} (camera aimed at "
        f"{[round(v, 3) for v in results['target']]}), minimising log10 tr F̂⁻¹ under {noise_text(noise)}: "
        f"{results['initial']} Sobol views, then qLogNoisyExpectedImprovement batches of {results['batch']} to "
        f"{results['evaluations']} evaluations, each from {results['fd_rounds']} unbiased FD rounds at "
        f"{results['spp']} spp with its jackknife SE as known noise; {results['renders']} renders, "
        f"{results['pixel_samples']:.3g} pixel-samples in all (confirmations included).",
        "",
        f"![search path]({study_dir.name}/{path.name})",
        "",
        (f"The search returns ({results['found'][0] * 100:.3g}, {results['found'][1] * 100:.3g}) cm (posterior "
         f"log10 score {results['posterior_log10']:.3g} ± {results['posterior_sd']:.2g})." if results["found"] else
         "No evaluated view has a resolved score (F̂ positive definite): the search returns no view (more spp or FD "
         "rounds would resolve one).") +
        f" Confirmed with fresh renders ({results['confirm_rounds']} rounds, seeds the search never used); one-sided "
        f"95 % limits, {units} summed over θ (∞: F̂ not positive definite, no resolved information):",
        "",
        "| view | offsets [cm] | noise | tr F̂⁻¹ | lower | upper |",
        "|---|---|---|---|---|---|",
    ]
    notes = set()
    for r in read_csv(study_dir / "confirmed.csv"):
        offs = "; ".join("(" + ", ".join(f"{float(v) * 100:.3g}" for v in o.split()) + ")"
                         for o in r["offsets"].split(";"))
        lines.append(f"| {r['confirm']} | {offs} | {r['noise']} | {_fmt(r['log10_score'])} | "
                     f"{_fmt(r['score_lower'])} | {_fmt(r['score_upper'])} |")
        if r["score_lower_note"]:
            notes.add(r["score_lower_note"])
    pr = results["pair"]
    if pr and not math.isfinite(pr["predicted_log10"]):
        lines += ["", f"No pair among {pr['candidates']} views has a positive definite summed F̂: no pair confirmed."]
    elif pr:
        lines += ["", f"The pair was chosen ({pr['method']}, no new render) among {pr['candidates']} views' Fisher "
                      f"matrices (predicted tr (F̂_a + F̂_b)⁻¹ = {_fmt(pr['predicted_log10'])}); its confirmed score is "
                      "the joint one, its views' own scores beside it. Two cameras at the best single view would "
                      "halve that view's score."]
    if notes:
        lines += ["", "Lower ends: " + "; ".join(sorted(notes)) + " (the upper ends are confidence limits)."]
    return "\n".join(lines)


def _fmt(lg) -> str:
    """A log10 value as a number (∞ for +inf, 0 for −inf, – for NaN)."""
    v = float(lg)
    return "∞" if v == math.inf else "0" if v == -math.inf else "–" if math.isnan(v) else f"{10 ** v:.3g}"


def _path_plot(study_dir: Path, results: dict) -> Path:
    """The search's evaluations, numbered in order, over the offset box [cm] (and over a grid's A-optimal map of
    the same noise model when the run has one), with the returned view, the pair and the standard view."""
    plt = _plt()
    k = results["noise"]
    noise = results["noises"][k]
    rows = [r for r in read_csv(study_dir / "evaluations.csv") if r["noise"] == noise]
    fig, ax = plt.subplots(figsize=(6.2, 5))
    x = np.array([[float(r["offset_0"]), float(r["offset_1"])] for r in rows]) * 100
    score = np.array([float(r["log10_score"]) for r in rows])
    grid = None if not results.get("grid") else bayesopt.read_grid(
        Path(results["grid_csv"]) if results["grid_from"] else study_dir.parent / results["grid_csv"], noise)
    shown = np.concatenate([score] + ([grid[2].ravel()] if grid else []))
    shown = shown[np.isfinite(shown)]
    norm = {"vmin": shown.min(), "vmax": shown.max()} if shown.size else {}  # one colour scale: grid and path
    label = "log10 tr F̂⁻¹ (evaluations" + (f"; grid {results['grid']})" if grid else ")")
    mappable = None
    if grid:
        u0, u1, val, _ = grid
        h0, h1 = (u0[1] - u0[0]) * 50 if len(u0) > 1 else 1, (u1[1] - u1[0]) * 50 if len(u1) > 1 else 1
        mappable = ax.imshow(val.T, origin="lower", cmap="viridis_r", interpolation="nearest", **norm,
                             extent=[u0[0] * 100 - h0, u0[-1] * 100 + h0, u1[0] * 100 - h1, u1[-1] * 100 + h1])
    sobol = np.array([r["phase"] == "sobol" for r in rows])
    for mask, marker, name in ((sobol, "s", "Sobol design"), (~sobol, "o", "model-guided")):
        if mask.any():
            sc = ax.scatter(x[mask, 0], x[mask, 1], c=np.where(np.isfinite(score[mask]), score[mask], np.nan),
                            cmap="viridis_r", marker=marker, edgecolors="k", s=45, label=name, zorder=3, **norm)
            mappable = mappable or sc
    fig.colorbar(mappable, ax=ax, fraction=0.046, pad=0.04, label=label)
    ax.plot(x[:, 0], x[:, 1], "-", color="0.5", lw=0.6, zorder=2)
    for n, (a, b) in enumerate(x):
        ax.annotate(str(n), (a, b), textcoords="offset points", xytext=(4, 4), fontsize=7, zorder=4)
    if results["found"]:
        ax.plot(*np.array(results["found"]) * 100, "*", color="red", ms=16, mec="k", label="returned view", zorder=5)
    ax.plot(0, 0, "P", color="white", ms=10, mec="k", label="standard view", zorder=5)
    if results["pair"] and math.isfinite(results["pair"]["predicted_log10"]):
        pv = np.array(results["pair"]["views"]) * 100
        ax.plot(pv[:, 0], pv[:, 1], "D--", color="orange", ms=9, mec="k", label="best pair", zorder=5)
    lo, hi = np.array(results["box"]).T * 100
    pad = 0.04 * (hi - lo)  # the box's edges stay visible, with the views on them
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    ax.add_patch(plt.Rectangle(lo, *(hi - lo), fill=False, ls=":", color="0.3", zorder=1))
    ax.set_xlabel("camera offset along axis 0 [cm]")
    ax.set_ylabel("camera offset along axis 1 [cm]")
    ax.set_title(f"search path, log10 tr F̂⁻¹ under {noise_text(noise)}", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    path = study_dir / "search_path.png"
    save_figure(fig, path, dpi=120)
    return path
