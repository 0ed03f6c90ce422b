"""Wall time and peak memory of a piece of work (one gradient image, one forward render).

Memory is the process's resident set size (RSS), because Dr.Jit's LLVM backend allocates its
buffers with the system allocator, outside Python's heap: `tracemalloc` would see none of it.
Before the work, Dr.Jit's allocation cache is flushed and glibc's free memory is returned to the
system (`malloc_trim`), so that memory kept from earlier work is not silently reused. Then, best first:
- "vmhwm" (Linux): the kernel's peak RSS (VmHWM) is reset by writing 5 to /proc/self/clear_refs and
  read after the work: exact, no sampling, no overhead. Nested blocks keep their own peaks.
- "rss-sampled" (psutil installed, no /proc): a thread samples RSS every `interval` seconds;
  spikes shorter than that are missed.
- "maxrss-delta" (neither): the increase of the lifetime maximum RSS (`resource.getrusage`): a lower
  bound, 0 unless the work sets a new lifetime peak.
The peak is reported above the RSS at the start of the block.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import re
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

_STATUS, _CLEAR_REFS = Path("/proc/self/status"), Path("/proc/self/clear_refs")


@dataclass
class Cost:
    """seconds: wall time; peak_bytes: peak RSS increase during the work; method: how it was measured.

    Examples
    --------
    >>> nb.diagnostics.Cost()  # what `measure` fills in when its block ends
    Cost(seconds=0.0, peak_bytes=0, method='')
    """

    seconds: float = 0.0
    peak_bytes: int = 0
    method: str = ""


def _release_free_memory() -> None:
    if "drjit" in sys.modules:
        sys.modules["drjit"].flush_malloc_cache()
    libc = ctypes.util.find_library("c")
    if libc and sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(libc).malloc_trim(0)
        except (OSError, AttributeError):  # not glibc
            pass


def _status_bytes(field: str) -> int:
    return int(re.search(rf"^{field}:\s+(\d+) kB", _STATUS.read_text(), re.M).group(1)) * 1024


def _reset_peak() -> bool:
    """Reset the kernel's peak RSS to the current RSS; False where that is not possible."""
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


#: open "vmhwm" blocks, outermost first: an inner block's reset must not lose an outer block's peak
_OPEN: list[measure] = []


class measure:
    """`with measure() as c: work()` fills `c` (a Cost) when the block ends.

    Examples
    --------
    >>> import numpy as np
    >>> with nb.diagnostics.measure() as cost:
    ...     block = np.ones(2**24)  # 128 MiB, every page written
    >>> cost.seconds > 0, cost.method in ("vmhwm", "rss-sampled", "maxrss-delta")
    (True, True)
    >>> cost.peak_bytes >= 2**27 or cost.method == "maxrss-delta"  # the last method sees only a new lifetime peak
    True
    """

    def __init__(self, interval: float = 0.002):
        self.interval = interval
        self.cost = Cost()
        self._proc = None

    def __enter__(self) -> Cost:
        _release_free_memory()
        seen = _status_bytes("VmHWM") if _OPEN else 0
        if _reset_peak():
            for outer in _OPEN:
                outer._seen = max(outer._seen, seen)
            self._base, self._seen = _status_bytes("VmRSS"), 0
            self.cost.method = "vmhwm"
            _OPEN.append(self)
        else:
            try:
                import psutil

                self._proc = psutil.Process()
                self._base = self._seen = self._proc.memory_info().rss
                self._stop = threading.Event()
                self._thread = threading.Thread(target=self._poll, daemon=True)
                self._thread.start()
                self.cost.method = "rss-sampled"
            except ImportError:
                import resource

                self._base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
                self.cost.method = "maxrss-delta"
        self._t0 = time.perf_counter()
        return self.cost

    def _poll(self) -> None:
        while not self._stop.wait(self.interval):
            self._seen = max(self._seen, self._proc.memory_info().rss)

    def __exit__(self, *exc) -> None:
        self.cost.seconds = time.perf_counter() - self._t0
        if self.cost.method == "vmhwm":
            _OPEN.remove(self)
            peak = max(self._seen, _status_bytes("VmHWM"))
            for outer in _OPEN:
                outer._seen = max(outer._seen, peak)
        elif self._proc is not None:
            self._stop.set()
            self._thread.join()
            peak = max(self._seen, self._proc.memory_info().rss)
        else:
            import resource

            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        self.cost.peak_bytes = max(0, int(peak - self._base))
