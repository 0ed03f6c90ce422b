"""Append-only record logs (JSON lines) that survive being killed: the one way a study keeps finished work.

A record is one JSON object per line. `RecordLog.append` writes the line, flushes and fsyncs it, so a
record the caller was told about is on disk. A run killed while writing leaves at most one torn last
line (no newline at its end): `read` cuts it off the file, with a warning naming the file, and the work
it described is simply done again. Any other unreadable line is an error naming the file and the line:
such a log was edited or damaged, and guessing would mix numbers. Used by the trials study
(`montecarlo.run_trials`) and the viewpoints study; a run folder has one writer at a time (the run
lock in `experiment.rundir`), so appends never interleave.
"""
from __future__ import annotations

import json
import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


class RecordError(ValueError):
    """A record log holds a line that is not a record (not its torn last line)."""


class TornRecordWarning(UserWarning):
    """A torn last record (a run killed while writing it) was cut off a log."""


def parse(line: bytes, where: str) -> dict:
    """The record on one line of a log; RecordError naming `where` (file:line) when it is not one."""
    try:
        rec = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RecordError(f"{where}: not a record ({e}); the log was damaged or edited — remove that line (its "
                          "work is then done again) or start a new run") from None
    if not isinstance(rec, dict):
        raise RecordError(f"{where}: not a record (a JSON {type(rec).__name__}, expected an object)")
    return rec


class RecordLog:
    """Records (dicts) in a JSON-lines file at `path`; see the module docstring."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._file = None

    def read(self) -> list[dict]:
        """Every record in the file ([] when there is none); a torn last line is cut off (with a warning)."""
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return []
        end = raw.rfind(b"\n") + 1
        if end < len(raw):
            with self._naming_errors(), open(self.path, "r+b") as f:
                f.truncate(end)
                f.flush()
                os.fsync(f.fileno())
            warnings.warn(f"{self.path}: cut off a torn last record ({len(raw) - end} bytes, left by a run killed "
                          "while writing it); its work is done again", TornRecordWarning, stacklevel=2)
        return [parse(line, f"{self.path}:{n}") for n, line in enumerate(raw[:end].splitlines(), 1)]

    def reset(self) -> None:
        """Remove the log (a fresh start)."""
        self.close()
        self.path.unlink(missing_ok=True)

    def append(self, record: dict) -> None:
        """Write one record as a line, flushed and fsynced before returning."""
        line = json.dumps(record) + "\n"
        with self._naming_errors():
            if self._file is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = open(self.path, "a", encoding="utf-8")
            self._file.write(line)
            self._file.flush()
            os.fsync(self._file.fileno())

    @contextmanager
    def _naming_errors(self) -> Iterator[None]:
        """An OSError without a file name (a write, flush or fsync on a full disk: ENOSPC) names this log."""
        try:
            yield
        except OSError as e:
            if e.filename is not None or e.errno is None:
                raise
            raise OSError(e.errno, e.strerror or os.strerror(e.errno), str(self.path)) from e

    def close(self) -> None:
        if self._file is not None:
            file, self._file = self._file, None
            with self._naming_errors():
                file.close()

    def __enter__(self) -> RecordLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
