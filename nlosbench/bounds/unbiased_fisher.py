"""Unbiased Fisher information from Monte Carlo finite-difference Jacobians (a U-statistic over seeds).

A rendered FD Jacobian is an estimate J̃_r = J_ξ + E_r of the FD-smoothed derivative
J_ξ(ω) = E[(L(θ+ξ) − L(θ−ξ)) / 2ξ] (central pair at step ξ, common random numbers inside the pair), with
zero-mean rendering error E_r, independent across seeds r. The plug-in (single-pair) Fisher information
Σ_ω w(ω) J̃_r(ω)² is biased high, since E[J̃_r²] = J_ξ² + Var E_r: in NLOS the excess can be many times
the information itself. Products of two *independent* rounds have no such term, E[J̃_r J̃_s] = J_ξ² (r ≠ s),
so with R ≥ 2 rounds

    F̂_jk = 1 / (R(R−1)) · Σ_{r≠s} Σ_ω w(ω) J̃_{r,j}(ω) J̃_{s,k}(ω)

is an unbiased estimate of F_jk = Σ_ω w(ω) J_ξ,j(ω) J_ξ,k(ω) (a U-statistic of order 2 in the rounds),
for a weight w that does not depend on the rounds: AWGN w = 1/σ²; Poisson w = scale / L with L a mean image
rendered independently of every round (a high-spp render with its own seed), else w correlates with J̃.

What F̂ estimates is the Fisher information of the FD-smoothed derivative at step ξ (it converges to the
true FI as ξ → 0 only where L is smooth in θ). F̂ can be ≤ 0 or, for P > 1, indefinite when the signal is
below the rendering noise: that is reported, not clipped. 1/F̂ (the CRLB) is itself biased *high* by
Jensen's inequality (E[1/F̂] ≥ 1/F), by about (SE/F)² relative, so quote it with its interval.

Standard error: the jackknife over rounds (leave round k out, recompute F̂ from the other R−1 rounds;
Var_jack = (R−1)/R Σ_k (F̂_(−k) − F̄)²); it needs R ≥ 3 (with R = 2 the SE is NaN). It is right when the
signal dominates the rounds and conservative when the noise × noise products E_r·E_s dominate (the
degenerate part of the U-statistic, which the jackknife counts about twice): measured on toys, mean SE² /
Var F̂ = 1.0 (signal-dominated) and 1.6–1.7 (noise 3× the information, R = 4), 2.5–3.9 for R = 3 with pure
noise. With few rounds the SE has only R − 1 degrees of freedom, so intervals use Student's t quantile
(`crlb_interval`). (The exactly unbiased U-statistic variance estimate exists for R ≥ 4, but with few rounds
it is negative a third of the time when noise dominates; not used.)
Units: F in 1/(parameter units)², e.g. 1/m² for a position.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from nlosbench.bounds.ustat import u_statistic
from nlosbench.noise import QuadraticNoise, check_finite, to_float64


@dataclass
class UnbiasedFisher:
    """F̂ (P, P) float64 from R independent FD Jacobians, with its jackknife standard error.

    Returned by `unbiased_fisher`; each parameter below is stored as the attribute of the same name.

    Parameters
    ----------
    F : ndarray of shape (P, P)
        The U-statistic F̂ (units: 1/(parameter units)²); may be ≤ 0 or indefinite where rendering noise
        dominates (reported, not clipped).
    se : ndarray of shape (P, P)
        Jackknife SE of each entry, NaN when R = 2.
    rounds : int
        R, the number of independent FD rounds.
    leave_one_out : ndarray of shape (R, P, P)
        F̂ without round k (empty for R = 2).
    single : ndarray of shape (R, P, P)
        Each round's own plug-in (single-pair) estimate Σ w J̃_r J̃_rᵀ, biased high — for comparison only.
    pixel_map : ndarray of shape (P, *S)
        The unbiased per-pixel information of each parameter (diagonal terms; noisy, may be negative);
        sums to diag(F).

    Examples
    --------
    >>> import numpy as np
    >>> J = (np.array([1.0, 2.0, 2.0]) + 0.1 * np.random.default_rng(0).standard_normal((4, 3)))[:, None]
    >>> u = nb.bounds.unbiased_fisher(J, nb.noise.AWGN(3.0))
    >>> bool(u.excess[0, 0] > 0)  # each round's own plug-in is biased high by the FD noise
    True
    >>> crlb, lower, upper = u.crlb_interval()
    >>> bool(lower[0] <= crlb[0] <= upper[0]), bool(np.isclose(u.pixel_map.sum(), u.F[0, 0]))
    (True, True)
    """

    F: np.ndarray
    se: np.ndarray
    rounds: int
    leave_one_out: np.ndarray
    single: np.ndarray
    pixel_map: np.ndarray

    @property
    def excess(self) -> np.ndarray:
        """Mean single-pair estimate minus F̂ (P, P): the estimated rendering-noise term Σ w Var(J̃)."""
        return self.single.mean(axis=0) - self.F

    def quantile(self, level: float = 0.95) -> float:
        """Two-sided Student-t quantile with R − 1 degrees of freedom for a `level` interval (R = 5: 2.78).

        Parameters
        ----------
        level : float, optional
            The two-sided confidence level, in (0, 1).

        Returns
        -------
        float
            The quantile z, so that F̂ ± z·SE is the `level` interval.
        """
        from scipy import stats

        return float(stats.t.ppf(0.5 + level / 2, self.rounds - 1))

    def crlb_interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(CRLB, lower, upper) per component (P,), units².

        CRLB = diag(F̂⁻¹) (+inf where F̂ is not positive definite). With z the Student-t quantile for
        `level` (R − 1 degrees of freedom): for P = 1 the interval is [1/(F̂ + z·SE), 1/(F̂ − z·SE)] (upper
        end +inf when F̂ − z·SE ≤ 0), the CRLBs at the ends of F̂'s interval; for P > 1, CRLB ± z·(jackknife
        SE of the CRLB from the leave-one-out F̂s). NaN ends when R = 2 (no SE).

        Parameters
        ----------
        level : float, optional
            The two-sided confidence level, in (0, 1).

        Returns
        -------
        crlb : ndarray of shape (P,)
            diag(F̂⁻¹), parameter units².
        lower, upper : ndarray of shape (P,)
            The interval's ends, parameter units².
        """
        P = self.F.shape[0]
        value = _crlb(self.F)
        if self.rounds < 3:
            return value, np.full(P, np.nan), np.full(P, np.nan)
        z = self.quantile(level)
        if P == 1:
            f, s = self.F[0, 0], self.se[0, 0]
            lo = np.array([1.0 / (f + z * s) if f + z * s > 0 else math.inf])
            hi = np.array([1.0 / (f - z * s) if f - z * s > 0 else math.inf])
            return value, lo, hi
        loo = np.stack([_crlb(Fk) for Fk in self.leave_one_out])
        R = self.rounds
        se = np.sqrt((R - 1) / R * ((loo - loo.mean(axis=0)) ** 2).sum(axis=0))
        return value, value - z * se, value + z * se


def _crlb(F: np.ndarray) -> np.ndarray:
    """diag(F⁻¹) (P,), +inf everywhere if F is not (numerically) positive definite."""
    try:
        np.linalg.cholesky(F)
    except np.linalg.LinAlgError:
        return np.full(F.shape[0], math.inf)
    return np.diag(np.linalg.inv(F)).copy()


def unbiased_fisher(J, weight, L=None) -> UnbiasedFisher:
    """The U-statistic F̂ from R ≥ 2 independent FD Jacobians.

    Computed in float64 from direct products J̃_r·J̃_s (no norms): G_rs = Σ_ω w J̃_r J̃_sᵀ,
    F̂ = Σ_{r≠s} G_rs / (R(R−1)), symmetrised.

    Parameters
    ----------
    J : torch.Tensor or array_like of shape (R, P, *S)
        Round r's central-FD Jacobian of the image (pixels × channels, shape S) for each of the P
        parameters, any float dtype; every round from its own seeds (common random numbers only inside
        each ±ξ pair).
    weight : QuadraticNoise or array_like
        A quadratic noise model (`nlosbench.noise.AWGN`: 1/σ²; `Poisson`: scale/L, which needs `L`) or a
        per-pixel weight array broadcastable to the image shape S (≥ 0, finite).
    L : torch.Tensor or array_like of shape (*S), optional
        Mean image for a noise model whose weight depends on it; it must not come from the rounds'
        renders (use an independent, high-spp render). Only with a noise model.

    Returns
    -------
    UnbiasedFisher
        F̂ (P, P) in 1/(parameter units)², its jackknife SE, the leave-one-outs, the biased single-pair
        estimates and the per-pixel map.

    Examples
    --------
    Four rounds of a noisy Jacobian of L(θ) = θ·g under AWGN with F = 1:

    >>> import numpy as np
    >>> g = np.array([1.0, 2.0, 2.0])
    >>> J = (g + 0.1 * np.random.default_rng(0).standard_normal((4, 3)))[:, None]
    >>> u = nb.bounds.unbiased_fisher(J, nb.noise.AWGN(3.0))
    >>> u.F.round(3), u.se.round(3)
    (array([[1.001]]), array([[0.021]]))
    """
    J = to_float64(J, "J")
    check_finite(J, "J")
    if J.ndim < 3:
        raise ValueError(f"J must have shape (R, P, *S) with at least one image axis, got {tuple(J.shape)}")
    R, P = J.shape[0], J.shape[1]
    if R < 2:
        raise ValueError(f"the unbiased Fisher information needs R >= 2 independent rounds, got R = {R}")
    S = tuple(J.shape[2:])
    w = _weight(weight, L, S).numpy().reshape(-1)
    Jf = J.numpy().reshape(R * P, -1)  # float64 (numpy's BLAS: torch's float64 matmul stalls on a busy CPU)
    G = ((Jf * w) @ Jf.T).reshape(R, P, R, P).transpose(0, 2, 1, 3)  # (R, R, P, P): Σ_ω w J_r,p J_s,q
    G = 0.5 * (G + G.transpose(1, 0, 3, 2))  # exact symmetry (r, p) ↔ (s, q) against rounding
    diag = np.einsum("rrpq->rpq", G).copy()  # (R, P, P): G_rr, each round's own single-pair estimate
    u = u_statistic(G)
    F, se, loo = u.est, u.se, u.loo
    # per-pixel map of the diagonal: Σ_{r≠s} w J_r J_s = w((Σ_r J_r)² − Σ_r J_r²)
    Jr = Jf.reshape(R, P, -1)
    pix = w * (Jr.sum(axis=0) ** 2 - (Jr ** 2).sum(axis=0)) / (R * (R - 1))
    return UnbiasedFisher(F=F, se=se, rounds=R, leave_one_out=loo, single=diag, pixel_map=pix.reshape((P,) + S))


def _weight(weight, L, S: tuple) -> torch.Tensor:
    """Per-pixel weight as a float64 tensor of shape S (finite, ≥ 0)."""
    if isinstance(weight, QuadraticNoise):
        if L is None:
            probe = weight.weight(torch.ones(S, dtype=torch.float64))
            if probe.numel() != 1:
                raise ValueError(f"{type(weight).__name__}'s weight depends on the image: pass L, an independent "
                                 "mean image (e.g. a high-spp render with its own seed)")
            w = probe.expand(S)
        else:
            Lt = to_float64(L, "L")
            if tuple(Lt.shape) != S:
                raise ValueError(f"L must have the image shape {S}, got {tuple(Lt.shape)}")
            weight.validate(Lt, "L")
            w = weight.weight(Lt).expand(S)
    else:
        if L is not None:
            raise ValueError("L is only used with a noise model; a weight array is used as given")
        w = to_float64(weight, "weight")
        try:
            w = w.expand(S)
        except RuntimeError:
            raise ValueError(f"weight of shape {tuple(w.shape)} does not broadcast to the image shape {S}") from None
    if not bool(torch.isfinite(w).all()) or bool((w < 0).any()):
        raise ValueError("per-pixel weights must be finite and >= 0 (a Poisson pixel with L = 0 has infinite "
                         "weight: render L with more spp, or mask such pixels)")
    return w.contiguous()
