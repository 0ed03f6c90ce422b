"""The gradient policy `grad="auto"`, resolved here, above the forward layer, into concrete settings.

`resolve_gradient(model, settings)` turns a `GradientSettings("auto", verdicts=...)` request into "fd",
"ad" or "mixed" through `verdict.choose_backend` (measured verdicts of a `gradients` study, or the
paper's prior: colour → AD, geometry → FD), once per (model, settings); other settings pass through.
`render` is the public differentiable render (`nlosbench.render`): it resolves the policy, then calls
`forward.render`, which runs only concrete settings.
"""
from __future__ import annotations

import logging
import weakref

import torch

from ..forward import GradientSettings
from ..forward import render as forward_render
from ..forward.model import ForwardModel
from . import verdict

log = logging.getLogger("nlosbench.gradients")

#: model → {repr(auto settings): resolved settings}; weak, so a model's entries go with it
_RESOLVED: weakref.WeakKeyDictionary[ForwardModel, dict] = weakref.WeakKeyDictionary()


def resolve_gradient(model: ForwardModel, settings: GradientSettings) -> GradientSettings:
    """Concrete settings for `model` ("fd", "ad" or "mixed"). "auto" is resolved through
    `verdict.choose_backend` once per (model, settings) and cached; the choice is in `.chosen` and logged
    (logger `nlosbench.gradients`, INFO).

    Parameters
    ----------
    model : ForwardModel
        The model the gradients are for (its parameters' kinds and names select the backend).
    settings : GradientSettings
        The requested settings; any method other than "auto" is returned as it is.

    Returns
    -------
    GradientSettings
        Settings with method "fd", "ad" or "mixed"; for "auto", `.chosen` says per parameter what was
        picked and why.

    Examples
    --------
    >>> nb.resolve_gradient(nb.scenes.get("blob2d"), nb.GradientSettings("fd")).method
    'fd'
    """
    if settings.method != "auto":
        return settings
    per_model = _RESOLVED.setdefault(model, {})
    key = repr(settings)
    if key not in per_model:
        per_model[key] = verdict.choose_backend(model, settings.verdicts, base=settings)
        log.info("grad='auto' on %s: %s", model.name, per_model[key].chosen)
    return per_model[key]


def render(model: ForwardModel, theta, spp: int = 64, seed: int = 0, grad: str | GradientSettings = "fd",
           **options) -> torch.Tensor:
    """L_θ (H, W, C) float32, differentiable w.r.t. θ (a torch tensor with requires_grad).

    The forward pass is `model.render(θ, spp, seed)`; the backward pass contracts the incoming image
    gradient with ∂L/∂θ by the method of `grad`, with render seeds derived from `seed`.

    Parameters
    ----------
    model : ForwardModel
        The scene.
    theta : array_like or torch.Tensor
        θ, P values in parameter units (a tensor with requires_grad to differentiate; other values
        become a float64 tensor).
    spp : int, default 64
        Samples per pixel of the primal render.
    seed : int, default 0
        Render seed; gradient renders use seeds derived from it.
    grad : {"fd", "ad", "mixed", "auto"} or GradientSettings, default "fd"
        The gradient method, or complete settings. "auto" is resolved once per (model, settings) —
        `resolve_gradient(model, GradientSettings("auto")).chosen` says what it picked.
    **options
        With a string `grad`, the other `GradientSettings` fields (step, rounds, crn, spp, ad, ad_params,
        verdicts), e.g. `render(m, θ, 64, 0, grad="fd", step=0.005, rounds=4)` or
        `render(m, θ, 64, 0, grad="auto", verdicts="runs/x/gradients")`.

    Returns
    -------
    torch.Tensor
        L_θ (H, W, C) float32, attached to θ's autograd graph.

    Examples
    --------
    >>> import torch
    >>> model = nb.scenes.get("blob2d")
    >>> theta = torch.tensor([0.4, 0.6], dtype=torch.float64, requires_grad=True)
    >>> image = nb.render(model, theta, spp=4, seed=0, grad="fd", step=0.01)
    >>> image.shape
    torch.Size([24, 24, 1])
    >>> image.square().sum().backward()
    >>> theta.grad.shape
    torch.Size([2])
    """
    if isinstance(grad, GradientSettings):
        if options:
            raise ValueError(f"options {sorted(options)} go with a string `grad`; put them in the GradientSettings")
        settings = grad
    else:
        settings = GradientSettings(method=grad, **options)
    return forward_render(model, theta, spp, seed, resolve_gradient(model, settings))
