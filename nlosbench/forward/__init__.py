"""The forward model θ ↦ image, its gradients, and the differentiable `render` function."""
from .autograd import render
from .cache import RenderCache
from .gradients import GradientSettings, ad_jacobian, check_concrete, fd_jacobian, jacobian, vjp
from .model import Binned, ForwardModel, RenderError, RenderStats, Restricted

__all__ = [
    "render",
    "RenderCache",
    "GradientSettings",
    "check_concrete",
    "fd_jacobian",
    "ad_jacobian",
    "jacobian",
    "vjp",
    "Binned",
    "ForwardModel",
    "RenderError",
    "RenderStats",
    "Restricted",
]
