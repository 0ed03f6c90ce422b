"""Estimators: the registry and entry-point plug-ins, the fit contract (budget, box, seeds), recovery of
θ* from noise-free data, and mle-adam on the real Mitsuba scene with FD and AD gradients."""
import importlib.metadata

import numpy as np
import pytest
import torch

import nlosbench as nb
from nlosbench import estimators
from nlosbench.estimators import Budget, Estimator, Outcome, Problem
from nlosbench.forward import GradientSettings
from nlosbench.seeds import derive


class ConstantEstimator(Estimator):
    """A plug-in for the entry-point test: returns the centre of Θ."""

    name = "constant"
    valid_when = "never (a test plug-in)"

    def __init__(self, shift: float = 0.0):
        self.shift = shift

    def _fit(self, problem, y, theta0, rng, tracker):
        c = 0.5 * (problem.params.lower + problem.params.upper) + self.shift
        tracker.record(0, 0.0, c)
        return Outcome(c, 1, True, "constant", 0.0)


@pytest.fixture
def plugin(monkeypatch):
    """An estimator installed through the `nlosbench.estimators` entry-point group."""
    ep = importlib.metadata.EntryPoint(name="constant", value=f"{__name__}:ConstantEstimator",
                                       group=estimators.ENTRY_POINT_GROUP)
    real = importlib.metadata.entry_points

    def fake(**kw):
        if kw.get("group") == estimators.ENTRY_POINT_GROUP:
            return importlib.metadata.EntryPoints([ep])
        return real(**kw)

    monkeypatch.setattr(importlib.metadata, "entry_points", fake)
    return ep


def _fit(name, model, y, init, seed=0, noise=None, grad="ad", budget=Budget(), **options):
    problem = Problem(model, noise or nb.noise.AWGN(0.02), GradientSettings(grad), seed=derive(seed, "problem"))
    return estimators.get(name, **options).fit(problem, y, init, np.random.default_rng(derive(seed, "fit")), budget)


def test_registry_lists_builtins_and_describes_validity():
    assert {"mle-adam", "grid-search", "gauss-newton", "multi-start"} <= set(estimators.available())
    desc = estimators.describe()
    assert all("Valid when:" in desc[n] for n in ("mle-adam", "grid-search", "gauss-newton", "multi-start"))


def test_entry_point_plugin_is_listed_built_and_fitted(plugin):
    assert "constant" in estimators.available()
    assert "test plug-in" in estimators.describe()["constant"]
    est = estimators.get("constant", shift=0.1)
    assert isinstance(est, ConstantEstimator) and est.shift == 0.1
    model = nb.scenes.get("edge1d")
    e = est.fit(Problem(model, nb.noise.AWGN(0.1)), model.render([0.3], 1, 0), None, np.random.default_rng(1))
    assert e.theta.tolist() == pytest.approx([0.6]) and e.converged and e.renders == 0


def test_cli_lists_estimators_with_the_plugin(plugin, capsys):
    from nlosbench import cli

    assert cli.main(["list", "estimators"]) == 0
    listed = {line.split()[0].rstrip(":") for line in capsys.readouterr().out.splitlines() if line.strip()}
    assert {"constant", "mle-adam", "grid-search", "gauss-newton", "multi-start"} <= listed


def test_broken_plugin_names_its_entry_point(monkeypatch):
    ep = importlib.metadata.EntryPoint(
        name="broken", value="no_such_module_xyz:Thing", group=estimators.ENTRY_POINT_GROUP
    )
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda **kw: importlib.metadata.EntryPoints([ep]))
    with pytest.raises(ImportError, match="broken.*no_such_module_xyz"):
        estimators.get("broken")


@pytest.mark.parametrize(
    "call, err, msg",
    [
        (lambda: estimators.get("mle-adamm"), KeyError, "did you mean 'mle-adam'"),
        (lambda: estimators.get("mle-adam", learning_rate=0.1), ValueError, "bad options"),
        (lambda: estimators.get("mle-adam", lr_schedule="linear"), ValueError, "lr_schedule"),
        (lambda: estimators.get("mle-adam", spp=[[0.5, 64]]), ValueError, "start at fraction 0"),
        (lambda: estimators.get("grid-search", num=1), ValueError, "num >= 2"),
        (lambda: estimators.get("multi-start", base="multi-start"), ValueError, "another estimator"),
        (lambda: Budget(renders=0), ValueError, "renders must be > 0"),
    ],
)
def test_bad_options(call, err, msg):
    with pytest.raises(err, match=msg):
        call()


def test_fit_needs_a_seeded_generator_and_a_start_inside_theta():
    model = nb.scenes.get("edge1d")
    est, problem, y = estimators.get("mle-adam"), Problem(model, nb.noise.AWGN(0.1)), model.render([0.5], 1, 0)
    with pytest.raises(TypeError, match="numpy Generator"):
        est.fit(problem, y, [0.5], rng=None)
    with pytest.raises(ValueError, match="outside"):
        est.fit(problem, y, [0.95], np.random.default_rng(0))


@pytest.mark.parametrize(
    "name, options",
    [
        ("mle-adam", {}),
        ("gauss-newton", {}),
        ("grid-search", {"num": 31, "spp": 1}),
        ("multi-start", {"base": "gauss-newton", "starts": 3}),
    ],
)
def test_noise_free_data_recovers_theta(name, options):
    """y = L_θ* exactly (blob2d): the NLL's minimum is θ*, so every estimator must land on it."""
    model = nb.scenes.get("blob2d", width=0.15)
    truth = np.array([0.43, 0.61])
    e = _fit(name, model, model.render(truth, 1, 0), [0.6, 0.4], **options)
    assert np.abs(e.theta - truth).max() < 2e-4, (e.theta, e.reason)
    assert e.converged, e.reason
    assert e.init.tolist() == [0.6, 0.4] and e.trace
    assert e.renders + e.grad_passes > 0 and e.seconds > 0


def test_grid_search_finds_the_global_optimum_of_a_hard_edge_where_gauss_newton_sticks():
    """edge1d: the Jacobian is non-zero on one pixel only, so a local method from a far start stalls;
    the profile likelihood over the grid does not care."""
    model = nb.scenes.get("edge1d")
    truth, start = 0.6, [0.2]
    y = model.render([truth], 1, 0)
    grid = _fit("grid-search", model, y, start, num=65, spp=1)
    gn = _fit("gauss-newton", model, y, start)
    assert abs(grid.theta[0] - truth) < 1e-4
    assert abs(gn.theta[0] - truth) > 0.1


def test_grid_renders_are_cached_across_fits():
    model = nb.scenes.get("edge1d")
    est = estimators.get("grid-search", num=17, spp=1, refine=False)
    problem = Problem(model, nb.noise.AWGN(0.1), seed=5)
    first = est.fit(problem, model.render([0.3], 1, 0), None, np.random.default_rng(0))
    second = est.fit(problem, model.render([0.7], 1, 0), None, np.random.default_rng(1))
    assert first.renders == 17 and second.renders == 0
    assert second.theta[0] == pytest.approx(0.7)


def test_box_constraints_hold_when_theta_star_sits_on_the_bound():
    model = nb.scenes.get("blob2d", width=0.15)
    truth = np.array([0.8, 0.5])  # x at Θ's upper bound: the unconstrained optimum may lie outside
    noise = nb.noise.AWGN(0.05)
    y = noise.sample(model.render(truth, 1, 0), torch.Generator().manual_seed(derive(1, "noise")))
    for name in ("mle-adam", "gauss-newton"):
        e = _fit(name, model, y, [0.3, 0.3], noise=noise)
        pts = np.array([t["theta"] for t in e.trace] + [e.theta])
        assert ((pts >= model.params.lower) & (pts <= model.params.upper)).all(), name
        assert abs(e.theta[0] - 0.8) < 0.01, (name, e.theta)


def test_render_budget_stops_the_fit_and_is_reported():
    model = nb.scenes.get("blob2d", width=0.15)
    # FD: 1 + 2P = 5 renders per iteration; a budget of 23 allows 5 iterations (checked before each)
    e = _fit("mle-adam", model, model.render([0.5, 0.5], 1, 0), [0.3, 0.3], grad="fd", budget=Budget(renders=23))
    assert not e.converged and "render budget" in e.reason
    assert e.iterations == 5 and e.renders == 25


def test_same_seed_same_estimate_other_seed_other_start():
    model = nb.scenes.get("blob2d", width=0.15, render_noise=0.05)  # Monte Carlo-like rendering noise
    y = model.render([0.5, 0.5], 64, 1)
    a = _fit("mle-adam", model, y, None, seed=3, iterations=20)
    b = _fit("mle-adam", model, y, None, seed=3, iterations=20)
    c = _fit("mle-adam", model, y, None, seed=4, iterations=20)
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.init, b.init)
    assert not np.array_equal(a.init, c.init)


def test_poisson_nll_fit():
    model = nb.scenes.get("blob2d", width=0.15)
    noise = nb.noise.Poisson(scale=2000.0)
    truth = np.array([0.55, 0.45])
    y = noise.sample(model.render(truth, 1, 0), torch.Generator().manual_seed(derive(2, "noise")))
    e = _fit("mle-adam", model, y, [0.35, 0.65], noise=noise)
    assert np.isfinite(e.final_loss) and np.abs(e.theta - truth).max() < 0.01


def test_adam_spp_and_lr_schedules():
    est = estimators.get("mle-adam", lr=0.05, spp=[[0, 512], [0.5, 1024]], lr_final=0.01)
    assert [est.spp_at(k, 10) for k in (0, 4, 5, 9)] == [512, 512, 1024, 1024]
    assert est.lr_factor(0, 10) == 1.0 and est.lr_factor(9, 10) == pytest.approx(0.01)
    assert estimators.get("mle-adam", lr_schedule="exponential", lr_final=0.01).lr_factor(9, 10) == pytest.approx(0.01)
    auto = estimators.get("mle-adam")  # lr "auto": a constant schedule (the step follows F̂) and AUTO_SPP
    assert auto.lr_factor(9, 10) == 1.0 and auto.spp_at(9, 10) == estimators.mle_adam.AUTO_SPP


# -- the real Mitsuba scene --------------------------------------------------------------------------
def _cornell_case(cornell, name: str, truth: float, seed: int):
    """A noisy 32×32 observation of cornell_ball with θ = `name` only, and a random start far from θ*."""
    model = cornell.restrict([name])
    noise = nb.noise.AWGN(0.05)
    clean = model.render([truth], 128, derive(seed, "clean"))
    y = noise.sample(clean, torch.Generator().manual_seed(derive(seed, "noise")))
    p = model.params
    rng = np.random.default_rng(derive(seed, "start"))
    # uniform in the part of Θ at least 40 % of its width away from θ*
    far = [(lo, truth - 0.4 * (p.upper[0] - p.lower[0])) for lo in p.lower] + [
        (truth + 0.4 * (p.upper[0] - p.lower[0]), hi) for hi in p.upper
    ]
    lo, hi = max(far, key=lambda ab: ab[1] - ab[0])
    return model, noise, y, np.array([rng.uniform(lo, hi)])


def test_cornell_mle_adam_fd_reduces_the_error_of_the_ball_position(cornell):
    """FD gradients (central, common random numbers) through the visibility change of a moving ball."""
    model, noise, y, start = _cornell_case(cornell, "ball_x", 0.1, seed=11)
    problem = Problem(model, noise, GradientSettings("fd", step=0.02), seed=1)
    e = estimators.get("mle-adam", lr=0.1, iterations=10, spp=16).fit(problem, y, start, np.random.default_rng(2))
    assert abs(e.theta[0] - 0.1) < 0.15 * abs(start[0] - 0.1), (start, e.theta)
    assert e.renders == 10 * 3 and e.grad_passes == 0


def test_cornell_mle_adam_ad_reduces_the_error_of_the_ball_colour(cornell):
    """Mitsuba AD (prb) on the ball's red reflectance, where prb is exact. (For the ball's position
    plain prb ignores the visibility term — its gradient points the wrong way — and the projective
    integrators cost ~10–30 s per pass on 2 CPU cores, so the AD check uses the colour.)"""
    model, noise, y, start = _cornell_case(cornell, "ball_red", 0.8, seed=12)
    problem = Problem(model, noise, GradientSettings("ad", ad={"type": "prb"}), seed=1)
    e = estimators.get("mle-adam", lr=0.15, iterations=8, spp=8).fit(problem, y, start, np.random.default_rng(3))
    assert e.grad_passes == 8 and e.renders == 8
    assert abs(e.theta[0] - 0.8) < 0.1 * abs(start[0] - 0.8), (start, e.theta)


def test_reduced_benchmark_rows():
    """The benchmark in reduced mode (toys only): every estimator ran without failures and the CRN +
    single-load recipe reached the paper recipe's final error."""
    from nlosbench.benchmarks import estimators as bench

    rows = bench.run(reduced=True)
    per = [r for r in rows if r["bench"] == "per-trial"]
    assert {r["scene"] for r in per} == {"blob2d", "edge1d"} and all(r["failed"] == 0 for r in per)
    assert all(r["seconds"] > 0 and r["renders"] + r["ad_passes"] > 0 for r in per)
    (recipe,) = [r for r in rows if r["bench"] == "paper-recipe"]
    assert recipe["reached"] and recipe["renders_ratio"] > 1, recipe
