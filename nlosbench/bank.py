"""The render bank: the one place where a run's renders are made, counted and kept.

A render is fixed by (θ, spp, seed) on a given model (the model's `content_key` holds the rest:
scene content, defines, variant, integrator, pass size). Studies and the bound service describe what
they need as requests; the bank looks each up in its memory, renders the missing ones through the
run's executor (one task per request or per group, so worker processes share the load), and counts
every render once, worker processes included (a render served from memory or from the model's disk
cache counts 0). FD Jacobians (central, common random numbers inside each stencil) are requests too.

Executor tasks are module-level functions `fn(model, item)` (pickled by reference into spawned
workers); each returns its result with the number of renders it made in that process.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .executors import Executor, SerialExecutor
from .forward.gradients import GradientSettings, fd_jacobian
from .forward.model import ForwardModel
from .seeds import derive


@dataclass(frozen=True)
class Request:
    """One render: θ (parameter units, one value per parameter), samples per pixel, seed."""

    theta: tuple
    spp: int
    seed: int

    @classmethod
    def of(cls, theta, spp: int, seed: int) -> Request:
        return cls(tuple(float(v) for v in np.atleast_1d(np.asarray(theta, dtype=np.float64))), int(spp), int(seed))


@dataclass(frozen=True)
class JacobianRequest:
    """One central-FD image Jacobian at θ with step ξ, both sides of each stencil with `seed`'s derived
    seeds (common random numbers), `rounds` independent rounds averaged."""

    theta: tuple
    spp: int
    seed: int
    step: float
    rounds: int = 1

    @classmethod
    def of(cls, theta, spp: int, seed: int, step: float, rounds: int = 1) -> JacobianRequest:
        t = tuple(float(v) for v in np.atleast_1d(np.asarray(theta, dtype=np.float64)))
        return cls(t, int(spp), int(seed), float(step), int(rounds))


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


def level_requests(theta, levels: Sequence[int], replicates: int, seed: int, purpose: str = "levels",
                   index: int = 0) -> list[Request]:
    """Requests (k·R, level-major) for one θ point at k spp levels × R replicates: level i, replicate r
    renders levels[i] // R spp with seed derive(seed, "inexact-" + purpose, i, r, index) — independent
    renders (distinct seeds). Use a different `purpose` for each independent render set (e.g. "levels",
    "n-eff": the same seed at another spp shares samples) and a different `index` for each point."""
    spp = check_spp(levels, replicates) // replicates
    return [Request.of(theta, int(n), derive(seed, f"inexact-{purpose}", i, r, index))
            for i, n in enumerate(spp) for r in range(replicates)]


def render_task(model: ForwardModel, item: tuple) -> tuple:
    """Executor task: (tag, [Request, ...]) → (tag, images (N, H, W, C) float32, renders made here)."""
    tag, requests = item
    before = model.stats.snapshot()
    imgs = torch.stack([model.render(list(r.theta), r.spp, r.seed) for r in requests])
    return tag, imgs, model.stats.since(before).renders


def jacobian_task(model: ForwardModel, item: tuple) -> tuple:
    """Executor task: (tag, JacobianRequest) → (tag, FD Jacobian (P, H, W, C) float32, renders made here)."""
    tag, r = item
    before = model.stats.snapshot()
    jac = fd_jacobian(model, list(r.theta), r.spp, r.seed, GradientSettings(step=r.step, rounds=r.rounds))
    return tag, jac, model.stats.since(before).renders


class RenderBank:
    """Renders of one model for one run: `images`, `groups` and `jacobians` (see the module docstring).

    executor: where renders run (default: serially in this process, with `model`); progress:
    `progress(iterable, total, desc)` wrapping the results (e.g. RunContext.progress); memory_bytes: the
    most image bytes kept in memory for reuse (least recently used dropped first)."""

    def __init__(self, model: ForwardModel, executor: Executor | None = None, progress: Callable | None = None,
                 memory_bytes: int = 1 << 30):
        self.model = model
        self.executor = executor if executor is not None else SerialExecutor(model=model)
        self.progress = progress or (lambda it, total=None, desc="": it)
        self.memory_bytes = int(memory_bytes)
        self.renders = 0
        self._memo: OrderedDict[Hashable, torch.Tensor] = OrderedDict()
        self._held = 0

    # -- memory ----------------------------------------------------------------------------------
    def _get(self, key: Hashable) -> torch.Tensor | None:
        hit = self._memo.get(key)
        if hit is not None:
            self._memo.move_to_end(key)
        return hit

    def _keep(self, key: Hashable, value: torch.Tensor) -> None:
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
        types cannot describe (e.g. a camera posed outside θ); nothing is kept in memory."""
        for tag, value, renders in self.progress(self.executor.imap_unordered(fn, items), total=len(items), desc=desc):
            self.renders += renders
            yield tag, value

    # -- requests --------------------------------------------------------------------------------
    def images(self, requests: Sequence[Request], desc: str = "renders") -> torch.Tensor:
        """Images (N, H, W, C) float32 for `requests`, in their order (repeated requests rendered once)."""
        out: dict[Request, torch.Tensor] = {}
        todo = []
        for r in dict.fromkeys(requests):
            hit = self._get(r)
            if hit is None:
                todo.append(r)
            else:
                out[r] = hit
        for r, imgs in self.map(render_task, [(r, [r]) for r in todo], desc):
            out[r] = imgs[0]
            self._keep(r, imgs[0])
        return torch.stack([out[r] for r in requests])

    def groups(self, groups: dict[Hashable, Sequence[Request]], desc: str = "renders",
               on_done: Callable[[Hashable, torch.Tensor], None] | None = None) -> dict[Hashable, torch.Tensor]:
        """{tag: images (n, H, W, C)} with one executor task per group (its renders run together in one
        worker); `on_done(tag, images)` is called as each group finishes (e.g. to save it for resume).
        Groups are not kept in memory (they are the caller's unit of storage)."""
        out = {}
        for tag, imgs in self.map(render_task, [(tag, list(reqs)) for tag, reqs in groups.items()], desc):
            out[tag] = imgs
            if on_done is not None:
                on_done(tag, imgs)
        return out

    def jacobians(self, requests: Sequence[JacobianRequest], desc: str = "FD Jacobians") -> torch.Tensor:
        """FD Jacobians (N, P, H, W, C) float32 for `requests`, in their order."""
        out: dict[JacobianRequest, torch.Tensor] = {}
        todo = []
        for r in dict.fromkeys(requests):
            hit = self._get(r)
            if hit is None:
                todo.append(r)
            else:
                out[r] = hit
        for r, jac in self.map(jacobian_task, [(r, r) for r in todo], desc):
            out[r] = jac
            self._keep(r, jac)
        return torch.stack([out[r] for r in requests])

    def replicates(self, points, levels: Sequence[int], replicates: int, seed: int, purpose: str = "levels",
                   desc: str | None = None) -> torch.Tensor:
        """Renders (k, R, Q, H, W, C) float32 of Q θ points (points (Q,) or (Q, P)) at k spp levels × R
        replicates (`level_requests`, point index q), one executor task per point."""
        lv = check_spp(levels, replicates)
        pts = np.asarray(points, dtype=np.float64)
        pts = pts.reshape(pts.shape[0], -1) if pts.ndim else pts.reshape(1, 1)
        got = self.groups({q: level_requests(pts[q], lv, replicates, seed, purpose, q) for q in range(len(pts))},
                          desc or f"{purpose} points")
        X = torch.stack([got[q] for q in range(len(pts))], dim=1)  # (k·R, Q, *S)
        return X.reshape(len(lv), replicates, *X.shape[1:])
