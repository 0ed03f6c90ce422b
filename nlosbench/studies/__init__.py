"""Studies: one module per question a config can ask (`studies: [{type: bounds, ...}, ...]`).

A study is a small contract over shared services — the render bank (`ctx.bank`: every render), the
bound service (`ctx.bounds`: every bound at θ* and bound curves) and the executor — in the spirit of
benchopt's objective / dataset / solver and sbibm's task / algorithm / metric. No study imports another,
and none renders or computes a bound its own way. Contract of a study module (`bounds.py` is the
smallest complete one):
  NAME: str                      the `type` in configs
  SCHEMA: dict[str, Field]       the keys of its config block besides `type`
  plan(ctx, cfg) -> Plan         what to render and estimate, from the validated block; raises ConfigError
                                 (key path, expected, given) for what the schema cannot see. The runner calls
                                 every study's plan, with the scene loaded, before the run folder is made, so
                                 plan must not render or write (a Plan may carry `fingerprint`: what fixes its
                                 numbers beyond the config, kept in the run's fingerprint)
  cost(ctx, cfg, plan) -> estimate.Estimate
                                 its planned renders and pixel-samples (printed with an estimated time before
                                 the run starts; `estimate` says what is counted and what is estimated)
  run(ctx, cfg) -> dict          asks the services for the plan's work, writes its tables under
                                 ctx.study_dir(cfg) (files through `io`, resumable work through a
                                 `records.RecordLog`), returns a JSON-serialisable summary (results.json)
  smoke(block) -> dict           a reduced copy of its validated block (tiny grids, few spp/trials) for
                                 `nlosbench run --smoke`: the same code path in seconds
  check(block, path) (optional)  raises ConfigError for what can be checked without a scene (e.g. an
                                 unknown estimator), when the config is resolved
  report(study_dir, results) -> str
                                 a markdown section drawn only from saved tables (so `nlosbench report`
                                 re-makes it without rendering); figures in `plots`, number formats and the
                                 paper's table in `tables`
"""
from __future__ import annotations

import importlib

_MODULES = {"bounds": "bounds", "fisher-maps": "fisher_maps", "trials": "trials", "inexact": "inexact",
            "gradients": "gradients", "viewpoints": "viewpoints", "viewpoint-search": "viewpoint_search",
            "fidelity": "fidelity",
            "time-of-flight": "time_of_flight"}


def available() -> list[str]:
    """Study types whose module is present in this installation."""
    return [n for n in _MODULES if importlib.util.find_spec(f"{__name__}.{_MODULES[n]}") is not None]


def get(name: str):
    """The study module for a `type` name."""
    if name not in _MODULES or name not in available():
        import difflib

        close = difflib.get_close_matches(name, available(), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise KeyError(f"unknown study type {name!r}{hint} (available: {', '.join(available())})")
    return importlib.import_module(f"{__name__}.{_MODULES[name]}")
