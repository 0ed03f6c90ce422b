"""Every benchmark runs in reduced mode so it never rots (no timing assertions: ratios only exist)."""
import math

import pytest

from nlosbench import benchmarks


@pytest.mark.parametrize("name", benchmarks.names())
def test_benchmark_runs_reduced_and_reports_ratios(name):
    import importlib

    rows = importlib.import_module(f"nlosbench.benchmarks.{name}").run(reduced=True)
    assert rows, name
    ratios = [r["ratio"] for r in rows if "ratio" in r]
    assert ratios and all(math.isfinite(float(x)) and float(x) > 0 for x in ratios), rows
