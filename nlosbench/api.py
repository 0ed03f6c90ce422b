"""Entry points for Python (a script, a notebook) and for the one-line `nlosbench bound`: a run's tables as DataFrames,
one bound without a config file.

`run(config)` runs a config exactly as `nlosbench run` does (the same runner) and returns `Results`: the
run folder's CSV tables as pandas DataFrames and its plots' paths. `read(run_dir)` reads a finished run the
same way. `bound(scene, param, at, noise)` computes the HCR interval and the CRLB at one θ* through the bound
service and a render bank (the same code a `bounds` study uses), with stated defaults, and `OneBound.line()`
says it in one line, including what would settle an FD step that did not converge, an open end or a
precision target that was not met.
"""
from __future__ import annotations

import math
import re
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .schema import ConfigError

#: `bound`'s defaults, as `nlosbench bound --help` states them
SPP, REPLICATES, FD_STEP_FRACTION, MAX_HALVINGS, STEP_TOL, TEST_GRID = 64, 3, 0.01, 3, 0.1, 21


@dataclass
class Results:
    """A finished run, read from its folder.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    dir : Path
        The run folder.
    config : dict
        The resolved config (the folder's config.yaml).
    summary : dict
        The folder's results.json: per study its type, status, seconds and summary numbers.
    tables : dict of str to pandas.DataFrame
        Every CSV of the run, keyed by its path relative to the folder without ".csv" (e.g.
        "00-bounds/bounds", "local/summary").
    plots : list of Path
        Every PNG plot of the run, sorted.

    Examples
    --------
    >>> r = nb.read("results/quick")
    >>> "theta_object_position" in r.table("00-bounds/bounds").columns
    True
    >>> r.table("zzb")
    Traceback (most recent call last):
    KeyError: "several tables are named 'zzb' in results/quick; tables: ..."
    """

    dir: Path
    config: dict
    summary: dict
    tables: dict = field(default_factory=dict)
    plots: list = field(default_factory=list)

    @property
    def report(self) -> Path:
        """The run's report.md."""
        return self.dir / "report.md"

    def table(self, name: str):
        """One table of the run.

        Parameters
        ----------
        name : str
            A key of `tables`, or its last part where that is unique (e.g. "summary" in a run with one
            trials study).

        Returns
        -------
        pandas.DataFrame
            The table.

        Raises
        ------
        KeyError
            If no table, or several, have that name (the message lists the tables).
        """
        if name in self.tables:
            return self.tables[name]
        hits = [k for k in self.tables if k.rsplit("/", 1)[-1] == name]
        if len(hits) == 1:
            return self.tables[hits[0]]
        raise KeyError(f"{'several tables are' if hits else 'no table is'} named {name!r} in {self.dir}; tables: "
                       f"{', '.join(sorted(self.tables))}")


def read(run_dir: str | Path) -> Results:
    """The tables and plots of a finished run (a folder written by `nlosbench run` or `run`).

    Parameters
    ----------
    run_dir : str or Path
        The run folder (it holds results.json and config.yaml).

    Returns
    -------
    Results
        Its config, results.json, CSV tables as DataFrames and PNG paths.

    Raises
    ------
    ConfigError
        If the folder holds no run.

    Examples
    --------
    The demo's committed run:

    >>> r = nb.read("results/quick")
    >>> r.config["scene"]["name"], r.summary["studies"]["00-bounds"]["status"]
    ('pi_hallway', 'done')
    >>> bounds = r.table("00-bounds/bounds")
    >>> bool((bounds["crlb_lower"] <= bounds["log10_crlb"]).all())
    True
    """
    import json

    import pandas as pd

    d = Path(run_dir)
    if not (d / "results.json").is_file() or not (d / "config.yaml").is_file():
        raise ConfigError("run_dir", f"{d} holds no finished run (no results.json and config.yaml)")
    tables = {str(p.relative_to(d).with_suffix("")): pd.read_csv(p) for p in sorted(d.rglob("*.csv"))}
    return Results(d, yaml.safe_load((d / "config.yaml").read_text()), json.loads((d / "results.json").read_text()),
                   tables, sorted(d.rglob("*.png")))


def run(config: str | Path | Mapping, overrides: Sequence[str] = (), out: str | Path | None = None,
        resume: bool = False, quiet: bool = True, smoke: bool = False, yes: bool = False) -> Results:
    """Run a config as `nlosbench run` does and return its results.

    Parameters
    ----------
    config : str, Path or mapping
        A YAML config file, or the config itself as a mapping (keys as in a file: name, scene, noise,
        studies, ...; a relative scene spec path is then read from the working folder).
    overrides : sequence of str, optional
        `key.path=value` items, as `--set` takes them.
    out : str or Path, optional
        The run folder (default: OUTPUT/NAME from the config).
    resume : bool, default False
        Continue a run in `out`, keeping finished work.
    quiet : bool, default True
        No progress bars.
    smoke : bool, default False
        A seconds-long run of the same config (tiny image, grids, spp and trials).
    yes : bool, default False
        Run even when the estimated time is above an hour.

    Returns
    -------
    Results
        The finished run's tables (DataFrames) and plots.

    Raises
    ------
    ConfigError
        For a config, override or run folder the user can fix; nothing is written then.

    Examples
    --------
    A bound curve on the analytic blob, its config given as a mapping:

    >>> import tempfile
    >>> config = {"name": "blob", "scene": {"name": "blob2d", "params": ["x"]},
    ...           "noise": [{"model": "awgn", "sigma": 0.05}], "executor": {"type": "serial"},
    ...           "studies": [{"type": "bounds", "grid": {"start": 0.3, "stop": 0.7, "num": 5}, "spp": 4}]}
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     r = nb.run(config, ["noise.0.sigma=0.1"], out=f"{tmp}/blob")
    ...     plots = [p.name for p in r.plots]
    >>> r.config["noise"][0]["sigma"], plots
    (0.1, ['bounds.png'])
    >>> t = r.table("bounds")
    >>> t["theta_x"].round(2).tolist()
    [0.3, 0.4, 0.5, 0.6, 0.7]
    >>> bool((t["crlb_lower"] <= t["log10_crlb"]).all())
    True
    """
    from .experiment.runner import run as run_config

    if isinstance(config, Mapping):
        with tempfile.TemporaryDirectory(prefix="nlosbench-config-") as tmp:
            path = Path(tmp) / "config.yaml"
            path.write_text(yaml.safe_dump(dict(config), sort_keys=False))
            return read(run_config(path, list(overrides), out, resume, quiet, smoke, yes))
    return read(run_config(config, list(overrides), out, resume, quiet, smoke, yes))


@dataclass
class OneBound:
    """One θ*'s HCR interval and CRLB (`bound`), with the settings that made them.

    Each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    scene : str
        The scene's name.
    param : Param
        The parameter bounded (name, units, Θ).
    at : float
        θ*, parameter units.
    point : BoundPoint
        The bound service's result: `bounds["hcr"]` and `bounds["crlb"]` (parameter units²), and with a
        precision target its `precision` record.
    spp, replicates : int
        Samples per pixel of each render and the replicate sets of the pilot.
    fd_step : float
        The first FD step ξ, parameter units.
    max_halvings : int
        The most halvings of ξ.
    renders, pixel_samples : int
        What the call rendered in this process (pixel-samples: spp × pixels per render, summed).
    seconds : float
        Its wall time.
    """

    scene: str
    param: object
    at: float
    point: object
    spp: int
    replicates: int
    fd_step: float
    max_halvings: int
    renders: int
    pixel_samples: int
    seconds: float

    def line(self) -> str:
        """The result in one line: the HCR interval and CRLB with their RMS, the settings, and what would
        settle an FD step that did not converge, an open end or an unmet precision target."""
        from .bounds.precision import CEILING
        from .studies.plotstyle import noise_text

        hcr, crlb = self.point.bounds["hcr"], self.point.bounds["crlb"]
        u = _space(self.param.units)
        parts = [f"{self.scene}: {self.param.name} = {self.at:g}{u}, {noise_text(self.point.noise)}",
                 f"HCR {_interval(hcr)}{u and u + '²'} (RMS error ≥ {_rms(hcr.log10)}{u} for an unbiased estimator)",
                 f"CRLB {_fmt(crlb.log10)}{u and u + '²'} [{_fmt(crlb.lower)}, {_fmt(crlb.upper)}]",
                 f"one-sided {100 * hcr.level:.3g} % ends"]
        step = re.search(r"FD step converged: (.*)", crlb.reason)
        parts.append(f"{self.spp} spp × {self.replicates} replicate sets, FD step ξ = {self.fd_step:.3g}{u} halved "
                     f"up to {self.max_halvings}× until F settles within {STEP_TOL:.0%}"
                     + (f": settled, {step.group(1)}" if step else ""))
        note = hcr.lower_note or crlb.lower_note
        if note:
            parts.append(f"lower end {note}; to settle it: --max-halvings {self.max_halvings + 1} (ξ down to "
                         f"{self.fd_step / 2 ** (self.max_halvings + 1):.3g}{u}) or more --spp")
        if hcr.upper is None or not math.isfinite(hcr.upper):
            parts.append("upper end open (F or a tested Δ unresolved at this noise level); to close it: more "
                         "--replicates or --spp, or --precision")
        pr = self.point.precision
        if pr is not None:
            reached = f"precision ±{pr.target:.3g} {'met' if pr.met else 'not met'} (reached ±{pr.worst:.3g})"
            if not pr.met:
                reached += (f" after {pr.pixel_samples:.3g} of the {pr.budget:.3g} pixel-samples allowed (--budget; "
                            f"without it {CEILING} × the pilot's)")
            if pr.met:
                parts.append(reached)
            elif math.isfinite(pr.extra_pixel_samples):
                parts.append(f"{reached}: about {pr.extra_sets:g} more replicate sets, {pr.extra_pixel_samples:.3g} "
                             "more pixel-samples (--budget)")
            else:
                parts.append(f"{reached}: {pr.note}; no number of further replicate sets at {self.spp} spp is "
                             "predicted to meet it: raise --spp, settle the FD step or widen the target")
        parts.append(f"{self.renders} renders, {self.pixel_samples:.3g} pixel-samples, {self.seconds:.1f} s")
        return "; ".join(parts)


def _space(units: str) -> str:
    return f" {units}" if units and units != "1" else ""


def _fmt(lg: float | None) -> str:
    """A log10 value as a number (0, +inf kept as words)."""
    if lg is None or math.isnan(lg):
        return "n/a"
    if lg == math.inf:
        return "+inf (open)"
    if lg == -math.inf:
        return "0"
    return f"{10.0 ** lg:.3g}" if -300 < lg < 300 else f"1e{lg:.1f}"


def _interval(b) -> str:
    return f"[{_fmt(b.lower)}, {_fmt(b.upper)}]"


def _rms(lg: float) -> str:
    return f"{10.0 ** (lg / 2):.3g}" if math.isfinite(lg) else _fmt(lg / 2)


def bound(scene: str, param: str | None, at: float | None, noise, *, spp: int = SPP, replicates: int = REPLICATES,
          fd_step: float | None = None, max_halvings: int = MAX_HALVINGS, test_grid: int = TEST_GRID,
          precision: float | None = None, budget: int | None = None, seed: int = 0,
          fixed: Mapping[str, float] | None = None, options: Mapping | None = None) -> OneBound:
    """The HCR interval and the CRLB of one parameter at one θ* (the others held), from the bound service.

    Parameters
    ----------
    scene : str
        A registered scene name or a scene spec .yaml.
    param : str or None
        The parameter bounded (one of the scene's `params.names`); None: the scene's only one.
    at : float or None
        θ*, in the parameter's units, inside Θ; None: the parameter's default.
    noise : NoiseModel
        The observation noise (e.g. `nb.noise.AWGN(sigma=0.05)`).
    spp : int, default 64
        Samples per pixel of every render.
    replicates : int, default 3
        Independent replicate sets of every render (≥ 3: confidence limits).
    fd_step : float, optional
        The first FD step ξ, parameter units (default: 1 % of Θ's width).
    max_halvings : int, default 3
        The most halvings of ξ while F has not settled within 10 %.
    test_grid : int, default 21
        Test points Δ over Θ for the HCR (besides the axis offsets ±ξ·2^k).
    precision : float, optional
        A target relative half-width of both intervals (e.g. 0.1 for ±10 %): replicate sets are added until
        it is met or `budget` is spent.
    budget : int, optional
        The most pixel-samples (spp × pixels × renders) to spend with a precision target, the pilot included; None:
        the default ceiling, `bounds.precision.CEILING` × what the pilot costs.
    seed : int, default 0
        The seed every render seed derives from.
    fixed : mapping of str to float, optional
        Values of the other parameters (default: their defaults).
    options : mapping, optional
        Scene options (e.g. {"defines": {"res": 16}}).

    Returns
    -------
    OneBound
        The bounds (parameter units²) and what they cost.

    Raises
    ------
    ConfigError
        For an unknown parameter, θ* outside Θ or a bad setting (before anything renders).

    Examples
    --------
    >>> b = nb.bound("blob2d", "x", 0.5, nb.noise.AWGN(sigma=0.05), spp=4)
    >>> b.point.bounds["crlb"].log10 < b.point.bounds["hcr"].upper
    True
    """
    from . import scenes
    from .bank import RenderBank
    from .bounds.service import BoundService

    for key, value, ok in (("--spp", spp, spp >= 1), ("--replicates", replicates, replicates >= 3),
                           ("--max-halvings", max_halvings, 0 <= max_halvings <= 12),
                           ("--test-grid", test_grid, test_grid >= 2),
                           ("--precision", precision, precision is None or precision > 0),
                           ("--budget", budget, budget is None or budget > 0),
                           ("--seed", seed, 0 <= seed < 2**32)):
        if not ok:
            raise ConfigError(key, f"got {value}, expected " + {
                "--spp": "a positive integer", "--replicates": "at least 3 (confidence limits need 3)",
                "--max-halvings": "an integer in [0, 12]", "--test-grid": "at least 2",
                "--precision": "a relative half-width > 0 (0.1: ±10 %)", "--budget": "a positive number of "
                "pixel-samples", "--seed": "an integer in [0, 2^32)"}[key])
    if budget is not None and precision is None:
        raise ConfigError("--budget", "a budget goes with --precision")
    full = scenes.get(scene, **dict(options or {}))
    names = full.params.names
    if param is None:
        if len(names) != 1:
            raise ConfigError("--param", f"{full.name} has parameters {', '.join(names)}: name one")
        param = names[0]
    fixed = dict(fixed or {})
    for name in (param, *fixed):
        if name not in names:
            raise ConfigError("--param" if name == param else "--fix", f"{name!r} is not a parameter of {full.name} "
                              f"(its parameters: {', '.join(names)})")
    if param in fixed:
        raise ConfigError("--fix", f"{param!r} is the parameter bounded; fix the others only")
    try:
        model = full.restrict([param], fixed)
    except ValueError as e:
        raise ConfigError("--fix", str(e)) from None
    p = model.params.params[0]
    at = p.default if at is None else at
    if not (math.isfinite(at) and p.lower <= at <= p.upper):
        raise ConfigError("--at", f"{param} = {at:g} is outside Θ = [{p.lower:g}, {p.upper:g}] {p.units}")
    step = FD_STEP_FRACTION * (p.upper - p.lower) if fd_step is None else float(fd_step)
    if not (math.isfinite(step) and 0 < step < (p.upper - p.lower) / 2):
        raise ConfigError("--fd-step", f"expected a step in (0, {(p.upper - p.lower) / 2:g}) {p.units}, got {step:g}")
    bank = RenderBank(model, seed=seed)
    before, t0 = model.stats.snapshot(), time.perf_counter()
    [point] = BoundService(bank, [noise]).at([at], spp, want=("hcr", "crlb"), replicates=replicates,
                                             test_grid=test_grid, fd_step=step, step_tol=STEP_TOL,
                                             max_halvings=max_halvings, precision=precision, budget=budget)
    spent = model.stats.since(before)
    return OneBound(model.name, p, float(at), point, spp, replicates, step, max_halvings, spent.renders,
                    spent.samples, time.perf_counter() - t0)


#: a table's row keys, in order (a noise model's text is replaced by its index: two σ are one question)
KEYS = ("noise_index", "noise", "label", "param", "theta", "estimator", "name")
#: quantities quoted with limits: the point column is log10_<q> (ends in log10) or <q> itself (ends linear)
LIMITED = ("hcr", "crlb", "zzb", "mse", "bayes_mse")


def compare(a: str | Path | Results, b: str | Path | Results, tables: Sequence[str] = ()) -> str:
    """Two runs of the same question side by side: what their configs differ in, then per table row every
    quantity with limits (HCR, CRLB, ZZB, MSE) in both runs, their ratio and whether the intervals overlap.

    Parameters
    ----------
    a, b : str, Path or Results
        The two run folders (or their `read` results).
    tables : sequence of str, optional
        The tables to compare (keys of `Results.tables`); default: every table both runs have.

    Returns
    -------
    str
        The comparison, one line per (row, quantity).

    Raises
    ------
    ConfigError
        If a folder holds no run, the runs ask about another scene or parameters, share no table, or a table
        asked for is missing from one.

    Examples
    --------
    The demo's bound curve (96 spp, 3 replicate sets) against the same curve at 512 spp and 8 sets:

    >>> out = nb.compare("results/quick", "results/precise_nlos", tables=["00-bounds/bounds"])
    >>> out.splitlines()[:2]
    ['A: results/quick', 'B: results/precise_nlos']
    >>> crlb = [line for line in out.splitlines() if ": crlb " in line]
    >>> len(crlb), all(line.endswith("(limits overlap)") for line in crlb)
    (34, True)
    """
    ra, rb = (r if isinstance(r, Results) else read(r) for r in (a, b))
    question = [(k, x, y) for k, x, y in ((k, _question(ra.config, k), _question(rb.config, k))
                                          for k in ("scene", "parameters")) if x != y]
    if question:
        k, x, y = question[0]
        raise ConfigError("RUN_B", f"{rb.dir} asks another question than {ra.dir}: {k} {y} | {x} (compare runs of one "
                          "scene and parameters, changed in noise, camera, spp, ...)")
    common = [k for k in ra.tables if k in rb.tables]
    missing = [t for t in tables if t not in common]
    if missing:
        raise ConfigError("--table", f"{missing[0]!r} is not a table of both runs (shared: {', '.join(common)})")
    if not common:
        raise ConfigError("RUN_B", f"{rb.dir} shares no table with {ra.dir}: not two runs of the same question")
    diff = _config_diff(ra.config, rb.config)
    lines = [f"A: {ra.dir}", f"B: {rb.dir}",
             "configs differ in: " + ("; ".join(f"{k}: {va} | {vb}" for k, va, vb in diff) if diff else "nothing")]
    for name in tables or common:
        lines += _compare_table(name, ra.tables[name], rb.tables[name])
    return "\n".join(lines)


def _question(cfg: dict, what: str) -> str:
    """The scene's name (a spec by its file name) or the θ components a run asks about."""
    scene = cfg.get("scene") or {}
    if what == "scene":
        return Path(str(scene.get("name"))).stem
    return ", ".join(scene.get("params") or ["all"])


def _config_diff(x, y, path: str = "") -> list[tuple[str, object, object]]:
    """(key path, value in x, value in y) for every leaf that differs (name and output excepted)."""
    if isinstance(x, dict) and isinstance(y, dict):
        return [d for k in dict.fromkeys([*x, *y]) if not (not path and k in ("name", "output"))
                for d in _config_diff(x.get(k), y.get(k), f"{path}.{k}" if path else str(k))]
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        return [d for i, (u, v) in enumerate(zip(x, y, strict=True)) for d in _config_diff(u, v, f"{path}.{i}")]
    return [] if x == y else [(path, x, y)]


def _compare_table(name: str, ta, tb) -> list[str]:
    """The lines of one table: a heading, then per matched row each limited quantity of both runs."""
    import pandas as pd

    qs = [q for q in LIMITED if {f"{q}_lower", f"{q}_upper"} <= set(ta.columns) & set(tb.columns)]
    if not qs:
        return []
    keys = [k for k in (*KEYS, *sorted(c for c in ta.columns if c.startswith("theta_") and c != "theta_index"))
            if k in ta.columns and k in tb.columns and not (k == "noise" and "noise_index" in ta.columns)]
    ta, tb = (_round_keys(_noise_as_index(t), keys) for t in (ta, tb))
    both = pd.merge(ta, tb, on=keys, how="outer", suffixes=("_A", "_B"), indicator=True)
    lines = [f"{name}: {len(both)} rows ({', '.join(keys)}); A | B, B/A"]
    for _, row in both.iterrows():
        where = ", ".join(f"{k} {row[k]:.6g}" if isinstance(row[k], float) else f"{k} {row[k]}" for k in keys)
        if row["_merge"] != "both":
            lines.append(f"  {where}: only in {'A' if row['_merge'] == 'left_only' else 'B'}")
            continue
        for q in qs:
            ends = [_ends(row, q, s) for s in ("_A", "_B")]
            (pa, la, ua), (pb, lb, ub) = ends
            ratio = pb / pa if pa and math.isfinite(pa) and math.isfinite(pb) else math.nan
            apart = "B higher, limits apart" if lb > ua else "B lower, limits apart" if ub < la else "limits overlap"
            lines.append(f"  {where}: {q} {_lin(pa)} [{_lin(la)}, {_lin(ua)}] | {_lin(pb)} [{_lin(lb)}, {_lin(ub)}], "
                         f"×{ratio:.3g} ({apart})")
    return lines


def _round_keys(t, keys):
    """The table with its float key columns at 12 significant digits: one grid written by two runs as 0.79 and
    0.7899999999999999 matches row by row."""
    floats = [k for k in keys if t[k].dtype.kind == "f"]
    return t.assign(**{k: t[k].map(lambda v: float(f"{v:.12g}")) for k in floats}) if floats else t


def _noise_as_index(t):
    """The table with a `noise` text column (no noise_index) replaced by the model's index, in order of first
    appearance (the order of the config's `noise:` list)."""
    if "noise" in t.columns and "noise_index" not in t.columns:
        order = {n: i for i, n in enumerate(dict.fromkeys(t["noise"]))}
        t = t.assign(noise=t["noise"].map(order))
    return t


def _ends(row, q: str, side: str) -> tuple[float, float, float]:
    """(point, lower, upper) of quantity q in linear units (from log10 columns where the table has them)."""
    log = f"log10_{q}{side}" in row.index
    vals = [row.get(f"log10_{q}{side}" if log else f"{q}{side}"), row.get(f"{q}_lower{side}"),
            row.get(f"{q}_upper{side}")]
    vals = [math.nan if v is None or _isna(v) else float(v) for v in vals]
    return tuple(_exp10(v) if log else v for v in vals)


def _isna(v) -> bool:
    import pandas as pd

    return bool(pd.isna(v))


def _exp10(lg: float) -> float:
    return lg if math.isnan(lg) else math.inf if lg > 308 else 10.0 ** lg if lg > -400 else 0.0


def _lin(v: float) -> str:
    return "n/a" if math.isnan(v) else "+inf" if v == math.inf else f"{v:.3g}"
