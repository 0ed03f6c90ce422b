"""The signals that stop a run — SIGINT (Ctrl-C), SIGTERM (`kill`, a batch system's time limit) and SIGHUP (the
terminal closed) — and holding them back around native work that must not be cut in two.

The `nlosbench` command turns each into an `Interrupted` exception (a KeyboardInterrupt that remembers its signal:
exit 128 + signal number). Python runs a signal handler between bytecodes of the main thread, which may be in the
middle of importing a C extension (torch, Mitsuba, Dr.Jit) or of a callback from Mitsuba's scene loader: an exception
raised there can leave the extension half-initialised, be wrapped into another error by the binding, or abort the
interpreter (`Fatal Python error: PyThreadState_Get`; torch's import: `terminate called after throwing an
instance of 'pybind11::error_already_set'`). `deferred()` holds such a signal until the block ends, then
raises it; a second one during the block acts at once (the signal's default action), so nothing can hang.
"""
from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: the signals that stop a run, each as the command's exit code 128 + its number (130, 143, 129)
STOPPING: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """A run stopped by `signum` (SIGINT, SIGTERM or SIGHUP)."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def signum_of(e: BaseException) -> int:
    """The signal behind an interrupt: its `Interrupted.signum`, SIGINT for a plain KeyboardInterrupt."""
    return getattr(e, "signum", int(signal.SIGINT))


def interrupt_in(e: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt that an error raised by a binding (Mitsuba's, Dr.Jit's) carries, as its cause or
    context or only in its message (a binding that turned the Python exception into its own); else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        if "KeyboardInterrupt" in str(e):
            return KeyboardInterrupt()
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


@contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs (see the module docstring); on leaving it, a held
    signal goes to the handler that was there (the command's: it raises `Interrupted`). Only signals with a
    Python handler are held (SIG_DFL and SIG_IGN stay as they are); outside the main thread a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum, frame) -> None:
        if held:  # a second signal: its default action, at once (an import cannot be waited for forever)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        held.append(signum)

    previous = {}
    for s in STOPPING:
        handler = signal.getsignal(s)
        if callable(handler):
            previous[s] = signal.signal(s, hold)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if held:
            previous[held[0]](held[0], None)
