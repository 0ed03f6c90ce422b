"""The worked examples run end to end as a user runs them (a fresh Python process) and find sane numbers."""
import csv
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the verdicts of an MSE against a bound (nlosbench.verdicts.verdict), by their first words
VERDICTS = ("below", "inside", "above", "undetermined", "not tested")


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def own_scene(tmp_path_factory):
    """examples/own_scene.py run into a temp folder, or into $NLOSBENCH_OWN_SCENE_OUT (emptied first: `make test`
    keeps the run there for the documentation's own-scene tutorial): (its folder, its stdout)."""
    keep = os.environ.get("NLOSBENCH_OWN_SCENE_OUT")
    out = Path(keep).resolve() if keep else tmp_path_factory.mktemp("own_scene")
    if keep:
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "own_scene.py"), str(out)], cwd=out, env=env,
                          capture_output=True, text=True, timeout=500)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out, proc.stdout


def test_own_scene_writes_its_spec_checks_it_and_runs_every_step(own_scene):
    out, stdout = own_scene
    assert (out / "scene" / "room.xml").is_file() and (out / "scene" / "room.yaml").is_file()
    import nlosbench as nb  # the spec it wrote is a working scene spec

    model = nb.scenes.get(str(out / "scene" / "room.yaml"))
    assert list(model.params.names) == ["crate_x", "crate_size", "crate_paint"] and model.size == (32, 24)
    assert "crate.vertex_positions" in stdout and "crate.bsdf.reflectance.value" in stdout  # step 1: the keys
    assert list((out / "render").glob("room_spp64_seed0.*")) and (out / "check" / "check.png").is_file()
    assert "no warnings" in stdout  # check-scene on the example's own spec
    assert (out / "smoke" / "report.md").is_file() and (out / "run" / "report.md").is_file()
    for f in ("00-bounds/bounds.csv", "00-bounds/zzb.csv", "00-bounds/bounds.png", "01-fisher-maps/fisher.csv",
              "01-fisher-maps/centre_noise0_fisher_crate_x.exr", "02-trials/summary.csv", "bayes/summary.csv"):
        assert (out / "run" / f).is_file(), f


def test_own_scene_bounds_are_finite_and_consistent(own_scene):
    out, stdout = own_scene
    b = rows(out / "run" / "00-bounds" / "bounds.csv")
    assert len(b) == 41 and [float(r["theta_crate_x"]) for r in b] == pytest.approx([-0.4 + 0.025 * i
                                                                                      for i in range(41)])
    z = rows(out / "run" / "00-bounds" / "zzb.csv")[0]
    prior = float(z["prior_variance"])
    assert prior == pytest.approx(1.0 / 12, rel=0.01)  # uniform over Θ = [-0.4, 0.6] m
    for r in b:
        lo, point, crlb = float(r["hcr_lower"]), float(r["hcr_point"]), float(r["crlb_point"])
        # the HCR's sup includes Δ → 0, whose limit is the CRLB (same Fisher information): point ≥ CRLB
        assert math.isfinite(lo) and lo <= point and point >= crlb - 1e-9
        # the crate's position is known to within mm … decimetres: a bound of 1e-5 … the prior's variance
        assert -5 < lo < math.log10(prior)
    zzb = float(z["log10_zzb"])
    assert math.isfinite(zzb) and zzb <= float(z["zzb_upper"]) < math.log10(prior)
    fisher = rows(out / "run" / "01-fisher-maps" / "fisher.csv")[0]
    assert float(fisher["fisher_total"]) > 0 and math.isfinite(float(fisher["log10_crlb"]))
    found = json.loads((out / "found.json").read_text())
    assert found["hcr_log10"] == pytest.approx([float(r["log10_hcr"]) for r in b])
    assert "Ziv–Zakai bound on the Bayesian MSE" in stdout and "HCR lower end over Θ" in stdout


def test_own_scene_estimators_have_mse_rows_against_the_bounds(own_scene):
    out, stdout = own_scene
    local = rows(out / "run" / "02-trials" / "summary.csv")
    assert [(float(r["theta_crate_x"]), r["estimator"]) for r in local] == [
        (0.0, "grid-search"), (0.0, "gauss-newton"), (0.4, "grid-search"), (0.4, "gauss-newton")]
    for r in local:
        assert int(r["n"]) == 5 and int(r["n_failed"]) == 0
        assert 0 < float(r["mse"]) < 0.0834 and float(r["mse_se"]) >= 0  # better than guessing from the prior
        assert r["vs_hcr"].startswith(VERDICTS) and r["vs_crlb"].startswith(VERDICTS)
        assert float(r["hcr"]) > 0 and float(r["crlb"]) > 0
    (bayes,) = rows(out / "run" / "bayes" / "summary.csv")
    assert int(bayes["n"]) == 10 and float(bayes["bayes_mse"]) > 0
    # the ZZB bounds every estimator's Bayesian MSE: 'below' at the verdict's level would mean a bug
    assert bayes["vs_zzb"].startswith(VERDICTS) and not bayes["vs_zzb"].startswith("below")
    assert stdout.count("hcr ") >= 4 and "MSE / ZZB" in stdout
    # the bounds at θ* to ±25 % within 6e6 pixel-samples (the pilot charged too): each θ* says what it reached,
    # within the budget, and where it missed, a predicted extra cost
    prec = rows(out / "run" / "02-trials" / "bounds.csv")
    assert {float(r["theta_crate_x"]) for r in prec} == {0.0, 0.4}
    for r in prec:
        assert float(r["precision_target"]) == 0.25 and 0 < int(r["precision_pixel_samples"]) <= 6_000_000
        assert float(r["precision_reached"]) <= 0.25 or float(r["precision_extra_pixel_samples"]) > 0
    assert "Precision of the bounds at θ*" in stdout
