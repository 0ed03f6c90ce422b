"""nlosbench: how well can a hidden scene parameter be estimated from noisy images, and how close
does a real estimator get? Renderer-backed HCR / CRLB / Barankin bounds and ML estimators."""
from . import bounds, diagnostics, estimators, noise, scenes, variant
from .bank import RenderBank
from .diagnostics import render, resolve_gradient
from .forward import ForwardModel, GradientSettings, RenderCache, RenderError
from .params import Param, ParamSpace

__version__ = "0.1.0"

__all__ = ["bounds", "diagnostics", "estimators", "noise", "scenes", "variant", "render", "resolve_gradient",
           "ForwardModel", "GradientSettings", "RenderBank", "RenderCache", "RenderError", "Param", "ParamSpace"]
