"""Pooled Fisher information maps: cells of pixels chosen on half of the FD rounds, estimated on the other half.

A per-pixel unbiased FI map from a few rounds is mostly rendering noise of both signs wherever the signal is
weak (NLOS): no pixel is resolved. Pooling pixels into cells adds their information (F_C = Σ_{i∈C} F_i) while
the noise of a U-statistic adds in quadrature (pixels are independent: each pixel's Monte Carlo samples are
its own), so a large enough cell is resolved. The cells adapt to where the information is.

Per pixel i and round r, J_r,i (channels c) is round r's central-FD Jacobian and w_i,c the noise model's
weight (AWGN 1/σ², Poisson scale/L). Over a set S of m independent rounds, the pixel's U-statistic
T_i = Σ_{r≠s∈S} Σ_c w_ic J_r,ic J_s,ic / (m(m−1)) is unbiased for F_i = Σ_c w_ic (E J_ic)² (÷ C channels
for `reduce="mean"`), and its variance estimate v_i is the delete-one jackknife over the m rounds
(`ustat.pixel_terms`, m ≥ 3) or, for m = 2, T_i² itself (E T_i² = Var T_i + F_i² ≥ Var T_i: conservative;
a cell of n pixels then has |T_C|/SE_C ≤ √n, so cells of fewer than about q² pixels are never resolved).
A cell C has T_C = Σ_{i∈C} T_i, SE_C² = Σ_{i∈C} v_i and Satterthwaite's degrees of freedom
(Σ v_i)² / (Σ v_i² / (m − 1)), as `ustat.sum_terms` sums over pixels.

Cells (`select_cells`, on the selection rounds A): a quadtree over the image. A node is split into its (up
to) four quadrants where that resolves at least as many cells as the node alone: quadrants that resolve a
cell somewhere inside are split further, the others are pooled into one "rest" cell (their union, masked
where it is not resolved). Resolved on A means T − q·SE > 0 (and, with `precision` p, (T + q·SE)/T ≤ 1 + p
and T/(T − q·SE) ≤ 1 + p), q the one-sided Student-t quantile at `level` with Bonferroni over 2K limits, K
the number of cells (a fixed point: the partition is rebuilt with K from the last one until K repeats).

Estimates (`estimate_cells`, on the estimation rounds B, disjoint from A): per cell T_C, SE_C and the
one-sided limits T_C ∓ q_K·SE_C with q_K at `level` shared by the 2K limits of all cells (Bonferroni).
The map draws the cells chosen on A (resolved there), valued by B; a drawn cell whose B limits also exclude
0 is "resolved" (confirmed); cells not chosen on A are masked. Drawing only the cells B resolves would pick
them by B's own estimate again (measured on a weak ramp: ≈ 1.5–3× the true information).

Coverage whatever the cells. (1) The cells and the choice of drawn cells are functions of the rounds A alone,
and the rounds B are independent of A, so given A they are fixed and the T_C over B have their unconditional
distribution: unbiased, E[T_C | A] = F_C. (2) For fixed cells each of the 2K limits holds with probability
≥ 1 − (1 − level)/(2K) (t limits of a sum of independent pixels), so by the union bound all hold together with
probability ≥ level given A, hence ≥ level averaged over A. (3) So every drawn value is unbiased and every
interval, resolved or not, holds jointly at `level`. Choosing and estimating on the same rounds breaks (1):
cells drawn around noise peaks are biased high (winner's curse) and pure noise is "resolved".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nlosbench.bounds.hcr import as_numpy
from nlosbench.bounds.ustat import pixel_terms, sum_terms, t_quantile


@dataclass(frozen=True)
class PixelTerms:
    """Per-pixel U-statistics of one parameter's Fisher information over m rounds.

    Parameters
    ----------
    est : ndarray of shape (H, W)
        T_i, unbiased for the pixel's FI, 1/(parameter units)² (may be < 0).
    var : ndarray of shape (H, W)
        v_i, the estimate of Var T_i (jackknife for m ≥ 3; T_i² for m = 2), 1/(parameter units)⁴.
    rounds : int
        m, the number of rounds.
    """

    est: np.ndarray
    var: np.ndarray
    rounds: int


def pixel_fisher_terms(J, weight, reduce: str = "sum") -> PixelTerms:
    """Per-pixel unbiased Fisher information of one parameter and its variance estimate from m rounds.

    Parameters
    ----------
    J : array_like of shape (m, H, W, C) or (m, H, W)
        m ≥ 2 independent rounds of the parameter's central-FD Jacobian, radiance per parameter unit.
    weight : float or array_like broadcastable to (H, W, C)
        The noise model's per-pixel weight (AWGN 1/σ², Poisson scale/L), ≥ 0, independent of the rounds.
    reduce : {"sum", "mean"}, optional
        How the channels combine (as `fisher_maps`).

    Returns
    -------
    PixelTerms
        T_i and v_i (H, W), float64, and m.
    """
    if reduce not in ("sum", "mean"):
        raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
    J = np.asarray(as_numpy(J), dtype=np.float64)
    if J.ndim == 3:
        J = J[..., None]
    if J.ndim != 4 or J.shape[0] < 2:
        raise ValueError(f"need rounds J (m >= 2, H, W, C), got shape {J.shape}")
    m, H, W, C = J.shape
    w = np.broadcast_to(np.asarray(as_numpy(weight), dtype=np.float64), (H, W, C))
    x = J.reshape(m, H * W, C).transpose(0, 2, 1)  # (m, C, N): k = channels
    per, lo = pixel_terms(x, w.reshape(H * W, C).T)
    scale = 1.0 if reduce == "sum" else 1.0 / C
    est = scale * per.sum(axis=0)  # (N,)
    if m == 2:
        var = est * est
    else:
        _, _, se, _, _ = sum_terms(est[:, None], scale * lo.sum(axis=1)[:, :, None], m)  # each pixel its own sum
        var = se * se
    return PixelTerms(est.reshape(H, W), var.reshape(H, W), m)


@dataclass(frozen=True)
class CellStats:
    """Cell totals of per-pixel terms: the FI U-statistic, its SE and degrees of freedom, per cell.

    Parameters
    ----------
    est : ndarray of shape (K,)
        T_C = Σ_{i∈C} T_i, 1/(parameter units)².
    se : ndarray of shape (K,)
        √(Σ_{i∈C} v_i).
    df : ndarray of shape (K,)
        Satterthwaite's degrees of freedom.
    pixels : ndarray of shape (K,)
        Pixels per cell.
    """

    est: np.ndarray
    se: np.ndarray
    df: np.ndarray
    pixels: np.ndarray


def _satterthwaite(v: np.ndarray, v2: np.ndarray, rounds: int) -> np.ndarray:
    """(Σ v)² / (Σ v² / (m − 1)) from the sums v = Σ v_i and v2 = Σ v_i² (m − 1 where v = 0)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(v > 0, v * v / (v2 / (rounds - 1)), rounds - 1.0)


def cell_stats(terms: PixelTerms, labels: np.ndarray) -> CellStats:
    """Sum per-pixel terms over cells.

    Parameters
    ----------
    terms : PixelTerms
        Per-pixel T_i and v_i (H, W) over m rounds.
    labels : ndarray of int, shape (H, W)
        The cell of each pixel, 0 … K − 1.

    Returns
    -------
    CellStats
        Per cell: T_C, SE_C, Satterthwaite's degrees of freedom, pixel count.
    """
    lab = np.asarray(labels).reshape(-1)
    K = int(lab.max()) + 1
    v = terms.var.reshape(-1)

    def total(x):
        return np.bincount(lab, weights=x, minlength=K)

    var = total(v)
    return CellStats(total(terms.est.reshape(-1)), np.sqrt(var), _satterthwaite(var, total(v * v), terms.rounds),
                     np.bincount(lab, minlength=K))


def _limits(est, se, df, level: float, tests: int) -> tuple[np.ndarray, np.ndarray]:
    """One-sided limits est ∓ q·se at `level` shared by `tests` limits (NaN q where df < 2: −∞, +∞)."""
    q = np.asarray(t_quantile(level, df, tests), dtype=np.float64)
    q = np.where(np.isfinite(q), q, np.inf)
    with np.errstate(invalid="ignore"):
        lower = np.where(se > 0, est - q * se, np.where(est > 0, est, -np.inf))
        upper = np.where(se > 0, est + q * se, np.where(est > 0, est, np.inf))
    return np.nan_to_num(lower, nan=-np.inf), np.nan_to_num(upper, nan=np.inf)


def _resolved(est, lower, upper, precision: float | None) -> np.ndarray:
    """lower > 0, and with a precision p: upper/est ≤ 1 + p and est/lower ≤ 1 + p."""
    ok = lower > 0
    if precision is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            ok &= (upper <= (1 + precision) * est) & (est <= (1 + precision) * lower)
    return ok


def _children(y0: int, y1: int, x0: int, x1: int) -> list[tuple[int, int, int, int]]:
    """The (up to) four quadrants of a rectangle [y0, y1) × [x0, x1); none for a single pixel."""
    ys = [(y0, (y0 + y1) // 2), ((y0 + y1) // 2, y1)] if y1 - y0 >= 2 else [(y0, y1)]
    xs = [(x0, (x0 + x1) // 2), ((x0 + x1) // 2, x1)] if x1 - x0 >= 2 else [(x0, x1)]
    return [] if len(ys) == len(xs) == 1 else [(a, b, c, d) for a, b in ys for c, d in xs]


def _partition(terms: PixelTerms, level: float, tests: int, precision: float | None) -> np.ndarray:
    """The quadtree partition (labels (H, W)) of `select_cells` at a fixed Bonferroni count `tests`."""
    H, W = terms.est.shape
    nodes, kids, depths = [(0, H, 0, W)], [[]], [(0, 1)]  # the full quadtree, one depth [start, stop) at a time
    while depths[-1][1] > depths[-1][0]:
        start = len(nodes)
        for n in range(*depths[-1]):
            ch = _children(*nodes[n])
            kids[n] = list(range(len(nodes), len(nodes) + len(ch)))
            nodes.extend(ch)
            kids.extend([] for _ in ch)
        depths.append((start, len(nodes)))
    r = np.array(nodes)

    def res(est, var, var2):
        est, var, var2 = (np.asarray(a, dtype=np.float64) for a in (est, var, var2))
        lower, upper = _limits(est, np.sqrt(var), _satterthwaite(var, var2, terms.rounds), level, tests)
        return _resolved(est, lower, upper, precision)

    pix = np.stack([terms.est, terms.var, terms.var ** 2])  # (3, H, W)
    node_sums = np.empty((3, len(nodes)))
    for lo, hi in reversed(depths[:-1]):  # each node the sum of its quadrants, a pixel its own: no cancellation
        inner = np.array([n for n in range(lo, hi) if kids[n]], dtype=np.int64)
        leaf = np.array([n for n in range(lo, hi) if not kids[n]], dtype=np.int64)
        node_sums[:, leaf] = pix[:, r[leaf, 0], r[leaf, 2]]
        if inner.size:  # their quadrants are the next depth's nodes, in order
            first = np.array([kids[n][0] for n in inner])
            node_sums[:, inner] = np.add.reduceat(node_sums[:, first[0]:kids[inner[-1]][-1] + 1], first - first[0],
                                                  axis=1)
    alone = res(*node_sums)
    best: list = [None] * len(nodes)  # per node: (resolved cells, cells as lists of node indices)
    for lo, hi in reversed(depths):  # deepest first: children before parents
        split = {}
        for n in range(lo, hi):
            kept = [k for k in kids[n] if best[k][0] > 0]
            if kept:
                split[n] = (kept, [k for k in kids[n] if best[k][0] == 0])
            else:
                best[n] = (int(alone[n]), [[n]])
        with_rest = [n for n, (_, rest) in split.items() if rest]
        rest_ok = dict(zip(with_rest, res(*np.array([node_sums[:, split[n][1]].sum(axis=1) for n in with_rest]).T),
                           strict=True)) if with_rest else {}
        for n, (kept, rest) in split.items():
            cells = [c for k in kept for c in best[k][1]] + ([rest] if rest else [])
            score = sum(best[k][0] for k in kept) + int(rest_ok.get(n, False))
            best[n] = (score, cells) if score >= alone[n] else (int(alone[n]), [[n]])
    labels = np.empty((H, W), dtype=np.int64)
    for c, cell in enumerate(best[0][1]):
        for n in cell:
            y0, y1, x0, x1 = nodes[n]
            labels[y0:y1, x0:x1] = c
    return labels


def select_cells(terms: PixelTerms, level: float = 0.95, precision: float | None = None,
                 max_iter: int = 8) -> np.ndarray:
    """Cells of pixels from the selection rounds: a quadtree refined where its cells stay resolved.

    A node is split into its quadrants where that resolves at least as many cells as the node alone (a
    quadrant with a resolved cell inside is split further, the other quadrants are pooled into one cell);
    resolved at `level` with Bonferroni over 2K limits (K cells: a fixed point over the partition, at most
    `max_iter` rebuilds, the most conservative kept if it does not settle). Any rule would keep the
    estimation half's coverage (module docstring); this one aims at many small resolved cells.

    Parameters
    ----------
    terms : PixelTerms
        Per-pixel terms of the selection rounds only.
    level : float, optional
        Familywise confidence level of the limits, in (0, 1).
    precision : float, optional
        A relative precision p a resolved cell must also meet (None: lower limit > 0 only).
    max_iter : int, optional
        The most rebuilds of the partition with the Bonferroni count of the last.

    Returns
    -------
    ndarray of int64, shape (H, W)
        The cell of each pixel, 0 … K − 1.
    """
    K, seen, labels = 1, {}, None
    for _ in range(max(int(max_iter), 1)):
        labels = _partition(terms, level, 2 * K, precision)
        K_new = int(labels.max()) + 1
        seen[K] = labels
        if K_new == K:
            return labels
        if K_new in seen:  # a cycle: keep the partition built with the largest Bonferroni count
            return seen[max(seen)]
        K = K_new
    return seen[max(seen)]


@dataclass(frozen=True)
class PooledFisherMap:
    """A pooled Fisher information map: cells, their estimates and Bonferroni limits, which are resolved.

    Parameters
    ----------
    labels : ndarray of int64, shape (H, W)
        The cell of each pixel, 0 … K − 1 (chosen on the selection rounds).
    est : ndarray of shape (K,)
        Each cell's total FI from the estimation rounds, 1/(parameter units)².
    se : ndarray of shape (K,)
        Its standard error.
    df : ndarray of shape (K,)
        Its degrees of freedom.
    lower, upper : ndarray of shape (K,)
        One-sided limits at `level`, Bonferroni over the 2K limits (−∞ / +∞ where there is no SE).
    resolved : ndarray of bool, shape (K,)
        lower > 0 (and the precision met) on the estimation rounds.
    chosen : ndarray of bool, shape (K,)
        Resolved on the selection rounds: the cells the map draws (valued by the estimation rounds).
    pixels : ndarray of int64, shape (K,)
        Pixels per cell.
    level : float
        The familywise confidence level.
    select_rounds, estimate_rounds : tuple of int
        The round indices each half used (disjoint).
    precision : float or None
        The relative precision a resolved cell meets (None: lower > 0 only).

    Examples
    --------
    Six rounds: cells chosen on three, valued on the other three:

    >>> import numpy as np
    >>> mean = np.zeros((32, 32)); mean[8:16, 8:16] = 1.0
    >>> m = nb.bounds.pool_fisher_map(mean + np.random.default_rng(0).normal(size=(6, 32, 32)), 1.0)
    >>> m.select_rounds, m.estimate_rounds, m.tests == 2 * m.cells
    ((0, 1, 2), (3, 4, 5), True)
    >>> bool(np.isclose(np.nansum(m.density("all")), m.est.sum()))  # a cell's density sums to its estimate
    True
    """

    labels: np.ndarray
    est: np.ndarray
    se: np.ndarray
    df: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    resolved: np.ndarray
    chosen: np.ndarray
    pixels: np.ndarray
    level: float
    select_rounds: tuple
    estimate_rounds: tuple
    precision: float | None = None

    @property
    def cells(self) -> int:
        """K, the number of cells."""
        return int(self.est.size)

    @property
    def tests(self) -> int:
        """The Bonferroni count: 2K one-sided limits."""
        return 2 * self.cells

    def density(self, cells: str = "chosen") -> np.ndarray:
        """Each pixel's cell FI per pixel (the cell's estimate / its pixel count), NaN outside `cells`.

        Parameters
        ----------
        cells : {"chosen", "resolved", "all"}, optional
            Which cells keep a value: those chosen on the selection rounds (the drawn map: unbiased given
            the selection), those also resolved on the estimation rounds, or every cell.

        Returns
        -------
        ndarray of shape (H, W)
            FI per pixel, 1/(parameter units)²; it sums over a cell to the cell's estimate.
        """
        keep = {"chosen": self.chosen, "resolved": self.chosen & self.resolved,
                "all": np.ones(self.cells, dtype=bool)}
        if cells not in keep:
            raise ValueError(f"cells must be 'chosen', 'resolved' or 'all', got {cells!r}")
        d = np.where(keep[cells], self.est / np.maximum(self.pixels, 1), np.nan)
        return d[self.labels]


def estimate_cells(terms: PixelTerms, labels: np.ndarray, level: float = 0.95,
                   precision: float | None = None) -> tuple[CellStats, np.ndarray, np.ndarray, np.ndarray]:
    """Cell estimates with one-sided limits at `level`, Bonferroni over the 2K limits of K cells.

    Parameters
    ----------
    terms : PixelTerms
        Per-pixel terms of the estimation rounds (independent of those `labels` were chosen on).
    labels : ndarray of int, shape (H, W)
        The cells, 0 … K − 1.
    level : float, optional
        Familywise confidence level, in (0, 1).
    precision : float, optional
        A relative precision p a resolved cell must also meet.

    Returns
    -------
    tuple
        (CellStats, lower (K,), upper (K,), resolved (K,) bool).
    """
    st = cell_stats(terms, labels)
    lower, upper = _limits(st.est, st.se, st.df, level, 2 * st.est.size)
    return st, lower, upper, _resolved(st.est, lower, upper, precision)


def pool_fisher_map(J, weight, level: float = 0.95, reduce: str = "sum",
                    precision: float | None = None) -> PooledFisherMap:
    """A pooled, masked Fisher information map of one parameter from R ≥ 4 independent FD rounds.

    Cells are chosen on the first ⌊R/2⌋ rounds (`select_cells`) and estimated on the other ⌈R/2⌉
    (`estimate_cells`), so the limits hold jointly at `level` whatever the cells (module docstring).

    Parameters
    ----------
    J : array_like of shape (R, H, W, C) or (R, H, W)
        R ≥ 4 independent rounds of the parameter's central-FD Jacobian, radiance per parameter unit.
    weight : float or array_like broadcastable to (H, W, C)
        The noise model's per-pixel weight, independent of the rounds.
    level : float, optional
        Familywise confidence level, in (0, 1).
    reduce : {"sum", "mean"}, optional
        How the channels combine.
    precision : float, optional
        A relative precision p a resolved cell must meet as well (None: its lower limit > 0).

    Returns
    -------
    PooledFisherMap
        The cells, their estimates and limits, which are resolved.

    Examples
    --------
    A bright 8 × 8 square (per-pixel FI 1) on a dark 32 × 32 image, 6 rounds with noise σ = 1:

    >>> import numpy as np
    >>> mean = np.zeros((32, 32)); mean[8:16, 8:16] = 1.0
    >>> J = mean + np.random.default_rng(0).normal(size=(6, 32, 32))
    >>> m = nb.bounds.pool_fisher_map(J, 1.0)
    >>> bool((m.chosen & m.resolved).any()), float(np.nansum(m.density()) / 64) > 0.5
    (True, True)
    """
    J = np.asarray(as_numpy(J), dtype=np.float64)
    R = J.shape[0]
    if R < 4:
        raise ValueError(f"a pooled map needs >= 4 independent rounds (>= 2 to choose cells, >= 2 to estimate), "
                         f"got {R}")
    if precision is not None and not precision > 0:
        raise ValueError(f"precision must be > 0, got {precision}")
    a, b = tuple(range(R // 2)), tuple(range(R // 2, R))
    sel = pixel_fisher_terms(J[list(a)], weight, reduce)
    labels = select_cells(sel, level, precision)
    chosen = estimate_cells(sel, labels, level, precision)[3]
    st, lower, upper, ok = estimate_cells(pixel_fisher_terms(J[list(b)], weight, reduce), labels, level, precision)
    return PooledFisherMap(labels, st.est, st.se, st.df, lower, upper, ok, chosen, st.pixels, level, a, b, precision)


def pooled_summary(m: PooledFisherMap) -> str:
    """One line: cells, drawn (chosen), resolved, level, Bonferroni count, the rounds of each half.

    Parameters
    ----------
    m : PooledFisherMap
        The pooled map.

    Returns
    -------
    str
        E.g. "12 cells, 4 drawn (chosen on rounds [0, 1, 2]), 3 of them resolved at 95 % …".
    """
    drawn = m.chosen
    return (f"{m.cells} cells, {int(drawn.sum())} drawn (resolved on rounds {_span(m.select_rounds)}), "
            f"{int((drawn & m.resolved).sum())} of them resolved on rounds {_span(m.estimate_rounds)} at "
            f"{m.level:.0%} (Bonferroni over {m.tests} one-sided limits)")


def _span(rounds) -> str:
    """Round indices as written: "0–23" for a run of more than three, else "[0, 1, 2]"."""
    r = [int(x) for x in rounds]
    return f"{r[0]}–{r[-1]}" if len(r) > 3 and r == list(range(r[0], r[-1] + 1)) else str(r)
