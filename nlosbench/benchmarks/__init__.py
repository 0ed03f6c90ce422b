"""Benchmarks: each module has `run(reduced=False) -> list[dict]` comparing two paths side by side in
one process (rows carry a `ratio`). `run_all` prints a table and one JSON line per row;
`python -m nlosbench.benchmarks.<name> [--reduced]` runs one module."""
from __future__ import annotations

import importlib
import json
import pkgutil
import sys


def names() -> list[str]:
    return [m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")]


def print_rows(rows: list[dict], file=sys.stdout) -> None:
    """A plain table (one line per row) followed by one JSON line per row."""
    for r in rows:
        print("  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items()), file=file)
    for r in rows:
        print("BENCH " + json.dumps(r, default=float), file=file)


def run_all(selected: list[str] | None = None, reduced: bool = False) -> list[dict]:
    """Run the benchmark modules `selected` (default: all) and print their rows; ConfigError for an unknown name."""
    unknown = [n for n in selected or [] if n not in names()]
    if unknown:
        from ..schema import ConfigError

        raise ConfigError("names", f"unknown benchmark(s) {unknown} (available: {', '.join(names())})")
    rows = []
    for name in selected or names():
        mod = importlib.import_module(f"{__name__}.{name}")
        print(f"== {name}{' (reduced)' if reduced else ''}", flush=True)
        got = mod.run(reduced=reduced)
        print_rows(got)
        rows += got
    return rows


def main(module_name: str) -> None:
    """`__main__` helper for a benchmark module."""
    mod = importlib.import_module(module_name)
    print_rows(mod.run(reduced="--reduced" in sys.argv))
