"""Trial runner and the `trials` study: MSE against the CRLB and HCR with honest statistics, a complete
summary on the real Mitsuba scene, resume after a real kill, failures counted, bad input rejected."""
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import nlosbench as nb
from nlosbench import estimators
from nlosbench.bounds import crlb, fisher_matrix
from nlosbench.estimators import Estimator
from nlosbench.executors import SerialExecutor
from nlosbench.experiment.config import load as load_config
from nlosbench.experiment.config import resolve
from nlosbench.forward import GradientSettings, ad_jacobian
from nlosbench.io import read_csv
from nlosbench.montecarlo import LOG_NAME, Setting, make_trials, read_log, run_trials, summarize
from nlosbench.schema import ConfigError
from nlosbench.studies import trials as study
from nlosbench.studies.context import RunContext
from nlosbench.studies.tables import paper_table

TIMING = ("mean_seconds", "total_seconds")


def make_ctx(run_dir: Path, scene: dict, block: dict, noise=None, seed: int = 0, resume: bool = False):
    """A RunContext and the resolved study block for one `trials` study."""
    cfg = resolve({"seed": seed, "scene": scene, "noise": noise or [{"model": "awgn", "sigma": 0.1}],
                   "studies": [{"type": "trials", **block}]})
    return RunContext.create(cfg, Path(run_dir), resume=resume, quiet=True), cfg["studies"][0]


@pytest.mark.slow
def test_mle_adam_is_efficient_on_blob2d_at_high_snr(tmp_path):
    """240 trials at one θ*, AWGN σ = 0.02 (peak SNR 50), uniform random starts in Θ: the MSE of
    mle-adam (exact AD gradients) is within [0.75, 1.35] × CRLB. With 240 trials the MSE's relative
    standard error is about 1/√240 ≈ 0.065 (‖e‖² ≈ CRLB/2 · χ²₂), so the window is about −3.8 / +5.4 SE."""
    model = nb.scenes.get("blob2d", width=0.15)
    noise = nb.noise.AWGN(0.02)
    theta = np.array([[0.45, 0.58]])
    clean = model.render(theta[0], 1, 0)
    F = fisher_matrix(clean, ad_jacobian(model, theta[0], 1, 0), noise)
    bound = crlb(F).trace
    trials = make_trials(theta, 240, [Setting("mle-adam", {"iterations": 60}, gradient=GradientSettings("ad"))],
                         {0: noise}, {0: clean}, seed=21)
    records = run_trials(SerialExecutor(model), trials, tmp_path / LOG_NAME)
    (row,) = summarize(records, model.params.names, {(0, 0): {"crlb": {"value": bound, "log10": math.log10(bound)}}})
    assert row["n"] == 240 and row["n_failed"] == 0
    assert 0.75 <= row["mse_over_crlb"] <= 1.35, row
    assert row["mse_se"] / row["mse"] < 0.1  # the bootstrap SE agrees with the χ² estimate above


@pytest.mark.slow
def test_edge1d_mse_respects_hcr_and_far_above_is_flagged(tmp_path):
    """edge1d (hard shadow edge), AWGN σ = 0.1, 80 trials per θ* at 2 θ*. Each near-efficient
    estimator (grid-search, mle-adam) has MSE ≥ HCR − 3 SE (bootstrap SE over the 80 trials);
    gauss-newton from uniform random starts stalls on the piecewise-flat likelihood, its MSE is
    orders of magnitude above every bound, and the summary and report flag it. mle-adam runs with the
    0.1 step rule (lr 0.05 of Θ's width, cosine decay): its coarse early steps cross the flat pieces, where
    lr "auto" (Fisher-scale steps, a local method like gauss-newton) stops in the noise's local minimum
    of the pixel it starts in."""
    ctx, block = make_ctx(tmp_path, {"name": "edge1d"}, {
        "theta": [0.3, 0.5078125], "n": 80, "n_eff": 1, "bounds": ["hcr", "crlb", "hcr_neff", "barankin"],
        "hcr_grid": 161, "hcr_offsets": 10, "fd_step": 1e-4,
        "estimators": [{"name": "mle-adam", "options": {"lr": 0.05, "iterations": 60}, "gradient": {"method": "ad"}},
                       {"name": "grid-search", "options": {"num": 129, "spp": 1}},
                       {"name": "gauss-newton", "gradient": {"method": "ad"}}]}, seed=3)
    res = study.run(ctx, block)
    rows = res["summary"]
    assert len(rows) == 6 and all(r["n"] == 80 and r["n_failed"] == 0 for r in rows)
    for r in rows:
        assert r["mse"] + 3 * r["mse_se"] >= r["hcr"], r
    for r in (r for r in rows if r["estimator"] != "gauss-newton"):
        assert r["far_above"] == "" and r["mse_over_hcr"] < 3, r
    for r in (r for r in rows if r["estimator"] == "gauss-newton"):
        assert "hcr" in r["far_above"].split(",") and r["mse_over_hcr"] > 100, r
    md = study.report(ctx.dir / "trials", res)
    assert "**Far above**" in md and "gauss-newton at θ* #0 (hcr,crlb" in md
    # the paper's MLE-vs-HCR table: θ*, the paper's bound columns, then MSE and Var of each estimator
    assert ("| θ* (m) | HCR_Neff | MSE(mle-adam) | Var(mle-adam) | MSE(grid-search) | "
            "Var(grid-search) | MSE(gauss-newton) | Var(gauss-newton) |") in md
    adam = next(r for r in rows if r["estimator"] == "mle-adam" and r["theta_index"] == 1)
    assert f"| {adam['mse']:.4g} | {adam['var']:.4g} |" in md
    assert (ctx.dir / "trials" / "plots" / "mse_vs_theta.png").stat().st_size > 1000
    assert "hcr inside" in md or "hcr above" in md  # every row carries a verdict against the HCR interval


def test_cornell_study_produces_a_complete_summary(tmp_path):
    """The real 32×32 Mitsuba scene, θ = ball_x: two estimators, two θ*, two trials each (tiny spp)."""
    ctx, block = make_ctx(tmp_path, {"name": "cornell_ball", "params": ["ball_x"]}, {
        "theta": [-0.1, 0.15], "n": 2, "n_eff": 64, "truth_replicates": 1, "hcr_grid": 5, "hcr_offsets": 2,
        "fd_step": 0.02,
        "estimators": [{"name": "mle-adam", "label": "adam-auto", "options": {"lr": 0.1, "iterations": 6, "spp": 16},
                        "gradient": {"method": "auto", "step": 0.02}},
                       {"name": "grid-search", "options": {"num": 9, "spp": 16, "refine_evals": 6}}]},
        noise=[{"model": "awgn", "sigma": 0.05}], seed=1)
    before = ctx.model.stats.snapshot()
    res = study.run(ctx, block)
    used = ctx.model.stats.since(before)
    assert res["renders"] == used.renders + used.grad_passes  # serial: every render of the study is counted
    folder = ctx.dir / "trials"
    rows = read_csv(folder / "summary.csv")
    assert {(r["theta_ball_x"], r["estimator"]) for r in rows} == {
        (t, e) for t in ("-0.1", "0.15") for e in ("adam-auto", "grid-search")}
    for r in res["summary"]:
        assert r["n"] == 2 and r["n_failed"] == 0 and r["mse"] < 0.05, r
        assert r["mean_renders"] > 0 and r["mean_seconds"] > 0
        assert r["crlb"] > 0 and math.isfinite(r["mse_over_crlb"]) and r["mse_over_hcr"] > 0
    # at 64 spp rendering noise dominates λ (the paper's point): HCR_Neff may underflow, its log10 never
    assert all(math.isfinite(b["log10_hcr"]) and math.isfinite(b["log10_crlb"]) for b in res["bound_rows"])
    assert len(read_log(folder / LOG_NAME)) == 8
    for f in ("bounds.csv", "images/clean_000.exr", "images/clean_001.exr"):
        assert (folder / f).is_file(), f
    # grad auto on a position: the prior picks FD with the block's step; the choice is reported
    chosen = res["gradients"]["adam-auto"]
    assert chosen.startswith("fd(ξ=0.02,R=1,crn) (auto: ball_x → fd") and "prior" in chosen, chosen
    md = study.report(folder, res)
    for f in ("plots/mse_vs_theta.png", "plots/speed_vs_error.png"):  # drawn by the report, from saved data
        assert (folder / f).is_file(), f
    assert "| -0.1 | adam-auto | 2 (0) |" in md and "CRLB (trace of F̂⁻¹) from an unbiased Fisher information" in md
    assert f"gradient of **adam-auto**: {chosen}" in md


RESUME_SCRIPT = """
import json, sys
from pathlib import Path
from nlosbench.experiment.config import resolve
from nlosbench.studies.context import RunContext
from nlosbench.studies import trials as study
raw = json.loads(sys.argv[1])
cfg = resolve(raw)
ctx = RunContext.create(cfg, Path(sys.argv[2]), resume=sys.argv[3] == "1", quiet=True)
study.run(ctx, cfg["studies"][0])
"""
RESUME_CONFIG = {"seed": 5, "scene": {"name": "blob2d", "options": {"width": 0.15, "render_noise": 0.05}},
                 "noise": [{"model": "awgn", "sigma": 0.05}],
                 "studies": [{"type": "trials", "theta": [[0.4, 0.6], [0.6, 0.5]], "n": 12, "n_eff": 256,
                              "hcr_grid": 5, "fd_step": 0.002,
                              "estimators": [{"name": "mle-adam", "options": {"iterations": 30, "spp": 16},
                                              "gradient": {"method": "ad"}},
                                             {"name": "gauss-newton", "options": {"spp": 16}}]}]}


def _summary_without_timing(res: dict) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in TIMING} for r in res["summary"]]


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_summary(tmp_path):
    """A real subprocess is SIGKILLed after a few trials; resuming finishes only the missing trials
    and gives exactly the summary of an uninterrupted run (wall times aside). The blob2d model here
    has Monte Carlo-like rendering noise, so render seeds matter too."""
    script = tmp_path / "run.py"
    script.write_text(RESUME_SCRIPT)
    killed = tmp_path / "killed"
    log = killed / "trials" / LOG_NAME
    proc = subprocess.Popen([sys.executable, str(script), json.dumps(RESUME_CONFIG), str(killed), "0"])
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if log.exists() and log.read_bytes().count(b"\n") >= 6:
            break
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    total = 2 * 12 * 2
    n_before = len(read_log(log))
    assert 6 <= n_before < total, f"the run was not killed mid-way ({n_before} of {total} trials)"

    cfg = resolve(RESUME_CONFIG)
    ctx = RunContext.create(cfg, killed, resume=True, quiet=True)
    resumed = study.run(ctx, cfg["studies"][0])
    records = read_log(log)
    assert len(records) == total and len({(r["theta_index"], r["trial"], r["estimator"]) for r in records}) == total

    ctx_full = RunContext.create(cfg, tmp_path / "full", quiet=True)
    full = study.run(ctx_full, cfg["studies"][0])
    assert _summary_without_timing(resumed) == _summary_without_timing(full)
    assert resumed["bound_rows"] == full["bound_rows"]


def test_torn_last_line_is_cut_and_that_trial_rerun(tmp_path):
    model = nb.scenes.get("edge1d")
    noise = nb.noise.AWGN(0.1)
    trials = make_trials(np.array([[0.5]]), 3, [Setting("grid-search", {"num": 33, "spp": 1})], {0: noise},
                         {0: model.render([0.5], 1, 0)}, seed=1)
    log = tmp_path / LOG_NAME
    first = run_trials(SerialExecutor(model), trials, log)
    with open(log, "ab") as f:
        f.write(b'{"noise": 0, "theta_index": 0, "tri')  # killed while writing a fourth record
    lines = log.read_bytes().splitlines()
    os.truncate(log, sum(len(x) + 1 for x in lines[:2]) + len(b'{"noise": 0, "theta'))  # and the third was torn
    again = run_trials(SerialExecutor(model), trials, log, resume=True)
    assert len(read_log(log)) == 3
    assert sorted((r["trial"], r["theta_hat"]) for r in again) == sorted((r["trial"], r["theta_hat"]) for r in first)


class _Exploding(Estimator):
    name = "exploding"

    def _fit(self, problem, y, theta0, rng, tracker):
        problem.model.render(theta0, 1, 0)
        raise FloatingPointError("NLL is nan")


def test_failed_fits_are_counted_shown_and_not_silently_dropped(tmp_path):
    estimators.register("exploding", _Exploding)
    try:
        ctx, block = make_ctx(tmp_path, {"name": "edge1d"}, {
            "theta": [0.5], "n": 4, "n_eff": 1, "hcr_grid": 9,
            "estimators": [{"name": "exploding"}, {"name": "grid-search", "options": {"num": 17, "spp": 1}}]})
        res = study.run(ctx, block)
    finally:
        estimators._REGISTERED.pop("exploding")
    bad = next(r for r in res["summary"] if r["estimator"] == "exploding")
    assert bad["n"] == 4 and bad["n_failed"] == 4 and math.isnan(bad["mse"]) and bad["mean_renders"] == 1
    md = study.report(ctx.dir / "trials", res)
    assert "FloatingPointError: NLL is nan" in md and "| 0.5 | exploding | 4 (4) |" in md and "| failed 4 |" in md


def test_two_studies_of_a_run_draw_distinct_noise_start_and_fit_seeds(tmp_path):
    """Two trials studies in one run (ids a and b) with the same θ* and trial count: their starts (drawn from the
    study's own seed stream) differ, so the studies are independent; the same study id gives the same starts."""
    ctx, block = make_ctx(tmp_path, {"name": "edge1d"}, {
        "id": "a", "theta": [0.5], "n": 3, "n_eff": 1, "hcr_grid": 5, "bounds": [],
        "estimators": [{"name": "grid-search", "options": {"num": 5, "spp": 1, "refine": False}}]})
    starts = {sid: [r["init"] for r in read_log(ctx.dir / sid / LOG_NAME)] for sid in ("a", "b")
              if study.run(ctx, {**block, "id": sid})}
    assert len(starts["a"]) == len(starts["b"]) == 3
    assert all(a != b for a, b in zip(starts["a"], starts["b"], strict=True))
    study.run(ctx, {**block, "id": "a"})
    assert [r["init"] for r in read_log(ctx.dir / "a" / LOG_NAME)] == starts["a"]


@pytest.mark.parametrize("change, path, msg", [
    ({"estimators": [{"name": "mle-adamm"}]}, "estimators[0].name", "did you mean 'mle-adam'"),
    ({"estimators": [{"name": "mle-adam", "options": {"lr": -1}}]}, "estimators[0]", "lr must be > 0"),
    ({"estimators": [{"name": "mle-adam"}, {"name": "mle-adam"}]}, "estimators", "used twice"),
    ({"theta": [0.5, 0.95]}, "theta[1]", r"edge=0.95 outside \[0.1, 0.9\]"),
    ({"theta": []}, "theta", "non-empty"),
    ({"n": 0}, "n", "expected a positive integer, got 0"),
    ({"noise": 3}, "noise", "indices into the 1 noise model"),
    ({"budget": {"renders": 0}}, "budget", "renders must be > 0"),
    ({"bounds": ["barankin"], "theta": [0.5]}, None, None),
])
def test_bad_input_is_rejected_before_any_render(tmp_path, change, path, msg):
    """Estimator names and options fail when the config is resolved (`check`: studies[0]...), the rest
    when the study starts (trials...); either way before any render."""
    block = {"theta": [0.5], "n": 2, "n_eff": 1, "estimators": [{"name": "grid-search", "options": {"spp": 1}}],
             **change}
    if path is None:  # a valid block (scalar θ allows barankin): runs
        ctx, block = make_ctx(tmp_path, {"name": "edge1d"}, block)
        assert study.run(ctx, block)["trials"] == 2
        return
    ctx = None
    with pytest.raises(ConfigError, match=msg) as e:
        ctx, block = make_ctx(tmp_path, {"name": "edge1d"}, block)
        before = ctx.model.stats.renders
        study.run(ctx, block)
    where = "studies[0]" if ctx is None else "trials"
    assert str(e.value).startswith(f"{where}.{path}:"), str(e.value)
    assert ctx is None or ctx.model.stats.renders == before


def test_auto_gradient_follows_the_verdicts_or_the_prior(cornell, tmp_path):
    """`gradient: {method: auto}` is resolved when the block is parsed (the problem carries concrete
    settings): without verdicts the prior (colour → AD prb, position → FD); a verdicts file that judges
    the colour artifact-prone turns it to FD; a missing verdicts file is a config error naming the key."""
    from nlosbench.diagnostics import Verdict, save_verdicts

    red, x = cornell.restrict(["ball_red"]), cornell.restrict(["ball_x"])
    auto = [{"name": "mle-adam", "options": {}, "label": None, "gradient": {"method": "auto"}}]
    (s,) = study.parse_settings(auto, "trials.estimators", red)
    assert s.gradient == GradientSettings("ad", ad={"type": "prb"})
    (s,) = study.parse_settings(auto, "trials.estimators", x)
    assert s.gradient.method == "fd"
    path = save_verdicts(
        tmp_path / "verdicts.json",
        {
            "ball_red": Verdict(
                "ball_red", "ad-artifact-prone", "outliers", {"method": "fd", "step": 0.05, "rounds": 2, "crn": True}
            )
        },
    )
    auto[0]["gradient"] = {"method": "auto", "verdicts": str(path)}
    (s,) = study.parse_settings(auto, "trials.estimators", red)
    assert s.gradient == GradientSettings("fd") and "outliers" in s.gradient.chosen
    auto[0]["gradient"] = {"method": "auto", "verdicts": str(tmp_path / "nowhere")}
    with pytest.raises(ConfigError, match=r"trials.estimators\[0\].gradient: no gradient verdicts"):
        study.parse_settings(auto, "trials.estimators", red)


def test_paper_table_writes_bounds_below_float64_from_their_log10():
    """The paper's first row (θ* = 80 cm: HCR_Neff 4.17e-214, HCR-hat 1.30e-216) and a bound of 1e-400,
    which underflows float64: every cell comes from log10."""
    rows = [
        {"noise": 0, "theta_index": i, "theta_x": x, "estimator": "MLE", "mse": m, "var": v}
        for i, (x, m, v) in enumerate([(80.0, 0.0024, 0.0019), (100.0, 4.0518, 4.0372)])
    ]
    bound_rows = [
        {
            "noise_index": 0,
            "theta_index": 0,
            "log10_hcr_neff": math.log10(4.17) - 214,
            "log10_hcr_hat": math.log10(1.3) - 216,
        },
        {"noise_index": 0, "theta_index": 1, "log10_hcr_neff": -400.0, "log10_hcr_hat": math.inf},
    ]
    table = paper_table(rows, bound_rows, ["hcr_neff", "hcr_hat"], ["x"], ["cm"], 0)
    assert table == [
        "| θ* (cm) | HCR_Neff | HCR-hat | MSE(MLE) | Var(MLE) |",
        "|---|---|---|---|---|",
        "| 80 | 4.17e-214 | 1.3e-216 | 0.0024 | 0.0019 |",
        "| 100 | 1e-400 | – | 4.052 | 4.037 |",
    ]


def test_smoke_runs_the_paper_config_in_seconds(tmp_path):
    """`--smoke` on configs/paper_pi_trials.yaml (Π hallway, 5 θ* × 30 trials × 400 iterations at
    512/1024 spp, and a bayesian block): the smoke blocks keep the estimators and the code path but 2 θ*,
    2 trials and 3 iterations at 4 spp on the scene's tiny image; both studies finish with a complete
    summary, the table with the bounds beside each estimator and the bayes run against its ZZB."""
    root = Path(__file__).resolve().parents[1]
    cfg = load_config(root / "configs" / "paper_pi_trials.yaml", ["executor.type=serial", "cache=null"], smoke=True)
    block = cfg["studies"][0]
    assert block["theta"] == [0.8, 1.6] and block["n"] == 2 and block["n_eff"] == 32
    assert block["budget"]["iterations"] == 3
    assert block["estimators"][0]["options"] == {"lr": 0.05, "iterations": 3, "spp": [[0.0, 4], [0.5, 4]]}
    ctx = RunContext.create(cfg, tmp_path, quiet=True)
    res = study.run(ctx, block)
    assert res["trials"] == 8 and [r["n"] for r in res["summary"]] == [2, 2, 2, 2]
    assert all(r["n_failed"] == 0 and r["mean_iterations"] <= 3 for r in res["summary"])
    assert all(f"vs_{b}" in r for r in res["summary"] for b in ("hcr", "crlb"))
    bayes = study.run(ctx, cfg["studies"][1])
    (row,) = bayes["summary"]
    assert row["n"] == 2 and row["n_failed"] == 0 and "vs_zzb" in row


def test_smoke_caps_every_estimator_and_gradient_option():
    block = resolve(
        {
            "scene": {"name": "blob2d"},
            "studies": [
                {
                    "type": "trials",
                    "theta": [[0.3, 0.3], [0.4, 0.5], [0.7, 0.7]],
                    "n": 200,
                    "n_eff": 65536,
                    "hcr_grid": 41,
                    "levels": [2048, 4096, 8192],
                    "bootstrap": 5000,
                    "budget": {"iterations": 1000, "renders": 10000},
                    "estimators": [
                        {"name": "grid-search", "options": {"num": 65, "spp": 1024, "refine_evals": 150}},
                        {
                            "name": "multi-start",
                            "options": {"base": "gauss-newton", "starts": 8, "options": {"iterations": 30, "spp": 512}},
                            "gradient": {"method": "fd", "rounds": 16, "spp": 4096},
                        },
                    ],
                }
            ],
        }
    )["studies"][0]
    b = study.smoke({k: v for k, v in block.items() if k != "type"})
    assert b["theta"] == [[0.3, 0.3], [0.7, 0.7]] and b["n"] == 2 and b["n_eff"] == 32 and b["bootstrap"] == 20
    assert b["hcr_grid"] == 5 and b["levels"] == [8, 16]
    assert b["budget"] == {"iterations": 3, "renders": 10000, "seconds": None}
    assert b["estimators"][0]["options"] == {"num": 5, "spp": 4, "refine_evals": 4}
    assert b["estimators"][1]["options"] == {
        "base": "gauss-newton",
        "starts": 2,
        "options": {"iterations": 3, "spp": 4},
    }
    assert b["estimators"][1]["gradient"] == {"method": "fd", "rounds": 1, "spp": 4}
    assert block["n"] == 200 and block["estimators"][0]["options"]["num"] == 65  # a copy: the block is unchanged


def test_barankin_needs_a_scalar_theta(tmp_path):
    ctx, block = make_ctx(
        tmp_path,
        {"name": "blob2d"},
        {"theta": [[0.5, 0.5]], "n": 1, "bounds": ["barankin"], "estimators": [{"name": "mle-adam"}]},
    )
    with pytest.raises(ConfigError, match="barankin bounds a scalar θ"):
        study.run(ctx, block)


def test_resume_with_a_changed_config_is_refused(tmp_path, capsys):
    """The run folder's fingerprint (which folds in what the trials plan resolves, e.g. `auto` gradients)
    refuses a resume with another trial count, before anything is written."""
    import yaml

    from nlosbench.cli import main

    block = {
        "theta": [0.5],
        "n": 2,
        "n_eff": 1,
        "hcr_grid": 9,
        "estimators": [{"name": "grid-search", "options": {"num": 9, "spp": 1}}],
    }
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"scene": {"name": "edge1d"}, "executor": {"type": "serial"},
                                   "studies": [{"type": "trials", **block}]}))
    assert main(["run", str(cfg), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    before = (tmp_path / "run" / "config.yaml").read_bytes()
    assert main(["run", str(cfg), "--out", str(tmp_path / "run"), "--quiet", "--resume", "--set", "studies.0.n=3"]) == 2
    assert "studies[0].n = 2, this config has 3" in capsys.readouterr().err
    assert (tmp_path / "run" / "config.yaml").read_bytes() == before


def test_summary_statistics_against_hand_computed_values():
    """MSE, variance (ddof 1), bias and the ratio to a bound on three fixed estimates."""
    recs = [
        {
            "noise": 0,
            "theta_index": 0,
            "trial": k,
            "estimator": "e",
            "name": "e",
            "theta_true": [1.0],
            "theta_hat": [h],
            "error": None,
            "converged": k != 2,
            "seconds": 1.0,
            "renders": 10,
            "grad_passes": 0,
            "iterations": 3,
        }
        for k, h in enumerate([1.1, 0.8, 1.3])
    ]
    recs.append({**recs[0], "trial": 3, "theta_hat": None, "error": "boom", "converged": False})
    (row,) = summarize(recs, ["t"], {(0, 0): {"hcr": {"value": 0.01, "log10": -2.0}}}, far_above=2.0, bootstrap=200)
    e = np.array([0.1, -0.2, 0.3])
    assert row["n"] == 4 and row["n_failed"] == 1 and row["n_nonconverged"] == 1
    assert row["mse"] == pytest.approx((e**2).mean()) and row["var"] == pytest.approx(e.var(ddof=1))
    assert row["bias_t"] == pytest.approx(e.mean()) and row["mse_over_hcr"] == pytest.approx((e**2).mean() / 0.01)
    assert row["far_above"] == "hcr" and row["total_renders"] == 40 and row["mse_se"] > 0


def test_hcr_interval_from_spp_levels_is_compared(tmp_path):
    """edge1d with Monte Carlo-like rendering noise: HCR-hat (λ̂ fitted over two spp levels,
    bounds.inexact) lies above HCR_Neff, which rendering noise pulls down; both ratios are reported."""
    ctx, block = make_ctx(
        tmp_path,
        {"name": "edge1d", "options": {"render_noise": 0.3}},
        {
            "theta": [0.5078125],
            "n": 3,
            "n_eff": 2048,
            "bounds": ["hcr", "hcr_neff", "hcr_hat"],
            "levels": [512, 1536],
            "hcr_grid": 33,
            "hcr_offsets": 6,
            "fd_step": 1e-3,
            "estimators": [{"name": "grid-search", "options": {"num": 33, "spp": 256}}],
        },
        seed=4,
    )
    res = study.run(ctx, block)
    (b,) = res["bound_rows"]
    assert math.isfinite(b["log10_hcr_hat"]) and b["log10_hcr_hat"] > b["log10_hcr_neff"], b
    (row,) = res["summary"]
    assert row["mse_over_hcr_hat"] < row["mse_over_hcr_neff"]
    assert "HCR-hat" in study.report(ctx.dir / "trials", res)


def test_bias_test_p_value_is_uniform_without_bias_and_matches_the_verdict():
    """Zero-mean errors in 4 clean-image clusters of 3 trials (3 degrees of freedom): the two-sided p-value
    is uniform, so over 2000 data sets P(p < 0.05) = 0.05 (binomial SD 0.005; asserted within ±0.015) and
    P(p < 0.5) = 0.5 (±0.035); `biased` is exactly p < 0.05 (one parameter, level 0.95). A true bias of
    3 SE-of-the-mean is found far more often (measured 0.53 over 2000; asserted > 0.4 over 500)."""
    from nlosbench.montecarlo import bias_test

    rng = np.random.default_rng(7)
    clusters = np.repeat(np.arange(4), 3)
    ps, flags = [], []
    for _ in range(2000):
        r = bias_test(rng.normal(size=(12, 1)), clusters)
        ps.append(r["p"])
        flags.append(r["biased"])
        assert r["dof"] == 3 and r["biased"] == (r["p"] < 0.05)
    ps = np.array(ps)
    assert abs((ps < 0.05).mean() - 0.05) < 0.015 and abs((ps < 0.5).mean() - 0.5) < 0.035
    shifted = [bias_test(rng.normal(size=(12, 1)) + 3 / np.sqrt(12), clusters)["p"] < 0.05 for _ in range(500)]
    assert np.mean(shifted) > 0.4


def test_bias_test_holds_a_shared_offset_of_known_variance():
    """An estimator that reuses its renders in every fit shares their error as one offset of the run. 2000 runs of
    384 unit-variance errors in 16 clean-image clusters, each run shifted by one offset ~ N(0, v): without the
    offset in the SE the test calls zero-mean runs biased far too often (measured 0.35 at v = 0.01, 0.63 at 0.05);
    with `shared=v` P(p < 0.05) = 0.05 (measured 0.046, 0.051; binomial SD 0.005, asserted within ±0.015)."""
    from nlosbench.montecarlo import bias_test

    rng = np.random.default_rng(11)
    clusters = np.repeat(np.arange(16), 24)
    for v in (0.01, 0.05):
        plain, held = [], []
        for _ in range(2000):
            E = rng.normal(size=(384, 1)) + rng.normal(0.0, np.sqrt(v))
            plain.append(bias_test(E, clusters)["p"] < 0.05)
            held.append(bias_test(E, clusters, shared=np.array([v]))["p"] < 0.05)
        assert np.mean(plain) > 0.25 and abs(np.mean(held) - 0.05) < 0.015, (v, np.mean(plain), np.mean(held))


def test_grid_search_takes_its_grid_from_the_render_bank_once(tmp_path):
    """grid-search's grid comes from the run's render bank: a direct fit renders its own grid (9 renders); with the
    grid from a bank (replicate 0 of the bound service's sets) the fit renders only its refinement, and the bound
    grid asked for later shares those 9 renders. In a trials study whose grid-search grid is the bound grid (same
    θ, spp, seeds) the study renders nothing for it; at another spp it adds the grid once, never per fit."""
    from nlosbench.bank import RenderBank
    from nlosbench.bounds import BoundService
    from nlosbench.estimators import BankGrid, Problem

    model, noise = nb.scenes.get("edge1d", render_noise=0.05), nb.noise.AWGN(0.1)
    y = model.render([0.5], 64, 1)
    before = model.stats.renders
    estimators.get("grid-search", num=9, spp=4, refine_evals=3).fit(Problem(model, noise), y,
                                                                     rng=np.random.default_rng(0))
    alone = model.stats.renders - before
    svc = BoundService(RenderBank(model, seed=3), [noise])
    est = estimators.get("grid-search", num=9, spp=4, refine_evals=3)
    thetas, spp = est.grid_wanted(model.params)
    grid = BankGrid(thetas, svc.replicates(thetas, spp, "common", 1)[0], spp)
    assert svc.bank.renders == 9
    before = model.stats.renders
    est.fit(Problem(model, noise, grids=(grid,)), y, rng=np.random.default_rng(0))
    assert model.stats.renders - before == alone - 9 > 0  # the refinement only
    svc.replicates(thetas, spp, "common", 3)  # the bound grid: replicate 0 is the grid-search grid
    assert svc.bank.renders == 9 + 2 * 9

    def study_renders(gs_spp: int, sid: str) -> tuple[int, int]:
        ctx, block = make_ctx(tmp_path / sid, {"name": "edge1d", "options": {"render_noise": 0.05}}, {
            "theta": [0.5], "n": 3, "n_eff": 4, "truth_replicates": 1, "hcr_grid": 5, "bound_spp": 4, "replicates": 2,
            "bounds": [], "bootstrap": 5,
            "estimators": [{"name": "grid-search", "options": {"num": 5, "spp": gs_spp, "refine": False}}]})
        res = study.run(ctx, block)
        return res["bank_renders"], res["fit_renders"]

    assert study_renders(4, "shared") == (2 * 5 + 1, 0)  # bound grid (R × G) + the clean image; no fit renders
    assert study_renders(16, "own") == (2 * 5 + 1 + 5, 0)  # its own grid, once


def test_the_report_says_why_fits_stalled(tmp_path):
    """A fit that ends "stalled" is named with its own reason in the report's lines (up to 5 per estimator, then
    a count); converged fits and a missing log add nothing."""
    from nlosbench.records import RecordLog
    from nlosbench.studies.trials import _stalled

    log = RecordLog(tmp_path / "trials.jsonl")
    with log:
        for k in range(7):
            log.append({"noise": 0, "theta_index": 0, "trial": k, "estimator": "adam", "status": "stalled",
                        "reason": f"why {k}"})
        log.append({"noise": 0, "theta_index": 0, "trial": 7, "estimator": "gn", "status": "converged",
                    "reason": "fine"})
    lines = _stalled(tmp_path / "trials.jsonl")
    text = "\n".join(lines)
    assert "**adam** (7 stalled)" in text and "`why 4`" in text and "`why 5`" not in text and "2 more" in text
    assert "gn" not in text and "fine" not in text
    assert _stalled(tmp_path / "none.jsonl") == []
