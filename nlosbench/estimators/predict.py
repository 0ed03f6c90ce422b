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
every quadratic form Jᵀ A J is the U-statistic Σ_{r≠s} J_rᵀ A J_s / (K(K − 1)), which rendering
noise in J_r does not inflate (`bounds.unbiased_fisher`).

Colour channels. The C channels of one pixel come from the same light paths, so a render's error is correlated
across them (pi_hallway at 40 × 30: the red and green errors of a pixel correlate at 0.99, and the variance of a
32-spp render's error projected on J is 2.8× what channels drawn independently would give). A rendering
covariance (Σ_render, Σ_truth, the Jacobian's noise) is therefore a `PixelCov`: per pixel a C × C block
(M, C, C), M = N / C, or per element (N,) where the elements are independent (the observation's noise, the
analytic toys' synthetic noise); a quadratic form over blocks is the same U-statistic in each block's
eigenbasis (`Linearisation.quad`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ..bounds.unbiased_fisher import unbiased_fisher
from ..forward.gradients import GradientSettings, jacobian
from ..forward.model import ForwardModel
from ..noise import NoiseModel, to_float64
from ..seeds import derive

#: a per-pixel covariance: (N,) float64 for independent elements, or (M, C, C) float64 channel blocks (N = M·C)
PixelCov = np.ndarray
#: (spp) → the `PixelCov` of one render at θ* with s samples per pixel
RenderVariance = Callable[[int], np.ndarray]
#: (spp, gradient settings) → the covariance (P, P, M, C, C) float64 of one Jacobian evaluation at θ*: per pixel,
#: Cov(Ĵ_p(m, c), Ĵ_q(m, d)) across its channels (C = 1: per element)
JacobianCovariance = Callable[[int, GradientSettings], np.ndarray]


def blocks(a, channels: int) -> np.ndarray:
    """A `PixelCov` as channel blocks (M, C, C) float64: (N,) → diagonal blocks; blocks unchanged.

    Parameters
    ----------
    a : numpy.ndarray
        (N,) per element, or (M, C, C) per pixel.
    channels : int
        C, the channels per pixel.

    Returns
    -------
    numpy.ndarray
        (N / C, C, C) float64.
    """
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 3:
        return a
    C = int(channels)
    out = np.zeros((a.size // C, C, C))
    out[:, np.arange(C), np.arange(C)] = a.reshape(-1, C)
    return out


def weighted(w: np.ndarray, a, channels: int) -> np.ndarray:
    """W A W (M, C, C) for the diagonal weight w (N,) and a `PixelCov` a: the covariance of W e for an error e of
    covariance a."""
    C = int(channels)
    wb = np.asarray(w, dtype=np.float64).reshape(-1, C)
    return wb[:, :, None] * blocks(a, C) * wb[:, None, :]


def render_covariance(reps, channels: int) -> np.ndarray:
    """The per-pixel channel covariance (M, C, C) float64 of R ≥ 2 independent renders (R, N) (ddof 1: unbiased).

    Parameters
    ----------
    reps : array_like
        R independent renders of one θ, (R, N) (or (R, *S), flattened), radiance units.
    channels : int
        C, the channels per pixel (the last image axis).

    Returns
    -------
    numpy.ndarray
        (N / C, C, C) float64, radiance².
    """
    X = np.asarray(reps, dtype=np.float64)
    X = X.reshape(len(X), -1, int(channels))
    d = X - X.mean(axis=0)
    return np.einsum("rmc,rmd->mcd", d, d) / (len(X) - 1)


@dataclass(frozen=True)
class Linearisation:
    """The linear model of the fits at θ*. Pixels flattened to N.

    theta: θ* (P,); J: (K, P, N) float64 independent Jacobians of the mean image (K = 1: exact);
    w: the noise model's per-pixel weight (N,) (units: 1 / radiance²); obs_var: the observation noise's
    `PixelCov` Σ_obs; truth_var: the clean image's rendering `PixelCov` Σ_truth (0 for an exact model);
    render_var: Σ_render(s), a `PixelCov`; jacobian_cov: the covariance of one gradient
    Jacobian at s spp (None: exact gradients); start_cov: second moment (P, P) of the fits' starts about θ*
    (start_about "truth": a start drawn independently of y) or about ê (start_about "target": a start computed
    from y itself, e.g. the profile-likelihood minimum over grid renders) (parameter units²); channels: C, the
    channels per pixel that the block `PixelCov`s cover (1: every element its own); response: (K, P, N) Jacobians
    J₀ of how the mean image changes over the fits' errors (the derivative, where J is an FD-smoothed one at a
    larger step), round r made with the same seeds as J's round r (only r ≠ s products are used); None: J itself.

    Response. An estimator steps with its own Jacobian J (a secant over ±ξ), but near θ* the image moves by
    J₀ (θ − θ*). Its fixed point solves Jᵀ W (y − L* − J₀ (θ − θ*)) = 0: ê − θ* = G⁻¹ Jᵀ W (ε_obs + ε_truth)
    with G = Jᵀ W J₀, and a step removes G/F̂ of the error, not F/F̂. On the Π hallway at 40 × 30 in LOS
    (θ* = 0.79 m) the derivative's F₀ is 1.9× the 3-cm secant's F and G = 1.14 F, so the secant's variance is
    (F/G)² = 0.77 of what F⁻¹ would give."""

    theta: np.ndarray
    J: torch.Tensor
    w: np.ndarray
    obs_var: np.ndarray
    truth_var: np.ndarray
    render_var: RenderVariance
    jacobian_cov: JacobianCovariance | None
    start_cov: np.ndarray
    start_about: str = "truth"
    channels: int = 1
    response: torch.Tensor | None = None

    def quad(self, a: np.ndarray) -> np.ndarray:
        """Jᵀ A J (P, P) float64 for a `PixelCov` A (≥ 0; (N,): diag(a)): unbiased over the K Jacobians. Channel
        blocks A_m = V_m Λ_m V_mᵀ turn into a diagonal weight Λ on the Jacobians rotated into each block's
        eigenbasis, J_m V_m (Jᵀ A J = Σ_m (J_m V_m) Λ_m (J_m V_m)ᵀ), so the one U-statistic serves both."""
        J = self.J.double()
        if np.ndim(a) == 3:
            lam, V = np.linalg.eigh(np.asarray(a, dtype=np.float64))
            K, P, N = J.shape
            Jr = np.einsum("kpmc,mce->kpme", J.numpy().reshape(K, P, N // V.shape[-1], V.shape[-1]), V)
            rotated = dataclasses.replace(self, J=torch.from_numpy(Jr.reshape(K, P, N)))
            return rotated.quad(np.clip(lam.reshape(-1), 0.0, None))  # rounding: a covariance has no λ < 0
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

    @property
    def G(self) -> np.ndarray:
        """Jᵀ W J₀ (P, P) (1 / units²): the score's response to a change of θ (F where `response` is None),
        unbiased: Σ_{r≠s} J_rᵀ W J₀_s / (K(K − 1)) (round r of J and of J₀ share seeds)."""
        if self.response is None:
            return self.F
        J, J0 = self.J.double().numpy(), self.response.double().numpy()
        K = min(len(J), len(J0))
        pairs = [(r, s) for r in range(K) for s in range(K) if r != s]
        if not pairs:
            raise ValueError("the response needs K >= 2 rounds of J and of J0")
        return sum((J[r] * self.w) @ J0[s].T for r, s in pairs) / len(pairs)

    def sandwich(self, a: np.ndarray) -> np.ndarray:
        """G⁻¹ Jᵀ W A W J G⁻ᵀ (P, P) (G = F without a `response`): the covariance of ê from a zero-mean error of
        `PixelCov` A entering the score like the observation's."""
        Gi = np.linalg.inv(self.G)
        return Gi @ self.quad(self.weighted(a)) @ Gi.T

    def weighted(self, *covs: np.ndarray) -> np.ndarray:
        """W (A₁ + A₂ + …) W for `PixelCov`s A_i, each per element (N,) or in channel blocks (M, C, C),
        C = `channels` (also C = 1: a one-channel image's blocks are (M, 1, 1)): (N,) when every A_i is per element
        and C = 1, else blocks (M, C, C)."""
        C = self.channels
        if C == 1 and all(np.ndim(a) == 1 for a in covs):
            return self.w**2 * sum(covs)
        return weighted(self.w, sum(blocks(a, C) for a in covs), C)

    def jacobian_excess(self, spp: int, gradient: GradientSettings, a: np.ndarray) -> np.ndarray:
        """E[δĴᵀ A δĴ] = Σ_m Σ_cd A_m(c, d) Cov(Ĵ_i(m, c), Ĵ_j(m, d)) (P, P) of one gradient Jacobian at `spp` for a
        `PixelCov` A (0 for exact gradients). With A = w (diagonal) this is how far one FD pair's plug-in
        F̂ = Ĵᵀ W Ĵ lies above F in expectation; with A = W Σ W, the covariance of δĴᵀ W e for an error e of
        covariance Σ independent of δĴ."""
        P = self.J.shape[1]
        if self.jacobian_cov is None:
            return np.zeros((P, P))
        C = self.jacobian_cov(int(spp), gradient)
        return np.einsum("pqmcd,mcd->pq", C, blocks(a, C.shape[-1]))


    def drift_noise(self, spp: int, gradient: GradientSettings, V: np.ndarray) -> np.ndarray:
        """E[δJᵀ W J d dᵀ Jᵀ W δJ] (P, P) for an error d of second moment V (P, P): the Jacobian's noise against the
        model's own change J d, whose per-pixel channel block is J_m V J_mᵀ (C × C, unbiased over the K Jacobians),
        through `jacobian_excess`. It makes the contraction F̂⁻¹ Ĵᵀ W J random from step to step."""
        if self.jacobian_cov is None:
            return np.zeros_like(V)
        C = self.jacobian_cov(int(spp), gradient).shape[-1]
        K, P, N = self.J.shape
        J = self.J.double().numpy().reshape(K, P, N // C, C)
        if K == 1:
            q = np.einsum("pmc,pq,qmd->mcd", J[0], V, J[0])
        else:
            S = J.sum(axis=0)
            q = (np.einsum("pmc,pq,qmd->mcd", S, V, S) - np.einsum("kpmc,pq,kqmd->mcd", J, V, J)) / (K * (K - 1))
        return self.jacobian_excess(spp, gradient, weighted(self.w, q, C))


@dataclass(frozen=True)
class Prediction:
    """A predicted covariance (P, P) of θ̂ in parts: `obs` (the observation noise), `truth` (the clean image's
    rendering error, shared within a cluster), `fit` (what the estimator's own iterations leave: fit renders,
    noisy Jacobians, the start); `note` says what was assumed; `shared` (None: none) the covariance of an error
    every trial of a run shares (renders the estimator makes once and reuses, e.g. a surrogate's lattice): a
    bias of the run, not in the trials' variance, which the bias test's standard error holds."""

    obs: np.ndarray
    truth: np.ndarray
    fit: np.ndarray
    note: str = ""
    shared: np.ndarray | None = None

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


#: a response J₀ is used where its G = JᵀW J₀ has a jackknife SE (over the rounds) at most this fraction of G
RESPONSE_TOL = 0.1


def cross_products(J: np.ndarray, J0: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G, its jackknife SE) (P, P) for G = Σ_{r≠s} J_rᵀ W J₀_s / (R(R − 1)) from R rounds of J and J₀ (R, P, N)
    (round r of both from the same seeds, so only r ≠ s pairs), w (N,) the diagonal weight; the SE is NaN for
    R < 3.

    Parameters
    ----------
    J, J0 : numpy.ndarray
        (R, P, N) rounds of the secant and of the response Jacobian.
    w : numpy.ndarray
        (N,) the per-pixel weight.

    Returns
    -------
    tuple of numpy.ndarray
        G and its jackknife standard error, both (P, P).
    """
    R = len(J)
    M = np.einsum("rpn,n,sqn->rspq", J, w, J0)  # every round pair's product

    def g(keep):
        pairs = [(r, s) for r in keep for s in keep if r != s]
        return sum(M[r, s] for r, s in pairs) / len(pairs)

    G = g(range(R))
    if R < 3:
        return G, np.full_like(G, np.nan)
    loo = np.stack([g([r for r in range(R) if r != k]) for k in range(R)])
    return G, np.sqrt((R - 1) / R * ((loo - loo.mean(axis=0)) ** 2).sum(axis=0))


def choose_response(J: np.ndarray, candidates: list[tuple[float, np.ndarray]], w: np.ndarray,
                    tol: float = RESPONSE_TOL) -> tuple[float, np.ndarray] | None:
    """The finest-step response (step, rounds (R, P, N)) among `candidates` [(ξ, rounds), ...] whose G = JᵀW J₀
    is resolved: every diagonal entry positive with a jackknife SE ≤ `tol` × it (`cross_products`); None when none
    is (then J itself is the response: G = F). In NLOS at a few hundred spp the finest FD steps are noise, and
    their G would make the prediction noise too.

    Parameters
    ----------
    J : numpy.ndarray
        (R, P, N) rounds of the estimator's (secant) Jacobian.
    candidates : list of (float, numpy.ndarray)
        (ξ, rounds (R, P, N)) of finer FD steps, same seeds per round as J.
    w : numpy.ndarray
        (N,) the per-pixel weight.
    tol : float, optional
        The largest relative SE of G's diagonal.

    Returns
    -------
    tuple of (float, numpy.ndarray) or None
        The chosen step and its rounds, or None.
    """
    for step, J0 in sorted(candidates, key=lambda c: c[0]):
        G, se = cross_products(J, J0, w)
        d, e = np.diag(G), np.diag(se)
        if np.all(d > 0) and np.all(e <= tol * d):
            return step, J0
    return None


def target(lin: Linearisation) -> tuple[np.ndarray, np.ndarray]:
    """(obs, truth) covariances of the fixed point ê: G⁻¹ JᵀW Σ_obs WJ G⁻ᵀ and G⁻¹ JᵀW Σ_truth WJ G⁻ᵀ
    (`Linearisation.sandwich`; G = F where the fits' Jacobian is the derivative)."""
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
    E[δĴᵀ W (Σ_obs + Σ_truth + Σ_render) W δĴ] (the residual's correlation with J is neglected)."""
    r = lin.render_var(spp)
    return lin.quad(lin.weighted(r)) + lin.jacobian_excess(spp, gradient, lin.weighted(lin.obs_var, lin.truth_var, r))


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


def jacobian_covariance(reps: np.ndarray, spp: int, gradient: GradientSettings,
                        channels: int = 1) -> JacobianCovariance | None:
    """From K ≥ 2 Jacobians (K, P, N) made with `gradient` at `spp` (or at the gradient's own spp): (s, settings) →
    their per-pixel sample covariance across the `channels` of each pixel (P, P, M, C, C) × that spp / s (or / the
    gradient's own spp), for the same step, rounds and CRN as `gradient` (else ValueError); None when they do not
    vary (exact gradients)."""
    d = reps - reps.mean(axis=0)
    if not np.any(d):
        return None
    K, P, N = d.shape
    d = d.reshape(K, P, N // int(channels), int(channels))
    C = np.einsum("kpmc,kqmd->pqmcd", d, d) / (K - 1)
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
