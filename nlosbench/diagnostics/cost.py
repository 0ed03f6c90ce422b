"""Wall time and peak memory of a piece of work (one gradient image, one forward render).

Memory is the process's resident set size (RSS), because Dr.Jit's LLVM backend allocates its
buffers with the system allocator, outside Python's heap: `tracemalloc` would see none of it.
With psutil installed, a thread samples RSS every `interval` seconds and the peak above the RSS at
the start is reported ("rss-sampled"; spikes shorter than the interval can be missed). Without
psutil, the increase of the lifetime maximum RSS (`resource.getrusage`) is reported
("maxrss-delta": a lower bound, 0 unless the work sets a new lifetime peak). Dr.Jit's allocation
cache is flushed first so that memory kept from earlier work is not silently reused.
"""
from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass


@dataclass
class Cost:
    """seconds: wall time; peak_bytes: peak RSS increase during the work; method: how it was measured."""

    seconds: float = 0.0
    peak_bytes: int = 0
    method: str = ""


def _flush_drjit_cache() -> None:
    if "drjit" in sys.modules:
        sys.modules["drjit"].flush_malloc_cache()


class measure:
    """`with measure() as c: work()` fills `c` (a Cost) when the block ends."""

    def __init__(self, interval: float = 0.002):
        self.interval = interval
        self.cost = Cost()

    def __enter__(self) -> Cost:
        _flush_drjit_cache()
        try:
            import psutil

            self._proc = psutil.Process()
            self._base = self._peak = self._proc.memory_info().rss
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._poll, daemon=True)
            self._thread.start()
            self.cost.method = "rss-sampled"
        except ImportError:
            import resource

            self._proc = None
            self._base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
            self.cost.method = "maxrss-delta"
        self._t0 = time.perf_counter()
        return self.cost

    def _poll(self) -> None:
        while not self._stop.wait(self.interval):
            self._peak = max(self._peak, self._proc.memory_info().rss)

    def __exit__(self, *exc) -> None:
        self.cost.seconds = time.perf_counter() - self._t0
        if self._proc is not None:
            self._stop.set()
            self._thread.join()
            self._peak = max(self._peak, self._proc.memory_info().rss)
            self.cost.peak_bytes = int(self._peak - self._base)
        else:
            import resource

            self.cost.peak_bytes = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - self._base)
