"""Progress output a person can read: one tqdm bar (count, rate, ETA) per stage of a run, none for a stage
with nothing to do (e.g. renders the render bank already holds).

A stage is a bar's description less a trailing "(replicate N)" or "(round N)": the render sets of one stage
asked for one after another (replicate 0, 1, 2 …) extend one bar instead of drawing one each."""
from __future__ import annotations

import re
import sys
from collections.abc import Iterable, Iterator
from typing import TextIO

_PART = re.compile(r"\s*\((?:replicate|round) \d+\)$")


def stage(desc: str) -> str:
    """The stage a bar description belongs to: `desc` less a trailing "(replicate N)" / "(round N)"."""
    return _PART.sub("", desc)


class Progress:
    """`progress(iterable, total, desc)` → the iterable, counted on a bar on `file` (default: stderr).

    No bar when `quiet` or when `total` (or len(iterable)) is 0. A bar stays open after its iterable ends,
    so that the next call of the same stage extends it (its total grows); a call of another stage, `close()`
    or `RunContext.log` closes it. Bars of nested calls (a stage inside another's loop) stack as tqdm's do."""

    def __init__(self, quiet: bool = False, file: TextIO | None = None):
        self.quiet = quiet
        self.file = file
        self._open: tuple[str, object] | None = None  # (stage, tqdm bar) whose iterable has ended

    def __call__(self, iterable: Iterable, total: int | None = None, desc: str = "") -> Iterable:
        if total is None and hasattr(iterable, "__len__"):
            total = len(iterable)
        if self.quiet or total == 0:
            return iterable
        key = stage(desc)
        if self._open is not None and self._open[0] == key and total is not None and self._open[1].total is not None:
            bar = self._open[1]
            bar.total += total
            bar.refresh()
        else:
            from tqdm import tqdm

            self.close()
            bar = tqdm(total=total, desc=key, file=self.file or sys.stderr, dynamic_ncols=True)
        self._open = None
        return self._count(iterable, key, bar)

    def _count(self, iterable: Iterable, key: str, bar) -> Iterator:
        try:
            for item in iterable:
                bar.update(1)
                yield item
        finally:
            if self._open is not None and self._open[1] is not bar:
                self.close()
            self._open = (key, bar)

    def close(self) -> None:
        """Close the open bar (its last state stays on screen)."""
        if self._open is not None:
            self._open[1].close()
            self._open = None
