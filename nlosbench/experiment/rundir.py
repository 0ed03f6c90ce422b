"""A run folder's integrity: one writer at a time (`RunLock`), and a fingerprint of everything that
changes its numbers (`fingerprint`), so that `--resume` continues exactly the run that was started.

Fingerprint (fingerprint.json, written before any other file of the run): the resolved config without
the keys that cannot change a number (`NUMBERLESS`), the model's content key (a hash over every file the
scene loads, defines, variant, integrator, bindings, pass size, Mitsuba and Dr.Jit versions, and under
`model.render` what else decides a render's bits: the LLVM target, libLLVM, the host's ISA; the analytic
toys' settings), the components every render key holds (`forward.keys.environment`: the rendering code's
hash, ...), the code (nlosbench's version and a hash of each of its installed Python files), the versions of
Python and of every package that computes a number (`sources.versions`: numpy, scipy, torch, Mitsuba, Dr.Jit),
and what each study's plan fixes beyond the config (its `Plan.fingerprint`, e.g. the
trials study's `auto` gradients as resolved from a verdicts file). A resume whose fingerprint differs is
refused with the first differing key, before anything is written (a different machine named as such); a
difference in the code alone is refused naming the changed files unless the resume is asked for `anyway`
(the CLI's --resume-anyway), which the run then records (results.json, report.md).

Lock: an exclusive `fcntl.flock` on RUN/.lock, held for the whole run and released by the OS when the
process ends in any way (kill -9 included): a second run or resume into a held folder is refused at
once, naming the holder's PID (written into the lock file).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..io import write_json
from ..schema import ConfigError

FINGERPRINT = "fingerprint.json"
LOCK = ".lock"
#: config keys that cannot change a number, so a resume may change them: where and how work runs
#: (executor type, workers, scheduler address and timeout), the cross-run render cache (content-keyed),
#: keeping the run's renders on disk, and the output folder (only read when --out is absent). Progress bars
#: and messages (--quiet) are not in the config at all.
NUMBERLESS = ("executor", "cache", "keep_renders", "output")


class RunFolderError(ConfigError):
    """A run folder that this run may not write: held by another process, holding another run, or
    holding a run with a different fingerprint. Nothing was written."""


def fingerprint(cfg: dict, content_key: dict, plans: dict) -> dict:
    """The run's fingerprint (see the module docstring); JSON-normalised so it compares equal to its file."""
    from .. import __version__, sources
    from ..forward import keys

    numbers = {k: v for k, v in cfg.items() if k not in NUMBERLESS}
    extra = {sid: getattr(p, "fingerprint", None) for sid, p in plans.items()}
    fp = {"config": numbers, "model": content_key, "render": keys.environment(),
          "code": {"nlosbench": __version__, "source": sources.digest(),
                   "files": {name: d[:16] for name, d in sources.digests().items()}},
          "versions": sources.versions(),
          "plans": {sid: v for sid, v in extra.items() if v is not None}}
    return json.loads(json.dumps(fp, sort_keys=True, default=repr))


def _without_code(fp: dict) -> dict:
    """The fingerprint less its code parts ("code" and the render keys' "code" component)."""
    out = {k: v for k, v in fp.items() if k != "code"}
    if isinstance(out.get("render"), dict):
        out["render"] = {k: v for k, v in out["render"].items() if k != "code"}
    return out


def code_change(old: dict, new: dict) -> dict | None:
    """None when two fingerprints hold the same code; else {"from", "to": version + source hash,
    "changed": the package files added, removed or edited}."""
    was, now = old.get("code") or {}, new.get("code") or {}
    if was == now and (old.get("render") or {}).get("code") == (new.get("render") or {}).get("code"):
        return None
    a, b = was.get("files") or {}, now.get("files") or {}
    changed = sorted(n for n in set(a) | set(b) if a.get(n) != b.get(n))

    def label(c: dict) -> str:
        return f"{c.get('nlosbench', '?')} ({str(c.get('source', '?'))[:12]})"

    return {"from": label(was), "to": label(now), "changed": changed}


def first_difference(old, new, path: str = "") -> tuple[str, object, object] | None:
    """(key path, old value, new value) of the first difference between two JSON values, or None."""
    if isinstance(old, dict) and isinstance(new, dict):
        for k in list(old) + [k for k in new if k not in old]:
            if k not in old or k not in new:
                return _join(path, k), old.get(k, "<absent>"), new.get(k, "<absent>")
            d = first_difference(old[k], new[k], _join(path, k))
            if d:
                return d
        return None
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            d = first_difference(a, b, f"{path}[{i}]")
            if d:
                return d
        return None
    return None if old == new else (path or "<root>", old, new)


def _join(path: str, key) -> str:
    return f"{path}.{key}" if path else str(key)


def _short(v) -> str:
    text = json.dumps(v, default=repr) if not isinstance(v, str) else repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def holds_run(run_dir: Path) -> bool:
    """Whether the folder holds (part of) a run: its fingerprint or its results."""
    return (run_dir / FINGERPRINT).exists() or (run_dir / "results.json").exists()


def check(run_dir: Path, fp: dict, resume: bool, anyway: bool = False) -> dict | None:
    """Refuse (RunFolderError, one line) a new run into a folder that holds one, or a resume whose
    fingerprint differs from the folder's (naming the first differing key), or whose code differs (naming
    the changed files) unless `anyway`. Returns the code change a resume `anyway` goes across (else None).
    Reads only."""
    if not holds_run(run_dir):
        return None
    if not resume:
        raise RunFolderError(str(run_dir), "already holds a run; pass --resume to continue it or --out for a new one")
    try:
        old = json.loads((run_dir / FINGERPRINT).read_text())
    except FileNotFoundError:
        raise RunFolderError(str(run_dir), f"holds a run without {FINGERPRINT} (made by an older nlosbench), so a "
                                           "resume cannot be checked; start a new run with another --out") from None
    except ValueError as e:
        raise RunFolderError(str(run_dir / FINGERPRINT), f"unreadable ({e}); start a new run with another --out") \
            from None
    d = first_difference(_without_code(old), _without_code(fp))
    parts = d[0].split(".") if d else []
    if parts[:1] == ["model"] and "render" in parts:  # the machine (or a run from before it was recorded)
        _, was, now = d
        key = ".".join(parts[parts.index("render"):])
        raise RunFolderError(str(run_dir), f"was rendered with {key} = {_short(was)}, "
                                           f"this process has {_short(now)}, and renders differ in their last bits "
                                           "between the two: resume where it was started (same CPU, scene.llvm_target "
                                           "and versions), or use a new --out")
    if d:
        key, was, now = d
        key = key.removeprefix("config.")
        what = "the scene's files changed: " if key.startswith("model.") and key.endswith("scene") else ""
        raise RunFolderError(str(run_dir), f"{what}was run with {key} = {_short(was)}, this config has "
                                           f"{_short(now)}; a resume needs the same config (only "
                                           f"{', '.join(NUMBERLESS)} may differ): undo the change, or use a new --out")
    change = code_change(old, fp)
    if change and not anyway:
        files = change["changed"]
        named = ", ".join(files[:4]) + (f" and {len(files) - 4} more" if len(files) > 4 else "")
        raise RunFolderError(str(run_dir), f"was run with nlosbench {change['from']}, this is {change['to']} "
                                           f"(changed: {named or 'the rendering code'}); finished work would mix "
                                           "with this code's: undo the change, use a new --out, or pass "
                                           "--resume-anyway to continue and record it in the run")
    return change


def write_fingerprint(run_dir: Path, fp: dict) -> None:
    """Write fingerprint.json (atomically) unless the folder has it already (a checked resume)."""
    if not (run_dir / FINGERPRINT).exists():
        write_json(run_dir / FINGERPRINT, fp)


def lock_holder(run_dir: Path) -> int | None:
    """The PID of a process holding the folder's lock, or None when it is free (creates nothing)."""
    import fcntl

    try:
        fd = os.open(run_dir / LOCK, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return _pid(fd)
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _pid(fd: int) -> int:
    try:
        return int(os.pread(fd, 32, 0).split()[0])
    except (ValueError, IndexError, OSError):
        return -1


class RunLock:
    """Exclusive lock of a run folder (created if needed) for the life of this object's `with` block."""

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self._fd: int | None = None

    def __enter__(self) -> RunLock:
        import fcntl

        self.run_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.run_dir / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _pid(fd)
            os.close(fd)
            raise RunFolderError(str(self.run_dir), f"is in use by another nlosbench run (PID {pid}); wait for it to "
                                                    "finish or stop it, or use another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None
