"""Predicted variance of an estimate from its estimator's linearised update at convergence.

Near θ* the fit render at θ with its own rendering error ε (per pixel covariance Σ_render(s) at s spp) is
L̃(θ) ≈ L* + J (θ − θ*) + ε, and the observation is y = L* + ε_truth + ε_obs: the clean image's own
rendering error (shared by the trials of one clean-image cluster) plus the noise model's. With the noise
model's per-pixel weight W (the Fisher information per unit of L: AWGN 1/σ², Poisson scale/L) the score
is Jᵀ W (y − L̃(θ)) and F = Jᵀ W J. Every linearised estimator aims at the fixed point of the score on the
observation,

    ê − θ* = F⁻¹ Jᵀ W (ε_obs + ε_truth),   Cov = F⁻¹ Jᵀ W (Σ_obs + Σ_truth) W J F⁻¹        (the target)

(for AWGN with Σ_obs = σ² I, and for Poisson, the observation part is the CRLB F⁻¹), and misses it by what
its own iterations leave: the fit renders' noise and, with a noisy Jacobian, the start's error that its
steps did not remove. That part is the estimator family's (`Estimator.fit_cov`); this module holds what
they share: the `Linearisation` at θ* (J, W, the variances) and the `Prediction` it gives.

Unbiased products. J comes from K independent Jacobians J_r (K = 1: exact, e.g. AD on an analytic toy);
every quadratic form Jᵀ diag(a) J is the U-statistic Σ_{r≠s} J_rᵀ a J_s / (K(K − 1)), which rendering
noise in J_r does not inflate (`bounds.unbiased_fisher`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ..bounds.unbiased_fisher import unbiased_fisher
from ..forward.gradients import GradientSettings, jacobian
from ..forward.model import ForwardModel
from ..noise import NoiseModel, to_float64
from ..seeds import derive

#: (spp) → per-pixel variance (N,) float64 of one render at θ* with s samples per pixel
RenderVariance = Callable[[int], np.ndarray]
#: (spp, gradient settings) → per-pixel covariance (P, P, N) float64 of one Jacobian evaluation at θ*
JacobianCovariance = Callable[[int, GradientSettings], np.ndarray]


@dataclass(frozen=True)
class Linearisation:
    """The linear model of the fits at θ*. Pixels flattened to N.

    theta: θ* (P,); J: (K, P, N) float64 independent Jacobians of the mean image (K = 1: exact);
    w: the noise model's per-pixel weight (N,) (units: 1 / radiance²); obs_var: the observation noise's
    per-pixel variance Σ_obs (N,); truth_var: the clean image's per-pixel rendering variance Σ_truth (N,)
    (0 for an exact model); render_var: Σ_render(s); jacobian_cov: the covariance of one gradient
    Jacobian at s spp (None: exact gradients); start_cov: second moment (P, P) of the fits' starts about θ*
    (start_about "truth": a start drawn independently of y) or about ê (start_about "target": a start computed
    from y itself, e.g. the profile-likelihood minimum over grid renders) (parameter units²)."""

    theta: np.ndarray
    J: torch.Tensor
    w: np.ndarray
    obs_var: np.ndarray
    truth_var: np.ndarray
    render_var: RenderVariance
    jacobian_cov: JacobianCovariance | None
    start_cov: np.ndarray
    start_about: str = "truth"

    def quad(self, a: np.ndarray) -> np.ndarray:
        """Jᵀ diag(a) J (P, P) float64 for a per-pixel array a (N,): unbiased over the K Jacobians."""
        J = self.J.double()
        if J.shape[0] == 1:
            return ((J[0] * torch.as_tensor(a)) @ J[0].T).numpy()
        return unbiased_fisher(J, torch.as_tensor(np.asarray(a, dtype=np.float64))).F

    @property
    def F(self) -> np.ndarray:
        """Fisher information Jᵀ W J (P, P) of one observation (1 / units²); ValueError when the unbiased
        estimate is not positive definite (rendering noise above the signal: unresolved, not clipped)."""
        F = self.quad(self.w)
        e = np.linalg.eigvalsh(0.5 * (F + F.T))
        if not np.all(e > 0):
            raise ValueError(f"Fisher information unresolved: the unbiased F from {self.J.shape[0]} Jacobians has "
                             f"eigenvalues {e.tolist()}")
        return F

    def sandwich(self, a: np.ndarray) -> np.ndarray:
        """F⁻¹ Jᵀ W diag(a) W J F⁻¹ (P, P): the covariance of θ̂ from a zero-mean per-pixel error of variance a
        entering the score like the observation's."""
        Fi = np.linalg.inv(self.F)
        return Fi @ self.quad(self.w**2 * a) @ Fi

    def jacobian_excess(self, spp: int, gradient: GradientSettings, a: np.ndarray) -> np.ndarray:
        """Σ_ω a(ω) Cov(Ĵ_i(ω), Ĵ_j(ω)) (P, P) of one gradient Jacobian at `spp` (0 for exact gradients). With
        a = w this is how far one FD pair's plug-in F̂ = Ĵᵀ W Ĵ lies above F in expectation."""
        P = self.J.shape[1]
        if self.jacobian_cov is None:
            return np.zeros((P, P))
        return self.jacobian_cov(int(spp), gradient) @ a


    def drift_noise(self, spp: int, gradient: GradientSettings, V: np.ndarray) -> np.ndarray:
        """E[δJᵀ W J d dᵀ Jᵀ W δJ] (P, P) for an error d of second moment V (P, P): the Jacobian's noise against the
        model's own change J d, Σ_ω w² (J_ω V J_ωᵀ) Cov(Ĵ(ω)) (J_ω V J_ωᵀ per pixel unbiased over the K Jacobians).
        It makes the contraction F̂⁻¹ Ĵᵀ W J random from step to step."""
        if self.jacobian_cov is None:
            return np.zeros_like(V)
        J = self.J.numpy()
        K = J.shape[0]
        if K == 1:
            q = np.einsum("pn,pq,qn->n", J[0], V, J[0])
        else:
            S = J.sum(axis=0)
            q = (np.einsum("pn,pq,qn->n", S, V, S) - np.einsum("kpn,pq,kqn->n", J, V, J)) / (K * (K - 1))
        return self.jacobian_excess(spp, gradient, self.w**2 * q)


@dataclass(frozen=True)
class Prediction:
    """A predicted covariance (P, P) of θ̂ in parts: `obs` (the observation noise), `truth` (the clean image's
    rendering error, shared within a cluster), `fit` (what the estimator's own iterations leave: fit renders,
    noisy Jacobians, the start); `note` says what was assumed."""

    obs: np.ndarray
    truth: np.ndarray
    fit: np.ndarray
    note: str = ""

    def var(self, truth_share: float = 1.0) -> float:
        """Predicted expectation of the trials' sample variance (trace, units²): tr(obs + fit) + κ·tr(truth),
        κ = `truth_share` (`cluster_share`)."""
        return float(np.trace(self.obs + self.fit) + truth_share * np.trace(self.truth))

    def parts(self) -> dict[str, float]:
        return {"obs": float(np.trace(self.obs)), "truth": float(np.trace(self.truth)),
                "fit": float(np.trace(self.fit))}


def cluster_share(clusters) -> float:
    """κ = (n − Σ m_c² / n) / (n − 1): the share of a variance component shared within clusters (sizes m_c)
    that the sample variance (ddof 1) of n trials sees in expectation (1: independent trials; 0: one cluster,
    where it is a fixed offset: bias)."""
    _, m = np.unique(np.asarray(clusters), return_counts=True)
    n = int(m.sum())
    return float((n - (m**2).sum() / n) / (n - 1)) if n > 1 else float("nan")


def target(lin: Linearisation) -> tuple[np.ndarray, np.ndarray]:
    """(obs, truth) covariances of the fixed point ê: F⁻¹ JᵀW Σ_obs WJ F⁻¹ and F⁻¹ JᵀW Σ_truth WJ F⁻¹."""
    return lin.sandwich(lin.obs_var), lin.sandwich(lin.truth_var)


def start_moment(lin: Linearisation) -> np.ndarray:
    """Second moment (P, P) of the start's error about ê: the start's about θ* plus the target's covariance for a
    start independent of y (start_about "truth"), or as given for a start computed from y ("target")."""
    if lin.start_about == "target":
        return lin.start_cov
    obs, truth = target(lin)
    return lin.start_cov + obs + truth


def score_noise(lin: Linearisation, spp: int, gradient: GradientSettings) -> np.ndarray:
    """Covariance (P, P) of the noise of one evaluation of the score −Ĵᵀ W (y − L̃(θ)) near ê at `spp`: the fit
    render's error through J, Jᵀ W Σ_render W J, plus the Jacobian's own error against the whole residual,
    Σ_ω w² (Σ_obs + Σ_truth + Σ_render) Cov(Ĵ) (the residual's correlation with J is neglected)."""
    r = lin.render_var(spp)
    return lin.quad(lin.w**2 * r) + lin.jacobian_excess(spp, gradient, lin.w**2 * (lin.obs_var + lin.truth_var + r))


def model_linearisation(model: ForwardModel, noise: NoiseModel, theta, clean: torch.Tensor,
                        truth_var, render_var: RenderVariance, start_cov, gradient: GradientSettings,
                        jacobian_spp: int, jacobians: int = 8, seed: int = 0,
                        exact_jacobian: torch.Tensor | None = None, start_about: str = "truth") -> Linearisation:
    """A Linearisation at θ from renders made here: J from `jacobians` independent Jacobians with `gradient` at
    `jacobian_spp` (or `exact_jacobian` (P, *S) where it is known), the weight from the clean image (*S),
    and `jacobian_cov` from the spread of the same Jacobians scaled by jacobian_spp / s (rendering variance
    ∝ 1/spp). Seeds derive from `seed`. For a study, the render bank's sets serve instead (same maths)."""
    L = to_float64(clean)
    P = len(model.params)
    reps = torch.stack([jacobian(model, theta, jacobian_spp, derive(seed, "predict-jacobian", k), gradient)
                        for k in range(jacobians)]).double().reshape(jacobians, P, -1)
    cov = jacobian_covariance(reps.numpy(), jacobian_spp, gradient)
    J = reps if exact_jacobian is None else to_float64(exact_jacobian).reshape(1, P, -1)
    return Linearisation(np.asarray(theta, dtype=np.float64), J, weight(noise, L), variance(noise, L),
                         np.broadcast_to(np.asarray(truth_var, dtype=np.float64).reshape(-1), (L.numel(),)),
                         render_var, cov, np.atleast_2d(np.asarray(start_cov, dtype=np.float64)), start_about)


def jacobian_covariance(reps: np.ndarray, spp: int, gradient: GradientSettings) -> JacobianCovariance | None:
    """From K ≥ 2 Jacobians (K, P, N) made with `gradient` at `spp` (or at the gradient's own spp): (s, settings) →
    their per-pixel sample covariance (P, P, N) × that spp / s (or / the gradient's own spp), for the same step,
    rounds and CRN as `gradient` (else ValueError); None when they do not vary (exact gradients)."""
    d = reps - reps.mean(axis=0)
    if not np.any(d):
        return None
    C = np.einsum("kpn,kqn->pqn", d, d) / (len(reps) - 1)
    made = gradient.spp or spp  # the gradient's own spp, where it names one, is what the Jacobians used
    key = (gradient.method, np.asarray(gradient.step).tolist(), gradient.rounds, gradient.crn)

    def at(s: int, g: GradientSettings) -> np.ndarray:
        if (g.method, np.asarray(g.step).tolist(), g.rounds, g.crn) != key:
            raise ValueError(f"Jacobian noise was measured for {key}, not for {g}")
        return C * (made / float(g.spp or s))

    return at


def weight(noise: NoiseModel, L: torch.Tensor) -> np.ndarray:
    """The noise model's per-pixel Fisher weight w(L) (N,) float64: the information per unit dL² (0 where it is
    infinite, a Poisson pixel rendered as 0: the linearisation does not hold there)."""
    w = noise.fisher(L, torch.ones_like(L)).reshape(-1).numpy()
    return np.where(np.isfinite(w), w, 0.0)


def variance(noise: NoiseModel, L: torch.Tensor) -> np.ndarray:
    """The observation noise's per-pixel variance Σ_obs (N,) float64 (`NoiseModel.variance`)."""
    return to_float64(noise.variance(L)).expand(L.shape).reshape(-1).numpy()


def propagate(B: np.ndarray, Q: np.ndarray, V0: np.ndarray, ks, extra: Callable | None = None) -> np.ndarray:
    """Mean over k in `ks` of V_k for V_{k+1} = B V_k Bᵀ + Q + extra(V_k) from V_0 (all (P, P)): the second moment
    of a linear recursion d_{k+1} = B d_k + q_k with independent forcing q_k of covariance Q, and a forcing whose
    covariance grows with the state (`extra`, e.g. a random contraction; None: none)."""
    ks = np.asarray(list(ks), dtype=int)
    V, out = V0.copy(), np.zeros_like(V0)
    for k in range(int(ks.max()) + 1):
        out += (ks == k).sum() * V
        V = B @ V @ B.T + Q + (extra(V) if extra is not None else 0.0)
    return out / len(ks)
