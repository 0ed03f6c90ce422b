"""The installed package's own source files and their hashes: what "the code" of a run or a render is.

`digests()` maps every Python source file (`*.py`) of the package as installed (an editable install included: the
files as they are now, not as they were when installed; an editor's swap or backup file, `__pycache__` and compiled
files left out) to the SHA-256 of its bytes. `digest(names)` folds a set of them into one hex string. Reading the
~80 files takes a few milliseconds; the result is computed once per process. `versions()` names the installed
version of Python and of every package whose code computes a number of a run (`NUMERIC`).
"""
from __future__ import annotations

import ast
import hashlib
import platform
from functools import cache, lru_cache
from importlib import metadata
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: the packages whose code computes a run's numbers (renders, bounds, fits: scipy's bounded Brent search included)
NUMERIC = ("numpy", "scipy", "torch", "mitsuba", "drjit")


@lru_cache(maxsize=1)
def digests() -> dict[str, str]:
    """Relative path under the package (e.g. 'forward/cache.py') → SHA-256 hex of its bytes, for its `*.py` files."""
    out = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        if p.is_file() and "__pycache__" not in p.parts:
            out[p.relative_to(PACKAGE).as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def digest(names=None) -> str:
    """One SHA-256 hex over the files `names` (default: all), by name and content."""
    table = digests()
    h = hashlib.sha256()
    for name in sorted(table if names is None else names):
        h.update(f"{name}\0{table[name]}\n".encode())
    return h.hexdigest()


@cache
def closure(folder: str) -> tuple[str, ...]:
    """The files of subpackage `folder` (e.g. 'forward') and the top-level modules they import
    (relative imports such as `from ..seeds import derive`): the code that subpackage runs."""
    names = sorted(n for n in digests() if n.startswith(folder + "/") and n.endswith(".py"))
    top = set()
    for name in names:
        for node in ast.walk(ast.parse((PACKAGE / name).read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == name.count("/") + 1:
                top.update([node.module.split(".")[0]] if node.module else [a.name for a in node.names])
    return tuple(names + sorted(f"{m}.py" for m in top if f"{m}.py" in digests()))


@lru_cache(maxsize=1)
def versions() -> dict[str, str | None]:
    """{"python": its version, and each of `NUMERIC`: its installed version, None where it is not installed}."""
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in NUMERIC:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
