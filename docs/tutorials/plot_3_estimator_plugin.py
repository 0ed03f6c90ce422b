"""
An estimator of your own
========================

An estimator is a class with a ``fit(problem, y, init, rng, budget)`` method. Subclass
:class:`nlosbench.estimators.Estimator`, implement ``_fit``, register it, and every study, the CLI and
the Monte Carlo machinery can use it by name; the base class validates the inputs, draws a start when none
is given, enforces the budget and counts renders and seconds the same way for every estimator.
"""

# %%
# A golden-section search
# -----------------------
# A derivative-free estimator for a scalar θ: shrink a bracket over Θ by the golden ratio, comparing the
# negative log-likelihood of the observation at two renders per step. ``problem.nll`` applies the
# noise model; the renders of one fit share a seed drawn from the fit's generator, so the objective is
# deterministic during the search.
import math

import matplotlib.pyplot as plt
import numpy as np
import torch

import nlosbench as nb
from nlosbench.estimators import Estimator, Outcome


class GoldenSection(Estimator):
    """Golden-section search of the NLL over Θ for a scalar θ (no gradient)."""

    name = "golden"
    valid_when = "A scalar θ whose likelihood has one minimum over Θ."

    def __init__(self, spp: int = 1, tol: float = 1e-5, iterations: int = 60):
        self.spp, self.tol, self.iterations = int(spp), float(tol), int(iterations)

    def _fit(self, problem, y, theta0, rng, tracker):
        seed = int(rng.integers(0, 2**32))

        def loss(t: float) -> float:
            return float(problem.nll(y, problem.model.render([t], self.spp, seed)))

        g = (math.sqrt(5) - 1) / 2
        a, b = float(problem.params.lower[0]), float(problem.params.upper[0])
        for k in range(tracker.budget.cap(self.iterations)):
            if tracker.exhausted():
                return Outcome(np.array([(a + b) / 2]), k, "budget", tracker.exhausted(), loss((a + b) / 2))
            c, d = b - g * (b - a), a + g * (b - a)
            fc, fd = loss(c), loss(d)
            a, b = (a, d) if fc < fd else (c, b)
            tracker.record(k, min(fc, fd), np.array([(a + b) / 2]))
            if b - a < self.tol:
                return Outcome(np.array([(a + b) / 2]), k + 1, "converged", f"bracket < {self.tol:g}",
                               min(fc, fd))
        return Outcome(np.array([(a + b) / 2]), self.iterations, "max-iterations", "iteration cap", min(fc, fd))


nb.estimators.register("golden", GoldenSection)
print(nb.estimators.describe()["golden"])

# %%
# Monte Carlo trials against the bound
# ------------------------------------
# On ``blob2d``'s x at θ* = 0.5 m with AWGN σ = 0.05: fresh noise per trial on the clean image, one fit
# each. An unbiased estimator cannot beat the CRLB; we compare the MSE with it, with the standard error
# of the MSE over the trials.
model = nb.scenes.get("blob2d").restrict(["x"])
noise = nb.noise.AWGN(sigma=0.05)
problem = nb.estimators.Problem(model, noise)
est = nb.estimators.get("golden", spp=1)
truth = model.render([0.5], spp=1, seed=0)
gen = torch.Generator().manual_seed(1)
fits = [est.fit(problem, noise.sample(truth, gen), rng=np.random.default_rng(k)) for k in range(40)]
err2 = np.array([(f.theta[0] - 0.5) ** 2 for f in fits])
mse, se = err2.mean(), err2.std(ddof=1) / math.sqrt(len(err2))

bank = nb.RenderBank(model, seed=0)
crlb = nb.bounds.BoundService(bank, [noise]).curve([0.48, 0.49, 0.5, 0.51, 0.52], spp=1).points[2]
crlb = crlb.bounds["crlb"].value
print(f"40 trials: MSE {mse:.3g} ± {se:.2g} m², CRLB {crlb:.3g} m², MSE / CRLB = {mse / crlb:.2f}; "
      f"{np.mean([f.renders for f in fits]):.0f} renders and {np.mean([f.seconds for f in fits]):.3f} s per fit; "
      f"status: {sorted({f.status for f in fits})}")

fig, ax = plt.subplots(figsize=(6, 3.2))
ax.hist([f.theta[0] for f in fits], bins=15)
ax.axvline(0.5, color="k", ls=":", label="θ* = 0.5 m")
ax.set_xlabel("θ̂ [m]")
ax.set_ylabel("trials")
ax.set_title("golden-section fits, blob2d x, AWGN σ = 0.05")
ax.legend()
fig.tight_layout()

# %%
# Packaging it
# ------------
# In a package of your own, register the class through the entry-point group ``nlosbench.estimators``
# (``pyproject.toml``)::
#
#     [project.entry-points."nlosbench.estimators"]
#     golden = "mypackage.golden:GoldenSection"
#
# Then ``nlosbench list estimators`` shows it and a config's ``trials`` study uses it:
# ``estimators: [{name: golden, options: {spp: 64}}]``.
