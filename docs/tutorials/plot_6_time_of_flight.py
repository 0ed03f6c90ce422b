"""
What time of flight buys
========================

A pulsed laser scans a relay wall and a single-photon detector histograms the photons' arrival times. How
well does that histogram fix the depth of a hidden reflector, against the same scan summed over time, and
does a maximum-likelihood fit reach the bound? ``transient_point`` is the analytic toy of such a capture (a
point reflector behind the wall, confocal scan, Gaussian detector response, Poisson counts plus a
background): its Fisher information is in closed form, so every number here can be checked. The last
section renders a tiny real capture with mitransient where the ``transient`` extra is installed, and says so
where it is not.
"""

# %%
# The capture
# -----------
# θ = (x, y, depth, albedo): with ``free_albedo`` the reflector's albedo is a parameter too. The image is
# expected counts per bin, (scan_y, scan_x, T, 1): 4 × 4 scan points, 96 bins of 6 mm of optical path (20 ps),
# 30 ps detector jitter, 10⁵ signal photons per capture and 0.5 background counts per bin.
import importlib.util

import matplotlib.pyplot as plt
import numpy as np
import torch

import nlosbench as nb
from nlosbench.forward.analytic import TransientPoint

toy = TransientPoint(free_albedo=True)
theta = toy.params.default
L = toy.render(theta, spp=1, seed=0)
print(toy.params)
print("image", tuple(L.shape), f"{float(L.sum()):.4g} expected counts")
centres = 0.5 * (toy.edges[1:] + toy.edges[:-1])
fig, ax = plt.subplots(figsize=(6, 3))
for i, j in ((0, 0), (1, 2), (3, 3)):
    ax.step(centres, L[i, j, :, 0].numpy(), where="mid", label=f"scan point ({i}, {j})")
ax.set_xlabel("optical path d [m]")
ax.set_ylabel("expected counts per bin")
ax.legend()
fig.tight_layout()

# %%
# The depth bound: with and without timing, with the albedo known or not
# ------------------------------------------------------------------------
# ``fisher`` is the exact Fisher matrix (4 × 4). The depth's CRLB with x, y and the albedo known is 1 / F_dd;
# with the albedo unknown too it is (F⁻¹)_dd of the 2 × 2 matrix over (depth, albedo) — the nuisance parameter
# costs what the two share. ``summed=True`` is a detector without timing, counting each scan point's total.
# The time-of-flight study (``nuisance: [albedo]``) reports the same two numbers from renders.
idx = np.ix_([2, 3], [2, 3])
for jitter in (10.0, 30.0, 100.0):
    m = TransientPoint(free_albedo=True, jitter_ps=jitter)
    rows = []
    for summed in (False, True):
        F = m.fisher(theta, summed=summed)[idx]
        rows.append((1 / np.sqrt(F[0, 0]), np.sqrt(np.linalg.inv(F)[0, 0])))
    (tk, tu), (sk, su) = rows
    print(f"jitter {jitter:5.0f} ps: depth √CRLB transient {tk * 1e6:6.1f} µm (albedo unknown {tu * 1e6:6.1f}), "
          f"time-summed {sk * 1e3:6.3f} mm ({su * 1e3:7.3f}): time of flight buys ×{sk / tk:.0f} "
          f"(×{su / tu:.0f} with the albedo unknown)")

# %%
# A maximum-likelihood fit against the bound
# ------------------------------------------
# The MLE of the depth under Poisson counts: a grid search over Θ (101 depths, rendered once) then Brent's
# bounded search on the likelihood, from nothing but Θ (the estimators never see θ*). Over independent Poisson
# draws its MSE should approach the CRLB: n·MSE/CRLB is χ²_n for an efficient unbiased estimator, which gives
# the two-sided 95 % band printed below. The trials study does the same with verdicts
# (``tests/test_transient_mle.py`` runs it with Gauss–Newton and the backprojection localiser).
from scipy.stats import chi2  # noqa: E402

depth = toy.restrict(["depth"], {"x": theta[0], "y": theta[1], "albedo": theta[3]})
problem = nb.estimators.Problem(depth, nb.noise.Poisson(scale=1.0))
mle = nb.estimators.get("grid-search", num=101, spp=1, refine_spp=1)
mean = depth.render([theta[2]], spp=1, seed=0)
crlb = 1.0 / toy.fisher(theta)[2, 2]
n = 40
errors = []
for k in range(n):
    y = problem.noise.sample(mean, torch.Generator().manual_seed(nb.seeds.derive(0, "tutorial-tof", k)))
    est = mle.fit(problem, y, rng=np.random.default_rng(nb.seeds.derive(0, "tutorial-tof-fit", k)))
    errors.append(est.theta[0] - theta[2])
errors = np.array(errors)
lo, hi = chi2.ppf(0.025, n) / n, chi2.ppf(0.975, n) / n
print(f"{n} fits: RMSE {np.sqrt(np.mean(errors**2)) * 1e6:.1f} µm, bias {errors.mean() * 1e6:+.1f} µm, "
      f"√CRLB {np.sqrt(crlb) * 1e6:.1f} µm; MSE/CRLB = {np.mean(errors**2) / crlb:.2f} "
      f"(95 % band for an efficient estimator: [{lo:.2f}, {hi:.2f}])")

# %%
# A tiny transient render with mitransient
# ----------------------------------------
# ``transient_patch`` renders a 10 cm patch 0.75 m behind the wall with mitransient (the ``transient`` extra:
# ``pip install 'nlosbench[transient]'``). Here a 4 × 4 scan of 64 bins at 256 samples per scan point, seen
# through a detector of 30 ps jitter and 10⁴ photons per capture. Without the extra this section says why it
# is skipped and the tutorial still runs.
if importlib.util.find_spec("mitransient") is None:
    print("skipped: the transient extra (mitransient) is not installed — pip install 'nlosbench[transient]'")
else:
    from nlosbench.forward.detector import Detected, Detector

    patch = nb.scenes.get("transient_patch", scan=4, bins=64, bin_width=0.01, start=1.3)
    ref = patch.render(patch.params.default, spp=256, seed=0)
    w = patch.capture.bin_width
    det = Detector.for_budget(1e4, ref.numpy(), bin_width=w, start=patch.capture.start)
    det = Detector(bin_width=w, start=patch.capture.start, gain=det.gain, dark=0.01, jitter_ps=30.0)
    counts = Detected(patch, det).render(patch.params.default, spp=256, seed=0)
    print("mitransient capture", tuple(ref.shape), f"→ {float(counts.sum()):.4g} expected counts")
    edges = patch.capture.bin_edges()
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.step(0.5 * (edges[1:] + edges[:-1]), counts[1, 1].sum(axis=-1).numpy(), where="mid")
    ax.set_xlabel("optical path d [m]")
    ax.set_ylabel("expected counts per bin")
    ax.set_title("transient_patch, scan point (1, 1), 30 ps jitter")
    fig.tight_layout()
