"""Information bounds from renders: HCR (single offsets and grid curves), CRLB, Barankin, per-pixel
Fisher information maps, HCR intervals from inexact renders, and the bound service (`service`) that
studies ask for every bound at θ* and bound curves."""
from nlosbench.bounds.barankin import BarankinResult, barankin
from nlosbench.bounds.crlb import CRLBResult, crlb, crlb_from_hcr_limit, crlb_log10, fisher_matrix
from nlosbench.bounds.fisher_maps import fisher_maps, save_fisher_maps
from nlosbench.bounds.grid import HCRCurve, hcr_curve, hcr_curve_from_lambda, pairwise_lambda
from nlosbench.bounds.hcr import HCRResult, hcr, hcr_from_lambda

__all__ = [
    "BarankinResult", "CRLBResult", "HCRCurve", "HCRResult", "barankin", "crlb",
    "crlb_from_hcr_limit", "crlb_log10", "fisher_maps", "fisher_matrix", "hcr", "hcr_curve",
    "hcr_curve_from_lambda", "hcr_from_lambda", "pairwise_lambda", "save_fisher_maps",
]
from nlosbench.bounds.decay import DecayResult, decay_check, pixel_variances  # noqa: E402
from nlosbench.bounds.inexact import (  # noqa: E402
    InexactHCR,
    LambdaFit,
    check_levels,
    fit_lambda,
    half_sample_lambda,
    inexact_hcr,
    replicate_grams,
)

__all__ += ["DecayResult", "decay_check", "pixel_variances", "InexactHCR", "LambdaFit", "check_levels",
            "fit_lambda", "half_sample_lambda", "inexact_hcr", "replicate_grams"]
from nlosbench.bounds.hcr_interval import HCRInterval, hcr_interval  # noqa: E402
from nlosbench.bounds.service import Bound, BoundPoint, BoundService, Curve, FisherPoint  # noqa: E402
from nlosbench.bounds.unbiased_fisher import UnbiasedFisher, unbiased_fisher  # noqa: E402
from nlosbench.bounds.ustat import UStat, pairwise_ustat, u_statistic  # noqa: E402
from nlosbench.bounds.zzb import ZZBInterval, ZZBResult, ziv_zakai, zzb_interval  # noqa: E402

__all__ += ["Bound", "BoundPoint", "BoundService", "Curve", "FisherPoint", "HCRInterval", "hcr_interval",
            "UnbiasedFisher", "unbiased_fisher", "UStat", "pairwise_ustat", "u_statistic", "ZZBInterval", "ZZBResult",
            "ziv_zakai", "zzb_interval"]
