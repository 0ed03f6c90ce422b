"""One interface for independent work (trials, grid renders): `executor.imap_unordered(fn, items)`
yields `fn(model, item)` for every item, in completion order, where `model` is the worker's forward
model — built once per worker process from a picklable model spec (`scenes.build`).

* `SerialExecutor`: in this process, with a model already loaded (no reload).
* `LocalPoolExecutor` (the default): a process pool with the spawn start method (no fork of a
  process that holds Mitsuba/Dr.Jit or torch threads); each worker loads the scene on its first task.
* `DaskExecutor`: `dask.distributed` (the optional `dask` extra) on a scheduler address, or on a
  LocalCluster of worker processes; each worker loads the scene once.

`fn` must be a module-level function (it is pickled by reference) and `item` picklable. Warnings raised in
a worker come back with its result and are shown by the run's process, each once per run (`_replay`).

Workers prove their code: every result comes with its worker's name and `identity` (the package's code hash, the
render keys' components, the numeric packages' versions and the model's content key as that worker builds it:
variant, ISA, scene files), computed once per worker process. A pool or Dask worker whose identity differs from
the run's process (another copy of the code on its import path, another scipy, another CPU) stops the run with
`WorkerMismatch` naming the worker and what differs, before any of its results is used.

Stopping: pool workers never see Ctrl-C, SIGTERM or SIGHUP (started with them blocked, `_spawning`: the
parent decides: `abort` kills them at once, `close` lets running tasks finish), and each runs a watchdog
thread that exits the worker as soon as its parent is gone — killed with SIGKILL included — so no worker
outlives the run (`_init_worker`).
"""
from __future__ import annotations

import asyncio
import errno
import hashlib
import json
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, CancelledError, ProcessPoolExecutor, wait
from contextlib import contextmanager

from . import interrupts, scenes, sources
from .forward import keys
from .forward.model import ForwardModel

# -- the worker side -------------------------------------------------------------------------
_MODELS: dict[str, ForwardModel] = {}
_LOCK = threading.Lock()  # Dask runs tasks in threads; a scene holds one θ at a time
#: models built in this process (tests check one scene load per worker)
builds = 0


def worker_model(spec: dict, threads: int | None = None, load_warnings: bool = True) -> ForwardModel:
    """The model for `spec` in this process, built on first use (and its CPU threads limited). Without
    `load_warnings`, the warnings of building it are not shown: a pool or Dask worker builds the scene the
    run's process has already loaded and warned about, so a warning is shown once per run, not per worker."""
    global builds
    key = json.dumps(spec, sort_keys=True, default=repr)
    if key not in _MODELS:
        if threads:
            import torch

            torch.set_num_threads(threads)
        with warnings.catch_warnings():
            if not load_warnings:
                warnings.simplefilter("ignore")
            _MODELS[key] = scenes.build(spec)
        builds += 1
        if threads and "drjit" in sys.modules:
            import drjit

            drjit.set_thread_count(threads)
    return _MODELS[key]


#: seconds between a pool worker's checks that its parent is alive
PARENT_POLL = 0.5


def _init_worker(parent: int) -> None:
    """Pool worker initialiser: ignore Ctrl-C (the parent stops the pool) and exit when the parent
    process `parent` is gone (its children are then re-parented, so `os.getppid()` changes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="nlosbench-parent-watch", daemon=True).start()


@contextmanager
def _spawning() -> Iterator[None]:
    """Around the pool's construction and a submit (either may start a process: a worker, or multiprocessing's
    resource tracker): the stop signals (SIGINT, SIGTERM, SIGHUP) are blocked in this thread, so a process
    started here inherits them blocked across exec — a signal sent to the whole process group (a terminal's
    Ctrl-C or hang-up, a batch system's SIGTERM) never reaches a worker that is still importing, nor kills the
    resource tracker (whose death prints tracebacks); the run's process decides and stops its workers
    (`abort`). In this process the signals are held (`interrupts.deferred`) and raised after the block, never
    in the middle of the pool's bookkeeping (which left a future cancelled that a worker then finished:
    InvalidStateError in the pool's thread)."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    with interrupts.deferred():
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, interrupts.STOPPING)
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def identity(model: ForwardModel) -> dict:
    """What this process's numbers depend on beyond the config: {"code": the package's Python files' hash,
    "render": a hash of the render keys' components (`keys.environment`), "versions": Python's and the numeric
    packages' (`sources.versions`), "model": a hash per component of the model's content key (variant, ISA,
    scene files, Mitsuba and Dr.Jit versions...)}."""
    def short(value) -> str:
        return hashlib.sha256(keys.canonical(value).encode()).hexdigest()[:16]

    return {"code": sources.digest(), "render": short(keys.environment()), "versions": sources.versions(),
            "model": {k: short(v) for k, v in model.content_key().items()}}


class WorkerMismatch(ConnectionError):
    """A worker computes with other code, package versions or render settings than the run's process."""


#: spec key → this worker process's identity for that model (`_call`)
_IDENTITIES: dict[str, dict] = {}


def _worker_name() -> str:
    if "distributed" in sys.modules:
        from distributed import get_worker

        try:
            return f"Dask worker {get_worker().address}"
        except ValueError:  # not inside a Dask worker
            pass
    return f"pool worker (PID {os.getpid()})"


def _call(spec: dict, threads: int | None, fn: Callable, item) -> tuple[object, list[tuple], tuple[str, dict]]:
    """In a worker: fn(model, item), the warnings it raised as (message, category, file, line), for the
    run's process to show (`_replay`): a warning raised in every worker is then shown once, not once each; and
    (this worker's name, its `identity`) for the run's process to check (`_checked`)."""
    with _LOCK, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = worker_model(spec, threads, load_warnings=False)
        key = json.dumps(spec, sort_keys=True, default=repr)
        if key not in _IDENTITIES:
            _IDENTITIES[key] = identity(model)
        value = fn(model, item)
    return value, [(str(w.message), _picklable(w.category), w.filename, w.lineno) for w in caught], (
        _worker_name(), _IDENTITIES[key])


def _differences(want: dict, got: dict, prefix: str = "") -> list[str]:
    """The dotted names in which two identities differ."""
    out = []
    for k in sorted(set(want) | set(got)):
        a, b = want.get(k), got.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}" + (f" ({b} there, {a} here)" if prefix == "versions." else ""))
    return out


def _picklable(category: type[Warning]) -> type[Warning]:
    return UserWarning if "<locals>" in category.__qualname__ else category


#: (category, message) of the worker warnings shown in this process
_SHOWN: set[tuple[type, str]] = set()


def _checked(result: tuple, expected: dict) -> object:
    """The value of a `_call` (`_replay`) once its worker's identity is `expected`; else `WorkerMismatch` naming the
    worker and what differs, its result unused."""
    name, got = result[2]
    if got != expected:
        raise WorkerMismatch(f"{name} computes with other code or settings than this process (differs: "
                             f"{', '.join(_differences(expected, got))}); its results are not used: install the same "
                             "nlosbench and packages on every worker (its import path must not hold another copy)")
    return _replay(result[:2])


def _replay(result: tuple[object, list[tuple]]):
    """The value of a `_call`, its warnings shown here, each (category, message) once per process (run)."""
    value, caught = result
    for message, category, filename, lineno in caught:
        if (category, message) not in _SHOWN:
            _SHOWN.add((category, message))
            warnings.warn_explicit(message, category, filename, lineno)
    return value


# -- executors ---------------------------------------------------------------------------------
class Executor(ABC):
    """Runs fn(model, item) for independent items; use as a context manager or call close()."""

    workers: int = 1

    @abstractmethod
    def imap_unordered(self, fn: Callable, items: Iterable) -> Iterator:
        """Results of fn(model, item), yielded as they finish (any order)."""

    def start(self) -> None:  # noqa: B027 - a concrete no-op default: most executors start on first use
        """Acquire what the executor needs before work is given to it (Dask: connect to the scheduler)."""

    def close(self) -> None:  # noqa: B027 - a concrete no-op default: a serial executor holds no workers
        """Release workers (a no-op for the serial executor), letting running tasks finish."""

    def abort(self) -> None:
        """Stop at once (after Ctrl-C or an error): running tasks are dropped, workers terminated."""
        self.close()

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(Executor):
    """In this process, in order, with `model` (or a model built from `spec` on first use)."""

    def __init__(self, model: ForwardModel | None = None, spec: dict | None = None):
        if model is None and spec is None:
            raise ValueError("SerialExecutor needs a model or a model spec")
        self.model, self.spec = model, spec

    def imap_unordered(self, fn: Callable, items: Iterable) -> Iterator:
        if self.model is None:
            self.model = worker_model(self.spec)
        for item in items:
            yield fn(self.model, item)


def _default_threads(workers: int) -> int:
    return max(1, (os.cpu_count() or 1) // workers)


def _check_workers(workers) -> int:
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    return int(workers)


class SharedMemoryError(OSError):
    """/dev/shm is full or too small for the tensors passed between the run and its pool workers."""


#: the one line of a full /dev/shm: what it is and how to fix it
SHM_FULL = ("shared memory (/dev/shm) is full or too small: torch passes the images between the run and its pool "
            "workers through it; mount a larger /dev/shm (Docker: --shm-size=2g; Kubernetes: an emptyDir with medium: "
            "Memory at /dev/shm) or set executor.type: serial (no worker processes)")


def _shm_full(e: BaseException) -> bool:
    """Whether `e` says shared memory ran out: torch's `unable to allocate shared memory` / `unable to write to
    file </torch_...>` (a RuntimeError, raised here or in a worker) or ENOSPC creating the pool's semaphores and
    queues (an OSError naming no file or a file in /dev/shm)."""
    text = str(e)
    if isinstance(e, OSError):
        return e.errno == errno.ENOSPC and (e.filename is None or str(e.filename).startswith("/dev/shm"))
    return isinstance(e, RuntimeError) and ("shared memory" in text or "/dev/shm" in text
                                            or ("</torch_" in text and "No space left" in text))


@contextmanager
def _shared_memory_errors() -> Iterator[None]:
    """A full /dev/shm becomes a `SharedMemoryError` saying so (`SHM_FULL`); any other error passes."""
    try:
        yield
    except (RuntimeError, OSError) as e:
        if _shm_full(e):
            raise SharedMemoryError(SHM_FULL) from e
        raise


class _Workers(Executor):
    """An executor whose tasks run in other processes: each result is used only once its worker's identity is this
    process's (`_checked`), that of `model` (the run's loaded model; None: one built here from `spec`)."""

    spec: dict
    model: ForwardModel | None = None
    _identity: dict | None = None

    def _result(self, result: tuple) -> object:
        if self._identity is None:  # the run's process has loaded this scene and shown its warnings already
            model = self.model if self.model is not None else worker_model(self.spec, load_warnings=False)
            self._identity = identity(model)
        return _checked(result, self._identity)


class LocalPoolExecutor(_Workers):
    """A pool of `workers` spawned processes, each loading the scene once (on its first task) and
    using `threads` CPU threads for torch and Dr.Jit (default: cores / workers). At most
    `2 × workers` tasks are queued at a time, so a stopped run leaves little work in flight; `model` the run's
    loaded model, whose identity the workers' must match (`_Workers`)."""

    def __init__(self, spec: dict, workers: int = 2, threads: int | None = None, model: ForwardModel | None = None):
        self.spec, self.workers, self.model = spec, _check_workers(workers), model
        self.threads = threads or _default_threads(self.workers)
        self._pool: ProcessPoolExecutor | None = None

    def imap_unordered(self, fn: Callable, items: Iterable) -> Iterator:
        with _shared_memory_errors():
            if self._pool is None:
                with _spawning():  # its queues' semaphores start the resource tracker, which inherits the mask
                    self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                                     initializer=_init_worker, initargs=(os.getpid(),))
            yield from self._results(fn, items)

    def _results(self, fn: Callable, items: Iterable) -> Iterator:
        pending, queue = set(), iter(items)
        try:
            while True:
                for item in queue:
                    with _spawning():  # a worker spawned by this submit starts with the stop signals blocked
                        pending.add(self._pool.submit(_call, self.spec, self.threads, fn, item))
                    if len(pending) >= 2 * self.workers:
                        break
                if not pending:
                    return
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield self._result(f.result())
        finally:
            for f in pending:
                f.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def abort(self) -> None:
        if self._pool is not None:
            workers = list((getattr(self._pool, "_processes", None) or {}).values())
            manager = getattr(self._pool, "_executor_manager_thread", None)  # shutdown drops the reference
            # shut down first: the pool's thread then drops the cancelled futures before it sees its workers
            # killed (killing first made it mark a cancelled future failed: InvalidStateError: CANCELLED there)
            self._pool.shutdown(wait=False, cancel_futures=True)
            # … once it has: it clears `_cancel_pending_futures` after dropping them (CPython's process pool); under
            # load a kill before that still raced it. Wait at most 2 s: a thread that never wakes is killed anyway.
            deadline = time.monotonic() + 2.0
            while getattr(self._pool, "_cancel_pending_futures", False) and time.monotonic() < deadline:
                time.sleep(0.005)
            for proc in workers:
                proc.kill()  # SIGKILL: a worker has the stop signals blocked (`_spawning`)
            # let that thread end (it closes its wakeup pipe as it does): interpreter exit writes to every live
            # pool's pipe, and CPython's check-then-write there raced the thread's close (EBADF traceback at exit)
            if manager is not None:
                manager.join(5.0)
            self._pool = None


class WorkersLost(ConnectionError):
    """No Dask worker was alive for `executor.worker_timeout` seconds (none at the start, or all lost mid-run)."""


class SchedulerLost(ConnectionError):
    """The Dask scheduler went away mid-run (its connection closed, its futures cancelled)."""


#: what Dask raises when a wait times out (asyncio's TimeoutError is the builtin one from Python 3.11 on)
_TIMEOUTS = (TimeoutError, asyncio.TimeoutError)
#: seconds between a Dask run's checks that a worker is alive (at most; a quarter of the timeout when shorter)
WORKER_POLL = 1.0


class DaskExecutor(_Workers):
    """dask.distributed: a scheduler at `address` (given up after `connect_timeout` seconds with a
    ConnectionError naming it), or a LocalCluster of `workers` processes with one thread each. Every
    worker process loads the scene once (on its first task). A run whose scheduler has no live worker for
    `worker_timeout` seconds — none at the start, or all lost mid-run — stops with `WorkersLost` (a
    ConnectionError naming the scheduler and the key): finished work is kept, the run can be resumed. A
    scheduler lost mid-run stops it with `SchedulerLost` naming its address (and the log). With `log`, the
    `distributed` loggers of this process write to that file, not to the terminal (and a LocalCluster's worker
    processes log only what is critical). Each worker's results are used only once its identity matches
    `model`'s (`_Workers`)."""

    def __init__(self, spec: dict, address: str | None = None, workers: int = 2, threads: int | None = None,
                 connect_timeout: float = 10.0, worker_timeout: float = 60.0, log: str | os.PathLike | None = None,
                 model: ForwardModel | None = None):
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise ImportError("the dask executor needs dask.distributed: pip install 'nlosbench[dask]'") from None
        self.spec, self.address, self.workers, self.model = spec, address, _check_workers(workers), model
        self.threads = threads or _default_threads(self.workers)
        self.connect_timeout = float(connect_timeout)
        self.worker_timeout = float(worker_timeout)
        self.log = log
        self._client = None
        self._cluster = None
        self._logging: _DaskLog | None = None
        self._no_worker_since: float | None = None

    def start(self) -> None:
        client = self.client()
        try:
            client.wait_for_workers(1, timeout=self.worker_timeout)
        except _TIMEOUTS:
            raise self._lost("no Dask worker at the scheduler {where} within {t:g} s") from None

    def client(self):
        """The dask Client (started on first use)."""
        if self._client is None:
            if self.log is not None and self._logging is None:
                self._logging = _DaskLog(self.log)
            from distributed import Client, LocalCluster

            if self.address:
                try:
                    self._client = Client(self.address, timeout=self.connect_timeout)
                except OSError as e:
                    raise ConnectionError(f"cannot reach the Dask scheduler at {self.address} within "
                                          f"{self.connect_timeout:g} s (executor.connect_timeout): {e}") from None
            else:
                self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                             dashboard_address=None,
                                             silence_logs=logging.CRITICAL if self.log is not None else logging.WARN)
                self._client = Client(self._cluster)
        return self._client

    def _lost(self, what: str) -> WorkersLost:
        """`WorkersLost` saying `what` (formatted with the scheduler's address `where` and the timeout `t`)."""
        where = self.address or getattr(getattr(self._client, "scheduler", None), "address", "the LocalCluster")
        return WorkersLost(what.format(where=where, t=self.worker_timeout) + " (executor.worker_timeout): start "
                           f"workers for that scheduler (dask worker {where}) or raise executor.worker_timeout")

    def _check_workers(self) -> None:
        """Raise `WorkersLost` once the scheduler has had no worker for `worker_timeout` seconds."""
        alive = len(self._client.nthreads()) > 0  # worker address → threads, asked of the scheduler
        if alive:
            self._no_worker_since = None
        elif self._no_worker_since is None:
            self._no_worker_since = time.monotonic()
        elif time.monotonic() - self._no_worker_since >= self.worker_timeout:
            raise self._lost("no Dask worker left at the scheduler {where} for {t:g} s (all lost mid-run)")

    def imap_unordered(self, fn: Callable, items: Iterable) -> Iterator:
        from distributed import wait as wait_for

        items = list(items)
        if not items:
            return
        client = self.client()
        pending = [client.submit(_call, self.spec, self.threads, fn, item, pure=False) for item in items]
        poll = min(WORKER_POLL, self.worker_timeout / 4)
        try:
            while pending:
                try:
                    done, left = wait_for(pending, timeout=poll, return_when="FIRST_COMPLETED")
                except _TIMEOUTS:
                    done, left = (), pending
                self._check_workers()
                pending = list(left)
                for fut in done:
                    yield self._result(self._fetch(fut, poll))
        except (CancelledError, OSError) as e:  # a cancelled future or a closed comm: lost, unless still connected
            if client.status == "running":
                raise
            where = self.address or "the LocalCluster"
            log = f"; Dask's messages are in {self.log}" if self.log is not None else ""
            raise SchedulerLost(f"lost the Dask scheduler at {where} mid-run ({type(e).__name__}); finished work is "
                                f"kept: restart the scheduler and its workers{log}") from None
        finally:
            if client.status == "running":
                client.cancel([f for f in pending if not f.done()])

    def _fetch(self, fut, poll: float):
        """The result of a finished future, checking the workers every `poll` seconds while it waits: a worker lost
        after it finished a task takes the result with it, the task goes back to waiting (the scheduler recomputes
        it elsewhere), and with no worker left a plain `result()` would wait for ever."""
        while True:
            try:
                return fut.result(timeout=poll)
            except _TIMEOUTS:
                self._check_workers()

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
        if self._logging is not None:
            self._logging.close()
            self._logging = None


class _DaskLog:
    """The `distributed` loggers (and tornado's, which Dask's networking uses) of this process written to a file
    instead of the terminal, until `close` puts their handlers back: the top ones and every one below them with
    its own handler (Dask gives `distributed.client` a terminal handler of its own)."""

    NAMES = ("distributed", "tornado")

    def __init__(self, path: str | os.PathLike):
        self.handler = logging.FileHandler(path, encoding="utf-8")
        self.handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
        self.saved = {}
        below = [name for name, logger in list(logging.root.manager.loggerDict.items())
                 if isinstance(logger, logging.Logger) and logger.handlers
                 and any(name.startswith(top + ".") for top in self.NAMES)]
        for name in (*self.NAMES, *below):
            logger = logging.getLogger(name)
            self.saved[name] = (list(logger.handlers), logger.propagate)
            for h in list(logger.handlers):
                logger.removeHandler(h)
            logger.addHandler(self.handler)
            logger.propagate = False

    def close(self) -> None:
        for name, (handlers, propagate) in self.saved.items():
            logger = logging.getLogger(name)
            logger.removeHandler(self.handler)
            for h in handlers:
                logger.addHandler(h)
            logger.propagate = propagate
        self.handler.close()


def create(config: dict, spec: dict, model: ForwardModel | None = None,
           log: str | os.PathLike | None = None) -> Executor:
    """The executor a run config asks for: `config` is its `executor` block {type: local | serial |
    dask, workers, address, connect_timeout, worker_timeout}; `spec` the model spec workers build from; `model`
    the already-loaded model (used by the serial executor, so it loads nothing; the others check their workers'
    identity against it); `log` where Dask logs."""
    kind = config.get("type", "local")
    workers = config.get("workers", 2)
    if kind == "serial":
        return SerialExecutor(model=model, spec=spec)
    if kind == "local":
        return LocalPoolExecutor(spec, workers=workers, model=model)
    if kind == "dask":
        return DaskExecutor(spec, address=config.get("address"), workers=workers,
                            connect_timeout=config.get("connect_timeout", 10.0),
                            worker_timeout=config.get("worker_timeout", 60.0), log=log, model=model)
    raise ValueError(f"unknown executor type {kind!r}; expected serial, local or dask")
