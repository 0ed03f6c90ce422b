"""`surrogate`: the MLE of a scalar θ on a per-pixel polynomial surrogate of L(θ) built from a lattice of renders.

A lattice t_g = a + g·h (g = 0 … G − 1) over a region [a, b] of Θ (`grid_wanted`) is rendered once per run at `spp`
in K independent sets, each with one seed shared by every point (common random numbers: a pixel whose light paths do
not meet the moving object has the same rendering error at every t_g, which cancels in every difference between
them). The trials study renders the sets in its render bank (`Problem.grids`: once per run, counted with the bank's
renders, shared by every fit); a direct fit renders them once per process. Where L(θ) has edges at pixel scale over
part of Θ (a silhouette in line of sight) and is smooth over centimetres elsewhere, the lattice is made of
`segments`, each a uniform lattice over its own region at its own step and spp (contiguous: one segment's end is the
next one's start, a point both hold); a window never straddles two segments, and every set keeps one seed per
segment. A fit renders nothing:

1. the NLL of y at every lattice point's mean render M_g; g₀ its minimum;
2. the window of 2w + 1 lattice points centred on g₀ (shifted inside g₀'s segment at its ends) and, per set k and
   pixel ω, the least-squares polynomial of degree d in u = (θ − t_c) / h (t_c the window's centre) through them,
   S_kω(θ) = Σ_j c_{kjω} u^j, c_k = (VᵀV)⁻¹Vᵀ L_k,window, V the window's Vandermonde matrix (2w + 1, d + 1);
3. θ̂ = argmin Q(θ), Q = NLL(y, M(θ)) − ½ Σ_ω w_ω s²_ω(θ) / K, M the sets' mean and s² their sample variance
   per pixel, w the noise model's Fisher weight at max(M, SE), SE = s / √K the standard error of M (Brent's
   bounded search over the window's span: no render); when θ̂ lies nearer another lattice point than t_{g₀} (in the
   segment holding θ̂; the current one where two hold it, the next one where θ̂ stops at their join), the window
   moves there and 2–3 repeat (at most `max_moves` times). The NLL and w both see their mean floored by
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
    segments : sequence of mappings, optional
        Instead of `region` and `step`: uniform lattices {region: [a, b], step: h, spp: s (default `spp`)} over
        contiguous regions of Θ, in order (one's b the next one's a), each holding ≥ 2w + 1 points: a fine step
        where L(θ) has edges at pixel scale, a coarse one where it is smooth.
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
                 sets: int = 2, window: int = 2, degree: int = 2, max_moves: int = 4, xtol: float = 1e-6,
                 segments: Sequence[dict] | None = None):
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
        self.segments = None if segments is None else _check_segments(segments, self.spp, step, region)
        self._grids: dict[tuple, list[torch.Tensor]] = {}

    def parts(self, params: ParamSpace) -> list[tuple[np.ndarray, int]]:
        """Each segment's lattice a + g·h (G_s, 1) float64 (parameter units) and its spp: one segment (`region`,
        `step`, `spp`) unless `segments` are given.

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        list of (numpy.ndarray, int)
            Per segment, in order: its points (G_s, 1), G_s ≥ 2·window + 1, and spp.

        Raises
        ------
        ValueError
            For more than one parameter, a region outside Θ, fewer points than the window needs or more than
            `MAX_GRID` in all.
        """
        if params.dim != 1:
            raise ValueError(f"surrogate: one parameter only, the model has {list(params.names)}")
        segs = self.segments or [{"region": self.region or [float(params.lower[0]), float(params.upper[0])],
                                  "step": self.step, "spp": self.spp}]
        out, total = [], 0.0
        for seg in segs:
            lo, hi = seg["region"]
            if lo < params.lower[0] - 1e-12 or hi > params.upper[0] + 1e-12:
                raise ValueError(f"surrogate: region [{lo}, {hi}] is not inside Θ = [{params.lower[0]}, "
                                 f"{params.upper[0]}]")
            h = (hi - lo) / 24 if seg["step"] is None else seg["step"]
            total += (hi - lo) / h
            if not total < MAX_GRID:  # before anything is allocated (a tiny step is billions of points)
                raise ValueError(f"surrogate: step {h:g} gives {total:.3g} lattice renders up to {hi:g}, above the "
                                 f"ceiling of {MAX_GRID}; use a larger step or a smaller region")
            G = int(np.floor((hi - lo) / h + 1e-9)) + 1
            if G < 2 * self.window + 1:
                raise ValueError(f"surrogate: the region [{lo:g}, {hi:g}] holds {G} lattice points at step {h:g}, "
                                 f"the window needs {2 * self.window + 1}")
            out.append(((lo + h * np.arange(G, dtype=np.float64)).reshape(-1, 1), int(seg["spp"])))
        return out

    def lattice(self, params: ParamSpace) -> np.ndarray:
        """Every lattice point (G, 1) float64, parameter units, segment after segment (a point two segments share
        appears in both).

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        numpy.ndarray
            The lattice points (G, 1).
        """
        return np.concatenate([t for t, _ in self.parts(params)])

    def grid_wanted(self, params: ParamSpace) -> tuple[np.ndarray, int, int] | list[tuple[np.ndarray, int, int]]:
        """The lattice (G, 1), its spp and its independent render sets, rendered by the run's bank (`Problem.grids`);
        with `segments`, one such grid per segment.

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.

        Returns
        -------
        tuple of (numpy.ndarray, int, int), or a list of them
            The lattice points (G, 1) in parameter units, their spp and `sets`.
        """
        wanted = [(t, spp, self.sets) for t, spp in self.parts(params)]
        return wanted if self.segments else wanted[0]

    def renders(self, problem: Problem) -> list[tuple[np.ndarray, torch.Tensor]]:
        """Per segment, (lattice (G_s,), renders (K, G_s, N) float64): the run's when the problem carries them
        (`Problem.find_grid`), else rendered on first use in this process, set k of segment s with one seed derived
        from the problem's (common random numbers across the segment), and kept.

        Parameters
        ----------
        problem : Problem
            The problem (its grids, model and seed).

        Returns
        -------
        list of (numpy.ndarray, torch.Tensor)
            Per segment, its points (G_s,) and their K sets of renders flattened to (K, G_s, N) float64.
        """
        out = []
        for s, (thetas, spp) in enumerate(self.parts(problem.params)):
            K, G = self.sets, len(thetas)
            given = problem.find_grid(np.tile(thetas, (K, 1)), spp)
            if given is not None:
                out.append((thetas[:, 0], given.images.double().reshape(K, G, -1)))
                continue
            key = (repr(problem.model.content_key()), spp, K, problem.seed, thetas.tobytes())
            if key not in self._grids:
                self._grids[key] = [problem.model.render(t, spp, derive(problem.seed, "surrogate-lattice", k,
                                                                        *((s,) if s else ())))
                                    for k in range(K) for t in thetas]
            out.append((thetas[:, 0], torch.stack(self._grids[key]).double().reshape(K, G, -1)))
        return out

    def _fit(self, problem: Problem, y: torch.Tensor, theta0: np.ndarray, rng: np.random.Generator,
             tracker: Tracker) -> Outcome:
        segs = self.renders(problem)
        K, w = self.sets, self.window
        shape = y.shape
        profs = [np.array([nll(problem, y, L.reshape(shape)) for L in sets.mean(dim=0)]) for _, sets in segs]
        s0 = int(np.argmin([p.min() for p in profs]))
        g0 = int(np.argmin(profs[s0]))
        tracker.record(0, float(profs[s0][g0]), segs[s0][0][g0:g0 + 1])
        u = np.arange(-w, w + 1, dtype=np.float64)
        pinv = torch.as_tensor(np.linalg.pinv(np.vander(u, self.degree + 1, increasing=True)))  # (d+1, 2w+1)
        seen, theta, loss = set(), float(segs[s0][0][g0]), float(profs[s0][g0])
        for move in range(self.max_moves + 1):
            t, sets = segs[s0]
            G, h = len(t), t[1] - t[0]
            lo = min(max(g0 - w, 0), G - 2 * w - 1)
            # (K, d+1, N): each set's polynomial per pixel over the window, in u about t[lo + w]
            C = torch.einsum("jg,kgn->kjn", pinv, sets[:, lo:lo + 2 * w + 1])
            c0 = t[lo + w]

            def f(v: float, C=C, c0=c0, h=h) -> float:
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
            seen.add((s0, lo))
            s1 = _segment_of(theta, [seg[0] for seg in segs], s0)
            tol = 10 * self.xtol * h
            if s1 == s0 and s0 > 0 and lo == 0 and theta - t[0] < tol:  # at the join: the minimum may lie beyond it
                s1 = s0 - 1
            elif s1 == s0 and s0 < len(segs) - 1 and lo == G - 2 * w - 1 and t[-1] - theta < tol:
                s1 = s0 + 1
            t1 = segs[s1][0]
            g1 = int(np.clip(np.rint((theta - t1[0]) / (t1[1] - t1[0])), 0, len(t1) - 1))
            if (s1, min(max(g1 - w, 0), len(t1) - 2 * w - 1)) in seen:  # the window θ̂ asks for was fitted already
                break
            s0, g0 = s1, g1
        else:
            return Outcome(np.array([theta]), self.max_moves + 1, "max-iterations",
                           f"the window moved {self.max_moves} times", loss)
        first, last = segs[0][0], segs[-1][0]
        edge = (theta - first[0] < 0.5 * (first[1] - first[0]) and first[0] > problem.params.lower[0] + 1e-12) or \
            (last[-1] - theta < 0.5 * (last[1] - last[0]) and last[-1] < problem.params.upper[0] - 1e-12)
        if edge:
            return Outcome(np.array([theta]), move + 1, "stalled",
                           f"the minimum lies at the end of the lattice region [{first[0]:g}, {last[-1]:g}]", loss)
        where = f"{lo}–{lo + 2 * w}" + (f" of segment {s0}" if len(segs) > 1 else "")
        return Outcome(np.array([theta]), move + 1, "converged", f"minimum of the surrogate on lattice window {where}",
                       loss)

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
        return lin.sandwich(lin.render_var(self.sets * self._local(problem.params, lin.theta)[0]))

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
        spp, h = self._local(problem.params, lin.theta)
        note = ""
        if self.segments and g.step is not None and abs(g.step - 0.744 * h) > 0.1 * 0.744 * h:
            note = (f" (not 0.744h = {0.744 * h:.3g} of the lattice step h = {h:g} at θ*: the prediction is for a "
                    f"lattice step ξ / 0.744)")
        total = self.sets * spp
        if self.sets > 1:
            V = Fi @ lin.jacobian_excess(total, g, lin.weighted(lin.obs_var, lin.truth_var)) @ Fi
        else:
            V = np.linalg.inv(F + lin.jacobian_excess(total, g, lin.w)) - Fi
        rho = float(np.trace(Fi @ lin.jacobian_excess(spp, g, lin.w)))
        return V, (f"surrogate slope noise of {self.sets} set(s) at {spp} spp as a central FD of step "
                   f"{problem.gradient.step} with common random numbers{note} (one set's ρ = F̃/F − 1 = {rho:.3g}); "
                   f"the lattice's value error is an offset shared by the trials (bias)")

    def stand_in(self, params: ParamSpace, theta, gradient):
        """With `segments`, the gradient at the step whose central-FD noise the cubic's centre slope has in θ*'s
        segment, ξ = 0.744 h (module docstring); else the setting's own.

        Parameters
        ----------
        params : ParamSpace
            Θ; one parameter.
        theta : array_like
            θ* (1,) in parameter units.
        gradient : GradientSettings
            The setting's gradient (FD with common random numbers).

        Returns
        -------
        GradientSettings
            The gradient the prediction measures at θ*.
        """
        if not self.segments:
            return gradient
        return dataclasses.replace(gradient, step=round(0.744 * self._local(params, theta)[1], 12))

    def _local(self, params: ParamSpace, theta) -> tuple[int, float]:
        """(spp, step h) of the segment holding θ (the first where two hold it)."""
        parts = self.parts(params)
        s = _segment_of(float(np.ravel(theta)[0]), [t[:, 0] for t, _ in parts], 0)
        t, spp = parts[s]
        return spp, float(t[1, 0] - t[0, 0])


def _segment_of(theta: float, lattices: Sequence[np.ndarray], current: int) -> int:
    """Index of the segment whose span [t₀, t_last] holds θ: `current` where it does (two share their join), else
    the first that does, else the nearest."""
    if lattices[current][0] - 1e-12 <= theta <= lattices[current][-1] + 1e-12:
        return current
    gaps = [max(t[0] - theta, theta - t[-1], 0.0) for t in lattices]
    return int(np.argmin(gaps))


def _check_segments(segments, spp: int, step, region) -> list[dict]:
    """The segments as [{region: [a, b], step: h, spp: s}] (ValueError, one line, for a malformed one, for segments
    given with `step` or `region`, or for regions that are not contiguous and in order)."""
    if step is not None or region is not None:
        raise ValueError("surrogate: give either segments or step/region, not both")
    if isinstance(segments, (str, dict)) or not len(segments):
        raise ValueError(f"surrogate: segments must be a non-empty list of {{region, step, spp}}, got {segments!r}")
    out = []
    for k, seg in enumerate(segments):
        if not isinstance(seg, dict) or set(seg) - {"region", "step", "spp"} or not {"region", "step"} <= set(seg):
            raise ValueError(f"surrogate: segments[{k}] must be {{region: [a, b], step: h, spp: s (optional)}}, "
                             f"got {seg!r}")
        r, h, n = seg["region"], seg["step"], seg.get("spp", spp)
        if len(r) != 2 or not float(r[0]) < float(r[1]):
            raise ValueError(f"surrogate: segments[{k}].region must be [a, b] with a < b, got {r!r}")
        if isinstance(h, bool) or not isinstance(h, (int, float)) or not h > 0:
            raise ValueError(f"surrogate: segments[{k}].step must be > 0, got {h!r}")
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"surrogate: segments[{k}].spp must be a positive integer, got {n!r}")
        if out and abs(float(r[0]) - out[-1]["region"][1]) > 1e-12:
            raise ValueError(f"surrogate: segments[{k}] starts at {r[0]}, not where segments[{k - 1}] ends "
                             f"({out[-1]['region'][1]}): segments must be contiguous and in order")
        out.append({"region": [float(r[0]), float(r[1])], "step": float(h), "spp": int(n)})
    return out
