"""Precision on request in the studies (`studies.precise`): the `trials` study's θ* bounds and the `bounds` study's
quoted θ reach a target the analytic toy can meet and say so; without a target the outputs carry no precision
columns; bad keys stop the run at config time (one line naming the key, exit 2, nothing written)."""
import json
import math

import numpy as np
import pytest
import yaml

from nlosbench.cli import main
from nlosbench.io import read_csv

# blob2d's x with rendering noise 2 (the toy of tests/test_precision.py): θ = 0.7 misses ±10 % at the pilot of 3
# sets at 16 spp and meets it after fresh sets
SCENE = {"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]}
TRIALS = {"type": "trials", "id": "t", "theta": [0.7], "n": 2, "n_eff": 16, "truth_replicates": 1,
          "bounds": ["hcr", "crlb"], "bound_spp": 16, "replicates": 3, "hcr_grid": 3, "hcr_offsets": 1,
          "fd_step": 0.01, "max_halvings": 1, "bootstrap": 10,
          "estimators": [{"name": "grid-search", "options": {"spp": 4, "num": 5, "refine": False}}]}
BOUNDS = {"type": "bounds", "id": "b", "grid": {"start": 0.2, "stop": 0.8, "num": 3}, "spp": 16, "replicates": 3,
          "fd_step": 0.01, "max_halvings": 1, "zzb": False, "save_images": False}


def _run(tmp_path, studies: list[dict], name: str = "run") -> tuple[int, str, object]:
    cfg = tmp_path / f"{name}.yaml"
    cfg.write_text(yaml.safe_dump({"name": name, "seed": 5, "scene": SCENE,
                                   "noise": [{"model": "awgn", "sigma": 0.3}], "executor": {"type": "serial"},
                                   "cache": None, "studies": studies}))
    out = tmp_path / name
    return main(["run", str(cfg), "--out", str(out), "--quiet", "--yes"]), out  # --yes: the estimate varies with load


def test_trials_and_bounds_reach_a_reachable_target_and_report_it(tmp_path):
    """Both studies quote θ = 0.7 to ±10 %: the target is met after fresh sets, bounds.csv / precise.csv carry the
    precision_* columns, results.json the per-bound record, the reports their precision tables (with a time: a
    prepared run has a measured rate), and the bounds plot is drawn with the quoted points."""
    rc, out = _run(tmp_path, [{**TRIALS, "precision": 0.1, "looks": 3},
                              {**BOUNDS, "precision": 0.1, "precision_at": [0.7], "precision_budget": 10**9}])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["studies"]
    for sid, table in (("t", "bounds.csv"), ("b", "precise.csv")):
        (rec,) = res[sid]["results"]["precision"]
        assert rec["met"] and rec["looks"] > 1 and rec["target"] == 0.1, rec
        assert set(rec["bounds"]) == {"hcr", "crlb"} and max(b["reached"] for b in rec["bounds"].values()) <= 0.1
        (row,) = read_csv(out / sid / table)
        assert float(row["precision_reached"]) <= 0.1 and int(row["precision_pixel_samples"]) > 0
        assert res[sid]["results"]["seconds_per_sample"] > 0
    report = (out / "report.md").read_text()
    assert "### Precision of the bounds at θ*" in report and "### Precision at the quoted θ" in report
    assert report.count("(±10 %) | yes |") == 4, report  # hcr and crlb in each study
    assert (out / "b" / "bounds.png").stat().st_size > 0
    # the same θ to the same target in both studies: the same service call, so the same interval
    t, b = (res[s]["results"]["precision"][0]["bounds"]["hcr"] for s in ("t", "b"))
    assert t["reached"] <= 0.1 and b["reached"] <= 0.1


def test_an_unmet_target_says_what_more_would_cost(tmp_path):
    """A budget of 1 pixel-sample allows only the pilot: not met, the note says why, the predicted extra sets
    and pixel-samples are in the record and the report (with a time from the run's rate)."""
    rc, out = _run(tmp_path, [{**BOUNDS, "precision": 0.1, "precision_at": [0.7], "precision_budget": 1}])
    assert rc == 0
    (rec,) = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]["precision"]
    assert not rec["met"] and rec["looks"] == 1 and "budget" in rec["note"]
    assert rec["extra_sets"] >= 3 and rec["extra_pixel_samples"] > 0
    report = (out / "report.md").read_text()
    assert f"{rec['extra_pixel_samples']:.3g} pixel-samples, ≈ " in report


def test_the_bounds_report_counts_the_resolved_points_and_what_the_rest_would_cost(tmp_path):
    """A bounds study quoting every grid θ to ±5 % with a budget of 1 (the pilot and the prediction only): the text
    under the figure gives the number of grid θ whose HCR and CRLB ends are all finite confidence limits (counted here
    from bounds.csv) and, over every quoted θ (resolved on the curve or not), how many met the target and the sum of
    the others' predicted extra pixel-samples with a time."""
    rc, out = _run(tmp_path, [{**BOUNDS, "fd_step": None, "max_halvings": 4, "precision": 0.1, "precision_budget": 1}])
    assert rc == 0
    rows = read_csv(out / "b" / "bounds.csv")
    ok = [all(math.isfinite(float(r[f"{k}_{e}"])) and not r[f"{k}_{e}_note"] for k in ("hcr", "crlb")
              for e in ("lower", "upper")) for r in rows]
    res = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]
    rest = [rec for rec in res["precision"] if not rec["met"]]
    assert rest and all(math.isfinite(rec["extra_pixel_samples"]) for rec in rest)
    report = (out / "report.md").read_text()
    line = f"- AWGN, σ = 0.3: {sum(ok)} of 3 points resolved; at the 3 quoted θ, {3 - len(rest)} met ±10 %, "
    assert line in report, report
    assert f"would need ≈ {sum(rec['extra_pixel_samples'] for rec in rest):.3g} more pixel-samples" in report
    assert "on this machine at its measured" in report


def test_a_bounds_target_without_precision_at_quotes_every_grid_theta(tmp_path):
    """`precision` without `precision_at`: every grid θ (0.2, 0.5, 0.8) is quoted from the curve's sets as the pilot,
    each with its own record, and results.json counts per noise model the θ quoted and those that met the target
    (as precise.csv's reached and target columns say); a θ met at the pilot gets no fresh set while another gets some
    (the allocation is per θ: blob2d's x with rendering noise 2 at ±16 %: 0.2 and 0.5 meet it at the pilot, whose
    ends are at 1 − α/20 (measured 0.154 and 0.144), 0.8 (0.173) after fresh sets)."""
    rc, out = _run(tmp_path, [{**BOUNDS, "precision": 0.16}])
    assert rc == 0
    recs = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]["precision"]
    assert sorted(r["theta"]["x"] for r in recs) == pytest.approx([0.2, 0.5, 0.8])
    assert all(r["met"] for r in recs), recs
    fresh = [r["fresh_sets"] for r in recs]
    assert min(fresh) == 0 < max(fresh), fresh
    precise = read_csv(out / "b" / "precise.csv")
    assert len(precise) == 3
    summary = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]["noise"]
    met = sum(float(r["precision_reached"]) <= float(r["precision_target"]) for r in precise)
    assert [(v["quoted"], v["met"]) for v in summary.values()] == [(3, met)]


def test_a_looser_target_beyond_a_theta_reaches_the_quoted_bounds_beyond_it(tmp_path):
    """`precision_beyond: [0.6, 0.5]` with `precision: 0.15` and `precision_predict: 0.15`: the quoted records and
    the curve's own predictions at 0.2 and 0.5 carry 0.15, those at 0.8 carry 0.5; a prediction's pixel-samples are
    its fresh sets of the whole grid, each 3 θ × (the θ + 2 steps × 2 stencils) renders of 16 spp × 24 × 24."""
    rc, out = _run(tmp_path, [{**BOUNDS, "precision": 0.15, "precision_beyond": [0.6, 0.5], "hcr_offsets": 0,
                               "precision_fd_step": 0.02, "precision_predict": 0.15}])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]
    for key in ("precision", "predicted"):
        got = sorted((round(r["theta"]["x"], 6), r["target"]) for r in res[key])
        assert got == [(0.2, 0.15), (0.5, 0.15), (0.8, 0.5)], (key, got)
    finite = [r for r in res["predicted"] if math.isfinite(r["extra_sets"]) and not r["met"]]
    assert all(r["extra_pixel_samples"] == r["extra_sets"] * 3 * 5 * 16 * 24 * 24 for r in finite), finite


def test_first_steps_per_range_start_the_quoted_bounds_there(tmp_path):
    """`precision_fd_step_until: [[0.3, 0.005], [0.6, 0.01]]` with `precision_fd_step: 0.02`, one halving: the quoted
    CRLB at 0.2 checks its step from 5 mm (its reason names ξ = 0.005 and no step above it), the one at 0.5 from 1 cm
    and the one at 0.8 from 2 cm."""
    rc, out = _run(tmp_path, [{**BOUNDS, "precision": 0.15, "precision_fd_step": 0.02, "hcr_offsets": 0,
                               "precision_fd_step_until": [[0.3, 0.005], [0.6, 0.01]]}])
    assert rc == 0
    rows = {round(float(r["theta_x"]), 6): r["crlb_reason"] for r in read_csv(out / "b" / "precise.csv")}
    assert "at ξ = 0.005" in rows[0.2] and "0.01 " not in rows[0.2] and "0.02" not in rows[0.2], rows[0.2]
    assert "at ξ = 0.01" in rows[0.5] and "0.02" not in rows[0.5], rows[0.5]
    assert "at ξ = 0.02" in rows[0.8], rows[0.8]


def test_a_looser_step_tolerance_beyond_theta0_checks_only_the_quoted_bounds_there(tmp_path):
    """`precision_step_tol_beyond: 10` with `precision_beyond: [0.6, 0.3]` and `step_tol: 1e-4` (the pilot only:
    a budget of 1 pixel-sample): the quoted CRLB at 0.8 is shown converged at its first halving (F(ξ/2)/F(ξ) ≤ 11),
    those at 0.2 and 0.5 are not (0.2: F shown to fall by 0.6 %, below 1/1.0001; 0.5: ×1 ± 2.7e-5, not shown ≤
    1.0001), and the report states both tolerances."""
    rc, out = _run(tmp_path, [{**BOUNDS, "precision": 0.15, "precision_budget": 1, "hcr_offsets": 0,
                               "step_tol": 1e-4, "precision_beyond": [0.6, 0.3], "precision_step_tol_beyond": 10}])
    assert rc == 0
    rows = {round(float(r["theta_x"]), 6): r for r in read_csv(out / "b" / "precise.csv")}
    assert "FD step converged" in rows[0.8]["crlb_reason"] and not rows[0.8]["crlb_flags"], rows[0.8]
    for theta in (0.2, 0.5):  # (0.2: F shown to fall by 0.6 %; 0.5: F ×1 ± 2.7e-5)
        assert "FD step not converged" in rows[theta]["crlb_reason"], rows[theta]["crlb_reason"]
        assert rows[theta]["crlb_flags"] == "fd-step-not-converged", rows[theta]
    res = json.loads((out / "results.json").read_text())["studies"]["b"]["results"]
    assert res["step_tol_beyond"] == [0.6, 10]
    assert "shown ≤ 1 + 0.0001 (1 + 10 beyond 0.6, where the target is looser)" in (out / "report.md").read_text()


@pytest.mark.parametrize("ranges, beyond, want", [
    ([0.6, 0.005], 0.02, [0.005, 0.005, 0.02]),  # one pair, flat
    ([[0.6, 0.005]], 0.02, [0.005, 0.005, 0.02]),
    ([[0.3, 0.005], [0.6, 0.01]], 0.02, [0.005, 0.01, 0.02]),
    ([[0.2, 0.005], [0.5, 0.01], [0.8, 0.03]], 0.02, [0.005, 0.01, 0.03]),  # each range's upper θ included
])
def test_first_steps_take_each_thetas_range(ranges, beyond, want):
    """θ = 0.2, 0.5, 0.8: ξ_k of the first range [θ_k, ξ_k] with θ ≤ θ_k, else `precision_fd_step`."""
    from nlosbench.studies.bounds import first_steps, step_ranges

    got = first_steps(np.array([0.2, 0.5, 0.8]), step_ranges(ranges, "x"), beyond)
    assert got.tolist() == want


def test_a_trials_study_starts_each_theta_stars_fd_step_where_asked(tmp_path):
    """`fd_step: [0.005, 0.02]` at θ* = 0.3 and 0.7 (one halving): each θ*'s CRLB checks its own first step (the
    reason names ξ = 0.005 at 0.3 and 0.02 at 0.7, and not the other's)."""
    rc, out = _run(tmp_path, [{**TRIALS, "theta": [0.3, 0.7], "fd_step": [0.005, 0.02]}])
    assert rc == 0
    rows = {round(float(r["theta_x"]), 6): r["crlb_reason"] for r in read_csv(out / "t" / "bounds.csv")}
    assert "at ξ = 0.005" in rows[0.3] and "0.02" not in rows[0.3], rows[0.3]
    assert "at ξ = 0.02" in rows[0.7] and "0.005" not in rows[0.7], rows[0.7]


def test_without_a_target_the_outputs_are_unchanged(tmp_path):
    rc, out = _run(tmp_path, [TRIALS, BOUNDS])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["studies"]
    assert "precision" not in res["t"]["results"] and "precision" not in res["b"]["results"]
    assert not any(k.startswith("precision") for k in read_csv(out / "t" / "bounds.csv")[0])
    assert not any(k.startswith("precision") for k in read_csv(out / "b" / "bounds.csv")[0])
    assert not (out / "b" / "precise.csv").exists()
    assert "Precision" not in (out / "report.md").read_text()


@pytest.mark.parametrize("study, message", [
    ({**TRIALS, "precision": 0}, "studies[0].precision: expected a finite number > 0, got 0"),
    ({**TRIALS, "precision_budget": 10**6}, "t.precision_budget: a budget needs a precision target"),
    ({**TRIALS, "precision": 0.2, "looks": 0}, "studies[0].looks: expected an integer in [1, 64], got 0"),
    ({**TRIALS, "precision": 0.2, "replicates": 2}, "t.replicates: a precision target needs >= 3 replicates"),
    ({**TRIALS, "fd_step": [0.01, 0.02]}, "t.fd_step: one step, or one per θ* (1), got 2"),
    ({**TRIALS, "fd_step": [0.01, -0.02]}, "studies[0].fd_step[1]: expected a finite number > 0"),
    ({**TRIALS, "precision": 0.2, "bounds": ["hcr_neff"]}, "t.precision: a precision target needs an interval bound"),
    ({**TRIALS, "mode": "bayesian", "theta": None, "hcr_grid": 5, "precision": 0.2},
     "t.precision: a precision target applies to the bounds at θ* (local mode)"),
    ({**BOUNDS, "precision": 0.0, "precision_at": [0.5]}, "studies[0].precision: expected a finite number > 0"),
    ({**BOUNDS, "precision_budget": 10**6, "precision": None}, "b.precision_budget: a budget needs a precision"),
    ({**BOUNDS, "precision_at": [0.5]}, "b.precision_at: quoting bounds at θ needs a `precision` target"),
    ({**BOUNDS, "precision": 0.2, "precision_at": [0.5, 0.95]}, "b.precision_at[1]: θ out of range"),
    ({**BOUNDS, "precision_beyond": [0.6, 0.5]}, "b.precision_beyond: needs a `precision` or `precision_predict`"),
    ({**BOUNDS, "precision_predict": 0.0}, "studies[0].precision_predict: expected a finite number > 0, got 0.0"),
    ({**BOUNDS, "precision_predict": 0.2, "replicates": 2}, "b.replicates: a precision target needs >= 3 replicates"),
    ({**BOUNDS, "precision": 0.2, "precision_beyond": [0.6]}, "b.precision_beyond: expected [θ₀, p₀] with p₀ > 0"),
    ({**BOUNDS, "precision": 0.2, "precision_fd_step": -0.01}, "b.precision_fd_step: expected a step > 0"),
    ({**BOUNDS, "precision_fd_step_until": [0.5, 0.005]}, "b.precision_fd_step_until: needs a `precision` target"),
    ({**BOUNDS, "precision": 0.2, "precision_fd_step_until": [0.5, 0]},
     "b.precision_fd_step_until: expected [θ₀, ξ₀] pairs with ξ₀ > 0"),
    ({**BOUNDS, "precision": 0.2, "precision_fd_step_until": [[0.5, 0.01], [0.6]]},
     "b.precision_fd_step_until: expected [θ₀, ξ₀] pairs with ξ₀ > 0"),
    ({**BOUNDS, "precision": 0.2, "precision_fd_step_until": [[0.5, 0.01], [0.4, 0.02]]},
     "b.precision_fd_step_until: expected the pairs' θ increasing"),
    ({**BOUNDS, "precision": 0.2, "hcr_offsets": -1}, "b.hcr_offsets: expected an integer >= 0"),
    ({**BOUNDS, "precision": 0.2, "precision_step_tol_beyond": 0.2},
     "b.precision_step_tol_beyond: needs a `precision` target and `precision_beyond`"),
    ({**BOUNDS, "precision_predict": 0.2, "precision_beyond": [0.6, 0.5], "precision_step_tol_beyond": 0.2},
     "b.precision_step_tol_beyond: needs a `precision` target and `precision_beyond`"),
    ({**BOUNDS, "precision": 0.2, "precision_beyond": [0.6, 0.5], "precision_step_tol_beyond": 0},
     "studies[0].precision_step_tol_beyond: expected a finite number > 0, got 0"),
])
def test_bad_precision_keys_stop_the_run_at_config_time(tmp_path, capsys, study, message):
    """Schema errors name studies[0].<key> (the config is resolved), the rest <id>.<key> (the study's plan, with the
    scene loaded): both before the run folder is made."""
    rc, out = _run(tmp_path, [study])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and message in err and len(err.splitlines()) == 1, err
    assert not out.exists()
