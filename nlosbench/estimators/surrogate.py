"""`surrogate`: the MLE of a scalar θ on a per-pixel polynomial surrogate of L(θ) built from a lattice of renders.

A lattice t_g = a + g·h (g = 0 … G − 1) over a region [a, b] of Θ (`grid_wanted`) is rendered once per run at `spp`
with one seed shared by every point (common random numbers: a pixel whose light paths do not meet the moving
object has the same rendering error at every t_g, which cancels in every difference between them). The trials
study renders it in its render bank (`Problem.grids`: once per run, counted with the bank's renders, shared by
every fit); a direct fit renders it once per process. A fit renders nothing:

1. the NLL of y at every lattice render; g₀ its minimum;
2. the window of 2w + 1 lattice points centred on g₀ (shifted inside the lattice at its ends) and, per pixel ω,
   the least-squares polynomial of degree d in u = (θ − t_{g₀}) / h through them,
   L̃_ω(θ) = Σ_j c_{jω} u^j, c = (VᵀV)⁻¹Vᵀ L_window, V the window's Vandermonde matrix (2w + 1, d + 1);
3. θ̂ = argmin NLL(y, L̃(θ)) over the window's span (Brent's bounded search: no render, 3600 pixels a
   polynomial evaluation); when θ̂ lies nearer another lattice point than t_{g₀}, g₀ moves there and 2–3
   repeat (at most `max_moves` times).

Error of θ̂ (scalar, AWGN for the formulas; W = the noise model's weight in general). With the lattice's
rendering error e (per-pixel variance Σ_render(spp) at each point, one seed for all) the surrogate is
L̃ = L + e_w(θ) + b(θ), e_w the window's polynomial fit of e and b the polynomial's own misfit of L (the
nonlinearity of L over the window, O(h^{d+1}) per pixel). Near θ* the score equation J̃ᵀW(y − L̃(θ̂)) = 0 with
J̃ = J + e_w' gives

    θ̂ − θ* ≈ F⁻¹ Jᵀ W (ε_obs + ε_truth) − F⁻¹ JᵀW (e_w(θ*) + b(θ*)) + F⁻¹ e_w'ᵀ W ε_obs.

The first term is the target (the observation at the CRLB, and the clean image's own error). The second is the
same for every trial at θ* (one lattice per run): an offset, shown as bias, of variance F⁻¹ JᵀWΣ_render(spp)WJ
F⁻¹ over lattice seeds, i.e. a fraction ≈ Σ_render(1)/(spp σ²) of the CRLB. The third is independent from
trial to trial: the surrogate's slope noise against the observation's noise, covariance
F⁻¹ [Σ_ω w_ω² Σ_obs,ω Var(e_w'(ω))] F⁻¹ = (F̃ / F − 1) · F⁻¹ for AWGN, F̃ = E[J̃ᵀWJ̃] the plug-in Fisher
information of the surrogate's slope (`fit_cov`, with the slope's noise measured as that of a central FD
Jacobian with common random numbers whose step ξ is the setting's: for a least-squares slope over 2w + 1
points with independent errors Var = Σ_render / (h² Σk²), which a central FD matches at ξ = h √(Σk² / 2), e.g.
ξ = h√5 for w = 2). So θ̂'s MSE over the trials at one θ* is CRLB · (1 + F̃/F − 1) + the target's clean-image
part + the offset², and the lattice's cost is shared by every trial at every θ* its region holds.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.optimize
import torch

from ..params import ParamSpace
from ..seeds import derive
from .base import Budget, Estimator, Outcome, Problem, Tracker, finite_or_raise, nll
from .predict import Linearisation


class Surrogate(Estimator):
    """The MLE of a scalar θ on a per-pixel polynomial surrogate of L(θ) from a lattice of common-seed renders.

    Parameters
    ----------
    step : float, optional
        Lattice spacing h in parameter units (default: the region's width / 24).
    region : sequence of two floats, optional
        [a, b] ⊂ Θ the lattice covers (default: Θ); its points are a + g·h, g = 0 … ⌊(b − a) / h⌋.
    spp : int, default 4096
        Samples per pixel of each lattice render.
    window : int, default 2
        Half-width w of the local fit, in lattice points (2w + 1 points, ≥ degree + 1).
    degree : int, default 2
        Degree d of the per-pixel polynomial in θ.
    max_moves : int, default 4
        How often the window may move to the lattice point nearest θ̂ before the fit stops ("max-iterations").
    xtol : float, default 1e-6
        Brent's θ tolerance, in units of h.
    """

    name = "surrogate"
    valid_when = ("One parameter, and L(θ) smooth over a few lattice steps (the polynomial's misfit of L over the "
                  "window is an offset in θ̂): its lattice, rendered once at high spp with common seeds, is shared "
                  "by every fit, so it pays where many observations are fitted in the same region of Θ (trials, "
                  "a sequence of frames). The region must hold the NLL's minimum; a minimum at its end is reported "
                  "as 'stalled'.")

    def __init__(self, step: float | None = None, region: Sequence[float] | None = None, spp: int = 4096,
                 window: int = 2, degree: int = 2, max_moves: int = 4, xtol: float = 1e-6):
        for k, v in {"spp": spp, "window": window, "degree": degree, "max_moves": max_moves}.items():
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"surrogate: {k} must be a positive integer, got {v!r}")
        if 2 * window + 1 < degree + 1:
            raise ValueError(f"surrogate: a degree-{degree} polynomial needs 2·window + 1 >= {degree + 1} points, "
                             f"got window = {window}")
        if step is not None and not step > 0:
            raise ValueError(f"surrogate: step must be > 0, got {step!r}")
        if region is not None and (len(region) != 2 or not region[0] < region[1]):
            raise ValueError(f"surrogate: region must be [a, b] with a < b, got {region!r}")
        if not xtol > 0:
            raise ValueError(f"surrogate: xtol must be > 0, got {xtol!r}")
        self.step = None if step is None else float(step)
        self.region = None if region is None else [float(region[0]), float(region[1])]
        self.spp, self.window, self.degree, self.max_moves = int(spp), int(window), int(degree), int(max_moves)
        self.xtol = float(xtol)
        self._grids: dict[tuple, list[torch.Tensor]] = {}

    def lattice(self, params: ParamSpace) -> np.ndarray:
        """The lattice a + g·h over the region (G, 1) float64, parameter units.

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        numpy.ndarray
            The lattice points (G, 1), G ≥ 2·window + 1.

        Raises
        ------
        ValueError
            For more than one parameter, a region outside Θ, or fewer points than the window needs.
        """
        if params.dim != 1:
            raise ValueError(f"surrogate: one parameter only, the model has {list(params.names)}")
        lo, hi = (float(params.lower[0]), float(params.upper[0])) if self.region is None else self.region
        if lo < params.lower[0] - 1e-12 or hi > params.upper[0] + 1e-12:
            raise ValueError(f"surrogate: region [{lo}, {hi}] is not inside Θ = [{params.lower[0]}, {params.upper[0]}]")
        h = (hi - lo) / 24 if self.step is None else self.step
        G = int(np.floor((hi - lo) / h + 1e-9)) + 1
        if G < 2 * self.window + 1:
            raise ValueError(f"surrogate: the region holds {G} lattice points at step {h:g}, the window needs "
                             f"{2 * self.window + 1}")
        return (lo + h * np.arange(G, dtype=np.float64)).reshape(-1, 1)

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int]:
        """The lattice (G, 1) and its spp, rendered by the run's bank (`Problem.grids`).

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        tuple of (numpy.ndarray, int)
            The lattice points (G, 1) in parameter units and `spp`.
        """
        return self.lattice(params), self.spp

    def renders(self, problem: Problem) -> tuple[np.ndarray, torch.Tensor]:
        """(lattice (G,), renders (G, N) float64): the run's when the problem carries them (`Problem.find_grid`),
        else rendered on first use in this process with one seed derived from the problem's (common random
        numbers) and kept.

        Parameters
        ----------
        problem : Problem
            The problem (its grids, model and seed).

        Returns
        -------
        tuple of (numpy.ndarray, torch.Tensor)
            The lattice points (G,) and their renders flattened to (G, N) float64.
        """
        thetas = self.lattice(problem.params)
        given = problem.find_grid(thetas, self.spp)
        if given is not None:
            return thetas[:, 0], given.images.double().reshape(len(thetas), -1)
        key = (repr(problem.model.content_key()), self.spp, problem.seed, thetas.tobytes())
        if key not in self._grids:
            seed = derive(problem.seed, "surrogate-lattice")
            self._grids[key] = [problem.model.render(t, self.spp, seed) for t in thetas]
        return thetas[:, 0], torch.stack(self._grids[key]).double().reshape(len(thetas), -1)

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        t, Ls = self.renders(problem)
        G, w, h = len(t), self.window, t[1] - t[0]
        shape = y.shape
        prof = np.array([nll(problem, y, L.reshape(shape)) for L in Ls])
        g0 = int(np.argmin(prof))
        tracker.record(0, float(prof[g0]), t[g0:g0 + 1])
        u = np.arange(-w, w + 1, dtype=np.float64)
        pinv = torch.as_tensor(np.linalg.pinv(np.vander(u, self.degree + 1, increasing=True)))  # (d+1, 2w+1)
        seen, theta, loss = set(), float(t[g0]), float(prof[g0])
        for move in range(self.max_moves + 1):
            lo = min(max(g0 - w, 0), G - 2 * w - 1)
            C = pinv @ Ls[lo:lo + 2 * w + 1]  # (d+1, N): the window's polynomial per pixel, in u about t[lo + w]
            c0 = t[lo + w]

            def f(v: float, C=C, c0=c0) -> float:
                uu = (v - c0) / h
                L = sum(C[j] * uu**j for j in range(self.degree + 1))
                return nll(problem, y, L.reshape(shape))

            res = scipy.optimize.minimize_scalar(f, bounds=(t[lo], t[lo + 2 * w]), method="bounded",
                                                 options={"xatol": self.xtol * h})
            theta, loss = float(res.x), finite_or_raise(float(res.fun), "NLL on the surrogate")
            tracker.record(move + 1, loss, np.array([theta]))
            seen.add(lo)
            g1 = int(np.clip(np.rint((theta - t[0]) / h), 0, G - 1))
            if min(max(g1 - w, 0), G - 2 * w - 1) in seen:  # the window θ̂ asks for was fitted already
                break
            g0 = g1
        else:
            return Outcome(np.array([theta]), self.max_moves + 1, "max-iterations",
                           f"the window moved {self.max_moves} times", loss)
        edge = (theta - t[0] < 0.5 * h and t[0] > problem.params.lower[0] + 1e-12) or \
            (t[-1] - theta < 0.5 * h and t[-1] < problem.params.upper[0] - 1e-12)
        if edge:
            return Outcome(np.array([theta]), move + 1, "stalled",
                           f"the minimum lies at the end of the lattice region [{t[0]:g}, {t[-1]:g}]", loss)
        return Outcome(np.array([theta]), move + 1, "converged",
                       f"minimum of the surrogate on lattice window {lo}–{lo + 2 * w}", loss)

    def fit_cov(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None,
                budget: Budget, statuses: Sequence[str] | None = None) -> tuple[np.ndarray, str]:
        """Covariance of θ̂ − ê from the surrogate's slope noise against the observation's (and clean image's)
        noise, F⁻¹ [Σ_ω w_ω² (Σ_obs + Σ_truth)_ω Var(e_w'(ω))] F⁻¹ (module docstring), with Var(e_w') that of
        the setting's gradient (a central FD with its step and common random numbers) at `spp`. The lattice's own
        value error is one offset for every trial at θ* (bias, not variance): not in this covariance.

        Parameters
        ----------
        problem : Problem
            The estimation problem (its gradient settings: the FD step whose noise stands for the slope's).
        lin : Linearisation
            The linearisation at θ* (`estimators.predict`).
        iterations : sequence of int, optional
            Unused (the surrogate's minimum does not depend on the moves that found it).
        budget : Budget
            Unused.
        statuses : sequence of str, optional
            Unused.

        Returns
        -------
        tuple of (numpy.ndarray, str)
            The covariance (1, 1) in parameter units² and a note of what was assumed.
        """
        Fi = np.linalg.inv(lin.F)
        V = Fi @ lin.jacobian_excess(self.spp, problem.gradient, lin.w**2 * (lin.obs_var + lin.truth_var)) @ Fi
        return V, (f"surrogate slope noise at {self.spp} spp as a central FD of step {problem.gradient.step} with "
                   f"common random numbers; the lattice's value error is an offset shared by the trials (bias)")
