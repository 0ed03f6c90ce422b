"""`nb.run` (a config → its tables as DataFrames, its plots) and `nlosbench compare` (two runs side by side), on
blob2d's exact images: the CRLB scales as σ², so a run at 2σ reads 4× the CRLB of a run at σ."""
import math
import re
from pathlib import Path

import pandas as pd
import pytest

import nlosbench as nb
from nlosbench.cli import BAD_INPUT, main


def config(sigma: float) -> dict:
    return {"name": "blob", "scene": {"name": "blob2d", "params": ["x"]}, "noise": [{"model": "awgn", "sigma": sigma}],
            "executor": {"type": "serial"}, "keep_renders": False,
            "studies": [{"type": "bounds", "grid": {"start": 0.3, "stop": 0.7, "num": 5}, "spp": 4,
                         "save_images": False}]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return nb.run(config(0.05), out=root / "s05"), nb.run(config(0.1), out=root / "s10")


def test_run_returns_the_tables_as_dataframes_and_the_plots(runs):
    r = runs[0]
    t = r.table("bounds")
    assert isinstance(t, pd.DataFrame) and t["theta_x"].tolist() == pytest.approx([0.3, 0.4, 0.5, 0.6, 0.7])
    assert set(r.tables) == {"00-bounds/bounds", "00-bounds/zzb"}
    assert [p.name for p in r.plots] == ["bounds.png"] and r.report.is_file()
    assert r.summary["studies"]["00-bounds"]["status"] == "done" and r.config["noise"][0]["sigma"] == 0.05
    again = nb.read(r.dir)  # a finished run reads back the same
    pd.testing.assert_frame_equal(again.table("00-bounds/bounds"), t)


def test_compare_puts_two_sigmas_side_by_side_with_their_limits(runs, capsys):
    a, b = runs
    assert main(["compare", str(a.dir), str(b.dir), "--table", "00-bounds/bounds"]) == 0
    out = capsys.readouterr().out
    assert "configs differ in: noise.0.sigma: 0.05 | 0.1" in out
    lines = [ln for ln in out.splitlines() if ": crlb " in ln]
    assert len(lines) == 5
    for ln in lines:  # exact images: the CRLB is σ²/F, ×4 at 2σ, and the limits of the two runs are apart
        assert float(re.search(r"×([\d.]+)", ln).group(1)) == pytest.approx(4, rel=1e-3)
        assert "B higher, limits apart" in ln
    row = a.table("00-bounds/bounds").iloc[0]
    assert f"theta_x 0.3: crlb {10**row['log10_crlb']:.3g} [{10**row['crlb_lower']:.3g}, " in out
    assert not math.isnan(row["crlb_lower"])


def test_compare_refuses_runs_without_a_table_in_common(runs, tmp_path, capsys):
    assert main(["compare", str(runs[0].dir), "results/quick"]) == BAD_INPUT
    assert "asks another question than" in capsys.readouterr().err  # pi_hallway, not blob2d
    assert main(["compare", str(runs[0].dir), str(tmp_path)]) == BAD_INPUT
    assert "holds no finished run" in capsys.readouterr().err
    assert main(["compare", str(runs[0].dir), str(runs[1].dir), "--table", "local/summary"]) == BAD_INPUT
    assert "'local/summary' is not a table of both runs (shared: 00-bounds/bounds, 00-bounds/zzb)" in \
        capsys.readouterr().err


def test_compare_matches_a_grid_written_with_other_rounding(tmp_path):
    """precise_nlos copied with every θ written one float step below (0.7899999999999999 where quick has 0.79, as a
    CSV written before θ was printed at its precision has it; the same 34-point grid, AWGN in both): every row is
    in both runs, none is one run's own."""
    import csv
    import shutil

    import numpy as np

    other = tmp_path / "precise_nlos"
    shutil.copytree("results/precise_nlos", other)
    table = other / "00-bounds" / "bounds.csv"
    with table.open(newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["theta_object_position"] = repr(float(np.nextafter(float(r["theta_object_position"]), -np.inf)))
    with table.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    assert "0.7899999999999999," in table.read_text()
    assert "0.7899999999999999," not in Path("results/quick/00-bounds/bounds.csv").read_text()
    out = nb.compare("results/quick", str(other), ["00-bounds/bounds"])
    assert not [ln for ln in out.splitlines() if "only in" in ln], out
    assert sum(": crlb " in ln for ln in out.splitlines()) == 34
