"""What a finished study left in its folder, recorded in results.json, and the check that it is all there.

`manifest(folder)`: every file of a study's folder (temporary files aside) → what can be checked of it
later: a CSV's data rows and the SHA-256 of its bytes, a record log's complete records, nothing more for other
files. `problems(folder, manifest)` says, per file, what is missing or damaged now: a file gone, a CSV or JSON
file that does not parse, has fewer rows than recorded or other bytes (a value edited in place), a record log
with fewer complete records or a torn last line (a run killed while appending: the study's own reading cuts it),
an empty or foreign image (a record log with a damaged line before its last is an error naming the file and the
line). A resume
rebuilds a study with problems (renders from the run's store, work from its record logs); `report` refuses
to draw from a table that lost rows. `load_results` reads results.json, naming it when it is damaged.
"""
from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

from ..records import RecordError, parse
from .rundir import RunFolderError

#: the first bytes of the image files a study writes
_MAGIC = {".png": b"\x89PNG", ".exr": b"\x76\x2f\x31\x01"}


def _rows(path: Path) -> int:
    """Data rows of a CSV file (ValueError when it does not parse as one: a row of another width than the
    header's, or a last line without its end, as a file cut short has)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f, strict=True))  # quoted fields may hold line breaks
    with open(path, "rb") as f:
        f.seek(max(path.stat().st_size - 1, 0))
        ends = f.read() in (b"", b"\n")
    if not ends or any(len(r) != len(rows[0]) for r in rows):
        raise ValueError("a row is cut short")
    return max(len(rows) - 1, 0)


def _records(path: Path) -> tuple[int, bool]:
    """(complete records, whether a torn last line follows them) of a JSON-lines log; RecordError naming the file
    and line when a complete line is not a record (the log itself is damaged: nothing can rebuild it, so it is an
    error, not a rebuild)."""
    raw = path.read_bytes()
    end = raw.rfind(b"\n") + 1
    lines = raw[:end].splitlines()
    for n, line in enumerate(lines, 1):
        parse(line, f"{path}:{n}")
    return len(lines), end < len(raw)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_results(path: Path) -> dict:
    """results.json of a run; RunFolderError naming the file when it is damaged (one line, nothing written)."""
    try:
        results = json.loads(Path(path).read_text())
        if not isinstance(results.get("studies"), dict):
            raise ValueError("no 'studies' table")
    except (ValueError, UnicodeDecodeError, AttributeError) as e:
        raise RunFolderError(str(path), f"is damaged ({' '.join(str(e).split())}); move it away and resume to "
                                        "rebuild every study from the render store and the record logs") from None
    return results


def manifest(folder: Path) -> dict[str, dict]:
    """Relative path → {"rows": n, "sha256": hex} (CSV), {"records": n} (.jsonl) or {} for every file under
    `folder`."""
    out = {}
    for p in sorted(Path(folder).rglob("*")):
        if not p.is_file() or p.name.startswith("."):
            continue
        name = p.relative_to(folder).as_posix()
        out[name] = {"rows": _rows(p), "sha256": _sha256(p)} if p.suffix == ".csv" else \
            {"records": _records(p)[0]} if p.suffix == ".jsonl" else {}
    return out


def problems(folder: Path, recorded: dict[str, dict], suffixes: tuple[str, ...] | None = None
             ) -> list[tuple[Path, str]]:
    """(file, what is wrong with it) for each of the `recorded` files of `folder` (those ending in
    `suffixes`, default all) that is missing or damaged now ([] when all is well)."""
    out = []
    for name, facts in recorded.items():
        p = Path(folder) / name
        if suffixes is not None and p.suffix not in suffixes:
            continue
        if not p.is_file():
            out.append((p, "is missing"))
            continue
        try:
            if p.suffix == ".csv" and _rows(p) < facts.get("rows", 0):
                out.append((p, f"has {_rows(p)} rows, results.json says {facts['rows']}"))
            elif p.suffix == ".csv" and facts.get("sha256", _sha256(p)) != _sha256(p):
                out.append((p, "was changed after it was written (its SHA-256 is not the one results.json holds)"))
            elif p.suffix == ".jsonl" and _records(p)[1]:
                out.append((p, "ends in a torn record"))
            elif p.suffix == ".jsonl" and _records(p)[0] < facts.get("records", 0):
                out.append((p, f"has {_records(p)[0]} records, results.json says {facts['records']}"))
            elif p.suffix == ".json":
                json.loads(p.read_text())
            elif p.suffix in _MAGIC and not p.read_bytes().startswith(_MAGIC[p.suffix]):
                out.append((p, f"is not a {p.suffix[1:].upper()} image"))
        except RecordError:
            raise
        except (ValueError, UnicodeDecodeError, csv.Error) as e:
            out.append((p, f"does not parse ({' '.join(str(e).split())})"))
    return out
