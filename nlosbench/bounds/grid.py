"""HCR curve over a parameter grid from G renders (G renders in total, reused for every θ*).

`pairwise_lambda` fills the (G, G) matrix λ[i, j] = λ(θ* = θ_i, θ_j) in blocks of renders × pixels,
each block cast to float64 only inside the chunk, so G = 1000 renders of 256×512×3 float32 (a
numpy memmap works) need a bounded amount of memory. λ is additive over independent pixels for any
noise model (1 + χ² multiplies), so pixel chunks are summed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from nlosbench.bounds.hcr import as_numpy, hcr_from_lambda
from nlosbench.noise import NoiseModel, to_float64


def pairwise_lambda(renders, noise: NoiseModel, chunk_bytes: int = 256 * 2**20) -> np.ndarray:
    """λ[i, j] = noise.chi2_exponent(renders[i], renders[j]) for all pairs → (G, G) float64.

    For a symmetric noise model (AWGN) only j > i is computed, about half the work.

    Parameters
    ----------
    renders : torch.Tensor or ndarray of shape (G, *S)
        One noise-free render per grid point: a torch tensor (any device) or a numpy array / memmap, any
        float dtype (cast to float64 one block at a time).
    noise : NoiseModel
        The observation model whose χ² exponent is taken.
    chunk_bytes : int, optional
        float64 working memory per block (a block of columns and its differences), in bytes.

    Returns
    -------
    ndarray of shape (G, G)
        λ[i, j] = log(1 + χ²(p_θj ‖ p_θi)), float64, with θ* = θ_i and test point θ_j (0 on the diagonal).

    Raises
    ------
    ValueError
        Naming the render when one holds NaN/Inf (or is invalid for the model).

    Examples
    --------
    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> renders = torch.stack([t * g for t in (0.0, 0.5, 1.0)])
    >>> nb.bounds.pairwise_lambda(renders, nb.noise.AWGN(3.0))
    array([[0.  , 0.25, 1.  ],
           [0.25, 0.  , 0.25],
           [1.  , 0.25, 0.  ]])
    """
    G = len(renders)
    X = renders.reshape(G, -1)
    N = X.shape[1]
    n = int(min(N, max(1, chunk_bytes // 16)))
    bj = int(min(G, max(1, chunk_bytes // (16 * n))))
    dev = X.device if isinstance(X, torch.Tensor) else None
    lam = torch.zeros((G, G), dtype=torch.float64, device=dev)
    for c0 in range(0, N, n):
        c1 = min(N, c0 + n)
        for j0 in range(0, G, bj):
            j1 = min(G, j0 + bj)
            XJ = to_float64(X[j0:j1, c0:c1])
            for r in range(j1 - j0):
                noise.validate(XJ[r], f"renders[{j0 + r}]")
            for i in range(j1 - 1 if noise.symmetric else G):  # symmetric: the upper triangle j > i suffices
                Xi = XJ[i - j0] if j0 <= i < j1 else to_float64(X[i, c0:c1])
                k = max(i + 1 - j0, 0) if noise.symmetric else 0
                lam[i, j0 + k:j1] += noise.chi2_exponent(Xi, XJ[k:], check=False)
    if noise.symmetric:
        lam = lam + lam.T
    return as_numpy(lam)


@dataclass
class HCRCurve:
    """HCR bound at every grid point θ_i over Δ = θ_j − θ_i, j ≠ i (units: parameter units²).

    Returned by `hcr_curve`. Arrays are indexed by the grid point i; each parameter below is stored as
    the attribute of the same name.

    Parameters
    ----------
    thetas : ndarray of shape (G,) or (G, P)
        The grid, parameter units.
    log10 : ndarray of shape (G,)
        log10 of the bound at each θ_i (exact; −inf where no Δ is usable).
    value : ndarray of shape (G,)
        The bound at each θ_i, parameter units² (may underflow to 0).
    delta : ndarray of shape (G,) or (G, P)
        The Δ at the sup, NaN where no Δ is usable.
    index : ndarray of int, shape (G,)
        The maximising render j (−1 if none).
    at_edge : ndarray of object, shape (G,)
        "smallest", "largest" or None per θ_i, as in `HCRResult`.
    unresolved : ndarray of bool, shape (G,)
        Some test point has λ ≤ 0, as in `HCRResult`.
    reason : list of str
        Per θ_i, as in `HCRResult`.
    component_log10 : ndarray of shape (G, P)
        log10 per-component bounds on Var(θ̂_j).
    lam : ndarray of shape (G, G)
        The χ² exponents used, λ[i, j] with θ* = θ_i.

    Examples
    --------
    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> thetas = np.linspace(0.0, 2.0, 5)
    >>> c = nb.bounds.hcr_curve(torch.stack([t**2 * g for t in thetas]), thetas, nb.noise.AWGN(3.0))
    >>> bool(np.allclose(c.lam, c.lam.T)), c.lam.diagonal().tolist()  # AWGN: λ is symmetric; no Δ = 0 term
    (True, [0.0, 0.0, 0.0, 0.0, 0.0])
    >>> c.at_edge.tolist()  # 5 points: most sups sit at the nearest neighbour, where a finer grid may raise them
    ['smallest', 'smallest', 'largest', 'smallest', 'smallest']
    """

    thetas: np.ndarray
    log10: np.ndarray
    value: np.ndarray
    delta: np.ndarray
    index: np.ndarray
    at_edge: np.ndarray
    unresolved: np.ndarray
    reason: list[str]
    component_log10: np.ndarray
    lam: np.ndarray


def hcr_curve_from_lambda(lam, thetas, lower=None, upper=None) -> HCRCurve:
    """HCR curve from a (G, G) matrix λ[i, j] (e.g. `pairwise_lambda`, or bias-corrected λ̂).

    Parameters
    ----------
    lam : array_like of shape (G, G)
        λ[i, j] with θ* = θ_i and test point θ_j.
    thetas : array_like of shape (G,) or (G, P)
        The grid, parameter units.
    lower, upper : float or array_like of shape (P,), optional
        Limits of the parameter space Θ: θ_j outside is not used as a test point. None: no limit.

    Returns
    -------
    HCRCurve
        The HCR bound (parameter units²) at every grid point.
    """
    lam = as_numpy(lam)
    T = as_numpy(thetas)
    G = T.shape[0]
    if lam.shape != (G, G):
        raise ValueError(f"lam must have shape ({G}, {G}), got {lam.shape}")
    T2 = T.reshape(G, -1)
    P = T2.shape[1]
    out = HCRCurve(thetas=T, log10=np.full(G, -np.inf), value=np.zeros(G),
                   delta=np.full(T.shape, np.nan), index=np.full(G, -1),
                   at_edge=np.full(G, None, dtype=object), unresolved=np.zeros(G, bool),
                   reason=[""] * G, component_log10=np.full((G, P), -np.inf), lam=lam)
    for i in range(G):
        others = np.flatnonzero(np.arange(G) != i)
        d = T2[others] - T2[i]
        r = hcr_from_lambda(lam[i, others], d[:, 0] if T.ndim == 1 else d,
                            None if lower is None else as_numpy(lower) - T2[i],
                            None if upper is None else as_numpy(upper) - T2[i])
        out.log10[i], out.value[i], out.at_edge[i] = r.log10, r.value, r.at_edge
        out.unresolved[i], out.reason[i], out.component_log10[i] = r.unresolved, r.reason, r.component_log10
        if r.index >= 0:
            out.index[i] = others[r.index]
            out.delta[i] = r.delta
    return out


def hcr_curve(renders, thetas, noise: NoiseModel, lower=None, upper=None,
              chunk_bytes: int = 256 * 2**20) -> HCRCurve:
    """HCR curve from grid renders (G, *S) at thetas (G,) or (G, P): every render serves as θ* and
    as a test point for all others (G renders, never G²).

    Parameters
    ----------
    renders : torch.Tensor or ndarray of shape (G, *S)
        One noise-free render per grid point (tensor on any device, or a numpy array / memmap).
    thetas : array_like of shape (G,) or (G, P)
        The grid, parameter units.
    noise : NoiseModel
        The observation model.
    lower, upper : float or array_like of shape (P,), optional
        Limits of the parameter space Θ: θ_j outside is not used as a test point. None: no limit.
    chunk_bytes : int, optional
        float64 working memory per block of `pairwise_lambda`, in bytes.

    Returns
    -------
    HCRCurve
        The HCR bound (parameter units²) at every grid point, and the λ matrix used.

    Examples
    --------
    L(θ) = θ·g under AWGN with F = 1: every grid point's sup is at its nearest neighbour, Δ = ±0.5.

    >>> import numpy as np, torch
    >>> g = torch.tensor([1.0, 2.0, 2.0])
    >>> thetas = np.linspace(0.0, 2.0, 5)
    >>> c = nb.bounds.hcr_curve(torch.stack([t * g for t in thetas]), thetas, nb.noise.AWGN(3.0))
    >>> c.value.round(4)
    array([0.8802, 0.8802, 0.8802, 0.8802, 0.8802])
    >>> c.delta
    array([ 0.5, -0.5, -0.5, -0.5, -0.5])
    """
    return hcr_curve_from_lambda(pairwise_lambda(renders, noise, chunk_bytes), thetas, lower, upper)
