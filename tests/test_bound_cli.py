"""`nlosbench bound` and `nb.bound`: one HCR interval and CRLB at one θ*, in one line, on the analytic toys."""
import math
import re

import pytest

import nlosbench as nb
from nlosbench.cli import main


def exact_crlb(sigma: float, at: float) -> float:
    """blob2d's CRLB on x at (at, 0.5) for AWGN σ: 1 / Σ (∂L/∂x)² · σ², from its exact derivative."""
    J = nb.scenes.get("blob2d").jvp([at, 0.5], 0).double()
    return sigma**2 / float((J**2).sum())


def test_the_line_brackets_the_exact_crlb_and_states_its_settings(capsys):
    assert main(["bound", "blob2d", "--param", "x", "--at", "0.4", "--sigma", "0.05", "--spp", "4"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    b = nb.bound("blob2d", "x", 0.4, nb.noise.AWGN(sigma=0.05), spp=4)  # the same bound, as numbers
    crlb, hcr = b.point.bounds["crlb"], b.point.bounds["hcr"]
    exact = math.log10(exact_crlb(0.05, 0.4))
    assert crlb.lower - 1e-3 <= exact <= crlb.upper + 1e-3  # float32 renders: 0.2 % in F
    assert hcr.lower <= crlb.upper and not hcr.lower_note  # HCR ≥ CRLB in truth; a settled step: a confidence limit
    assert f"HCR [{10**hcr.lower:.3g}, {10**hcr.upper:.3g}] m²" in out
    assert "4 spp × 3 replicate sets" in out and "FD step ξ = 0.006 m" in out and "settled" in out
    assert f"{b.renders} renders" in out and b.renders > 0


def test_an_unsettled_step_says_what_would_settle_it():
    b = nb.bound("blob2d", "x", 0.5, nb.noise.AWGN(sigma=0.05), spp=16, fd_step=0.05, max_halvings=1,
                 options={"render_noise": 0.2})
    line = b.line()
    assert b.point.bounds["hcr"].lower_note.startswith("not a confidence limit")
    assert "lower end not a confidence limit" in line and "--max-halvings 2 (ξ down to 0.0125 m)" in line


def test_a_precision_target_reports_what_it_reached():
    b = nb.bound("blob2d", "x", 0.5, nb.noise.AWGN(sigma=0.05), spp=4, precision=0.1)
    assert b.point.precision.met and "precision ±0.1 met" in b.line()


def test_a_target_without_a_budget_is_capped_at_the_default_ceiling_and_says_what_more_would_cost(capsys):
    """`nlosbench bound --precision` without `--budget`, a target not met at 4 spp (±0.001 %; ±0.1 % is met, measured
    ±0.053 %, at a step finer than the pilot's): the line says it was not met, having spent more than the pilot and
    at most the pixel-samples allowed, CEILING × the pilot's (the pilot measured alone with --budget 1), and what
    finishing would take."""
    from nlosbench.bounds.precision import CEILING

    argv = ["bound", "blob2d", "--param", "x", "--at", "0.5", "--sigma", "0.05", "--spp", "4", "--precision", "0.00001"]
    assert main([*argv, "--budget", "1"]) == 0
    pilot = float(re.search(r"after (\S+) of the 1 pixel-samples", capsys.readouterr().out).group(1))
    assert main(argv) == 0
    line = capsys.readouterr().out
    spent, allowed = (float(v) for v in re.search(r"not met \(reached ±\S+\) after (\S+) of the (\S+) "
                                                  r"pixel-samples allowed", line).groups())
    assert pilot < spent <= allowed == pytest.approx(CEILING * pilot, rel=1e-2)  # 3 digits printed
    assert "more pixel-samples (--budget)" in line or "no number of further replicate sets" in line


def test_the_others_are_held_where_fix_says():
    a = nb.bound("blob2d", "x", 0.5, nb.noise.AWGN(sigma=0.05), spp=4, fixed={"y": 0.3})
    assert a.point.bounds["crlb"].log10 == pytest.approx(math.log10(exact_crlb(0.05, 0.5)), abs=1e-3)  # y: no effect
    assert "Poisson, scale = 100" in nb.bound("edge1d", "edge", 0.5, nb.noise.Poisson(scale=100.0), spp=4).line()


def test_a_one_parameter_scene_needs_no_param_and_at_defaults_to_its_default(capsys):
    assert main(["bound", "edge1d", "--sigma", "0.1", "--spp", "4"]) == 0
    assert capsys.readouterr().out.startswith("edge1d: edge = 0.5 m, AWGN, σ = 0.1; HCR [")  # its default: 0.5


@pytest.mark.parametrize("argv, key", [
    (["blob2d", "--sigma", "0.1"], "--param: blob2d has parameters x, y"),
    (["blob2d", "--param", "z", "--sigma", "0.1"], "--param: 'z' is not a parameter of blob2d"),
    (["blob2d", "--param", "x", "--at", "2", "--sigma", "0.1"], "--at: x = 2 is outside Θ = [0.2, 0.8] m"),
    (["blob2d", "--param", "x", "--sigma", "-1"], "--sigma: AWGN sigma must be finite and > 0"),
    (["blob2d", "--param", "x", "--sigma", "1", "--scale", "2"], "give exactly one of --sigma"),
    (["blob2d", "--param", "x", "--sigma", "1", "--replicates", "2"], "--replicates: got 2, expected at least 3"),
    (["blob2d", "--param", "x", "--sigma", "1", "--fix", "x=0.3"], "--fix: 'x' is the parameter bounded"),
    (["blob2d", "--param", "x", "--sigma", "1", "--budget", "1e6"], "--budget: a budget goes with --precision"),
    (["blob2d", "--param", "x", "--noise", "nope"], "--noise: unknown noise model 'nope'"),
])
def test_bad_input_is_one_line_and_exit_2(argv, key, capsys):
    assert main(["bound", *argv]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and key in err
