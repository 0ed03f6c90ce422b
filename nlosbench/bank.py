"""The render bank: the one place where a run's renders are planned, made, counted and kept.

A render is fixed by (θ, spp, seed) on a given model (the model's `content_key` holds the rest:
scene content, defines, variant, integrator, pass size). Studies and the bound service ask for *render
sets*: images (or FD Jacobians, or spp levels × replicates) of a list of θ for a named purpose. The
bank derives every seed itself (`seed`), looks each render up in its memory, renders the missing ones
through the run's executor (one task per request or per group, so worker processes share the load),
and counts every render once, worker processes included (a render served from memory or from the
model's disk cache counts 0; one read back from the run's store counts what it cost when it was made, once,
if the `owner` that asks now made it: a resumed study's count covers the work of every invocation). FD
Jacobians (central, common random numbers inside each stencil) are requests too.

Seed policy. seed = derive(run seed, "bank/" + purpose, spp, replicate[, key of θ]):
- a render set is (purpose, spp, replicate); two sets never share a seed, so independent render sets,
  each spp level and each replicate included, are independent (whether two spp counts of one seed
  share samples depends on how they split into passes, so they are never given one seed);
- `common=True` leaves θ out: every θ of the set gets the same seed (common random numbers across θ,
  so differences L(θ+Δ) − L(θ) carry far less rendering noise); otherwise the seed also depends on θ
  itself (not on its position in a list), so the same θ asked for by two studies is one render;
- purposes name what a set is for; the observation's mean (`TRUTH`) has its own purpose, so an
  estimator, which only ever sees other sets, never fits its own data's rendering noise.
Seeds are 32-bit (Mitsuba's), so two distinct sets collide with probability 2⁻³² per pair.

Store. With a `store` (a RenderCache, e.g. the run directory's renders/), every image and Jacobian the
bank makes is also kept on disk (atomic, checksummed), keyed by the model's content key and the
request: a resumed run reads them back instead of rendering, and a changed scene or setting can never
be served an old image (its key differs).

Charges. A caller whose decisions depend on what it spends (a precision budget) opens a `Ledger`: it is charged
every distinct request it asks for at what making it costs, whether the bank renders it, reads it from the store
or serves it from memory, so its decisions are the same cold, warm, resumed or after another study; the renders
this process made meanwhile are kept beside it (what was paid, never what decides).

Executor tasks are module-level functions `fn(model, item)` (pickled by reference into spawned
workers); each returns its result with the number of renders it made in that process.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from .executors import Executor, SerialExecutor
from .forward.cache import RenderCache, RenderKey, render_key
from .forward.gradients import GradientSettings, jacobian
from .forward.model import ForwardModel
from .seeds import derive

#: purpose of the renders that make an observation's mean (what noise is added to in a trial)
TRUTH = "truth"


def _rounded(theta) -> tuple:
    """θ as a tuple of floats rounded to 1e-12 of its units (−0 → 0)."""
    return tuple(float(v) for v in np.round(np.atleast_1d(np.asarray(theta, dtype=np.float64)), 12) + 0.0)


def theta_key(theta) -> int:
    """A 64-bit integer naming θ (rounded to 1e-12 of its units) for seed derivation."""
    import hashlib

    t = np.round(np.atleast_1d(np.asarray(theta, dtype=np.float64)), 12) + 0.0  # + 0.0: −0 → 0
    return int.from_bytes(hashlib.blake2b(repr(t.tolist()).encode(), digest_size=8).digest(), "little")


@dataclass(frozen=True)
class Request:
    """One render: θ (parameter units, one value per parameter), samples per pixel, seed."""

    theta: tuple
    spp: int
    seed: int

    @classmethod
    def of(cls, theta, spp: int, seed: int) -> Request:
        """θ rounded to 1e-12 of its units, so θ + ξ and a grid point equal to it are one request."""
        return cls(_rounded(theta), int(spp), int(seed))


@dataclass(frozen=True)
class JacobianRequest:
    """One image Jacobian at θ: central FD with step ξ, both sides of each stencil with `seed`'s derived
    seeds (common random numbers), `rounds` independent rounds averaged; or, with method "ad", Mitsuba's
    forward-mode AD with the integrator options `ad` (sorted (key, value) pairs)."""

    theta: tuple
    spp: int
    seed: int
    step: float
    rounds: int = 1
    method: str = "fd"
    ad: tuple = ()

    @classmethod
    def of(cls, theta, spp: int, seed: int, step: float, rounds: int = 1, method: str = "fd",
           ad: dict | None = None) -> JacobianRequest:
        """The request; an AD Jacobian has no step, so its step is GradientSettings' default whatever is given
        (one AD Jacobian is one request, not one per FD step a caller happens to pass)."""
        step = float(step) if method == "fd" else GradientSettings.step
        return cls(_rounded(theta), int(spp), int(seed), step, int(rounds), method, tuple(sorted((ad or {}).items())))

    def settings(self) -> GradientSettings:
        """The forward layer's GradientSettings for this request."""
        return GradientSettings(self.method, step=self.step, rounds=self.rounds, ad=dict(self.ad))


def charge(request: Request | JacobianRequest, result: torch.Tensor) -> int:
    """Pixel-samples a request costs to make, from its result's shape: spp × H × W per render; a Jacobian (P, H, W,
    C) 2 renders per parameter and round (central FD) or one pass per parameter (AD)."""
    pixels = int(result.shape[-3]) * int(result.shape[-2])
    if isinstance(request, JacobianRequest):
        per = 2 * request.rounds if request.method == "fd" else 1
        return per * int(result.shape[0]) * request.spp * pixels
    return request.spp * pixels


@dataclass
class Ledger:
    """What a caller asked a bank for while the ledger was open (`RenderBank.ledger`): `pixel_samples`, every
    distinct request charged once at its cost to make (`charge`), whatever served it; `rendered`, the
    pixel-samples of the renders (and AD passes) this process, its workers included, made for them (spp × H × W
    each; a render served by the model's disk cache is not made)."""

    pixel_samples: int = 0
    rendered: int = 0
    _seen: set = field(default_factory=set, repr=False)

    def ask(self, request: Request | JacobianRequest, result: torch.Tensor, renders: int) -> None:
        """Charge `request` (once) and record the `renders` made for it now."""
        if request not in self._seen:
            self._seen.add(request)
            self.pixel_samples += charge(request, result)
        self.rendered += renders * request.spp * int(result.shape[-3]) * int(result.shape[-2])


def check_spp(levels: Sequence[int], replicates: int = 1) -> np.ndarray:
    """spp levels as int64 (k,) after checking they are positive integers divisible by `replicates`
    (every replicate renders N/R spp)."""
    lv = np.asarray(levels)
    if lv.ndim != 1 or lv.size == 0 or not np.all(np.isfinite(lv)) or np.any(lv != np.round(lv)) or np.any(lv < 1):
        raise ValueError(f"levels must be a list of positive integer spp, got {levels!r}")
    if isinstance(replicates, bool) or int(replicates) != replicates or replicates < 1:
        raise ValueError(f"replicates must be a positive integer, got {replicates!r}")
    lv = lv.astype(np.int64)
    bad = lv[lv % int(replicates) != 0]
    if bad.size:
        raise ValueError(f"spp {bad.tolist()} not divisible by replicates = {replicates} "
                         "(each replicate renders N/R spp)")
    return lv


def render_task(model: ForwardModel, item: tuple) -> tuple:
    """Executor task: (tag, [Request, ...]) → (tag, images (n, H, W, C) float32, renders made here)."""
    tag, requests = item
    before = model.stats.snapshot()
    imgs = torch.stack([model.render(list(r.theta), r.spp, r.seed) for r in requests])
    return tag, imgs, model.stats.since(before).renders


def jacobian_task(model: ForwardModel, item: tuple) -> tuple:
    """Executor task: (tag, JacobianRequest) → (tag, Jacobian (P, H, W, C) float32, renders + AD passes made here)."""
    tag, r = item
    before = model.stats.snapshot()
    jac = jacobian(model, list(r.theta), r.spp, r.seed, r.settings())
    used = model.stats.since(before)
    return tag, jac, used.renders + used.grad_passes


class RenderBank:
    """Renders of one model for one run (see the module docstring): render sets by purpose (`at`,
    `jacobians_at`, `levels_at`), and the request-level `images`, `jacobians` and `map`.

    `renders` counts the renders made for this bank (worker processes included; a render served from
    memory or the model's disk cache counts 0).

    Parameters
    ----------
    model : ForwardModel
        The scene every request renders.
    executor : Executor, optional
        Where renders run (default: serially in this process, with `model`).
    progress : callable, optional
        `progress(iterable, total, desc)` wrapping the results (e.g. RunContext.progress); default: none.
    memory_bytes : int, default 2**30
        The most image bytes kept in memory for reuse (least recently used dropped first).
    seed : int, default 0
        The run's seed, from which every render seed derives.
    store : RenderCache, optional
        An on-disk cache for every result (resume); None keeps results in memory only.

    Examples
    --------
    >>> bank = nb.RenderBank(nb.scenes.get("blob2d"), seed=1)
    >>> bank.at([[0.4, 0.5], [0.6, 0.5]], spp=4, purpose="demo").shape
    torch.Size([2, 24, 24, 1])
    >>> bank.renders
    2
    """

    def __init__(self, model: ForwardModel, executor: Executor | None = None, progress: Callable | None = None,
                 memory_bytes: int = 1 << 30, seed: int = 0, store: RenderCache | None = None):
        self.model = model
        self.run_seed = int(seed)
        self.store = store
        self.executor = executor if executor is not None else SerialExecutor(model=model)
        self.progress = progress or (lambda it, total=None, desc="": it)
        self.memory_bytes = int(memory_bytes)
        self.renders = 0
        self.owner = ""  # who asks now (the runner sets the study's id): kept with each stored render
        self._counted: set[str] = set()  # store keys whose renders this bank has counted
        self._memo: OrderedDict[Hashable, torch.Tensor] = OrderedDict()
        self._held = 0
        self._ledgers: list[Ledger] = []

    @contextmanager
    def ledger(self) -> Iterator[Ledger]:
        """A Ledger charged every request asked for inside the `with` block (see the module docstring)."""
        book = Ledger()
        self._ledgers.append(book)
        try:
            yield book
        finally:
            self._ledgers.remove(book)

    def _ask(self, request: Request | JacobianRequest, result: torch.Tensor, renders: int) -> None:
        for book in self._ledgers:
            book.ask(request, result, renders)

    # -- seeds and render sets ---------------------------------------------------------------------
    def seed(self, purpose: str, spp: int, theta=None, replicate: int = 0) -> int:
        """The seed of θ in render set (purpose, spp, replicate); θ None: the set's common seed.

        Parameters
        ----------
        purpose : str
            What the render set is for (e.g. "truth", "grid"); sets of different purposes never share seeds.
        spp : int
            Samples per pixel of the set.
        theta : array_like, optional
            θ in parameter units; None gives the seed every θ of the set shares (common random numbers).
        replicate : int, default 0
            The replicate of the set.

        Returns
        -------
        int
            A 32-bit render seed derived from the run's seed.
        """
        idx = [int(spp), int(replicate)] + ([] if theta is None else [theta_key(theta)])
        return derive(self.run_seed, f"bank/{purpose}", *idx)

    def request(self, theta, spp: int, purpose: str, common: bool = False, replicate: int = 0) -> Request:
        """The Request of θ in a render set (see `seed`).

        Parameters
        ----------
        theta : array_like
            θ in parameter units.
        spp : int
            Samples per pixel.
        purpose : str
            The render set's purpose.
        common : bool, default False
            Give θ the set's common seed instead of one that depends on θ.
        replicate : int, default 0
            The replicate of the set.

        Returns
        -------
        Request
            (θ rounded to 1e-12 of its units, spp, seed).
        """
        return Request.of(theta, spp, self.seed(purpose, spp, None if common else theta, replicate))

    def at(self, thetas, spp: int, purpose: str, common: bool = False, replicate: int = 0,
           desc: str | None = None) -> torch.Tensor:
        """Images (N, H, W, C) float32 of thetas (N,) or (N, P) in render set (purpose, spp, replicate).

        Parameters
        ----------
        thetas : array_like
            N points in parameter units, (N, P), or (N,) for a one-parameter model.
        spp : int
            Samples per pixel.
        purpose : str
            The render set's purpose.
        common : bool, default False
            Every θ gets the set's common seed (common random numbers across θ).
        replicate : int, default 0
            The replicate of the set.
        desc : str, optional
            The progress label (default: "<purpose> renders").

        Returns
        -------
        torch.Tensor
            The images (N, H, W, C) float32, in the order of `thetas`.
        """
        return self.images([self.request(t, spp, purpose, common, replicate) for t in _points(thetas)],
                           desc or f"{purpose} renders")

    def sets(self, thetas, spp: int, purpose: str, replicates: range, common: bool = False,
             desc: str | None = None) -> torch.Tensor:
        """Images (R, N, H, W, C) float32 of thetas (N,) or (N, P) in the R render sets `replicates` of (purpose,
        spp): `at` for each replicate, asked for in one list so that each θ's R renders are made one after the
        other (the scene is written once per θ).

        Parameters
        ----------
        thetas : array_like
            N points in parameter units, (N, P), or (N,) for a one-parameter model.
        spp : int
            Samples per pixel.
        purpose : str
            The render sets' purpose.
        replicates : range
            The replicate indices r of the sets, R of them.
        common : bool, default False
            Every θ of a set gets the set's common seed (common random numbers across θ).
        desc : str, optional
            The progress label (default: "<purpose> renders").

        Returns
        -------
        torch.Tensor
            The images (R, N, H, W, C) float32: [r, i] is θ_i in set replicates[r].

        Examples
        --------
        >>> bank = nb.RenderBank(nb.scenes.get("blob2d"), seed=0)
        >>> bank.sets([[0.4, 0.5], [0.6, 0.5]], spp=4, purpose="demo", replicates=range(3)).shape
        torch.Size([3, 2, 24, 24, 1])
        """
        pts = _points(thetas)
        imgs = self.images([self.request(t, spp, purpose, common, r) for r in replicates for t in pts],
                           desc or f"{purpose} renders")
        return imgs.reshape((len(replicates), len(pts)) + tuple(imgs.shape[1:]))

    def jacobians_at(self, thetas, spp: int, step: float, purpose: str, common: bool = False, replicate: int = 0,
                     rounds: int = 1, desc: str | None = None, method: str = "fd", ad: dict | None = None
                     ) -> torch.Tensor:
        """Jacobians (N, P, H, W, C) of thetas in render set (purpose + "-fd", spp, replicate): central FD with
        step ξ, R `rounds` averaged, every stencil with common random numbers inside it (with `common`
        every θ shares the set's seed too); or method "ad" with integrator options `ad`.

        Parameters
        ----------
        thetas : array_like
            N points in parameter units, (N, P), or (N,) for a one-parameter model.
        spp : int
            Samples per pixel of each render.
        step : float
            FD step ξ, in parameter units.
        purpose : str
            The render set's purpose ("-fd" is appended).
        common : bool, default False
            Every θ gets the set's common seed.
        replicate : int, default 0
            The replicate of the set.
        rounds : int, default 1
            FD rounds averaged (independent seeds).
        desc : str, optional
            The progress label (default: "<purpose> FD Jacobians").
        method : {"fd", "ad"}, default "fd"
            Finite differences or forward-mode AD.
        ad : dict, optional
            AD integrator options (method "ad").

        Returns
        -------
        torch.Tensor
            The Jacobians (N, P, H, W, C) float32, image units per parameter unit.
        """
        reqs = [JacobianRequest.of(t, spp, self.seed(purpose + "-fd", spp, None if common else t, replicate), step,
                                   rounds, method, ad) for t in _points(thetas)]
        return self.jacobians(reqs, desc or f"{purpose} FD Jacobians")

    def levels_at(self, thetas, levels: Sequence[int], replicates: int, purpose: str, common: bool = False,
                  desc: str | None = None) -> torch.Tensor:
        """Renders (k, R, N, H, W, C) of thetas at k spp levels N_i × R replicates of N_i / R spp each:
        level i, replicate r is render set (purpose, N_i / R, r) — independent across levels and
        replicates; with `common`, every θ of a (level, replicate) shares its seed.

        Parameters
        ----------
        thetas : array_like
            N points in parameter units, (N, P), or (N,) for a one-parameter model.
        levels : sequence of int
            The k total spp levels N_i, each divisible by `replicates`.
        replicates : int
            R, the replicates per level.
        purpose : str
            The render sets' purpose.
        common : bool, default False
            Every θ of a (level, replicate) shares its seed.
        desc : str, optional
            The progress label (default: "<purpose> levels").

        Returns
        -------
        torch.Tensor
            The renders (k, R, N, H, W, C) float32.
        """
        lv = check_spp(levels, replicates) // replicates
        pts = _points(thetas)
        reqs = [self.request(t, int(n), purpose, common, r) for n in lv for r in range(replicates) for t in pts]
        X = self.images(reqs, desc or f"{purpose} levels")
        return X.reshape(len(lv), replicates, len(pts), *X.shape[1:])

    # -- memory ----------------------------------------------------------------------------------
    def _store_key(self, key: Hashable) -> RenderKey:
        return render_key(model=self.model.content_key(), request=repr(key))

    def _get(self, key: Hashable) -> torch.Tensor | None:
        hit = self._memo.get(key)
        if hit is not None:
            self._memo.move_to_end(key)
        elif self.store is not None:
            skey = self._store_key(key)
            entry = self.store.read(skey)
            if entry is not None:
                hit, meta = entry
                if skey.hex not in self._counted and meta.get("by") == self.owner:  # made by an earlier invocation
                    self.renders += int(meta.get("renders", 0))
                    self._counted.add(skey.hex)
                self._remember(key, hit)
        return hit

    def _keep(self, key: Hashable, value: torch.Tensor, renders: int) -> None:
        if self.store is not None:
            skey = self._store_key(key)
            self.store.put(skey, value, renders=renders, by=self.owner)
            self._counted.add(skey.hex)
        self._remember(key, value)

    def _remember(self, key: Hashable, value: torch.Tensor) -> None:
        size = value.numel() * value.element_size()
        if size > self.memory_bytes or key in self._memo:
            return
        self._memo[key] = value
        self._held += size
        while self._held > self.memory_bytes:
            _, old = self._memo.popitem(last=False)
            self._held -= old.numel() * old.element_size()

    def map(self, fn: Callable, items: list, desc: str) -> Iterable[tuple[Hashable, object]]:
        """(tag, value) of a study's own render task `fn(model, item) → (tag, value, renders made)` over
        `items` through the executor, as they finish; renders are counted. For renders the bank's request
        types cannot describe (e.g. a camera posed outside θ); nothing is kept in memory.

        Parameters
        ----------
        fn : callable
            A module-level function `fn(model, item)` returning (tag, value, renders made).
        items : list
            The tasks' inputs.
        desc : str
            The progress label.

        Yields
        ------
        tuple of (hashable, object)
            (tag, value) of each task, in the order they finish.
        """
        for tag, value, _ in self._tasks(fn, items, desc):
            yield tag, value

    def _tasks(self, fn: Callable, items: list, desc: str) -> Iterable[tuple[Hashable, object, int]]:
        """As `map`, with the renders each task made."""
        for tag, value, renders in self.progress(self.executor.imap_unordered(fn, items), total=len(items), desc=desc):
            self.renders += renders
            yield tag, value, renders

    # -- requests --------------------------------------------------------------------------------
    def images(self, requests: Sequence[Request], desc: str = "renders") -> torch.Tensor:
        """Images (N, H, W, C) float32 for `requests`, in their order (repeated requests rendered once).

        Parameters
        ----------
        requests : sequence of Request
            The N renders.
        desc : str, default "renders"
            The progress label.

        Returns
        -------
        torch.Tensor
            The images (N, H, W, C) float32.
        """
        out: dict[Request, torch.Tensor] = {}
        todo = []
        for r in dict.fromkeys(requests):
            hit = self._get(r)
            if hit is None:
                todo.append(r)
            else:
                out[r] = hit
                self._ask(r, hit, 0)
        # one task per θ: a model writes θ into its scene only when θ changes (a mesh's update rebuilds its
        # acceleration structure, which costs as much as a small render), so R replicates of a θ pay it once,
        # whichever worker renders them
        groups: dict[tuple, list[Request]] = {}
        for r in todo:
            groups.setdefault(r.theta, []).append(r)
        for theta, imgs, renders in self._tasks(render_task, list(groups.items()), desc):
            group = groups[theta]
            for i, (r, img) in enumerate(zip(group, imgs, strict=True)):
                made = renders // len(group) + (i < renders % len(group))  # the task's renders, one per image
                out[r] = img
                self._keep(r, img, made)
                self._ask(r, img, made)
        return torch.stack([out[r] for r in requests])

    def jacobians(self, requests: Sequence[JacobianRequest], desc: str = "FD Jacobians") -> torch.Tensor:
        """Jacobians (N, P, H, W, C) float32 for `requests`, in their order.

        Parameters
        ----------
        requests : sequence of JacobianRequest
            The N Jacobians.
        desc : str, default "FD Jacobians"
            The progress label.

        Returns
        -------
        torch.Tensor
            The Jacobians (N, P, H, W, C) float32.
        """
        out: dict[JacobianRequest, torch.Tensor] = {}
        todo = []
        for r in dict.fromkeys(requests):
            hit = self._get(r)
            if hit is None:
                todo.append(r)
            else:
                out[r] = hit
                self._ask(r, hit, 0)
        for r, jac, renders in self._tasks(jacobian_task, [(r, r) for r in todo], desc):
            out[r] = jac
            self._keep(r, jac, renders)
            self._ask(r, jac, renders)
        return torch.stack([out[r] for r in requests])


def _points(thetas) -> np.ndarray:
    """θ points as (N, P) float64 from (N,) (scalar θ) or (N, P)."""
    t = np.asarray(thetas, dtype=np.float64)
    return t.reshape(-1, 1) if t.ndim <= 1 else t
