"""nlosbench: how well can a hidden scene parameter be estimated from noisy images, and how close
does a real estimator get? Renderer-backed HCR / CRLB / Barankin bounds and ML estimators."""
from . import bounds, estimators, noise, scenes
from .forward import ForwardModel, GradientSettings, RenderCache, RenderError, render
from .params import Param, ParamSpace

__version__ = "0.1.0"

__all__ = ["bounds", "estimators", "noise", "scenes", "render", "ForwardModel", "GradientSettings", "RenderCache", "RenderError", "Param", "ParamSpace"]
