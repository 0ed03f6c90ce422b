"""`render(model, θ, spp, seed, grad=...)`: the forward model as a differentiable torch function.

The forward pass is `model.render(θ, spp, seed)`; the backward pass contracts the incoming image
gradient with ∂L/∂θ by FD (common random numbers), AD or both ("mixed") — see `gradients.py`.
Gradient renders use seeds derived from `seed`, so a whole optimisation step is reproducible.
`grad="auto"` is resolved above this layer (`nlosbench.render`, `nlosbench.diagnostics.resolve_gradient`).
"""
from __future__ import annotations

import torch

from .gradients import GradientSettings, check_concrete, vjp
from .model import ForwardModel


class _Render(torch.autograd.Function):
    @staticmethod
    def forward(ctx, theta: torch.Tensor, model: ForwardModel, spp: int, seed: int, settings: GradientSettings):
        ctx.model, ctx.spp, ctx.seed, ctx.settings = model, spp, seed, settings
        ctx.save_for_backward(theta)
        return model.render(theta.detach(), spp, seed)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        (theta,) = ctx.saved_tensors
        g = vjp(ctx.model, theta.detach(), grad_out, ctx.spp, ctx.seed, ctx.settings)
        return torch.as_tensor(g, dtype=theta.dtype), None, None, None, None


def render(model: ForwardModel, theta, spp: int = 64, seed: int = 0, grad: str | GradientSettings = "fd",
           **options) -> torch.Tensor:
    """L_θ (H, W, C) float32, differentiable w.r.t. θ (a torch tensor with requires_grad).

    Concrete settings only: `nlosbench.render` resolves grad="auto" first, then calls this.

    Parameters
    ----------
    model : ForwardModel
        The scene.
    theta : array_like or torch.Tensor
        θ, P values in parameter units (a tensor with requires_grad to differentiate).
    spp : int, default 64
        Samples per pixel of the primal render.
    seed : int, default 0
        Render seed; gradient renders use seeds derived from it.
    grad : {"fd", "ad", "mixed"} or GradientSettings, default "fd"
        The gradient method, or complete settings.
    **options
        With a string `grad`, the other `GradientSettings` fields (step, rounds, crn, spp, ad, ad_params),
        e.g. `render(m, θ, 64, 0, grad="fd", step=0.005, rounds=4)`.

    Returns
    -------
    torch.Tensor
        L_θ (H, W, C) float32, attached to θ's autograd graph.
    """
    if isinstance(grad, GradientSettings):
        if options:
            raise ValueError(f"options {sorted(options)} go with a string `grad`; put them in the GradientSettings")
        settings = grad
    else:
        settings = GradientSettings(method=grad, **options)
    check_concrete(settings)
    if not isinstance(theta, torch.Tensor):
        theta = torch.as_tensor(theta, dtype=torch.float64)
    return _Render.apply(theta, model, spp, seed, settings)
