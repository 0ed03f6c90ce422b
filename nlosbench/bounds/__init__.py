"""Information bounds from renders: HCR (single offsets and grid curves), CRLB, Barankin, Ziv–Zakai,
per-pixel Fisher information maps (and pooled into resolved cells), HCR intervals from inexact renders, and
the bound service (`service`) that studies ask for every bound at θ* and bound curves.

`__all__` is the public API: the bound functions and the result types they return. Helpers the package
uses internally (e.g. `check_levels`, `replicate_grams`, `fit_lambda`, `half_sample_lambda`,
`pixel_variances`, `crlb_from_hcr_limit`, `crlb_log10`, `hcr_curve_from_lambda`) stay importable from here
and from their submodules, but are not part of the documented API and may change between releases.
"""
# `from m import name as name`: an internal helper re-exported for existing imports, not in `__all__`
from nlosbench.bounds.barankin import BarankinResult, barankin
from nlosbench.bounds.crlb import CRLBResult, crlb, fisher_matrix
from nlosbench.bounds.crlb import crlb_from_hcr_limit as crlb_from_hcr_limit
from nlosbench.bounds.crlb import crlb_log10 as crlb_log10
from nlosbench.bounds.decay import DecayResult, decay_check
from nlosbench.bounds.decay import pixel_variances as pixel_variances
from nlosbench.bounds.fisher_maps import fisher_maps, save_fisher_maps
from nlosbench.bounds.grid import HCRCurve, hcr_curve, pairwise_lambda
from nlosbench.bounds.grid import hcr_curve_from_lambda as hcr_curve_from_lambda
from nlosbench.bounds.hcr import HCRResult, hcr, hcr_from_lambda
from nlosbench.bounds.hcr_interval import HCRInterval, hcr_interval
from nlosbench.bounds.inexact import InexactHCR, LambdaFit, inexact_hcr
from nlosbench.bounds.inexact import check_levels as check_levels
from nlosbench.bounds.inexact import fit_lambda as fit_lambda
from nlosbench.bounds.inexact import half_sample_lambda as half_sample_lambda
from nlosbench.bounds.inexact import replicate_grams as replicate_grams
from nlosbench.bounds.pooling import PooledFisherMap, pool_fisher_map
from nlosbench.bounds.service import Bound, BoundPoint, BoundService, Curve, FisherPoint, cameras_crlb
from nlosbench.bounds.unbiased_fisher import UnbiasedFisher, unbiased_fisher
from nlosbench.bounds.ustat import UStat, pairwise_ustat, u_statistic
from nlosbench.bounds.zzb import ZZBInterval, ZZBResult, ziv_zakai, zzb_interval

__all__ = [
    # bounds at θ* from exact renders
    "hcr", "hcr_from_lambda", "HCRResult", "crlb", "fisher_matrix", "CRLBResult", "barankin", "BarankinResult",
    # curves over a parameter grid, and the Ziv–Zakai bound
    "pairwise_lambda", "hcr_curve", "HCRCurve", "ziv_zakai", "ZZBResult",
    # Fisher information per pixel
    "fisher_maps", "save_fisher_maps", "pool_fisher_map", "PooledFisherMap",
    # bounds from Monte Carlo renders: U-statistics, unbiased Fisher information, intervals
    "u_statistic", "pairwise_ustat", "UStat", "unbiased_fisher", "UnbiasedFisher", "hcr_interval", "HCRInterval",
    "zzb_interval", "ZZBInterval",
    # the paper's HCR_Neff / HCR-hat from inexact renders, and the rendering-noise decay check
    "inexact_hcr", "InexactHCR", "LambdaFit", "decay_check", "DecayResult",
    # the bound service studies use
    "BoundService", "Bound", "BoundPoint", "Curve", "FisherPoint",
    # the CRLB of θ from independent cameras (their Fisher matrices add)
    "cameras_crlb",
]
