"""The `time-of-flight` study on the analytic toy, against closed forms: the transient detector's depth bound is the
toy's at the combined response (σ² = σ_toy² + σ_det² + w²/12), the time-summed one the toy's summed-counts Fisher
information, and the ratio of RMS bounds their quotient (exact renders: only FD truncation separates them)."""
import json

import numpy as np
import pytest
import yaml

from nlosbench.cli import main
from nlosbench.forward.analytic import TransientPoint
from nlosbench.forward.detector import ps_to_m
from nlosbench.io import read_csv

WINDOW = {"start": 1.15, "bins": 144}
SA, SB, W = 30.0, 40.0, 0.006


def test_study_bounds_and_ratio_match_the_closed_forms(tmp_path):
    cfg = {"name": "tof-toy", "seed": 0, "scene": {"name": "transient_point",
                                                   "options": {"jitter_ps": SA, "background": 1e-9, "free_albedo": True,
                                                               **WINDOW}},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "time-of-flight", "param": "depth", "nuisance": ["albedo"], "photons": 1e5,
                        "jitters_ps": [SB],
                        "background": 0.5, "wall_return": 0.0, "spp": 4, "replicates": 3, "fd_step": 1e-3,
                        "max_halvings": 1, "reference_spp": 4, "trials": 3, "voxel": 0.001, "budgets": [1e3, 1e7]}]}
    path = tmp_path / "tof.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    study = tmp_path / "run" / "00-time-of-flight"
    rows = {r["detector"]: r for r in read_csv(study / "bounds.csv")}
    results = json.loads((tmp_path / "run" / "results.json").read_text())["studies"]["00-time-of-flight"]["results"]
    gain = results["gain"]
    assert gain == pytest.approx(1.0, rel=1e-3)  # the toy's own 1e5 photons: the budget asks for as many
    sigma = np.sqrt(ps_to_m(SA) ** 2 + ps_to_m(SB) ** 2 + W**2 / 12) / ps_to_m(1.0)
    toy = TransientPoint(jitter_ps=sigma, background=0.5, photons=1e5 * gain, **WINDOW)
    t = toy.params.default
    rms_tr = 1 / np.sqrt(toy.fisher(t)[2, 2])
    rms_sum = 1 / np.sqrt(toy.fisher(t, summed=True)[2, 2])
    assert float(rows[f"transient {SB:g} ps"]["rms_bound"]) == pytest.approx(rms_tr, rel=0.01)
    assert float(rows["time-summed"]["rms_bound"]) == pytest.approx(rms_sum, rel=0.01)
    # the HCR over the study's test Δ: for this Gaussian shift family every Δ term lies below the Δ → 0 one, so the
    # exact HCR is the closed-form CRLB (χ²(Δ) ≥ F Δ² here: Δ²/(exp χ² − 1) < 1/F)
    for label, want in ((f"transient {SB:g} ps", rms_tr), ("time-summed", rms_sum)):
        assert float(rows[label]["rms_hcr"]) == pytest.approx(want, rel=0.01), label
    (ratio,) = [r for r in read_csv(study / "ratios.csv") if r["summed"] == "time-summed"]
    assert float(ratio["ratio"]) == pytest.approx(rms_sum / rms_tr, rel=0.02)
    assert float(ratio["ratio_lower"]) <= float(ratio["ratio"]) <= float(ratio["ratio_upper"])
    assert int(rows[f"transient {SB:g} ps"]["bp_trials"]) == 3
    # the albedo unknown too: (F⁻¹)_depth,depth of the toy's closed-form 2 × 2 Fisher matrix over (depth, albedo)
    joint = TransientPoint(jitter_ps=sigma, background=0.5, photons=1e5 * gain, free_albedo=True, **WINDOW)
    F2 = joint.fisher(joint.params.default)[np.ix_([2, 3], [2, 3])]
    F2s = joint.fisher(joint.params.default, summed=True)[np.ix_([2, 3], [2, 3])]
    nu_tr, nu_sum = np.sqrt(np.linalg.inv(F2)[0, 0]), np.sqrt(np.linalg.inv(F2s)[0, 0])
    # an unknown albedo never helps (Schur complement); without timing, depth and albedo both only scale the counts
    assert nu_tr >= rms_tr and nu_sum > 2 * rms_sum, (nu_tr / rms_tr, nu_sum / rms_sum)
    for label, want in ((f"transient {SB:g} ps", nu_tr), ("time-summed", nu_sum)):
        r = rows[label]
        assert float(r["rms_nuisance"]) == pytest.approx(want, rel=0.01), (label, r["rms_nuisance"], want)
        assert float(r["rms_nuisance_lower"]) <= float(r["rms_nuisance"]) <= float(r["rms_nuisance_upper"])
    assert float(ratio["ratio_nuisance"]) == pytest.approx(nu_sum / nu_tr, rel=0.02)
    # other photon budgets from the same renders: each the toy's closed form at that budget (background unchanged,
    # so the RMS bound does not simply scale as 1/√photons: at 1e3 photons the background weighs more)
    budgets = {(r["detector"], float(r["photons"])): float(r["rms_bound"]) for r in read_csv(study / "budgets.csv")}
    for n in (1e3, 1e5, 1e7):
        at_n = TransientPoint(jitter_ps=sigma, background=0.5, photons=n * gain, **WINDOW)
        F = at_n.fisher(at_n.params.default)[2, 2], at_n.fisher(at_n.params.default, summed=True)[2, 2]
        assert budgets[f"transient {SB:g} ps", n] == pytest.approx(1 / np.sqrt(F[0]), rel=0.01), n
        assert budgets["time-summed", n] == pytest.approx(1 / np.sqrt(F[1]), rel=0.01), n
    assert budgets["time-summed", 1e3] / budgets["time-summed", 1e5] > 1.05 * 10  # the background's share grows
    assert "albedo unknown" in (tmp_path / "run" / "report.md").read_text()


def test_study_mle_is_efficient_on_the_toy(tmp_path):
    """The study's maximum-likelihood fits (the surrogate on a lattice around a pilot draw's backprojection estimate)
    on the exact toy: over 100 Poisson draws their MSE lies in the χ²₁₀₀ band (99.9 %) around the closed-form
    CRLB, with no significant bias, and the study's verdict against its own CRLB is "inside"."""
    from scipy import stats

    n = 100
    cfg = {"name": "tof-mle", "seed": 0, "scene": {"name": "transient_point",
                                                   "options": {"jitter_ps": SA, "background": 1e-9, **WINDOW}},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "time-of-flight", "param": "depth", "photons": 1e5, "jitters_ps": [SB],
                        "background": 0.5, "wall_return": 0.0, "spp": 4, "replicates": 3, "fd_step": 1e-3,
                        "max_halvings": 1, "reference_spp": 4, "trials": n, "voxel": 0.001, "mle_spp": 4,
                        "mle_step": 5e-4, "mle_halfwidth": 4e-3}]}
    path = tmp_path / "tof.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    (row,) = [r for r in read_csv(tmp_path / "run" / "00-time-of-flight" / "bounds.csv") if r["timing"] == "True"]
    sigma = np.sqrt(ps_to_m(SA) ** 2 + ps_to_m(SB) ** 2 + W**2 / 12) / ps_to_m(1.0)
    toy = TransientPoint(jitter_ps=sigma, background=0.5, photons=1e5, **WINDOW)
    crlb = 1 / toy.fisher(toy.params.default)[2, 2]
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n) / n
    assert lo <= float(row["mle_mse"]) / crlb <= hi, float(row["mle_mse"]) / crlb
    assert float(row["mle_bias_p"]) > 0.001, row["mle_bias"]
    assert row["mle_status"] == f"converged {n}" and int(row["mle_n_failed"]) == 0
    assert row["mle_vs_crlb"].startswith("inside"), row["mle_vs_crlb"]
    assert "Maximum likelihood" in (tmp_path / "run" / "report.md").read_text()


def test_study_refuses_an_mle_lattice_narrower_than_its_window(tmp_path, capsys):
    cfg = {"name": "tof-mle-bad", "seed": 0, "scene": {"name": "transient_point", "options": WINDOW},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "time-of-flight", "jitters_ps": [SB], "trials": 2, "mle_step": 1e-3,
                        "mle_halfwidth": 1e-3}]}
    path = tmp_path / "tof.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "mle_halfwidth" in err and "at least 2 lattice steps" in err, err
    assert not (tmp_path / "run" / "00-time-of-flight").exists()
    # a ZZB prior that leaves Θ (depth in [0.5, 1.0], θ* 0.75), or an even grid, is refused before anything runs
    for key, value, says in (("zzb_halfwidth", 0.3, "leaves Θ"), ("zzb_points", 4, "odd integer")):
        study = {"type": "time-of-flight", "jitters_ps": [SB], "trials": 0, "zzb_halfwidth": 0.01, key: value}
        path.write_text(yaml.safe_dump({**cfg, "studies": [study]}))
        assert main(["run", str(path), "--out", str(tmp_path / key), "--quiet"]) != 0
        err = capsys.readouterr().err
        assert key in err and says in err, err
        assert not (tmp_path / key / "00-time-of-flight").exists()


def test_the_bounds_study_runs_on_a_transient_scene(tmp_path):
    """The `bounds` study on the toy (images (scan_y, scan_x, T, C)): its CRLB at every grid point is the
    closed-form one (exact renders), its ZZB is written, and its saved renders hold the T·C values per scan point
    as EXR channels (a transient image used to stop the study at the image writer)."""
    from nlosbench.io import read_exr

    cfg = {"name": "toy-bounds", "seed": 0, "scene": {"name": "transient_point", "params": ["depth"],
                                                      "options": WINDOW},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "bounds", "grid": {"start": 0.7499, "stop": 0.7501, "num": 5}, "spp": 1,
                        "replicates": 3}]}
    path = tmp_path / "toy.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    study = tmp_path / "run" / "00-bounds"
    toy = TransientPoint(**WINDOW)
    for r in read_csv(study / "bounds.csv"):
        t = toy.params.default.copy()
        t[2] = float(r["theta_depth"])
        assert 10 ** float(r["log10_crlb"]) == pytest.approx(1 / toy.fisher(t)[2, 2], rel=0.01), r["theta_depth"]
    assert read_csv(study / "zzb.csv")
    H, W_, T, C = toy.render(toy.params.default, 1, 0).shape
    assert read_exr(study / "images" / "grid_0000.exr").shape == (H, W_, T * C)


def test_the_fisher_maps_study_runs_on_a_transient_scene(tmp_path):
    """The `fisher-maps` study on the toy: a map per scan point (each point's T·C values summed) that sums to the
    closed-form Fisher information of the depth (exact renders), and its figure (a transient image stopped the
    study at the map writer before)."""
    cfg = {"name": "toy-maps", "seed": 0, "scene": {"name": "transient_point", "params": ["depth"],
                                                    "options": WINDOW},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "fisher-maps", "at": [0.75], "spp": 1, "fd_step": 5e-4, "fd_rounds": 3}]}
    path = tmp_path / "toy.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    study = tmp_path / "run" / "00-fisher-maps"
    (row,) = read_csv(study / "fisher.csv")
    toy = TransientPoint(**WINDOW)
    t = toy.params.default.copy()
    t[2] = 0.75
    assert float(row["fisher_total"]) == pytest.approx(toy.fisher(t)[2, 2], rel=0.01)
    from nlosbench.io import read_exr

    H, W_ = toy.render(t, 1, 0).shape[:2]
    assert read_exr(study / "p0_noise0_fisher_depth.exr").shape[:2] == (H, W_)
    assert (study / "fisher_maps.png").is_file()


def _zzb_exact(toy: TransientPoint, t: float, hw: float, n: int = 801) -> float:
    """The toy's Ziv–Zakai bound on the Bayesian MSE of the depth, uniform on t ± hw, with the Poisson P_e ≥
    ½(1 − √(1 − ρ²)) from the Bhattacharyya coefficient ρ = exp(−½ Σ (√L1 − √L0)²) of its exact mean counts,
    integrated finely here (n points: A(h) by the trapezoid rule over φ, valley filling, then ∫ h V(h) dh)."""
    phi = np.linspace(t - hw, t + hw, n)
    theta = toy.params.default.copy()
    roots = []
    for p in phi:
        theta[2] = p
        roots.append(np.sqrt(toy.render(theta, 1, 0).numpy().astype(np.float64).ravel()))
    R = np.array(roots)
    T, d = 2 * hw, phi[1] - phi[0]
    A = []
    for k in range(1, n):
        rho = np.exp(-0.5 * ((R[k:] - R[:-k]) ** 2).sum(axis=1))
        pe = 0.5 * (1 - np.sqrt(np.clip(1 - rho**2, 0.0, None)))
        A.append(2 / T * np.trapezoid(pe, dx=d) if len(pe) > 1 else 0.0)
    V = np.maximum.accumulate(np.array(A)[::-1])[::-1]
    h = d * np.arange(1, n)
    return 0.5 * np.trapezoid(np.concatenate([[0.0], h * V]), np.concatenate([[0.0], h]))


def test_study_zzb_matches_the_toys_exact_ziv_zakai_bound(tmp_path):
    """With `zzb_halfwidth`, the study's Ziv–Zakai bound on the exact toy (21 grid points over a prior 4 RMS CRLBs
    wide, every detector on the same renders) is the toy's exact ZZB, integrated finely apart (`_zzb_exact`), to
    within the 21-point lower sum's grid error (it may only fall below, by less than 15 %), and below the prior's
    variance; the detectors share their raw renders: the time-summed ones render nothing of their own."""
    sigma = np.sqrt(ps_to_m(SA) ** 2 + ps_to_m(SB) ** 2 + W**2 / 12) / ps_to_m(1.0)
    toy = TransientPoint(jitter_ps=sigma, background=0.5, photons=1e3, **WINDOW)
    t = float(toy.params.default[2])
    hw = 2 / np.sqrt(toy.fisher(toy.params.default)[2, 2])
    cfg = {"name": "tof-zzb", "seed": 0, "scene": {"name": "transient_point",
                                                   "options": {"jitter_ps": SA, "background": 1e-9, **WINDOW}},
           "noise": [{"model": "poisson", "scale": 1.0}], "executor": {"type": "serial"},
           "studies": [{"type": "time-of-flight", "param": "depth", "photons": 1e3, "jitters_ps": [SB],
                        "background": 0.5, "wall_return": 0.0, "spp": 1, "replicates": 3, "fd_step": 1e-3,
                        "max_halvings": 0, "reference_spp": 1, "trials": 0, "zzb_halfwidth": float(hw),
                        "zzb_points": 21}]}
    path = tmp_path / "tof.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    rows = {r["detector"]: r for r in read_csv(tmp_path / "run" / "00-time-of-flight" / "bounds.csv")}
    zzb = float(rows[f"transient {SB:g} ps"]["rms_zzb"]) ** 2
    exact = _zzb_exact(toy, t, hw)
    assert 0.85 * exact <= zzb <= 1.001 * exact, (zzb, exact)
    assert zzb < hw**2 / 3 and float(rows["time-summed"]["rms_zzb"]) ** 2 < hw**2 / 3
    # every detector sees the same raw renders: the time-summed ones render nothing of their own
    assert rows["time-summed"]["renders"] == rows["time-summed + wall"]["renders"] == "0"
    assert "Ziv–Zakai" in (tmp_path / "run" / "report.md").read_text()
