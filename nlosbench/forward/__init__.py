"""The forward model θ ↦ image, its gradients, and the differentiable `render` function."""
from .autograd import render
from .cache import RenderCache
from .gradients import GradientSettings, ad_jacobian, fd_jacobian, jacobian, resolve, vjp
from .model import ForwardModel, RenderError, RenderStats

__all__ = ["render", "RenderCache", "GradientSettings", "fd_jacobian", "ad_jacobian", "jacobian", "resolve", "vjp",
           "ForwardModel", "RenderError", "RenderStats"]
