"""nlosbench: how well can a hidden scene parameter be estimated from noisy images, and how close
does a real estimator get? Renderer-backed HCR / CRLB / Barankin bounds and ML estimators.

The public names below are imported on first use: `import nlosbench` itself loads neither torch, SciPy nor
Mitsuba, so the `nlosbench` command has its signal handlers in place before they load (a Ctrl-C during
their import is one line, not a traceback)."""
from __future__ import annotations

import importlib
import importlib.util

__version__ = "0.1.0"

#: a public name that is not a submodule → the submodule that defines it
_FROM = {"render": "diagnostics", "resolve_gradient": "diagnostics", "RenderBank": "bank", "ForwardModel": "forward",
         "GradientSettings": "forward", "RenderCache": "forward", "RenderError": "forward", "Param": "params",
         "ParamSpace": "params", "run": "api", "read": "api", "bound": "api", "compare": "api",
         "Results": "api"}

__all__ = ["bounds", "diagnostics", "estimators", "noise", "scenes", "variant", "render", "resolve_gradient",
           "ForwardModel", "GradientSettings", "RenderBank", "RenderCache", "RenderError", "Param", "ParamSpace",
           "run", "read", "compare", "bound", "Results"]


def __getattr__(name: str):
    """A public name (or any submodule: `nlosbench.io`), imported on first use and kept."""
    if name in _FROM:
        value = getattr(importlib.import_module(f"{__name__}.{_FROM[name]}"), name)
    elif not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
