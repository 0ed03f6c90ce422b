"""Studies: one module per question a config can ask (`studies: [{type: bounds, ...}, ...]`).

Contract of a study module (see `bounds.py` for a complete one):
  NAME: str                      the `type` in configs
  SCHEMA: dict[str, Field]       the keys of its config block besides `type`
  run(ctx, cfg) -> dict          does the work, writes files under ctx.study_dir(cfg), returns a
                                 JSON-serialisable summary (stored in results.json)
  smoke(block) -> dict           a reduced copy of its validated block (tiny grids, few spp/trials) for
                                 `nlosbench run --smoke`: the same code path in seconds
  check(block, path) (optional)  raises ConfigError for what the schema cannot see (e.g. an unknown
                                 estimator), so a bad config fails before anything is written
  report(study_dir, results) -> str
                                 a markdown section made only from saved data (so `nlosbench report`
                                 re-makes it without rendering)
"""
from __future__ import annotations

import importlib

_MODULES = {"bounds": "bounds", "fisher-maps": "fisher_maps", "trials": "trials", "inexact": "inexact",
            "gradients": "gradients", "viewpoints": "viewpoints", "fidelity": "fidelity"}


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
