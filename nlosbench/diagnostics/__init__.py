"""AD-vs-FD gradient diagnostics: gradient images per backend (`images`), artifact metrics
(`metrics`), their cost (`cost`), remedies (`remedies`), a verdict per parameter and the backend
choice for `grad="auto"` (`verdict`), the policy that resolves it above the forward layer and the
public differentiable `render` (`policy`), and the paper-style figure (`figures`)."""
from .cost import Cost, measure
from .images import (
                     GradientRun,
                     applicable_integrators,
                     backend,
                     forward_cost,
                     gradient_images,
                     label,
                     param_kind,
                     spec_of,
)
from .metrics import (
                     Reference,
                     clusters,
                     image_metrics,
                     outlier_mask,
                     outlier_scores,
                     persistence,
                     summarize,
                     total_agreement,
)
from .policy import render, resolve_gradient
from .remedies import REMEDIES, mean_of_k, median_of_k, remedy_run
from .verdict import Verdict, choose_backend, judge, load_verdicts, save_verdicts

__all__ = ["Cost", "measure", "GradientRun", "applicable_integrators", "backend", "forward_cost", "gradient_images",
           "label", "param_kind", "spec_of", "Reference", "clusters", "image_metrics", "outlier_mask",
           "outlier_scores", "persistence", "summarize", "total_agreement", "REMEDIES", "mean_of_k", "median_of_k",
           "remedy_run", "render", "resolve_gradient", "Verdict", "choose_backend", "judge", "load_verdicts",
           "save_verdicts"]
