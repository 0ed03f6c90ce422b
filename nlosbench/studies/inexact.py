"""Study `inexact`: HCR intervals [HCR_Neff, HCR-hat] from Monte Carlo renders at equal render budget.

For every θ* and Δ the scene is rendered at k spp levels (λ̃^(N_i), fitted to λ̂ = the N → ∞ limit)
and once at N_eff (HCR_Neff, the direct bound); each level and the N_eff set are R independent
replicates of N/R spp, which the half-sample bootstrap resamples for confidence intervals. A render
at a θ point serves every θ* that uses it (as θ* or as θ*+Δ), so a grid-aligned Δ set costs about
one render set per grid point. The θ* replicates also feed the 1/N decay check (the paper's
appendix), whose measured p the fit can use (`power: measured`).

Resume. The work unit is a render point (a θ* or a θ*+Δ; for a grid-aligned Δ set, the θ* grid):
its k·R level renders and R N_eff renders go through the run's render bank as one executor task and are kept as
points/NNNNN.npz (float32, written atomically), beside plan.json (points, levels, N_eff, replicates,
seed, scene). A resumed run (`--resume`) reads the finished points, renders the rest and repeats the
analysis (Gram matrices, fits, bootstrap, decay check: seconds on small grids; estimated ≈ 3.5 h
at paper scale with 6 noise models, recomputed per noise model), so its numbers equal an uninterrupted
run's; a changed plan is a config error. Seeds derive from (experiment seed, set, level, replicate,
point), so results do not depend on the executor. Disk: 4·(k + 1)·R·H·W·C bytes per point (20 MB at
the paper's 160 × 120 RGB, 10 levels, 8 replicates).
"""
from __future__ import annotations

import copy
import json
import re
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import torch

from ..bank import check_spp, level_requests
from ..bounds.decay import decay_check, pixel_variances
from ..bounds.inexact import check_levels, inexact_hcr, quadratic
from ..io import atomic, read_csv, write_csv, write_json
from ..schema import GRID, Field, grid_values
from .context import RunContext
from .plots import _plt

NAME = "inexact"
BUDGET_TOLERANCE = 0.1  # warn when N_eff and Σ N_i differ by more than this fraction
SCHEMA = {
    "theta": GRID,
    "deltas": Field("any", help="offsets Δ (parameter units): a list or {start, stop, num}; list ± for both "
                                "sides; Δ = 0 and θ*+Δ outside Θ are skipped"),
    "levels": Field(list, [1024 * i for i in range(2, 12)], "spp levels N_1..N_k of the λ fit (the paper: "
                                                             "2048, 3072, …, 11264)", items=int),
    "n_eff": Field(int, 65536, "spp of the direct render set (equal budget: about the sum of the levels)"),
    "replicates": Field(int, 8, "independent renders per level and for N_eff, N/R spp each (bootstrap units)"),
    "bootstrap": Field(int, 200, "half-sample resamples for the confidence intervals (0: none)"),
    "confidence": Field(float, 0.9, "confidence level of the bootstrap intervals"),
    "noise": Field("any", None, "index or list of indices into the experiment's noise models (null: all)",
                   nullable=True),
    "power": Field("any", 1.0, "decay rate p in λ̃ = λ + C/N^p: a number, or 'measured' (the decay check)"),
    "decay_weights": Field(int, 10000, "random weightings W ~ U[0, 1] in the decay check (0: skip it)"),
    "p_range": Field(list, [0.5, 1.5, 0.001], "p grid of the decay check: [start, stop, step]", items=float),
    "p_tolerance": Field(float, 0.1, "warn when the measured p is farther than this from 1"),
}


def smoke(block: dict) -> dict:
    """A reduced copy of a validated `inexact` block that runs in seconds through the same code path:
    2 θ* (the grid's ends), the smallest Δ on each side, 2 levels × 2 replicates (2 and 4 spp each),
    N_eff = Σ N_i (equal budget), ≤ 10 bootstrap resamples, ≤ 200 decay weightings."""
    b = copy.deepcopy(block)
    theta = grid_values(b["theta"])
    b["theta"] = [theta[0], theta[-1]] if len(theta) > 1 else theta
    d = np.asarray(grid_values(b["deltas"]), dtype=np.float64)
    neg, pos = d[d < 0], d[d > 0]
    b["deltas"] = ([float(neg.max())] if neg.size else []) + ([float(pos.min())] if pos.size else [])
    b.update(replicates=2, levels=[4, 8], n_eff=12, bootstrap=min(b["bootstrap"], 10),
             decay_weights=min(b["decay_weights"], 200))
    return b


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_").lower()


def _noises(ctx: RunContext, spec) -> list:
    """The selected noise models (all when spec is None), each checked to be quadratic."""
    return [quadratic(n) for n in ctx.select_noises("all" if spec is None else spec, "noise").values()]


def _power(spec) -> float | str:
    if spec == "measured" or (isinstance(spec, (int, float)) and not isinstance(spec, bool) and spec > 0):
        return spec
    raise ValueError(f"power: expected a number > 0 or 'measured', got {spec!r}")


def _points(thetas: np.ndarray, deltas: np.ndarray, lo: float, hi: float):
    """Unique θ points (Q,), and per θ*: its point index, the usable Δ (inside Θ) and their point indices."""
    index: dict[float, int] = {}

    def at(v: float) -> int:
        return index.setdefault(round(float(v), 12), len(index))

    plan = []
    for t in thetas:
        d = deltas[(t + deltas >= lo) & (t + deltas <= hi)]
        plan.append((at(t), d, np.array([at(t + x) for x in d], dtype=np.int64)))
    return np.array(list(index), dtype=np.float64), plan


def run(ctx: RunContext, cfg: dict) -> dict:
    model = ctx.model
    if model.params.dim != 1:
        raise ValueError(f"the inexact study needs one parameter; set scene.params to one of {list(model.params.names)}")
    out = ctx.study_dir(cfg)
    lo, hi = float(model.params.lower[0]), float(model.params.upper[0])
    thetas = np.asarray(grid_values(cfg["theta"]), dtype=np.float64)
    for t in thetas:
        model.params.validate([t])
    deltas = np.asarray(grid_values(cfg["deltas"]), dtype=np.float64)
    deltas = deltas[deltas != 0]
    R = cfg["replicates"]
    levels = check_levels(cfg["levels"], R)
    n_eff = int(check_spp([cfg["n_eff"]], R)[0])
    noises = _noises(ctx, cfg["noise"])
    power = _power(cfg["power"])
    if cfg["bootstrap"] < 0 or (cfg["bootstrap"] and R < 2):
        raise ValueError("bootstrap must be >= 0 and needs replicates >= 2")
    if not 0 < cfg["confidence"] < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {cfg['confidence']}")
    if power == "measured" and not (cfg["decay_weights"] > 0 and R >= 2):
        raise ValueError("power: measured needs the decay check (decay_weights > 0 and replicates >= 2)")
    points, plan = _points(thetas, deltas, lo, hi)
    for t, (_, d, _) in zip(thetas, plan, strict=True):
        if d.size == 0:
            raise ValueError(f"no Δ in {deltas.tolist()} keeps θ* = {t:g} + Δ inside [{lo:g}, {hi:g}]")

    t0 = time.perf_counter()
    X, Xe, resumed = render_points(ctx, out, points, levels, n_eff, R)
    render_seconds = time.perf_counter() - t0

    summary: dict = {"parameter": model.params.names[0], "units": model.params.units[0],
                     "levels": levels.tolist(), "n_eff": n_eff, "replicates": R, "bootstrap": cfg["bootstrap"],
                     "confidence": cfg["confidence"], "theta_points": len(thetas), "render_points": len(points),
                     "renders": len(points) * R * (len(levels) + 1), "points_resumed": resumed,
                     "render_seconds": render_seconds, "samples_levels_per_image": int(levels.sum()),
                     "samples_eff_per_image": n_eff, "budget_ratio": n_eff / float(levels.sum()), "warnings": []}
    if abs(summary["budget_ratio"] - 1) > BUDGET_TOLERANCE:
        summary["warnings"].append(f"unequal render budget: N_eff = {n_eff} vs Σ N_i = {int(levels.sum())} spp per "
                                   "image; the two ends of the interval are not compared at equal cost")
        ctx.log(f"warning: {summary['warnings'][-1]}")
    decay = _decay(ctx, cfg, X, levels, out) if cfg["decay_weights"] > 0 and R >= 2 else None
    if decay is not None:
        summary["decay"] = decay
        if decay["warning"]:
            summary["warnings"].append(decay["warning"])
    p = decay["p"] if power == "measured" else float(power)
    summary["power"], summary["power_source"] = p, "measured" if power == "measured" else "assumed"

    hcr_rows, lam_rows, noise_summary = [], [], {}
    for m, noise in enumerate(noises):
        noise_summary[str(noise)], hr, lr = _analyse(ctx, cfg, m, noise, X, Xe, thetas, plan, levels, n_eff, p)
        hcr_rows += hr
        lam_rows += lr
    summary["noise"] = noise_summary
    write_csv(out / "hcr.csv", hcr_rows)
    write_csv(out / "lambda.csv", lam_rows)
    summary["plots"] = [str(q.name) for q in make_plots(out, summary)]
    return summary


def _render_plan(ctx: RunContext, points: np.ndarray, levels: np.ndarray, n_eff: int, R: int) -> dict:
    """Everything that fixes the renders of the render points (what a resumed run must share)."""
    plan = {"points": points.tolist(), "levels": levels.tolist(), "n_eff": n_eff, "replicates": R, "seed": ctx.seed,
            "scene": {k: v for k, v in ctx.model_spec.items() if k != "cache"}}
    return json.loads(json.dumps(plan, sort_keys=True, default=repr))


def render_points(ctx: RunContext, out: Path, points: np.ndarray, levels: np.ndarray, n_eff: int,
                  R: int) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Level renders X (k, R, Q, *S) and N_eff renders Xe (R, Q, *S), float32, of the Q render points,
    one render-bank group (executor task) per point, each finished point saved to out/points/ at once; with ctx.resume
    the saved points are read back instead of rendered. Returns (X, Xe, number of points read back)."""
    folder, plan_file = out / "points", out / "plan.json"
    plan = _render_plan(ctx, points, levels, n_eff, R)
    if ctx.resume and plan_file.exists() and json.loads(plan_file.read_text()) != plan:
        raise ValueError(f"the render plan (points, levels, n_eff, replicates, seed, scene) differs from the one "
                         f"{out} was started with; resume with the same config or start a new run directory")
    folder.mkdir(exist_ok=True)
    for f in [*folder.glob(".*.tmp"), *(() if ctx.resume else folder.glob("*.npz"))]:
        f.unlink()  # writes cut short by a kill; a fresh run's stale points
    write_json(plan_file, plan)
    X = Xe = None

    def place(q: int, Xq: torch.Tensor, Xeq: torch.Tensor) -> None:
        nonlocal X, Xe
        if X is None:
            X = torch.empty((Xq.shape[0], R, len(points), *Xq.shape[2:]), dtype=torch.float32)
            Xe = torch.empty((R, len(points), *Xeq.shape[1:]), dtype=torch.float32)
        X[:, :, q], Xe[:, q] = Xq, Xeq

    todo = []
    for q in range(len(points)):
        path = folder / f"{q:05d}.npz"
        got = _load_point(path, points[q], len(levels), R) if ctx.resume else None
        if got is None and ctx.resume and path.exists():
            ctx.log(f"warning: {path} unreadable or not of this plan; rendering point {q} again")
        if got is None:
            todo.append(q)
        else:
            place(q, *got)
    seed, k = ctx.seed_for("inexact"), len(levels)
    groups = {q: level_requests([points[q]], levels, R, seed, "levels", q)
              + level_requests([points[q]], [n_eff], R, seed, "n-eff", q) for q in todo}

    def done(q: int, imgs: torch.Tensor) -> None:
        Xq, Xeq = imgs[:k * R].reshape(k, R, *imgs.shape[1:]), imgs[k * R:]
        _save_point(folder / f"{q:05d}.npz", points[q], Xq, Xeq)
        place(q, Xq, Xeq)

    ctx.bank.groups(groups, "inexact render points", on_done=done)
    return X, Xe, len(points) - len(todo)


def _save_point(path: Path, theta: float, X: torch.Tensor, Xe: torch.Tensor) -> None:
    """One point's renders as .npz (no pickle), written atomically."""
    with atomic(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, theta=np.float64(theta), X=X.numpy(), Xe=Xe.numpy())


def _load_point(path: Path, theta: float, k: int, R: int) -> tuple[torch.Tensor, torch.Tensor] | None:
    """A saved point's (X (k, R, *S), Xe (R, *S)), or None if missing, unreadable or not θ with k levels × R."""
    try:
        with np.load(path, allow_pickle=False) as z:
            t, X, Xe = float(z["theta"]), z["X"], z["Xe"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if t != float(theta) or X.shape[:2] != (k, R) or Xe.shape[:1] != (R,) or X.shape[2:] != Xe.shape[1:]:
        return None
    return torch.from_numpy(X), torch.from_numpy(Xe)


def _decay(ctx: RunContext, cfg: dict, X, levels: np.ndarray, out: Path) -> dict:
    """The 1/N decay check on the per-pixel variances of every point's replicates (all θ points as
    pixels); writes decay*.csv and returns the summary (warnings are logged, not raised)."""
    R = X.shape[1]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = decay_check(pixel_variances(X.reshape(len(levels), R, -1)), levels // R, cfg["decay_weights"],
                        p_grid=tuple(cfg["p_range"]), seed=ctx.seed_for("inexact-decay"), tolerance=cfg["p_tolerance"])
    for w in caught:
        ctx.log(f"warning: {w.message}")
    write_csv(out / "decay.csv", [{"p": p, "fit_error": e} for p, e in zip(d.p_grid, d.fit_error, strict=True)])
    vals, counts = np.unique(d.p_opt, return_counts=True)
    write_csv(out / "decay_popt.csv", [{"p_opt": v, "count": int(c)} for v, c in zip(vals, counts, strict=True)])
    write_csv(out / "decay_gamma.csv", [{"spp": int(n), "gamma": g} for n, g in zip(levels // R, d.gamma_example, strict=True)])
    ip = int(np.argmin(np.abs(d.p_grid - 1.0)))
    return {"p": d.p, "mean": d.mean, "std": d.std, "mode": d.mode, "q05": d.q05, "q95": d.q95, "at_edge": d.at_edge,
            "n_weights": int(d.p_opt.size), "fit_error_at_1": float(d.fit_error[ip]),
            "fit_error_min": float(d.fit_error.min()), "c_example": d.c_example, "warning": d.warning}


def _analyse(ctx: RunContext, cfg: dict, m: int, noise, X, Xe, thetas, plan, levels, n_eff: int,
             p: float) -> tuple[dict, list[dict], list[dict]]:
    """inexact_hcr at every θ* for noise model m → (its summary, hcr.csv rows, lambda.csv rows)."""
    n_unres = n_inv = 0
    widths, hcr_rows, lam_rows = [], [], []
    for t, (theta, (q0, d, qd)) in enumerate(zip(thetas, plan, strict=True)):
        r = inexact_hcr(X[:, :, q0], X[:, :, qd], d, levels, noise, Xe[:, q0], Xe[:, qd], n_eff,
                        power=p, bootstrap=cfg["bootstrap"], confidence=cfg["confidence"],
                        seed=ctx.seed_for("inexact-bootstrap", m, t))
        he, hh = r.hcr_neff, r.hcr_hat
        n_unres += hh.unresolved
        n_inv += r.inverted
        widths.append(r.width)
        hcr_rows.append({"noise": str(noise), "theta": theta, "log10_hcr_neff": he.log10, "log10_hcr_hat": hh.log10,
                         "width_decades": r.width, "inverted": r.inverted,
                         "ci_neff_lo": r.ci_neff[0], "ci_neff_hi": r.ci_neff[1],
                         "ci_hat_lo": r.ci_hat[0], "ci_hat_hi": r.ci_hat[1],
                         "delta_neff": he.delta, "delta_hat": hh.delta, "at_edge_neff": he.at_edge or "",
                         "at_edge_hat": hh.at_edge or "", "unresolved_hat": hh.unresolved,
                         "boot_unresolved": r.boot_unresolved, "noise_dominated": int(r.fit.noise_dominated.sum()),
                         "reason_hat": hh.reason})
        for j, dj in enumerate(d):
            lam_rows.append({"noise": str(noise), "theta": theta, "delta": dj,
                             **{f"lam_l{i}": r.lam_levels[i, j] for i in range(len(levels))},
                             "lam_neff": r.lam_eff[j], "lam_hat": r.fit.lam[j], "lam_se": r.fit.se[j],
                             "C": r.fit.C[j], "noise_dominated": bool(r.fit.noise_dominated[j]),
                             "log10_f_neff": he.functional[j], "log10_f_hat": hh.functional[j]})
    return ({"unresolved_hat": int(n_unres), "inverted": int(n_inv), "median_width_decades": float(np.median(widths)),
             "max_width_decades": float(np.max(widths))}, hcr_rows, lam_rows)


def _f(v: str) -> float:
    return float(v) if v not in ("", None) else np.nan


def make_plots(study_dir: Path, results: dict) -> list[Path]:
    """PNG plots from the saved CSVs: HCR vs θ* with the interval shaded (per noise); λ̃^(N) vs Δ per
    level with λ̂, and the HCR functional from λ̃^(N_eff) and λ̂, at the θ* with the widest and the
    narrowest interval (sup near Δ = 0 vs away from it, as in the paper); the decay check."""
    plt = _plt()
    hrows, lrows = read_csv(study_dir / "hcr.csv"), read_csv(study_dir / "lambda.csv")
    par = f"{results['parameter']} [{results['units']}]"
    paths = []
    for noise in dict.fromkeys(r["noise"] for r in hrows):
        rs = [r for r in hrows if r["noise"] == noise]
        x = np.array([_f(r["theta"]) for r in rs])
        ge, gh = (np.array([_f(r[k]) for r in rs]) for k in ("log10_hcr_neff", "log10_hcr_hat"))
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.fill_between(x, np.minimum(ge, gh), np.maximum(ge, gh), color="C0", alpha=0.25, label="[HCR_Neff, HCR-hat]")
        for key, col, name in (("neff", "C3", f"HCR_Neff (N_eff = {results['n_eff']})"),
                               ("hat", "k", f"HCR-hat (λ̂ from {len(results['levels'])} levels)")):
            lo_, hi_ = (np.array([_f(r[f"ci_{key}_{s}"]) for r in rs]) for s in ("lo", "hi"))
            if np.isfinite(lo_).any():
                ax.fill_between(x, np.where(np.isfinite(lo_), lo_, np.nan), np.where(np.isfinite(hi_), hi_, np.nan),
                                color=col, alpha=0.12, label=f"{name.split(' ')[0]}: {results['confidence']:.0%} bootstrap CI")
            ax.plot(x, ge if key == "neff" else gh, "-o", ms=3, color=col, label=name)
        un = np.array([r["unresolved_hat"] == "True" for r in rs])
        if un.any():
            ax.plot(x[un], gh[un], "x", color="C1", ms=8, label="HCR-hat unresolved (some λ̂ ≤ 0)")
        ax.set_xlabel(f"θ* = {par}")
        ax.set_ylabel(f"log10 bound [{results['units']}²]")
        ax.set_title(f"HCR interval from inexact renders, {noise}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        paths.append(study_dir / f"hcr_vs_theta_{_slug(noise)}.png")
        fig.savefig(paths[-1], dpi=120)
        plt.close(fig)

        width = np.array([_f(r["width_decades"]) for r in rs])
        picks = {"widest": int(np.nanargmax(width)), "narrowest": int(np.nanargmin(width))} if np.isfinite(width).any() else {}
        for tag, i in picks.items():
            th = rs[i]["theta"]
            paths.append(_lambda_plot(plt, [r for r in lrows if r["noise"] == noise and r["theta"] == th], results,
                                      study_dir / f"lambda_{_slug(noise)}_{tag}.png",
                                      f"{noise}, θ* = {_f(th):g} ({tag} interval: {width[i]:.3g} decades)"))
    if (study_dir / "decay.csv").exists():
        paths.append(_decay_plot(plt, study_dir, results))
    return paths


def _lambda_plot(plt, rows: list[dict], results: dict, path: Path, title: str) -> Path:
    d = np.array([_f(r["delta"]) for r in rows])
    o = np.argsort(d)
    d = d[o]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    cmap = plt.get_cmap("viridis")
    k = len(results["levels"])
    for i, n in enumerate(results["levels"]):
        a1.plot(d, np.array([_f(r[f"lam_l{i}"]) for r in rows])[o], ".-", lw=0.8, color=cmap(i / max(k - 1, 1)),
                label=f"λ̃, N = {n}" if i in (0, k - 1) else None)
    a1.plot(d, np.array([_f(r["lam_neff"]) for r in rows])[o], "-", color="C3", label=f"λ̃, N_eff = {results['n_eff']}")
    lam_hat = np.array([_f(r["lam_hat"]) for r in rows])[o]
    a1.plot(d, np.where(lam_hat > 0, lam_hat, np.nan), "-", color="k", lw=1.5, label="λ̂ (fit, N → ∞)")
    bad = lam_hat <= 0
    if bad.any():
        a1.plot(d[bad], np.full(bad.sum(), np.nanmin(np.where(lam_hat > 0, lam_hat, np.nan)) if (~bad).any() else 1.0),
                "v", color="C1", label="λ̂ ≤ 0 (unresolved)")
    a1.set_yscale("log")
    a1.set_xlabel(f"Δ [{results['units']}]")
    a1.set_ylabel("λ")
    a1.legend(fontsize=7)
    a1.grid(alpha=0.3)
    for key, col, name in (("log10_f_neff", "C3", "from λ̃^(N_eff)"), ("log10_f_hat", "k", "from λ̂")):
        f = np.array([_f(r[key]) for r in rows])[o]
        a2.plot(d, np.where(np.isfinite(f), f, np.nan), "-o", ms=3, color=col, label=name)
    a2.set_xlabel(f"Δ [{results['units']}]")
    a2.set_ylabel(f"log10 Δ²/(exp λ − 1) [{results['units']}²]")
    a2.legend(fontsize=7)
    a2.grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _decay_plot(plt, study_dir: Path, results: dict) -> Path:
    dc = read_csv(study_dir / "decay.csv")
    hist = read_csv(study_dir / "decay_popt.csv")
    gam = read_csv(study_dir / "decay_gamma.csv")
    dec = results["decay"]
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(12, 3.6))
    a1.plot([_f(r["p"]) for r in dc], [_f(r["fit_error"]) for r in dc], "-")
    a1.set_yscale("log")
    a1.set_xlabel("p")
    a1.set_ylabel("mean relative fit error ‖γ − C N^−p‖²/‖γ‖²")
    a2.bar([_f(r["p_opt"]) for r in hist], [int(r["count"]) for r in hist],
           width=max(1e-3, float(np.diff([_f(r["p"]) for r in dc[:2]])[0])), color="C0")
    a2.axvline(1.0, color="gray", lw=0.8)
    a2.set_xlabel(f"p_opt (median {dec['p']:.3f}, {dec['n_weights']} weightings)")
    a2.set_ylabel("count")
    n = np.array([_f(r["spp"]) for r in gam])
    a3.loglog(n, [_f(r["gamma"]) for r in gam], "o", label="γ(N), one weighting")
    a3.loglog(n, dec["c_example"] * n ** -dec["p"], "-", label=f"C N^−{dec['p']:.3f}")
    a3.set_xlabel("spp per render N")
    a3.legend(fontsize=7)
    for a in (a1, a2, a3):
        a.grid(alpha=0.3)
    fig.suptitle("rendering-noise decay check: Σ W Var L̃^(N) = C N^−p?", fontsize=9)
    fig.tight_layout()
    path = study_dir / "decay.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def report(study_dir: Path, results: dict) -> str:
    if not all((study_dir / p).is_file() for p in results.get("plots", [])):
        make_plots(study_dir, results)
    rows = read_csv(study_dir / "hcr.csv")
    lv = results["levels"]
    name = study_dir.name
    lines = [f"HCR interval from inexact renders for θ = {results['parameter']} at {results['theta_points']} θ* "
             f"({results['render_points']} distinct render points, {results['renders']} renders, "
             f"{results['render_seconds']:.1f} s wall time rendering"
             + (f"; {results['points_resumed']} points read back from an earlier run" if results.get("points_resumed") else "")
             + f"). λ̂: weighted least squares of λ̃ = λ + C/N^p over "
             f"{len(lv)} levels N = {', '.join(map(str, lv))} (Σ = {results['samples_levels_per_image']} spp per image) "
             f"with p = {results['power']:.3f} ({results['power_source']}); HCR_Neff: one render set at "
             f"N_eff = {results['n_eff']} spp. Each level and N_eff: {results['replicates']} independent replicates.", "",
             "HCR_Neff is typically *below* the true HCR (rendering noise inflates λ); HCR-hat is above it only "
             "*in expectation* — one run can fall on either side. The bracketed ranges are "
             f"{results['confidence']:.0%} half-sample bootstrap intervals over the render replicates "
             f"({results['bootstrap']} resamples): how far another run of the same budget may land. "
             "Values: log10 of the bound on the variance [units²].", ""]
    for w in results["warnings"]:
        if w != results.get("decay", {}).get("warning"):
            lines += [f"**Warning:** {w}.", ""]
    dec = results.get("decay")
    if dec:
        lines += [f"**Decay check** ({dec['n_weights']} random weightings of per-pixel variances): "
                  f"p_opt median {dec['p']:.3f}, mean {dec['mean']:.3f} ± {dec['std']:.3f}, "
                  f"90 % within [{dec['q05']:.3f}, {dec['q95']:.3f}]; mean relative fit error "
                  f"{dec['fit_error_at_1']:.2e} at p = 1, {dec['fit_error_min']:.2e} at best. "
                  + (f"**Warning:** {dec['warning']}." if dec["warning"] else "Consistent with the assumed 1/N rate."),
                  "", f"![decay check]({name}/decay.png)", ""]
    for noise, s in results["noise"].items():
        lines += [f"### {noise}", "", f"![HCR vs θ*]({name}/hcr_vs_theta_{_slug(noise)}.png)", "",
                  f"Median width {s['median_width_decades']:.3g} decades (max {s['max_width_decades']:.3g}); "
                  f"HCR-hat unresolved (some λ̂ ≤ 0) at {s['unresolved_hat']} θ*; ends crossed "
                  f"(HCR-hat < HCR_Neff) at {s['inverted']} θ*.", "",
                  "| θ* | log10 HCR_Neff [CI] | log10 HCR-hat [CI] | width (decades) | flags |", "|---|---|---|---|---|"]
        for r in (r for r in rows if r["noise"] == noise):
            flags = [f for f, on in (("HCR-hat unresolved", r["unresolved_hat"] == "True"),
                                     ("ends crossed", r["inverted"] == "True"),
                                     (f"sup at {r['at_edge_hat']} Δ", bool(r["at_edge_hat"])),
                                     (f"{r['noise_dominated']} Δ noise-dominated", r["noise_dominated"] not in ("0", ""))) if on]
            lines.append(f"| {_f(r['theta']):.4g} | {_f(r['log10_hcr_neff']):.4g} [{_f(r['ci_neff_lo']):.3g}, "
                         f"{_f(r['ci_neff_hi']):.3g}] | {_f(r['log10_hcr_hat']):.4g} [{_f(r['ci_hat_lo']):.3g}, "
                         f"{_f(r['ci_hat_hi']):.3g}] | {_f(r['width_decades']):.3g} | {'; '.join(flags)} |")
        lines.append("")
    return "\n".join(lines)
