"""Run an experiment in two steps.

`prepare` checks everything before anything is written: the config against the schema, the scene (loaded
once), every study's plan (`plan(ctx, cfg)`: θ inside Θ, grids, spp, counts, estimator options, noise
indices), the cost (each study's `cost(ctx, cfg, plan)` at a rate measured on this machine: above
`CONFIRM_ABOVE` seconds the run needs `yes`), the run folder (not held by another run; a new run into a
folder that holds one, or a resume whose fingerprint differs, is refused). Any problem is a ConfigError
(one line, key path, what was expected and what was given) and nothing has been written.

`Run.execute` then holds the folder's lock (`rundir.RunLock`), writes fingerprint.json and config.yaml
(resolved), runs each study (a resumed run skips finished studies whose outputs are all there and parse, as
results.json lists them, and rebuilds the others with a warning; studies resume their own partial work from
their record logs and the render store), writes results.json after every study, then machine.json (`machine`: the
machine, its load, the command) and report.md.
On Ctrl-C or an error the executor's workers are stopped at once (`abort`). An error that is not a
ConfigError after the checks is not the input's fault: the CLI reports it as an internal error (exit 3,
traceback in RUN/error.log)."""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .. import studies
from ..io import write_json, write_text
from ..records import RecordError
from ..schema import ConfigError
from ..studies import estimate
from ..studies.context import RunContext
from . import config as config_mod
from . import machine, outputs, rundir
from .report import make_report

#: an estimated time above this (seconds) needs `yes` (the CLI's --yes)
CONFIRM_ABOVE = 3600.0
#: the most renders one study may plan (each is a task and an entry in RUN/renders/): above it the config is refused
MAX_PLAN_RENDERS = 10**7


class RebuildWarning(UserWarning):
    """A resumed run found a finished study's outputs missing or damaged and runs that study again."""


@dataclass
class Run:
    """A checked run, ready to execute: config, folder, context (scene loaded), plans and estimates."""

    cfg: dict
    dir: Path
    ctx: RunContext
    plans: dict
    estimates: dict
    seconds: float
    fingerprint: dict
    resume: bool = False
    notes: list = field(default_factory=list)
    anyway: bool = False  # resume across a code change (--resume-anyway)
    command: str = ""  # the `nlosbench run` line that makes this run (machine.json)

    def execute(self) -> Path:
        """Run every study into the folder (see the module docstring); returns the folder."""
        cfg, ctx, run_dir = self.cfg, self.ctx, self.dir
        results_path = run_dir / "results.json"
        loads = {"start": machine.load()}
        with rundir.RunLock(run_dir):
            change = rundir.check(run_dir, self.fingerprint, self.resume, self.anyway)  # again, now no one else writes
            try:
                ctx.start()  # the executor (an unreachable Dask scheduler fails here, before any file is written)
                rundir.write_fingerprint(run_dir, self.fingerprint)
                write_text(run_dir / "config.yaml", yaml.safe_dump(cfg, sort_keys=False))
                results = outputs.load_results(results_path) if self.resume and results_path.exists() \
                    else {"studies": {}}
                if change:
                    ctx.log(f"resuming across a code change ({change['from']} → {change['to']}), as --resume-anyway "
                            "asks; recorded in results.json and report.md")
                    at = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
                    results.setdefault("resumed_anyway", []).append({**change, "at": at})
                    write_json(results_path, results)
                for study in cfg["studies"]:
                    sid = study["id"]
                    done = results["studies"].get(sid, {})
                    if done.get("status") == "done":
                        bad = outputs.problems(run_dir / sid, done.get("outputs", {}))
                        if not bad:
                            ctx.log(f"[{sid}] done already, skipped")
                            continue
                        more = f" (and {len(bad) - 1} more of its files)" if len(bad) > 1 else ""
                        warnings.warn(f"study {sid}: {bad[0][0]} {bad[0][1]}{more}; rebuilding the study from the "
                                      "render store and its record logs", RebuildWarning, stacklevel=1)
                    ctx.log(f"[{sid}] running")
                    ctx.bank.owner = sid  # renders it reads back from the store count for it if it made them
                    before, t0 = ctx.model.stats.snapshot(), time.perf_counter()
                    try:
                        summary = studies.get(study["type"]).run(ctx, study)
                    except (ConfigError, RecordError):  # input the user can fix (a damaged record log)
                        raise
                    except (ValueError, KeyError) as e:  # not the input's fault (that is a ConfigError): an
                        # internal error (the CLI's exit 3); name the study, keep the kind
                        msg = f"study {sid}: {e.args[0] if isinstance(e, KeyError) and e.args else e}"
                        raise (KeyError if isinstance(e, KeyError) else ValueError)(msg) from e
                    spent = ctx.model.stats.since(before)
                    results["studies"][sid] = {"type": study["type"], "status": "done", "results": summary,
                                               "seconds": time.perf_counter() - t0,
                                               "renders_in_process": spent.renders,
                                               "render_seconds_in_process": spent.seconds,
                                               "outputs": outputs.manifest(run_dir / sid)}
                    loads[sid] = machine.load()
                    write_json(results_path, results)
            except BaseException:
                ctx.abort()
                raise
            ctx.close()
            results["seconds_total"] = sum(s.get("seconds", 0) for s in results["studies"].values())
            write_json(results_path, results)
            write_json(run_dir / "machine.json", machine.describe(results, self.fingerprint, self.command, loads))
            make_report(run_dir)
        return run_dir


def prepare(config_path: str | Path, overrides: list[str] = (), out: str | Path | None = None, resume: bool = False,
            quiet: bool = False, smoke: bool = False, yes: bool = False, anyway: bool = False) -> Run:
    """Check a run completely without writing anything (see the module docstring); ConfigError otherwise.
    `anyway`: a resume may go across a code change (recorded in the run)."""
    cfg = _load(config_path, overrides, smoke)
    run_dir = Path(out) if out else Path(cfg["output"]) / cfg["name"]
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError("--out", f"{run_dir} is a file, not a folder")
    holder = rundir.lock_holder(run_dir) if run_dir.is_dir() else None
    if holder is not None:  # at once: before the scene is loaded
        raise rundir.RunFolderError(str(run_dir), f"is in use by another nlosbench run (PID {holder}); wait for it "
                                                  "to finish or stop it, or use another --out")
    if not resume:
        rundir.check(run_dir, {}, resume=False)
    elif (run_dir / "results.json").is_file():
        outputs.load_results(run_dir / "results.json")  # damaged: one line naming it, before the scene loads
    ctx = RunContext.create(cfg, run_dir, resume=resume, quiet=quiet)  # the scene: ConfigError if it cannot load
    plans, estimates = _plan(cfg, ctx)
    fp = rundir.fingerprint(cfg, ctx.model.content_key(), plans)
    rundir.check(run_dir, fp, resume, anyway)
    rate = estimate.rate(ctx.model)
    ctx.rate = rate.seconds_per_sample  # what a study predicts further work's time from
    least, total = seconds(estimates, rate)
    lines = [f"[{sid}] plan: {_cost(e, rate)}" + (f" ({e.note})" if e.note else "") for sid, e in estimates.items()]
    lines.append(f"estimate: ≈ {estimate.describe(total)} in all" + (
        f" at most, {estimate.describe(least)} if every precision pilot meets its target" if least < total else "") +
                 f", at {rate.seconds_per_sample * 1e9:.3g} ns per pixel-sample and "
                 f"{rate.seconds_per_render * 1e3:.3g} ms per render for its task and store write ({rate.source}); "
                 "a resumed run skips "
                 "what is done")
    for line in lines:
        ctx.log(line)
    if total > CONFIRM_ABOVE and not yes:
        samples = sum(e.samples for e in estimates.values())
        renders = sum(e.renders for e in estimates.values())
        raise ConfigError("--yes", f"this run is estimated at {estimate.describe(total)} ({samples:.3g} pixel-samples "
                                   f"at {rate.seconds_per_sample * 1e9:.3g} ns each and {renders} renders at "
                                   f"{rate.seconds_per_render * 1e3:.3g} ms each), above "
                                   f"{estimate.describe(CONFIRM_ABOVE)}: pass --yes to run it, or try --smoke first")
    return Run(cfg, run_dir, ctx, plans, estimates, total, fp, resume, lines, anyway,
               machine.command(config_path, overrides, out if out else run_dir, smoke))


def _load(config_path: str | Path, overrides: list[str], smoke: bool) -> dict:
    """The resolved config, each study with its id (given, or its index and type: 00-bounds)."""
    cfg = config_mod.load(config_path, overrides, smoke=smoke)
    ids = []
    for i, study in enumerate(cfg["studies"]):
        study["id"] = study.get("id") or f"{i:02d}-{study['type']}"
        if study["id"] in ids:
            raise ConfigError(f"studies[{i}].id", f"{study['id']!r} is used by an earlier study; give each its own id")
        ids.append(study["id"])
    return cfg


def _plan(cfg: dict, ctx: RunContext) -> tuple[dict, dict]:
    """Every study's plan and the Estimate of its cost, by study id (ConfigError for a plan above the ceiling)."""
    plans, estimates = {}, {}
    for study in cfg["studies"]:
        mod = studies.get(study["type"])
        plans[study["id"]] = mod.plan(ctx, study)
        estimates[study["id"]] = mod.cost(ctx, study, plans[study["id"]])
        if estimates[study["id"]].renders > MAX_PLAN_RENDERS:
            raise ConfigError(study["id"], f"plans {estimates[study['id']].renders} renders, above the ceiling "
                                           f"of {MAX_PLAN_RENDERS} a study may plan; make its grids, sets or trials "
                                           "smaller")
    return plans, estimates


def forecast(config_path: str | Path, overrides: list[str] = (), smoke: bool = False) -> tuple[RunContext, dict]:
    """What a run of the config will cost, as `prepare` plans it before a run, without a run folder or a rate:
    the context (its scene loaded, `ctx.model`) and each study's `estimate.Estimate` by study id. Nothing is
    written; ConfigError as `prepare` raises it."""
    cfg = _load(config_path, list(overrides), smoke)
    ctx = RunContext.create(cfg, Path(cfg["output"]) / cfg["name"], quiet=True)
    return ctx, _plan(cfg, ctx)[1]


def _cost(e: estimate.Estimate, rate: estimate.Rate) -> str:
    """'N renders, S pixel-samples, ≈ T', or with a data-dependent part (a precision target's fresh looks) the range
    from what is spent in any case to the most the budget allows."""
    if e.floor >= e.samples:
        return f"{e.renders} renders, {e.samples:.3g} pixel-samples, ≈ {estimate.describe(rate.seconds(e))}"
    lo = estimate.describe(_least(e, rate))
    return (f"at most {e.renders} renders, {e.floor:.3g} to {e.samples:.3g} pixel-samples (the pilot meeting its "
            f"precision target, or its budget spent), ≈ {lo} to {estimate.describe(rate.seconds(e))}")


def seconds(estimates: dict, rate: estimate.Rate) -> tuple[float, float]:
    """(seconds if every precision pilot meets its target, most seconds) of a run's study estimates at `rate`: the
    estimate `prepare` prints before a run."""
    return sum(_least(e, rate) for e in estimates.values()), sum(rate.seconds(e) for e in estimates.values())


def _least(e: estimate.Estimate, rate: estimate.Rate) -> float:
    """Seconds of what a study spends in any case (its pilots meeting their targets): pixel-samples and renders in
    the same proportion as its whole plan."""
    return rate.seconds(e) * (e.floor / e.samples if e.samples else 1.0)


def run(config_path: str | Path, overrides: list[str] = (), out: str | Path | None = None,
        resume: bool = False, quiet: bool = False, smoke: bool = False, yes: bool = False) -> Path:
    """Run every study of a config (shrunk to seconds with `smoke`); returns the run directory."""
    return prepare(config_path, overrides, out, resume, quiet, smoke, yes).execute()
