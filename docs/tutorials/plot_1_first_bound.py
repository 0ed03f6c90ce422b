"""
A first bound
=============

How well can the position of a Gaussian spot be estimated from one noisy image? ``blob2d`` is an
analytic toy (a spot at θ = (x, y) metres on a 24 × 24 image, exact renders), so its Cramér–Rao bound
has a closed form to check the renderer-backed numbers against.
"""

# %%
# The model and its parameters
# ----------------------------
# A forward model renders the mean image L(θ) (H, W, C) in radiance units. We study x alone; y stays at
# its default.
import matplotlib.pyplot as plt
import numpy as np
import torch

import nlosbench as nb

model = nb.scenes.get("blob2d").restrict(["x"])
print(model.params)
L0 = model.render([0.5], spp=1, seed=0)
print("image", tuple(L0.shape), L0.dtype)


def crlb_exact(theta: float, sigma: float) -> float:
    """AWGN: 1 / F with F = ‖∂L/∂x‖² / σ², differentiated exactly by torch (m²)."""
    full, y = nb.scenes.get("blob2d"), torch.tensor(0.5, dtype=torch.float64)
    J = torch.autograd.functional.jacobian(lambda v: full.clean(torch.stack([v, y])),
                                           torch.tensor(theta, dtype=torch.float64))
    return float(sigma**2 / (J**2).sum())


# %%
# The HCR is a sup over test offsets Δ
# ------------------------------------
# For every Δ the Hammersley–Chapman–Robbins functional Δ² / (exp(λ(Δ)) − 1) bounds the variance of an
# unbiased estimator; the HCR is its sup over Δ with θ* + Δ in Θ = [0.2, 0.8] m. As Δ → 0 the functional
# tends to the CRLB. With little noise the sup sits there; with much noise a large Δ sets it, and the
# HCR exceeds the CRLB (the threshold effect).
deltas = np.geomspace(1e-4, 0.3, 60)
L_alt = torch.stack([model.render([0.5 + d], spp=1, seed=0) for d in deltas])
fig, ax = plt.subplots(figsize=(6, 3.5))
for sigma in (0.5, 2.0, 5.0):
    b = nb.bounds.hcr(L0, L_alt, deltas, nb.noise.AWGN(sigma=sigma), lower=-0.3, upper=0.3)
    crlb = crlb_exact(0.5, sigma)
    ax.plot(deltas, b.functional - np.log10(crlb), label=f"σ = {sigma:g}")
    print(f"σ = {sigma:g}: HCR 10^{b.log10:.3f} m² at Δ = {float(b.delta):.3g} m; CRLB 10^{np.log10(crlb):.3f} m²")
ax.axhline(0, color="k", ls=":", label="CRLB")
ax.set_xscale("log")
ax.set_ylim(-2, 0.6)  # at σ = 0.5 the functional falls 35 decades by Δ = 0.3 m
ax.set_xlabel("Δ [m]")
ax.set_ylabel("log10 of Δ²/(exp λ − 1) over the CRLB")
ax.set_title("blob2d, x at θ* = 0.5 m, AWGN")
ax.legend()
fig.tight_layout()

# %%
# Bounds over a grid of θ, from a render bank
# -------------------------------------------
# In practice renders are Monte Carlo estimates and many θ* are wanted at once. The render bank makes
# every render once (seeds derived from its seed); the bound service computes every bound at each grid
# point from R·G renders: the HCR interval, whose sup includes the Δ → 0 term, and the CRLB, both with
# one-sided confidence ends over R replicate render sets (log10 of m²).
noise = nb.noise.AWGN(sigma=5.0)
bank = nb.RenderBank(model, seed=0)
curve = nb.bounds.BoundService(bank, [noise]).curve(np.linspace(0.2, 0.8, 31), spp=1, replicates=3)
p = curve.points[15]
print(f"{bank.renders} renders; at θ* = {p.theta[0]:.2f} m: HCR 10^{p.bounds['hcr'].log10:.3f} m² "
      f"(flags: {', '.join(p.bounds['hcr'].flags) or 'none'}), CRLB 10^{p.bounds['crlb'].log10:.3f} m², "
      f"closed form 10^{np.log10(crlb_exact(0.5, 5.0)):.3f} m²")

# %%
# The HCR matches the sup over the fine Δ above: at σ = 5 it is set by the largest Δ inside Θ. The CRLB
# from renders uses FD over the grid's 2 cm neighbours, an FD-smoothed derivative, so it sits a little
# above the closed form. Next: :doc:`plot_2_own_scene`.
