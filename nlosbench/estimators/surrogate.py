"""`surrogate`: the MLE of a scalar θ on a per-pixel polynomial surrogate of L(θ) built from a lattice of renders.

A lattice t_g = a + g·h (g = 0 … G − 1) over a region [a, b] of Θ (`grid_wanted`) is rendered once per run at `spp`
in K independent sets, each with one seed shared by every point (common random numbers: a pixel whose light paths do
not meet the moving object has the same rendering error at every t_g, which cancels in every difference between
them). The trials study renders the sets in its render bank (`Problem.grids`: once per run, counted with the bank's
renders, shared by every fit); a direct fit renders them once per process. A fit renders nothing:

1. the NLL of y at every lattice point's mean render M_g; g₀ its minimum;
2. the window of 2w + 1 lattice points centred on g₀ (shifted inside the lattice at its ends) and, per set k and
   pixel ω, the least-squares polynomial of degree d in u = (θ − t_c) / h (t_c the window's centre) through them,
   S_kω(θ) = Σ_j c_{kjω} u^j, c_k = (VᵀV)⁻¹Vᵀ L_k,window, V the window's Vandermonde matrix (2w + 1, d + 1);
3. θ̂ = argmin Q(θ), Q = NLL(y, M(θ)) − ½ Σ_ω w_ω s²_ω(θ) / K, M the sets' mean and s² their sample variance
   per pixel, w the noise model's Fisher weight at max(M, SE), SE = s / √K the standard error of M (Brent's
   bounded search over the window's span: no render); when θ̂ lies nearer another lattice point than t_{g₀}, the
   window moves there and 2–3 repeat (at most `max_moves` times). The NLL and w both see their mean floored by
   `Problem.nll`'s Poisson policy (`base.floored`: at least `POISSON_FLOOR` photons): a polynomial through one
   bright sample in a dark pixel dips below 0 between lattice points, and a fit never fails on it, so every
   trial's θ̂ enters the MSE. The SE bounds a pixel's correction by ½ q·SE (q the Poisson scale, photons per unit
   radiance): the second-order correction assumes the sets' error small against M, and where it is not (M ≈ 0
   within its SE) a mean as large as the SE is not ruled out; at the floor alone w would reach 10³·q², and one
   pixel's spread would set θ̂ whatever y is (a bright sample 0.5 in blob2d's darkest pixel pinned θ̂ at
   θ* − 1.9 mm for every observation: `tests/test_surrogate.py`).

For AWGN, Q = Σ_{k≠l} (y − S_k)ᵀ(y − S_l) / (2σ² K(K − 1)): the sets' errors enter only in cross products, so
E Q = NLL(y, L(θ)) up to the polynomial's misfit. For Poisson at q photons per unit radiance, NLL =
q Σ (M − y log M) has the curvature q·y/M² in M, and w = q/M is its mean over y at M = L: with v_ω = Var(M_ω)
(the sets' error, small against L_ω), E Q = NLL(y, L(θ)) + ½ Σ_ω q v_ω (y_ω − L_ω) / L_ω² up to third-order
terms in the sets' error. Q is unbiased for the NLL on average over observations at θ*, not for each y; the
remainder's slope offsets θ̂ by about ½ Σ_ω q v_ω J_ω / L_ω² / F (F the Fisher information), i.e. by the lattice's
relative variance v/L² per pixel. (The curvature itself, q·y/M², would remove the remainder but is unbounded where
a floored M meets y > 0.)

Error of θ̂ (scalar θ, AWGN; W = the noise model's weight in general): with set k's error e_k (per-pixel variance
Σ_render(spp), seeds common over the lattice), its window fit e_k(θ) and slope e_k', the polynomial's misfit b(θ)
of L (O(h^{d+1}) per pixel) and r = y − L(θ*), linearising Q' = 0 at θ*:

    θ̂ − θ* ≈ Σ_{k≠l} (J + e_k')ᵀ W (r − e_l − b) / Σ_{k≠l} (J + e_k')ᵀ W (J + e_l'),

whose denominator is unbiased for K(K − 1)·F. Over the observations (one lattice for all trials at θ*):
Var = F⁻¹ (J + ē')ᵀ W Σ_y W (J + ē') F⁻¹ ≈ CRLB + F⁻¹ [Σ_ω w_ω² Σ_y,ω Var(ē'_ω)] F⁻¹, Σ_y = Σ_obs + Σ_truth and ē'
the mean slope error (variance Var(e')/K): the CRLB times 1 + ρ/K, ρ = Σ_ω w_ω σ² Var(e'_ω) / F the plug-in
excess F̃/F − 1 of one set's slope (`fit_cov`; Var(e') is measured as that of a central FD Jacobian with common
random numbers at the setting's step ξ: a least-squares slope over 2w + 1 points with independent errors has
Var = Σ_render Σ_i p_1i² / h² (p_1 the slope row of (VᵀV)⁻¹Vᵀ), which a central FD matches at
ξ = h / √(2 Σ_i p_1i²): ξ = 0.744 h for w = 2, d = 3). The term in e_l is the same for every trial at θ*: an
offset, shown as bias, of variance ≈ F⁻¹ Jᵀ W Σ_render(K·spp) W J F⁻¹ over lattice seeds. With K = 1 the
denominator is the plug-in ‖J + e'‖²_W: θ̂'s response to θ* shrinks by 1 / (1 + ρ) and its variance over the
observations is (F + F ρ)⁻¹, below the CRLB by a bias gradient, not by efficiency (`fit_cov` gives that too).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.optimize
import torch

from ..params import ParamSpace
from ..seeds import derive
from .base import MAX_GRID, Budget, Estimator, Outcome, Problem, Tracker, finite_or_raise, floored, nll
from .predict import Linearisation, weight


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
    sets : int, default 2
        Independent render sets K of the lattice (each with its own common seed); with K ≥ 2 the objective is
        unbiased for the NLL at L(θ) (AWGN; Poisson: on average over observations, module docstring), with K = 1
        the slope's noise shrinks θ̂ towards the surrogate's own error.
    window : int, default 2
        Half-width w of the local fit, in lattice points (2w + 1 points, ≥ degree + 1).
    degree : int, default 2
        Degree d of the per-pixel polynomial in θ.
    max_moves : int, default 4
        How often the window may move to the lattice point nearest θ̂ before the fit stops ("max-iterations").
    xtol : float, default 1e-6
        Brent's θ tolerance, in units of h.

    Examples
    --------
    The lattice is rendered once per process, then every fit is a polynomial fit to it:

    >>> import numpy as np
    >>> model = nb.scenes.get("blob2d").restrict(["x"])
    >>> problem = nb.estimators.Problem(model, nb.noise.AWGN(sigma=0.01))
    >>> y = model.render([0.5], spp=64, seed=0)
    >>> fit = nb.estimators.Surrogate(spp=16).fit(problem, y, rng=np.random.default_rng(0))
    >>> fit.theta.round(4), fit.status
    (array([0.5]), 'converged')
    """

    name = "surrogate"
    grid_seeds = "common"  # the lattice's common random numbers, which its objective and prediction assume
    valid_when = ("One parameter, and L(θ) smooth over a few lattice steps (the polynomial's misfit of L over the "
                  "window is an offset in θ̂): its lattice, rendered once at high spp with common seeds, is shared "
                  "by every fit, so it pays where many observations are fitted in the same region of Θ (trials, "
                  "a sequence of frames). The region must hold the NLL's minimum; a minimum at its end is reported "
                  "as 'stalled'.")

    def __init__(self, step: float | None = None, region: Sequence[float] | None = None, spp: int = 4096,
                 sets: int = 2, window: int = 2, degree: int = 2, max_moves: int = 4, xtol: float = 1e-6):
        for k, v in {"spp": spp, "sets": sets, "window": window, "degree": degree, "max_moves": max_moves}.items():
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
        self.spp, self.sets, self.window, self.degree = int(spp), int(sets), int(window), int(degree)
        self.max_moves = int(max_moves)
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
            For more than one parameter, a region outside Θ, fewer points than the window needs or more than
            `MAX_GRID`.
        """
        if params.dim != 1:
            raise ValueError(f"surrogate: one parameter only, the model has {list(params.names)}")
        lo, hi = (float(params.lower[0]), float(params.upper[0])) if self.region is None else self.region
        if lo < params.lower[0] - 1e-12 or hi > params.upper[0] + 1e-12:
            raise ValueError(f"surrogate: region [{lo}, {hi}] is not inside Θ = [{params.lower[0]}, {params.upper[0]}]")
        h = (hi - lo) / 24 if self.step is None else self.step
        if not (hi - lo) / h < MAX_GRID:  # before anything is allocated (a tiny step is billions of points)
            raise ValueError(f"surrogate: step {h:g} gives {(hi - lo) / h:.3g} lattice renders over [{lo:g}, {hi:g}], "
                             f"above the ceiling of {MAX_GRID}; use a larger step or a smaller region")
        G = int(np.floor((hi - lo) / h + 1e-9)) + 1
        if G < 2 * self.window + 1:
            raise ValueError(f"surrogate: the region holds {G} lattice points at step {h:g}, the window needs "
                             f"{2 * self.window + 1}")
        return (lo + h * np.arange(G, dtype=np.float64)).reshape(-1, 1)

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int, int]:
        """The lattice (G, 1), its spp and its independent render sets, rendered by the run's bank (`Problem.grids`).

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        tuple of (numpy.ndarray, int, int)
            The lattice points (G, 1) in parameter units, `spp` and `sets`.
        """
        return self.lattice(params), self.spp, self.sets

    def renders(self, problem: Problem) -> tuple[np.ndarray, torch.Tensor]:
        """(lattice (G,), renders (K, G, N) float64): the run's when the problem carries them (`Problem.find_grid`),
        else rendered on first use in this process, set k with one seed derived from the problem's (common random
        numbers across the lattice), and kept.

        Parameters
        ----------
        problem : Problem
            The problem (its grids, model and seed).

        Returns
        -------
        tuple of (numpy.ndarray, torch.Tensor)
            The lattice points (G,) and their K sets of renders flattened to (K, G, N) float64.
        """
        thetas = self.lattice(problem.params)
        K, G = self.sets, len(thetas)
        given = problem.find_grid(np.tile(thetas, (K, 1)), self.spp)
        if given is not None:
            return thetas[:, 0], given.images.double().reshape(K, G, -1)
        key = (repr(problem.model.content_key()), self.spp, K, problem.seed, thetas.tobytes())
        if key not in self._grids:
            self._grids[key] = [problem.model.render(t, self.spp, derive(problem.seed, "surrogate-lattice", k))
                                for k in range(K) for t in thetas]
        return thetas[:, 0], torch.stack(self._grids[key]).double().reshape(K, G, -1)

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        t, sets = self.renders(problem)
        K, G, w, h = self.sets, len(t), self.window, t[1] - t[0]
        shape = y.shape
        Ls = sets.mean(dim=0)
        prof = np.array([nll(problem, y, L.reshape(shape)) for L in Ls])
        g0 = int(np.argmin(prof))
        tracker.record(0, float(prof[g0]), t[g0:g0 + 1])
        u = np.arange(-w, w + 1, dtype=np.float64)
        pinv = torch.as_tensor(np.linalg.pinv(np.vander(u, self.degree + 1, increasing=True)))  # (d+1, 2w+1)
        seen, theta, loss = set(), float(t[g0]), float(prof[g0])
        for move in range(self.max_moves + 1):
            lo = min(max(g0 - w, 0), G - 2 * w - 1)
            # (K, d+1, N): each set's polynomial per pixel over the window, in u about t[lo + w]
            C = torch.einsum("jg,kgn->kjn", pinv, sets[:, lo:lo + 2 * w + 1])
            c0 = t[lo + w]

            def f(v: float, C=C, c0=c0) -> float:
                uu = (v - c0) / h
                S = sum(C[:, j] * uu**j for j in range(self.degree + 1))  # (K, N)
                M = S.mean(dim=0)
                out = nll(problem, y, M.reshape(shape))
                if K > 1:  # less ½ Σ w·Var(M): the sets' spread, w at max(M, its SE) floored (module docstring)
                    v = S.var(dim=0) / K
                    at = floored(problem, torch.maximum(M, v.sqrt()).reshape(shape))
                    out -= 0.5 * float((torch.as_tensor(weight(problem.noise, at)) * v).sum())
                return out

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

    def shared_cov(self, problem: Problem, lin: Linearisation) -> np.ndarray:
        """The lattice's value error at θ*, one offset for every fit of a run: with common seeds across the lattice
        the surrogate's error there is about one render's error at θ* with the sets' K·spp samples, so the offset
        of θ̂ is G⁻¹ JᵀW δL with covariance G⁻¹ JᵀW Σ_render(K·spp) WJ G⁻ᵀ (`Linearisation.sandwich`).

        Parameters
        ----------
        problem : Problem
            The estimation problem (unused).
        lin : Linearisation
            The linearisation at θ* (its `render_var`).

        Returns
        -------
        numpy.ndarray
            (1, 1) in parameter units².
        """
        return lin.sandwich(lin.render_var(self.sets * self.spp))

    def fit_cov(self, problem: Problem, lin: Linearisation, iterations: Sequence[int] | None,
                budget: Budget, statuses: Sequence[str] | None = None) -> tuple[np.ndarray, str]:
        """Covariance of θ̂ − ê over the observations for one lattice (module docstring): with K ≥ 2 sets
        F⁻¹ [Σ_ω w_ω² (Σ_obs + Σ_truth)_ω Var(ē'_ω)] F⁻¹, the mean slope's noise Var(ē') = Var(e') / K measured as
        that of the setting's gradient (a central FD with its step and common random numbers) at K·`spp`; with
        K = 1, (F + E)⁻¹ − F⁻¹ (E the same excess), the shrinkage of a plug-in slope. The lattice's own value error
        is one offset for every trial at θ* (bias, not variance): not in this covariance.

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
        F = lin.F
        Fi = np.linalg.inv(F)
        g = dataclasses.replace(problem.gradient, spp=None)  # the slope's noise at the lattice's spp, not the FD's own
        total = self.sets * self.spp
        if self.sets > 1:
            V = Fi @ lin.jacobian_excess(total, g, lin.weighted(lin.obs_var, lin.truth_var)) @ Fi
        else:
            V = np.linalg.inv(F + lin.jacobian_excess(total, g, lin.w)) - Fi
        rho = float(np.trace(Fi @ lin.jacobian_excess(self.spp, g, lin.w)))
        return V, (f"surrogate slope noise of {self.sets} set(s) at {self.spp} spp as a central FD of step "
                   f"{problem.gradient.step} with common random numbers (one set's ρ = F̃/F − 1 = {rho:.3g}); the "
                   f"lattice's value error is an offset shared by the trials (bias)")
