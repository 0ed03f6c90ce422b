"""The bound service: every bound at θ*, and bound curves over a grid, from the run's render bank.

Studies and the trials summary ask here; nothing else assembles bounds. The service plans the render
sets a bound needs (through the bank, which derives their seeds), computes the bounds with the functions
of this package and returns one result type, `Bound`, per (noise model, θ, kind), grouped in BoundPoints.

Render sets. Every θ the service uses (θ*, test points θ* + Δ, FD stencils θ* ± ξ) is rendered in R
independent replicates (purpose "bounds", replicate r = 0 … R−1). `seeds="common"` gives every θ of a
replicate the same seed (common random numbers across θ: differences L(θ+Δ) − L(θ) carry far less
rendering noise); "independent" a seed per θ. A curve renders each grid θ R times and serves every θ* and
every Δ from them (R·G renders, not G²); the FD stencils of the Δ → 0 term are the grid neighbours (no
extra render). Bounds at θ* reuse the same sets, so a θ* on a curve's grid costs no new render.

Kinds (parameter units²; `Bound.log10` is the value to quote):
  hcr       the HCR on the MSE as a confidence interval with its Δ → 0 term, the CRLB term (`hcr_interval`):
            log10 = the lower end (a one-sided lower confidence limit at `level`), `upper` the upper end (+inf:
            open, whenever a tested Δ is unresolved), `point` the estimate, `terms` which term set each end.
            λ(Δ) and F are U-statistics over the R replicates (`ustat`): unbiased, so rendering noise no longer
            inflates λ (the C/N term) or F;
  crlb      the CRLB from the unbiased Fisher information (trace of F̂⁻¹; 1/F̂ for a scalar θ): log10 the
            central value (+inf when F̂ ≤ 0: no resolved information), `lower`/`upper` its ends (from the
            largest upper / smallest lower confidence limit of F over the FD steps tried). F is the FI of the
            FD-smoothed derivative, biased low where an edge crosses a pixel within the step: `at` and `fisher`
            halve the step until F is shown to have stopped rising (`fd_step`), `curve` checks h against 2h;
            a lower end whose step did not converge carries `lower_note` "not a confidence limit: …";
  hcr_neff  the paper's HCR_Neff: the plug-in λ̃ of the replicate means (R·spp samples per image), sup
            over the tested Δ only (no Δ → 0 term, so it can fall far below the CRLB: the paper's 80 cm row);
  hcr_hat   the paper's HCR-hat (bias-corrected λ̂ from a fit over spp levels), point estimate: an upper bound
            in expectation on the HCR restricted to the tested Δ (not on the HCR over every Δ);
  barankin  multi-point Barankin bound on Var θ̂ of a scalar θ from the replicate means (plug-in);
  zzb       (curves on a uniform grid) the Ziv–Zakai bound on the Bayesian MSE over the prior on the grid's
            range, for every estimator (`zzb`): log10 the lower end (the bound to quote: P_e is convex in the
            distance, so the point errs either way), with `upper`, `point`; for Poisson noise the Bhattacharyya
            distance is an upper estimate (`zzb.bhattacharyya_ustat`) whose weight comes from R weight renders,
            one per replicate set, so the ends carry the weight's noise too.

Poisson weights scale/L come from one render of each θ independent of every replicate (purpose
"bounds-weight", spp samples): a weight computed from the same replicates as a U-statistic would correlate
with it (E[1/L̄] > 1/L enters as a cross term). E[1/Y] ≥ 1/L, so the weight errs high by about Var(Y)/L²
(stated, not corrected). The *zero-pixel policy*: a pixel whose weight render is exactly 0 (no sample found
light) gets the weight of the smallest positive value in that image instead of +inf, and the count of such
pixels is in the flags (never a silent −inf or a dropped Δ).
"""
from __future__ import annotations

from nlosbench.bounds.service.at import AtTheta, axis_offsets
from nlosbench.bounds.service.curve import QUOTE_TEST_GRID, Curves, quote_test_grid
from nlosbench.bounds.service.fisher import FisherInformation, cameras_crlb
from nlosbench.bounds.service.interval import PaperIntervals, interval_points
from nlosbench.bounds.service.points import Bound, BoundPoint, Curve, FisherPoint, crlb_bound, hcr_bound, interval_bound
from nlosbench.bounds.service.renders import PURPOSE, SEEDS, poisson_weight_image


class BoundService(Curves, AtTheta, FisherInformation, PaperIntervals):
    """Bounds from a render bank for a set of noise models (see the module docstring).

    Parameters
    ----------
    bank : RenderBank
        The run's render bank (`nlosbench.RenderBank`): it renders, caches and seeds every render set, and
        its model's parameter space Θ bounds every Δ.
    noises : dict of int to NoiseModel, or sequence of NoiseModel
        The noise models (index → model; a list is indexed 0, 1, …). Bounds from replicated renders need
        quadratic models (AWGN, Poisson).
    level : float, optional
        One-sided confidence of every interval end, in (0, 1).

    See Also
    --------
    nlosbench.bound : One bound at one θ* from a scene's name, with stated defaults.

    Examples
    --------
    >>> bank = nb.RenderBank(nb.scenes.get("edge1d"), seed=0)
    >>> service = nb.bounds.BoundService(bank, [nb.noise.AWGN(sigma=0.05)])
    >>> [point] = service.at([0.5], spp=4)
    >>> sorted(point.bounds)
    ['crlb', 'hcr', 'hcr_neff']
    >>> crlb = point.bounds["crlb"]
    >>> crlb.lower <= crlb.point <= crlb.upper
    True
    """


__all__ = ["PURPOSE", "QUOTE_TEST_GRID", "SEEDS", "Bound", "BoundPoint", "BoundService", "Curve", "FisherPoint",
           "axis_offsets", "cameras_crlb", "crlb_bound", "hcr_bound", "interval_bound", "interval_points",
           "poisson_weight_image", "quote_test_grid"]
