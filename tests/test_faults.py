"""Fault injection: runs that cannot mix, tear or hang. One test (or a few) per row of the issue's table;
each docstring says what it simulates. Analytic toys (`edge1d`) where a Mitsuba scene is not essential,
the Π hallway at 16 × 12, max_depth 3 where it is (viewpoints, long renders). Subprocesses for Ctrl-C,
kill -9 and the lock."""
import json
import os
import re
import signal
import subprocess
import sys
import time
import types
import warnings
from pathlib import Path

import pytest
import yaml

from nlosbench.cli import main
from nlosbench.executors import _call as _CALL
from nlosbench.records import RecordLog

ROOT = Path(__file__).parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
PI = {"name": "pi_hallway", "options": {"defines": {"width": 16, "height": 12, "max_depth": 3}}}
EDGE = {"name": "edge1d", "options": {"render_noise": 0.05}}
BOUNDS = {"type": "bounds", "grid": {"start": 0.3, "stop": 0.7, "num": 9}, "spp": 16}
TRIALS = {"type": "trials", "theta": [0.5], "n": 6, "n_eff": 4, "hcr_grid": 9, "bootstrap": 20,
          "estimators": [{"name": "grid-search", "options": {"num": 9, "spp": 1}}]}
VIEWS = {"type": "viewpoints", "num": 3, "step": 0.3, "spp": 4, "at": [0.9]}


def config(tmp_path: Path, scene: dict, studies: list, name: str = "c.yaml", **top) -> Path:
    raw = {"name": "faults", "seed": 3, "scene": scene, "noise": [{"model": "awgn", "sigma": 0.025}],
           "executor": {"type": "serial"}, "studies": studies, **top}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def cli(capsys, *args) -> tuple[int, str]:
    """Run `nlosbench ARGS` in this process; (exit code, stderr)."""
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("nlosbench: error:")]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file of a run folder (the lock file aside: it only holds the last holder's PID)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".lock"}


def spawn(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nlosbench.cli", *map(str, args)], env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def children(pid: int) -> list[int]:
    """PIDs of the live (not zombie) pool workers of process `pid` (Linux /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes()
        except (OSError, ValueError):
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == pid and fields[0] != "Z" and b"spawn_main" in cmd:
            out.append(int(d.name))
    return out


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def wait_for(predicate, timeout: float = 120.0, every: float = 0.05) -> bool:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(every)
    return False


linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


# -- row 1 and 6: viewpoints (Π hallway) -------------------------------------------------------------------
@pytest.fixture(scope="module")
def views(tmp_path_factory):
    """A finished viewpoints run on the Π hallway (9 viewpoints) and its viewpoints.csv."""
    tmp = tmp_path_factory.mktemp("views")
    cfg = config(tmp, PI, [VIEWS])
    out = tmp / "full"
    assert main(["run", str(cfg), "--out", str(out), "--quiet"]) == 0
    return cfg, out, (out / "00-viewpoints" / "viewpoints.csv").read_text()


def _killed_copy(src: Path, dst: Path, keep: int, tail: bytes = b"") -> Path:
    """The state of a run killed in its first study: `keep` records in the log (+ `tail`), no results."""
    import shutil

    shutil.copytree(src, dst)
    for f in ("results.json", "report.md", "00-viewpoints/viewpoints.csv"):
        (dst / f).unlink()
    log = dst / "00-viewpoints" / "viewpoints.jsonl"
    lines = log.read_bytes().splitlines(keepends=True)
    log.write_bytes(b"".join(lines[:keep]) + tail)
    return log


def test_viewpoints_resume_with_another_sigma_is_refused_and_writes_nothing(views, tmp_path, capsys):
    """Row 1. Simulates a viewpoints run killed after 4 of 9 viewpoints (log cut, no results.json), then
    `--resume --set noise.0.sigma=0.5`: exit 2, one line naming the key, not one byte changed; the same
    config then resumes to the uninterrupted run's numbers, and its render count covers both invocations."""
    cfg, full, csv = views
    run = tmp_path / "killed"
    _killed_copy(full, run, keep=4)
    before = snapshot(run)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "noise.0.sigma=0.5", "--quiet")
    assert rc == 2 and len(errors(err)) == 1, err
    assert "noise[0].sigma = 0.025, this config has 0.5" in err
    assert snapshot(run) == before
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
    assert rc == 0, err
    assert (run / "00-viewpoints" / "viewpoints.csv").read_text() == csv
    assert len(RecordLog(run / "00-viewpoints" / "viewpoints.jsonl").read()) == 9
    counts = [json.loads((d / "results.json").read_text())["studies"]["00-viewpoints"]["results"]["renders"]
              for d in (full, run)]
    assert counts[0] == counts[1] == 9 * 5  # both invocations' renders: a render and 2 FD rounds per viewpoint


def test_torn_viewpoints_record_is_cut_with_a_warning_and_resumes(views, tmp_path):
    """Row 6. Simulates a kill while the 6th record was being written (a torn last line): the resume cuts it
    with a warning naming the file and gives the uninterrupted run's numbers."""
    cfg, full, csv = views
    run = tmp_path / "torn"
    log = _killed_copy(full, run, keep=5, tail=b'{"i": 2, "j": 1, "offset": [0.3')
    with pytest.warns(UserWarning, match=r"viewpoints\.jsonl: cut off a torn last record"):
        assert main(["run", str(cfg), "--out", str(run), "--resume", "--quiet"]) == 0
    assert (run / "00-viewpoints" / "viewpoints.csv").read_text() == csv
    lines = log.read_bytes().splitlines(keepends=True)
    assert len(lines) == 9 and all(json.loads(x) for x in lines)


def test_damaged_log_line_names_file_and_line(views, tmp_path, capsys):
    """Row 6 (cont.): a damaged line in the middle of the log (simulated: one record cut short) is an error
    naming the file and the line (exit 2), not a JSON message without a file."""
    cfg, full, _ = views
    bad = tmp_path / "damaged"
    log = _killed_copy(full, bad, keep=5)
    text = log.read_bytes().splitlines(keepends=True)
    log.write_bytes(b"".join(text[:2] + [b'{"i": 0, "j"\n'] + text[3:]))
    rc, err = cli(capsys, "run", cfg, "--out", bad, "--resume", "--quiet")
    assert rc == 2 and f"{log}:3: not a record" in err and len(errors(err)) == 1, err


def test_every_record_is_fsynced_before_the_next(tmp_path, monkeypatch):
    """Row 6 (cont.): the one record log (trials and viewpoints use it) fsyncs every record as it is appended.
    Simulates nothing: counts fsync calls on the log's descriptor."""
    synced = []
    real = os.fsync

    def counting(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}") if sys.platform.startswith("linux") else "?")
        real(fd)

    monkeypatch.setattr(os, "fsync", counting)
    with RecordLog(tmp_path / "log.jsonl") as log:
        for k in range(3):
            log.append({"k": k})
            assert len(synced) == k + 1
    assert [r["k"] for r in RecordLog(tmp_path / "log.jsonl").read()] == [0, 1, 2]


# -- rows 2 and 3: a resume with another config ---------------------------------------------------------------
def test_bounds_resume_with_other_sigma_and_spp_is_refused_and_rewrites_nothing(tmp_path, capsys):
    """Row 2. A finished bounds run resumed with σ and spp changed: exit 2 naming the first differing key;
    config.yaml, report.md and the tables unchanged. Keys that change no number (executor, cache) may differ."""
    cfg = config(tmp_path, EDGE, [BOUNDS])
    run = tmp_path / "run"
    assert cli(capsys, "run", cfg, "--out", run, "--quiet")[0] == 0
    before = snapshot(run)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "noise.0.sigma=0.5",
                  "--set", "studies.0.spp=32", "--quiet")
    assert rc == 2 and len(errors(err)) == 1 and "noise[0].sigma" in err, err
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "studies.0.spp=32", "--quiet")
    assert rc == 2 and "studies[0].spp = 16, this config has 32" in err, err
    assert snapshot(run) == before
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "executor.workers=1", "--quiet")
    assert rc == 0, err
    assert (run / "00-bounds" / "bounds.csv").read_bytes() == before["00-bounds/bounds.csv"]


def test_trials_resume_with_another_n_is_refused_before_config_yaml_is_written(tmp_path, capsys):
    """Row 3. The trials study's own plan.json check is now the run's fingerprint: refused with exit 2 and a
    single, unrepeated study name, config.yaml untouched."""
    cfg = config(tmp_path, EDGE, [TRIALS])
    run = tmp_path / "run"
    assert cli(capsys, "run", cfg, "--out", run, "--quiet")[0] == 0
    before = snapshot(run)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "studies.0.n=3", "--quiet")
    assert rc == 2 and errors(err) == [e for e in err.splitlines() if e], err
    assert "studies[0].n = 6, this config has 3" in err and "00-trials: 00-trials" not in err
    assert snapshot(run) == before and not (run / "00-trials" / "plan.json").exists()
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "new", "--set", "studies.0.n=0", "--quiet")
    assert rc == 2 and errors(err) == ["nlosbench: error: 00-trials.n: expected a positive integer, got 0"], err


# -- row 4: two writers --------------------------------------------------------------------------------------
@linux
def test_a_second_resume_into_a_running_folder_is_refused_at_once(tmp_path, capsys):
    """Row 4. Two resumes of one trials folder at once (a real second process holds the folder): the second
    exits 2 at once naming the holder's PID; the holder finishes with exactly one record per trial."""
    slow = {**TRIALS, "n": 16, "estimators": [{"name": "mle-adam", "options": {"iterations": 60, "spp": 1, "tol": 0}}]}
    cfg = config(tmp_path, EDGE, [slow])
    run = tmp_path / "run"
    holder = spawn("run", cfg, "--out", run, "--resume", "--quiet")
    log = run / "00-trials" / "trials.jsonl"
    try:
        assert wait_for(lambda: log.exists() or holder.poll() is not None), holder.communicate()
        assert holder.poll() is None, "the first run finished before the second could start"
        t0 = time.perf_counter()
        rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
        assert rc == 2 and f"in use by another nlosbench run (PID {holder.pid})" in err, err
        assert time.perf_counter() - t0 < 5
    finally:
        _, err = holder.communicate(timeout=300)
    assert holder.returncode == 0, err
    records = RecordLog(log).read()
    assert len(records) == 16 and len({(r["trial"], r["estimator"]) for r in records}) == 16
    results = json.loads((run / "results.json").read_text())
    assert results["studies"]["00-trials"]["results"]["summary"][0]["n"] == 16


# -- row 5 and 12: input types ---------------------------------------------------------------------------------
@pytest.mark.parametrize("override, message", [
    ('studies.0.grid="11"', "studies[0].grid: expected a non-empty list of numbers, {start, stop, num} or a list "
                            "of such segments, got str '11'"),
    ('studies.0.grid="0.8"', "got str '0.8'"),
    ("studies.0.grid=0.8", "got float 0.8"),
    ('studies.0.grid=[0.3, "0.5", 0.7]', "studies[0].grid[1]: expected a number or {start, stop, num}, got str"),
    ("studies.3.spp=8", "studies.3: expected an index below 1 into the list studies, got '3'"),
])
def test_a_string_where_numbers_are_expected_is_an_error(tmp_path, capsys, override, message):
    """Row 5. `--set` values parse as YAML; a string where the schema expects numbers is one clear line
    (exit 2), never a list of characters; nothing is written."""
    cfg = config(tmp_path, EDGE, [BOUNDS])
    out = tmp_path / "new" / "run"
    rc, err = cli(capsys, "run", cfg, "--out", out, "--set", override, "--quiet")
    assert rc == 2 and message in err and len(errors(err)) == 1, err
    assert not out.parent.exists()


@pytest.mark.parametrize("study, message", [
    ({**TRIALS, "theta": ["0.5"]}, "studies[0].theta: expected a non-empty list of θ points"),
    ({"type": "fisher-maps", "at": ["0.5"], "spp": 4}, "studies[0].at[0]: expected a number or a list of numbers"),
    ({"type": "inexact", "theta": [0.5], "deltas": "0.1"}, "studies[0].deltas: expected a non-empty list"),
])
def test_a_theta_given_as_a_string_writes_nothing(tmp_path, capsys, study, message):
    """Row 12. A θ given as a string: exit 2 before the run folder or config.yaml is written."""
    rc, err = cli(capsys, "run", config(tmp_path, EDGE, [study]), "--out", tmp_path / "run", "--quiet")
    assert rc == 2 and message in err, err
    assert not (tmp_path / "run").exists()


# -- row 7: the environment ----------------------------------------------------------------------------------
def _mount_tmpfs(where: Path, options: str) -> bool:
    """Mount a tmpfs at `where` (needs root and mount rights); False where that is not possible."""
    where.mkdir(parents=True, exist_ok=True)
    try:
        return subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                              capture_output=True).returncode == 0
    except OSError:
        return False


def _umount(where: Path) -> None:
    subprocess.run(["umount", str(where)], capture_output=True)


def _complete(folder: Path) -> None:
    """No temporary file left, and every data file under its final name reads back whole."""
    assert not [p for p in folder.rglob("*.tmp")], list(folder.rglob("*.tmp"))
    for p in folder.rglob("*"):
        if p.suffix == ".json":
            json.loads(p.read_text())
        elif p.suffix == ".yaml":
            assert yaml.safe_load(p.read_text())
        elif p.suffix == ".csv":
            assert p.read_text().endswith("\n")


@linux
def test_a_full_disk_gives_one_line_leaves_no_torn_file_and_resumes(tmp_path, capsys):
    """Row 7, full disk, for real: the run folder is a 64 KiB tmpfs (skipped where it cannot be mounted). The
    render store fills it (warned, the run goes on), then a table cannot be written: exit 1, one line naming
    the file, 'No space left on device (ENOSPC)' and how to resume; every file under its final name is
    complete. With the disk grown, the resume gives the numbers of a run that never failed."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "size=64k"):
        pytest.skip("cannot mount a tmpfs here (needs root); the in-process ENOSPC test below still runs")
    try:
        cfg = config(tmp_path, {"name": "blob2d", "params": ["x"], "options": {"render_noise": 0.05}}, [BOUNDS])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the render store's "cannot write" warning
            rc, err = cli(capsys, "run", cfg, "--out", disk / "run", "--quiet")
        assert rc == 1 and len(errors(err)) == 1, err
        assert "No space left on device (ENOSPC): " + str(disk / "run") in err
        assert f"resume with: nlosbench run {cfg} --out {disk / 'run'} --resume" in err
        _complete(disk / "run")
        subprocess.run(["mount", "-o", "remount,size=8m", str(disk)], check=True)
        assert cli(capsys, "run", cfg, "--out", disk / "run", "--resume", "--quiet")[0] == 0
        assert cli(capsys, "run", cfg, "--out", tmp_path / "clean", "--quiet")[0] == 0
        assert (disk / "run" / "00-bounds" / "bounds.csv").read_bytes() == \
            (tmp_path / "clean" / "00-bounds" / "bounds.csv").read_bytes()
    finally:
        _umount(disk)


def test_disk_full_while_writing_results_is_one_line_and_resumable(tmp_path, capsys, monkeypatch):
    """Row 7, full disk, in-process (runs everywhere): os.fsync raises ENOSPC for results.json, as a full
    disk does when the data is flushed. Exit 1 naming results.json; no half-written results.json; the resume
    (disk 'freed') finishes with the same numbers."""
    import errno

    cfg = config(tmp_path, EDGE, [BOUNDS])
    run = tmp_path / "run"
    real = os.fsync

    def full(fd):
        if os.readlink(f"/proc/self/fd/{fd}").split("/")[-1].startswith(".results.json"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd)

    if not sys.platform.startswith("linux"):
        pytest.skip("names the descriptor's file through /proc")
    monkeypatch.setattr(os, "fsync", full)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    assert rc == 1 and errors(err) == [
        f"nlosbench: error: No space left on device (ENOSPC): {run / 'results.json'} — free space on that disk or use "
        f"another --out; resume with: nlosbench run {cfg} --out {run} --resume"], err
    assert not (run / "results.json").exists() and (run / "00-bounds" / "bounds.csv").exists()
    _complete(run)
    monkeypatch.setattr(os, "fsync", real)
    assert cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")[0] == 0
    assert cli(capsys, "run", cfg, "--out", tmp_path / "clean", "--quiet")[0] == 0
    clean = tmp_path / "clean" / "00-bounds" / "bounds.csv"
    assert (run / "00-bounds" / "bounds.csv").read_bytes() == clean.read_bytes()


def test_unwritable_run_folders_give_one_line_naming_the_path(tmp_path, capsys):
    """Row 7, read-only or missing paths. --out under a regular file (ENOTDIR: a path no one can write, root
    included) always; a read-only tmpfs (EROFS) where one can be mounted. Exit 1, one line naming the path."""
    cfg = config(tmp_path, EDGE, [BOUNDS])
    (tmp_path / "afile").write_text("")
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "afile" / "run", "--quiet")
    assert rc == 1 and len(errors(err)) == 1 and f"(ENOTDIR): {tmp_path / 'afile' / 'run'}" in err, err
    ro = tmp_path / "ro"
    if _mount_tmpfs(ro, "ro,size=64k"):
        try:
            rc, err = cli(capsys, "run", cfg, "--out", ro / "run", "--quiet")
            assert rc == 1 and len(errors(err)) == 1 and f"Read-only file system (EROFS): {ro / 'run'}" in err, err
        finally:
            _umount(ro)


def test_an_invalid_scene_file_is_one_line_naming_it(tmp_path, capsys):
    """Row 7, invalid scene XML: exit 2 (bad input), one line naming the XML file, nothing written."""
    (tmp_path / "bad.xml").write_text('<scene version="3.0.0">\n  <shape type="sphere"\n</scene>\n')
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({"file": "bad.xml", "params": [
        {"name": "r", "kind": "radius", "object": "ball", "lower": 0.1, "upper": 0.2, "default": 0.15}]}))
    cfg = config(tmp_path, {"name": str(tmp_path / "bad.yaml")}, [BOUNDS])
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "run", "--quiet")
    assert rc == 2 and len(errors(err)) == 1 and f"{tmp_path / 'bad.xml'} does not load" in err, err
    assert "Parsing of XML file" in err and not (tmp_path / "run").exists()


def test_an_unreachable_dask_scheduler_gives_up_after_the_timeout(tmp_path, capsys):
    """Row 7, Dask: a scheduler address where nothing listens, `executor.connect_timeout: 1`: exit 1 within
    seconds, one line naming the address and how to resume; no config.yaml or fingerprint written."""
    pytest.importorskip("distributed")
    cfg = config(tmp_path, EDGE, [BOUNDS],
                 executor={"type": "dask", "address": "tcp://127.0.0.1:9", "connect_timeout": 1})
    t0 = time.perf_counter()
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "run", "--quiet")
    assert rc == 1 and len(errors(err)) == 1, err
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9 within 1 s" in err and "--resume" in err
    assert time.perf_counter() - t0 < 30
    assert not (tmp_path / "run" / "config.yaml").exists() and not (tmp_path / "run" / "fingerprint.json").exists()


# -- row 8: the cache is best-effort -----------------------------------------------------------------------------
def test_a_cache_that_cannot_be_written_only_warns(tmp_path, capsys):
    """Row 8, a read-only cache that misses: simulated by a cache folder whose shard folders are files (no
    entry can be written, root included; chmod would not stop root). One warning, exit 0, same numbers."""
    cache = tmp_path / "cache"
    cache.mkdir()
    for i in range(256):
        (cache / f"{i:02x}").write_text("")
    cfg = config(tmp_path, EDGE, [BOUNDS])
    with pytest.warns(UserWarning, match=f"render cache {cache}: cannot write") as caught:
        rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "cached", "--set", f"cache={cache}", "--quiet")
    assert rc == 0, err
    assert sum("cannot write" in str(w.message) for w in caught) == 1
    assert cli(capsys, "run", cfg, "--out", tmp_path / "plain", "--quiet")[0] == 0
    assert (tmp_path / "cached" / "00-bounds" / "bounds.csv").read_bytes() == \
        (tmp_path / "plain" / "00-bounds" / "bounds.csv").read_bytes()


def test_a_corrupt_entry_that_cannot_be_deleted_is_reported_and_skipped(tmp_path, capsys, monkeypatch):
    """Row 8, corrupt + undeletable: every cache entry overwritten with garbage, and deleting an entry fails
    (Path.unlink raises EACCES for the cache's files: as root, chmod would not stop it). The run re-renders
    (exit 0, same numbers) and reports each corrupt key once."""
    cache = tmp_path / "cache"
    cfg = config(tmp_path, EDGE, [BOUNDS])
    assert cli(capsys, "run", cfg, "--out", tmp_path / "first", "--set", f"cache={cache}", "--quiet")[0] == 0
    entries = sorted(cache.rglob("*.npc"))
    assert entries
    for e in entries:
        e.write_bytes(b"NLOSRC01" + b"\0" * 64)
    real = Path.unlink

    def stuck(self, missing_ok=False):
        if cache in self.parents:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self, missing_ok=missing_ok)

    monkeypatch.setattr(Path, "unlink", stuck)
    with pytest.warns(UserWarning) as caught:
        rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "second", "--set", f"cache={cache}", "--quiet")
    assert rc == 0, err
    corrupt = [str(w.message) for w in caught if "is corrupt" in str(w.message)]
    assert sorted(m.split("entry ")[1].split(" ")[0] for m in corrupt) == sorted(e.stem for e in entries)
    assert any("cannot delete the corrupt entry" in str(w.message) for w in caught)
    assert (tmp_path / "second" / "00-bounds" / "bounds.csv").read_bytes() == \
        (tmp_path / "first" / "00-bounds" / "bounds.csv").read_bytes()


# -- rows 9 and 10: Ctrl-C and kill -9 ---------------------------------------------------------------------------
LONG = {**BOUNDS, "grid": {"start": 0.8, "stop": 1.2, "num": 5}, "spp": 4096 * 200, "zzb": False}


@linux
@pytest.mark.parametrize("executor", [{"type": "serial"}, {"type": "local", "workers": 1}])
def test_ctrl_c_during_a_long_render_stops_with_a_resume_hint(tmp_path, executor):
    """Row 9. Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while a long Π-hallway render
    runs in the main process or in a pool worker: exit 130 within seconds, one line saying how to resume, no
    traceback (workers ignore SIGINT; the parent stops them), no worker left."""
    cfg = config(tmp_path, PI, [LONG], executor=executor)
    run = tmp_path / "run"
    proc = spawn("run", cfg, "--out", run, "--yes", start_new_session=True)
    err = ""
    try:
        assert wait_for(lambda: (run / "config.yaml").exists() or proc.poll() is not None), proc.communicate()
        time.sleep(3)  # inside the first grid render (about 200 passes of 2^20 samples)
        workers = children(proc.pid)
        assert proc.poll() is None and len(workers) == (executor["type"] == "local")
        t0 = time.perf_counter()
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert time.perf_counter() - t0 < 15
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert errors(err)[-1] == ("nlosbench: error: interrupted; resume with: "
                               f"nlosbench run {cfg} --out {run} --resume --yes")
    assert wait_for(lambda: not any(alive(w) for w in workers), timeout=5)


def test_a_second_ctrl_c_stops_at_once(tmp_path):
    """Row 9, the second Ctrl-C: a process inside `nlosbench run`'s interrupt handling whose cleanup hangs
    (simulated: it sleeps) is ended by a second SIGINT at once (the default action, exit by signal)."""
    script = tmp_path / "hang.py"
    script.write_text("import time\nfrom nlosbench.cli import _interrupts\ntry:\n    with _interrupts():\n"
                      "        print('ready', flush=True)\n        time.sleep(120)\nexcept KeyboardInterrupt:\n"
                      "    print('cleanup', flush=True)\n    time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, str(script)], env=ENV, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        proc.send_signal(signal.SIGINT)
        assert proc.stdout.readline().strip() == "cleanup"
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        assert time.perf_counter() - t0 < 2 and proc.returncode == -signal.SIGINT
    finally:
        if proc.poll() is None:
            proc.kill()


@linux
@pytest.mark.slow
def test_kill_9_of_the_main_process_leaves_no_worker(tmp_path):
    """Row 10. kill -9 of `nlosbench run` while its 2 pool workers render (the first renders are back, so
    both have started): every worker exits within seconds (each watches its parent), and the folder's lock
    is free again (the OS released it). A worker still importing when its parent dies exits as soon as its
    import ends (its watchdog starts in the pool initialiser)."""
    from nlosbench.experiment.rundir import lock_holder

    cfg = config(tmp_path, PI, [{**LONG, "spp": 4096 * 4}], executor={"type": "local", "workers": 2})
    run = tmp_path / "run"
    proc = spawn("run", cfg, "--out", run, "--yes", "--quiet")
    try:
        assert wait_for(lambda: any((run / "renders").rglob("*.npc")) or proc.poll() is not None, timeout=240), \
            proc.communicate()
        workers = children(proc.pid)
        assert proc.poll() is None and len(workers) == 2 and lock_holder(run) == proc.pid
        proc.kill()
        proc.wait()
        assert wait_for(lambda: not any(alive(w) for w in workers), timeout=10), [w for w in workers if alive(w)]
        assert lock_holder(run) is None
    finally:
        if proc.poll() is None:
            proc.kill()


# -- row 11: the cost ---------------------------------------------------------------------------------------------
def test_a_billion_spp_needs_yes_and_says_what_it_would_cost(tmp_path, capsys):
    """Row 11. `spp: 1000000000` on the Π hallway: before any render of the study, the plan and an estimated
    time (from a rate measured on this machine) are printed; above an hour the run needs --yes (exit 2 with
    the estimate), and nothing is written. A normal run prints its plan too."""
    cfg = config(tmp_path, PI, [{**BOUNDS, "grid": {"start": 0.8, "stop": 1.2, "num": 5}, "spp": 1000000000}])
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "run")
    assert rc == 2 and "[00-bounds] plan: 15 renders, 2.88e+12 pixel-samples" in err, err
    assert "this run is estimated at" in errors(err)[0] and "pass --yes to run it" in errors(err)[0]
    assert not (tmp_path / "run").exists()
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "small", "--set", "studies.0.spp=4")
    assert rc == 0 and "[00-bounds] plan: 15 renders" in err and "estimate: ≈" in err, err


# -- content keys, a verified render store, the code in the fingerprint ------------------------------------------
PI_BOUNDS = {"type": "bounds", "grid": {"start": 0.8, "stop": 1.2, "num": 3}, "spp": 4, "zzb": False}


def _pi_scene(tmp_path: Path, how: str) -> Path:
    """A copy of the Π hallway whose teapot is named through a define (`how` = "define": `$mesh.ply`, default
    `teapot`) or sits in an included file (`how` = "include": object.xml); returns its scene spec."""
    scenes = ROOT / "scenes"
    folder = tmp_path / how
    folder.mkdir()
    (folder / "teapot.ply").write_bytes((scenes / "teapot.ply").read_bytes())
    xml = (scenes / "pi_hallway.xml").read_text()
    start, end = xml.index('    <shape type="ply" id="object">'), xml.index("</scene>")
    if how == "define":
        xml = xml.replace('<scene version="3.0.0">', '<scene version="3.0.0"><default name="mesh" value="teapot"/>')
        xml = xml.replace('value="teapot.ply"', 'value="$mesh.ply"')
    else:
        (folder / "object.xml").write_text(f'<scene version="3.0.0">\n{xml[start:end]}</scene>\n')
        xml = xml[:start] + '    <include filename="object.xml"/>\n' + xml[end:]
    (folder / "pi.xml").write_text(xml)
    spec = yaml.safe_load((scenes / "pi_hallway.yaml").read_text())
    (folder / "pi.yaml").write_text(yaml.safe_dump({**spec, "file": "pi.xml"}))
    return folder / "pi.yaml"


def _scale_mesh(path: Path, factor: float) -> None:
    """Scale every vertex of a PLY mesh by `factor` (rewritten in place by Mitsuba)."""
    import mitsuba as mi

    mesh = mi.load_dict({"type": "ply", "filename": str(path)})
    params = mi.traverse(mesh)
    params["vertex_positions"] = params["vertex_positions"] * factor
    params.update()
    mesh.write_ply(str(path))


@pytest.mark.parametrize("how", ["define", "include"])
def test_an_edited_mesh_named_by_a_define_or_an_include_is_never_served_stale(tmp_path, capsys, how):
    """A mesh named through a define (`$mesh.ply`) or inside an `<include>`d file: a Π-hallway bounds run with a
    shared `cache`, then every vertex of the teapot scaled by 1.25. The next run through the same cache gives
    the numbers of a run without any cache (not the old mesh's), and `--resume` of the first run is refused
    (exit 2, naming the scene's files), writing nothing."""
    spec = _pi_scene(tmp_path, how)
    cache = tmp_path / "cache"
    cfg = config(tmp_path, {"name": str(spec), "options": PI["options"]}, [PI_BOUNDS], cache=str(cache))
    assert cli(capsys, "run", cfg, "--out", tmp_path / "old", "--quiet")[0] == 0
    old = (tmp_path / "old" / "00-bounds" / "bounds.csv").read_bytes()
    _scale_mesh(spec.parent / "teapot.ply", 1.25)
    assert cli(capsys, "run", cfg, "--out", tmp_path / "new", "--quiet")[0] == 0
    assert cli(capsys, "run", cfg, "--out", tmp_path / "fresh", "--set", "cache=null", "--quiet")[0] == 0
    new = (tmp_path / "new" / "00-bounds" / "bounds.csv").read_bytes()
    assert new != old and new == (tmp_path / "fresh" / "00-bounds" / "bounds.csv").read_bytes()
    before = snapshot(tmp_path / "old")
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "old", "--resume", "--quiet")
    assert rc == 2 and len(errors(err)) == 1 and "the scene's files changed: was run with model.scene" in err, err
    assert snapshot(tmp_path / "old") == before


def _killed_bounds(src: Path, dst: Path) -> None:
    """The state of a bounds run killed in its study: its render store kept, nothing else of the study."""
    import shutil

    shutil.copytree(src, dst)
    shutil.rmtree(dst / "00-bounds")
    for f in ("results.json", "report.md"):
        (dst / f).unlink()


def test_a_render_file_copied_over_another_is_detected_and_rerendered(tmp_path, capsys):
    """A valid render file copied over another in a run's render store (a restore, a sync or dedup tool,
    merged folders), then `--resume` of the run killed in its study: the copy fails the key check (a warning
    naming the entry's key), is re-rendered, and the numbers are those of the uninterrupted run."""
    cfg = config(tmp_path, EDGE, [BOUNDS])
    assert cli(capsys, "run", cfg, "--out", tmp_path / "full", "--quiet")[0] == 0
    run = tmp_path / "run"
    _killed_bounds(tmp_path / "full", run)
    a, b = sorted((run / "renders").rglob("*.npc"))[:2]
    b.write_bytes(a.read_bytes())
    with pytest.warns(UserWarning, match=f"entry {b.stem} is corrupt: it holds the render of another key"):
        assert cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")[0] == 0
    full = tmp_path / "full" / "00-bounds" / "bounds.csv"
    assert (run / "00-bounds" / "bounds.csv").read_bytes() == full.read_bytes()


def test_a_resume_across_a_code_change_is_refused_unless_resume_anyway(tmp_path, capsys, monkeypatch):
    """A finished bounds run, then nlosbench's code changes (simulated: the hash of studies/bounds.py, as an
    editable install sees an edited file). `--resume` is refused (exit 2) naming the changed file and
    --resume-anyway, nothing written; `--resume-anyway` goes on and records the change in results.json and
    report.md."""
    from nlosbench import sources

    cfg = config(tmp_path, EDGE, [BOUNDS])
    run = tmp_path / "run"
    assert cli(capsys, "run", cfg, "--out", run, "--quiet")[0] == 0
    before = snapshot(run)
    edited = {**sources.digests(), "studies/bounds.py": "0" * 64}
    monkeypatch.setattr(sources, "digests", lambda: edited)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
    assert rc == 2 and len(errors(err)) == 1 and "(changed: studies/bounds.py)" in err and "--resume-anyway" in err, err
    assert snapshot(run) == before
    assert cli(capsys, "run", cfg, "--out", run, "--resume-anyway", "--quiet")[0] == 0
    (record,) = json.loads((run / "results.json").read_text())["resumed_anyway"]
    assert record["changed"] == ["studies/bounds.py"]
    assert "**Resumed across a code change** (`--resume-anyway`" in (run / "report.md").read_text()


# -- a resume that rebuilds --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_studies(tmp_path_factory):
    """A finished run of a bounds and a trials study on edge1d, its config and a snapshot of its files."""
    tmp = tmp_path_factory.mktemp("two")
    cfg = config(tmp, EDGE, [BOUNDS, TRIALS])
    assert main(["run", str(cfg), "--out", str(tmp / "full"), "--quiet"]) == 0
    return cfg, tmp / "full", snapshot(tmp / "full")


def test_resume_rebuilds_a_deleted_study_folder_and_trials_log(two_studies, tmp_path, capsys):
    """A finished run whose bounds study folder was removed (`rm -rf RUN/00-bounds`) and whose trials.jsonl was
    deleted: `--resume` warns naming each, rebuilds both studies from the render store and the record logs,
    and gives the uninterrupted run's numbers (bounds.csv byte for byte, every trial's estimate); the render
    counts that report.md adds up cover the renders of both invocations (the rebuild reads them back from
    the store). Fit costs and wall times are not compared: fits in one process share a memo."""
    import shutil

    cfg, full, files = two_studies
    run = tmp_path / "run"
    shutil.copytree(full, run)
    shutil.rmtree(run / "00-bounds")
    (run / "01-trials" / "trials.jsonl").unlink()
    with pytest.warns(UserWarning) as caught:
        rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
    assert rc == 0, err
    rebuilt = [str(w.message) for w in caught if "rebuilding the study" in str(w.message)]
    assert len(rebuilt) == 2 and f"{run / '00-bounds'}/" in rebuilt[0] and "is missing" in rebuilt[0], rebuilt
    assert f"{run / '01-trials' / 'trials.jsonl'} is missing" in rebuilt[1], rebuilt
    assert (run / "00-bounds" / "bounds.csv").read_bytes() == files["00-bounds/bounds.csv"]
    estimates = [[(r["trial"], r["theta_hat"]) for r in RecordLog(d / "01-trials" / "trials.jsonl").read()]
                 for d in (full, run)]
    assert estimates[0] == estimates[1] and len(estimates[0]) == TRIALS["n"]
    counts = [json.loads((d / "results.json").read_text())["studies"] for d in (full, run)]
    assert counts[0]["00-bounds"]["results"]["renders"] == counts[1]["00-bounds"]["results"]["renders"] > 0
    assert counts[0]["01-trials"]["results"]["bank_renders"] == counts[1]["01-trials"]["results"]["bank_renders"] > 0


@pytest.mark.parametrize("name", ["results.json", "fingerprint.json", "01-trials/trials.jsonl"])
def test_a_damaged_run_record_is_one_line_naming_the_file(two_studies, tmp_path, capsys, name):
    """results.json or fingerprint.json cut short (as a copy or a disk error leaves them), or a line in the middle
    of trials.jsonl damaged: `--resume` exits 2 with one error line naming the file, not a bare JSON message."""
    import shutil

    cfg, full, _ = two_studies
    run = tmp_path / "run"
    shutil.copytree(full, run)
    damaged = run / name
    raw = damaged.read_bytes()
    damaged.write_bytes(raw[:len(raw) // 2] if name.endswith(".json") else raw.replace(b"\n", b"\n{\n", 1))
    rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
    assert rc == 2 and len(errors(err)) == 1 and str(damaged) in errors(err)[0], err


def test_report_refuses_a_table_cut_short(two_studies, tmp_path, capsys):
    """bounds.csv cut to its first rows (no torn line: a file truncated at a line's end): `nlosbench report`
    exits 2 naming the file and the rows results.json says it has, instead of drawing from what is left."""
    import shutil

    _, full, _ = two_studies
    run = tmp_path / "run"
    shutil.copytree(full, run)
    table = run / "00-bounds" / "bounds.csv"
    rows = table.read_text().splitlines(keepends=True)
    table.write_text("".join(rows[:4]))
    rc, err = cli(capsys, "report", run)
    assert rc == 2 and errors(err) == [f"nlosbench: error: {table}: has 3 rows, results.json says {len(rows) - 1}: "
                                       f"a report from it would be wrong; resume the run (nlosbench run <its config> "
                                       f"--out {run} --resume) to rebuild it"], err


# -- the small ones: a study id, a damaged rate, a record log that cannot be written, a full /dev/shm -------------
@pytest.mark.parametrize("sid", ["../escape", "a/b", "/abs", "..", ".", "", "a\\b"])
def test_a_study_id_that_is_not_a_plain_name_is_refused(tmp_path, capsys, sid):
    """A study `id` is the study's folder in the run directory: one with a path separator, `..`, `.` or empty
    (which would write outside the run folder, or into it) is exit 2 at config time, one line naming
    `studies[0].id`, nothing written (neither the run folder nor the folder the id points at)."""
    run = tmp_path / "out" / "run"
    rc, err = cli(capsys, "run", config(tmp_path, EDGE, [{**BOUNDS, "id": sid}]), "--out", run, "--quiet")
    assert rc == 2 and errors(err) == [f"nlosbench: error: studies[0].id: expected a file or folder name inside the "
                                       f"run folder (one path component: no '/', no '..', not empty, at most 200 "
                                       f"bytes), got {sid!r}"], err
    assert not (tmp_path / "out").exists() and not (tmp_path / "escape").exists()


@pytest.mark.parametrize("bad", [float("nan"), 0.0, -1e-9, float("inf"), "fast"])
def test_a_damaged_rate_is_measured_again_so_the_hour_guard_holds(tmp_path, capsys, monkeypatch, bad):
    """~/.cache/nlosbench/rates.json (here under a temporary XDG_CACHE_HOME) edited so that the scene's rate is
    NaN, 0, negative, infinite or text: a run of days without --yes is still refused (exit 2 with a finite
    estimate; before, NaN or a rate <= 0 made the estimate NaN or 0 and the run started), and the rate is
    measured again and kept."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    cfg = config(tmp_path, EDGE, [{**BOUNDS, "spp": 10 ** 12}])
    assert cli(capsys, "run", cfg, "--out", tmp_path / "first")[0] == 2
    rates = tmp_path / "xdg" / "nlosbench" / "rates.json"
    kept = json.loads(rates.read_text())
    rates.write_text(json.dumps({k: {**v, "seconds_per_sample": bad} for k, v in kept.items()}))
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "run")
    assert rc == 2 and "pass --yes to run it" in errors(err)[0] and "(measured now)" in err, err
    assert "days" in errors(err)[0] and not (tmp_path / "run").exists()
    again = [v["seconds_per_sample"] for v in json.loads(rates.read_text()).values()]
    assert len(again) == 1 and 0 < again[0] < float("inf")


@linux
def test_a_record_log_that_cannot_be_written_names_its_file(tmp_path, capsys, monkeypatch):
    """A full disk while a trial's record is appended (simulated: os.fsync raises ENOSPC on trials.jsonl, as it
    does when the data is flushed; such an error carries no file name): exit 1, one line naming trials.jsonl,
    'No space left on device (ENOSPC)' and how to resume, not a bare '[Errno 28]'. The record logs of every
    study (trials, viewpoints) are one `RecordLog`."""
    import errno

    cfg = config(tmp_path, EDGE, [TRIALS])
    run = tmp_path / "run"
    real = os.fsync

    def full(fd):
        if os.readlink(f"/proc/self/fd/{fd}").endswith("trials.jsonl"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd)

    monkeypatch.setattr(os, "fsync", full)
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    log = run / "00-trials" / "trials.jsonl"
    assert rc == 1 and errors(err) == [
        f"nlosbench: error: No space left on device (ENOSPC): {log} — free space on that disk or use another --out; "
        f"resume with: nlosbench run {cfg} --out {run} --resume"], err


@pytest.mark.parametrize("where", ["a result", "the pool's queues"])
def test_a_full_dev_shm_is_one_line_naming_it_and_the_fix(tmp_path, capsys, monkeypatch, where):
    """A full /dev/shm (simulated, not filled: the pool is replaced by one that fails as torch and multiprocessing
    do) — a worker's image cannot be put in shared memory (torch's RuntimeError 'unable to write to file
    </torch_...>: No space left on device') or the pool's semaphores cannot be made (ENOSPC, no file named):
    exit 1, one line naming /dev/shm and the fixes, with how to resume; not a RuntimeError traceback nor a
    'free space on that disk or use another --out' that sends one to the wrong disk."""
    import errno
    from concurrent.futures import Future

    from nlosbench import executors

    class FullShm:
        def __init__(self, *args, **kw):
            if where == "the pool's queues":
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def submit(self, *args, **kw) -> Future:
            f = Future()
            f.set_exception(RuntimeError("unable to write to file </torch_4242_1234_0>: No space left on device (28)"))
            return f

        def shutdown(self, *args, **kw) -> None:
            pass

    monkeypatch.setattr(executors, "ProcessPoolExecutor", FullShm)
    cfg = config(tmp_path, EDGE, [BOUNDS], executor={"type": "local", "workers": 1})
    run = tmp_path / "run"
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    assert rc == 1 and errors(err) == [f"nlosbench: error: {executors.SHM_FULL}; resume with: nlosbench run {cfg} "
                                       f"--out {run} --resume"], err
    assert "/dev/shm" in executors.SHM_FULL and "executor.type: serial" in executors.SHM_FULL


# -- stop signals at any moment ----------------------------------------------------------------------------------
SHORT = {"type": "bounds", "grid": {"start": 0.8, "stop": 1.2, "num": 3}, "spp": 64, "zzb": False}
#: (signal, seconds after the command's handlers are in place — its first lines, before torch or Mitsuba is
#: imported — or after config.yaml is written: the run's studies under way)
MOMENTS = {"SIGINT": [(0.0, "start"), (1.2, "start"), (0.0, "run"), (1.0, "run")],
           "SIGTERM": [(0.3, "start"), (2.0, "start"), (0.3, "run")],
           "SIGHUP": [(0.7, "start"), (1.6, "start"), (0.6, "run")]}
BAD = ("Traceback", "leaked semaphore", "Fatal Python error", "Exception ignored", "resource_tracker")


def handles(pid: int, signum: int) -> bool:
    """Whether process `pid` has a handler for `signum` (the SigCgt mask of /proc/PID/status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = next((line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), "0")
    return bool(int(mask, 16) >> (signum - 1) & 1)


def _signal_lane(cfg: Path, tmp: Path, name: str) -> list[tuple]:
    """Start `nlosbench run` (its own process group: the signal goes to the group, as a terminal's or a batch
    system's does) and send `name` at each of its MOMENTS, one run after another; (delay, when, code, stdout,
    stderr, folder, workers seen) per run. The moments are counted from events, so a loaded machine shifts
    none of them before the command runs."""
    out = []
    for k, (delay, when) in enumerate(MOMENTS[name]):
        run = tmp / f"{name}-{k}"
        proc = spawn("run", cfg, "--out", run, "--quiet", start_new_session=True)
        workers: list[int] = []
        try:
            if when == "run":
                wait_for(lambda p=proc, r=run: (r / "config.yaml").exists() or p.poll() is not None, 60, 0.01)
            else:  # a signal before the interpreter runs the command's first lines is Python's own business
                wait_for(lambda p=proc: handles(p.pid, signal.SIGHUP) or p.poll() is not None, 60, 0.005)
            time.sleep(delay)
            workers = children(proc.pid)
            try:
                os.killpg(proc.pid, getattr(signal, name))
            except ProcessLookupError:  # finished already
                pass
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        out.append((delay, when, proc.returncode, stdout, stderr, run, workers))
    return out


@linux
@pytest.mark.slow
def test_sigint_sigterm_and_sighup_at_any_moment_end_with_one_line(tmp_path):
    """SIGINT (Ctrl-C), SIGTERM and SIGHUP sent to `python -m nlosbench run` (a Π-hallway bounds study with one
    pool worker) at moments spread from its start — the import of torch and nlosbench, Dr.Jit's and Mitsuba's
    import, the scene load, the rate measurement — to the renders in the pool worker (after config.yaml is
    written): 10 runs, the three signals' runs side by side. Each ends with exit 128 + the signal's number
    (130, 143, 129) and its last stderr line `nlosbench: error: interrupted[ (SIGTERM|SIGHUP)]` (with the
    resume command once the run has started), or had finished (exit 0, `done:`); never a traceback, a
    'leaked semaphore' or resource-tracker warning, a `Fatal Python error`, nor a pool worker left. Before:
    a signal during the imports printed a KeyboardInterrupt traceback (SIGINT) or ended silently by the
    signal (SIGTERM, SIGHUP: -15, -1), and SIGHUP killed multiprocessing's resource tracker (KeyError
    tracebacks)."""
    from concurrent.futures import ThreadPoolExecutor

    cfg = config(tmp_path, PI, [SHORT], executor={"type": "local", "workers": 1})
    with ThreadPoolExecutor(len(MOMENTS)) as lanes:
        runs = {name: lanes.submit(_signal_lane, cfg, tmp_path, name) for name in MOMENTS}
        runs = {name: f.result() for name, f in runs.items()}
    interrupted = 0
    for name, results in runs.items():
        signum = getattr(signal, name)
        for delay, when, code, stdout, stderr, run, workers in results:
            where = f"{name} {delay} s after the {when}: exit {code}\n{stderr}"
            assert not any(b in stderr for b in BAD), where
            assert wait_for(lambda ws=workers: not any(alive(w) for w in ws), timeout=5), where
            if code == 0:
                assert stdout.startswith("done:"), where
                continue
            interrupted += 1
            lines = [line for line in stderr.splitlines() if line.strip()]
            line = "nlosbench: error: interrupted" + ("" if name == "SIGINT" else f" ({name})")
            assert code == 128 + signum and lines[-1].startswith(line) and len(errors(stderr)) == 1, where
            hint = f"; resume with: nlosbench run {cfg} --out {run} --resume"
            assert lines[-1] in (line, line + hint) and (when == "start" or lines[-1] == line + hint), where
    assert interrupted >= 7, "most runs must be stopped, not finished: the moments are too late for this machine"
    assert any(r[6] for rs in runs.values() for r in rs), "no signal came while the pool worker was alive"


def test_a_signal_during_a_native_import_or_the_scene_load_is_held_until_it_ends():
    """A SIGTERM that arrives inside `interrupts.deferred()` (where Dr.Jit and Mitsuba are imported and the
    scene is loaded) does not cut the block: the block finishes, then the run's handler raises Interrupted
    (SIGTERM). Without the deferral the handler's exception would be raised in the middle of the native
    import, where it can leave Mitsuba half-initialised or abort the interpreter."""
    from nlosbench import interrupts
    from nlosbench.cli import _interrupts

    def early(signum, frame):  # what runs if nothing holds the signal (instead of SIGTERM's default: the end)
        raise RuntimeError("SIGTERM was not held")

    saved = {s: signal.getsignal(s) for s in interrupts.STOPPING}
    finished = False
    try:
        signal.signal(signal.SIGTERM, early)
        with _interrupts(), pytest.raises(interrupts.Interrupted) as stop:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)  # the handler would have run here (between bytecodes of this thread)
                finished = True
        assert finished and stop.value.signum == signal.SIGTERM
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


@pytest.mark.parametrize("how", ["cause", "message"])
def test_an_interrupt_inside_mitsubas_variant_import_is_not_a_variant_diagnosis(monkeypatch, how):
    """Ctrl-C while Mitsuba imports a variant's native module, which the binding reports as its own error (the
    KeyboardInterrupt as the cause, or only named in the message): `variant.select` re-raises it as
    KeyboardInterrupt (the command: one line, exit 130), not the VariantError 'no usable Mitsuba variant'
    with a fix that fixes nothing. Simulated with a stand-in `mitsuba` module."""
    import types

    from nlosbench import variant

    def set_variant(name: str) -> None:
        if how == "message":
            raise RuntimeError(f"could not import mitsuba.{name}: KeyboardInterrupt")
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError(f"could not import mitsuba.{name}") from e

    monkeypatch.setitem(sys.modules, "mitsuba", types.SimpleNamespace(variants=lambda: ["llvm_ad_rgb"],
                                                                      set_variant=set_variant))
    monkeypatch.setattr(variant, "_selected", None)
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/usr/lib/libLLVM-19.so")
    with pytest.raises(KeyboardInterrupt):
        variant.select("llvm_ad_rgb")


# -- bounded waits: a Dask scheduler without workers ---------------------------------------------------------------
@pytest.fixture
def scheduler():
    """A Dask scheduler in this process with no worker (skipped without dask.distributed, the 'dask' extra).

    Its workers, when a test starts some, are threads of this process: a render still running in one after its
    scheduler was lost would share Dr.Jit with the next test's renders (seen as a failed `dr.while_loop` in a
    later test), so the teardown waits for every `_slow_call` to return."""
    distributed = pytest.importorskip("distributed", reason="dask.distributed is not installed (the 'dask' extra)")
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None) as cluster:
        yield cluster
    assert wait_for(lambda: not _IN_FLIGHT, timeout=60, every=0.05), "a render still runs in a Dask worker thread"


def test_a_dask_scheduler_without_workers_gives_up_after_worker_timeout(tmp_path, capsys, scheduler):
    """A reachable Dask scheduler that has no worker (none was started), `executor.worker_timeout: 2`: exit 1
    within seconds (not a wait for ever), one line on stderr naming the scheduler's address and the key, with
    how to resume; Dask's own log lines are in RUN/dask.log, not on the terminal. (The timeout must be a
    number > 0: 0 is exit 2 naming the key.)"""
    address = scheduler.scheduler_address
    cfg = config(tmp_path, EDGE, [BOUNDS], executor={"type": "dask", "address": address, "worker_timeout": 2})
    run = tmp_path / "run"
    t0 = time.perf_counter()
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    assert rc == 1 and [line for line in err.splitlines() if line.strip()] == [
        f"nlosbench: error: no Dask worker at the scheduler {address} within 2 s (executor.worker_timeout): start "
        f"workers for that scheduler (dask worker {address}) or raise executor.worker_timeout; resume with: "
        f"nlosbench run {cfg} --out {run} --resume"], err
    assert 2 <= time.perf_counter() - t0 < 15
    assert "distributed.scheduler" in (run / "dask.log").read_text()
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "zero", "--set", "executor.worker_timeout=0", "--quiet")
    assert rc == 2 and errors(err) == ["nlosbench: error: executor.worker_timeout: expected a finite number > 0, "
                                       "got 0"], err


_IN_FLIGHT: set[int] = set()  # ids of the `_slow_call`s running now (in Dask worker threads of this process)


def _slow_call(*args):
    """`executors._call`, 0.3 s slower (module level: Dask pickles it by reference)."""
    token = object()
    _IN_FLIGHT.add(id(token))
    try:
        time.sleep(0.3)
        return _CALL(*args)
    finally:
        _IN_FLIGHT.discard(id(token))


def test_dask_workers_all_lost_mid_run_give_up_after_worker_timeout(tmp_path, capsys, scheduler, monkeypatch):
    """Every Dask worker lost mid-run (simulated: the scheduler's one worker is removed once the first renders
    are back; each task takes 0.3 s), `executor.worker_timeout: 2`: exit 1 a few seconds later (the tasks left
    would otherwise wait for ever), one line naming the scheduler and the key with how to resume; the
    finished renders are kept in the run's render store, and the resume (here on the serial executor: executor
    keys may change on --resume) finishes the run with the numbers of one that never failed."""
    import threading

    from nlosbench import executors

    monkeypatch.setattr(executors, "_call", _slow_call)  # the worker runs in this process: it looks it up here
    scheduler.scale(1)
    scheduler.wait_for_workers(1, timeout=30)
    address = scheduler.scheduler_address
    cfg = config(tmp_path, EDGE, [BOUNDS], executor={"type": "dask", "address": address, "worker_timeout": 2})
    run = tmp_path / "run"

    def lose_workers() -> None:
        wait_for(lambda: any((run / "renders").rglob("*.npc")), timeout=60, every=0.02)
        scheduler.scale(0)

    threading.Thread(target=lose_workers, daemon=True).start()
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    assert rc == 1 and errors(err) == [
        f"nlosbench: error: no Dask worker left at the scheduler {address} for 2 s (all lost mid-run) "
        f"(executor.worker_timeout): start workers for that scheduler (dask worker {address}) or raise "
        f"executor.worker_timeout; resume with: nlosbench run {cfg} --out {run} --resume"], err
    kept = list((run / "renders").rglob("*.npc"))
    assert kept and not (run / "00-bounds" / "bounds.csv").exists()
    monkeypatch.setattr(executors, "_call", _CALL)
    assert cli(capsys, "run", cfg, "--out", run, "--resume", "--set", "executor.type=serial", "--quiet")[0] == 0
    assert cli(capsys, "run", cfg, "--out", tmp_path / "clean", "--set", "executor.type=serial", "--quiet")[0] == 0
    assert (run / "00-bounds" / "bounds.csv").read_bytes() == \
        (tmp_path / "clean" / "00-bounds" / "bounds.csv").read_bytes()


def test_stopping_a_pool_with_queued_tasks_leaves_no_error_in_its_thread(monkeypatch):
    """The state a Ctrl-C leaves while pool workers start (2 workers busy, more tasks queued, the queued ones
    cancelled as the interrupt passes through `imap_unordered`), then `abort`: the pool's management thread ends
    without an exception, and has ended when `abort` returns. Before, the workers were killed first and that
    thread marked the cancelled futures failed: `InvalidStateError: CANCELLED` with a thread traceback printed
    after the run's error line; and a thread still closing its wakeup pipe as the interpreter exited raced exit's
    write to that pipe (`OSError: [Errno 9] Bad file descriptor` traceback after a SIGTERM's error line)."""
    import multiprocessing
    import threading
    from concurrent.futures import ProcessPoolExecutor

    from nlosbench.executors import LocalPoolExecutor

    caught = []
    monkeypatch.setattr(threading, "excepthook", lambda args: caught.append(args.exc_value))
    pool = LocalPoolExecutor({"name": "edge1d"}, workers=2)
    pool._pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"))
    futures = [pool._pool.submit(time.sleep, 30) for _ in range(6)]
    assert wait_for(lambda: sum(f.running() for f in futures) >= 2, timeout=60)
    for f in futures:
        f.cancel()
    manager = pool._pool._executor_manager_thread
    pool.abort()
    assert not manager.is_alive() and not caught, caught


# blob2d's x with rendering noise (tests/test_precision_studies.py): θ = 0.7 misses ±10 % at the pilot; a budget
# of 300 000 pixel-samples is below the pilot's charge plus a fresh look's, so only a run that counted cached
# renders as free would take one
BLOB = {"name": "blob2d", "options": {"width": 0.15, "render_noise": 2.0}, "params": ["x"]}
PRECISE = {"type": "trials", "id": "t", "theta": [0.7], "n": 2, "n_eff": 16, "truth_replicates": 1,
           "bounds": ["hcr", "crlb"], "bound_spp": 16, "replicates": 3, "hcr_grid": 3, "hcr_offsets": 1,
           "fd_step": 0.01, "max_halvings": 1, "bootstrap": 10, "precision": 0.07, "precision_budget": 300000,
           "estimators": [{"name": "grid-search", "options": {"spp": 4, "num": 5, "refine": False}}]}
QUOTE = {"type": "bounds", "id": "b", "grid": {"start": 0.2, "stop": 0.8, "num": 3}, "spp": 16, "replicates": 3,
         "fd_step": 0.01, "max_halvings": 1, "zzb": False, "save_images": False, "precision": 0.1,
         "precision_at": [0.7], "precision_budget": 10**9}


def _numbers(run: Path) -> tuple[bytes, list[dict]]:
    """bounds.csv's bytes and summary.csv's rows without its wall times."""
    from nlosbench.io import read_csv

    rows = [{k: v for k, v in r.items() if not k.endswith("_seconds")} for r in read_csv(run / "t" / "summary.csv")]
    return (run / "t" / "bounds.csv").read_bytes(), rows


def test_a_precision_budget_decides_the_same_cold_warm_resumed_and_after_another_study(tmp_path, capsys):
    """A trials study with `precision` and `precision_budget` on blob2d, run cold on an empty shared `cache`, warm
    on the same cache (every render served from it), resumed after its `renders/` store and study folder were
    deleted, and after a bounds study that quotes the same θ* (so every pilot render is already in memory): the
    budget is charged by request, so bounds.csv is the same byte for byte and summary.csv the same but for wall
    times; the record says what each run rendered (the warm run: nothing)."""
    import shutil

    cache = str(tmp_path / "cache")
    runs = {}
    for name, studies in (("cold", [PRECISE]), ("warm", [PRECISE]), ("after", [QUOTE, PRECISE])):
        cfg = config(tmp_path, BLOB, studies, f"{name}.yaml", noise=[{"model": "awgn", "sigma": 0.3}], cache=cache)
        rc, err = cli(capsys, "run", cfg, "--out", tmp_path / name, "--quiet", "--yes")  # the estimate varies with load
        assert rc == 0, err
        runs[name] = tmp_path / name
    resumed = tmp_path / "resumed"
    shutil.copytree(runs["cold"], resumed)
    shutil.rmtree(resumed / "renders")
    shutil.rmtree(resumed / "t")
    with pytest.warns(UserWarning, match="rebuilding the study"):
        rc, err = cli(capsys, "run", tmp_path / "cold.yaml", "--out", resumed, "--resume", "--quiet", "--yes")
    assert rc == 0, err
    runs["resumed"] = resumed
    recs = {n: json.loads((r / "results.json").read_text())["studies"]["t"]["results"]["precision"][0]
            for n, r in runs.items()}
    assert recs["cold"]["rendered_pixel_samples"] > 0 and recs["warm"]["rendered_pixel_samples"] == 0, recs
    assert len({r["pixel_samples"] for r in recs.values()}) == 1, recs
    assert not recs["cold"]["met"] and recs["cold"]["pixel_samples"] <= PRECISE["precision_budget"], recs["cold"]
    reference = _numbers(runs["cold"])
    for name in ("warm", "resumed", "after"):
        assert _numbers(runs[name]) == reference, name


@pytest.mark.parametrize("step", [1e-10, 1e-300, 1e-6])
def test_a_lattice_above_its_ceiling_is_one_line_at_config_time(tmp_path, capsys, step):
    """The surrogate estimator's `step: 1e-10` (6·10⁹ lattice points on blob2d's region: a 22 GiB allocation and exit
    3 before), 1e-300, or 1e-6 (6·10⁵ renders: hours with their store writes): exit 2, one line naming the setting,
    the lattice's size and the ceiling (`estimators.base.MAX_GRID`), and no run folder."""
    from nlosbench.estimators.base import MAX_GRID

    study = {**TRIALS, "estimators": [{"name": "surrogate", "options": {"step": step, "spp": 4}}]}
    rc, err = cli(capsys, "run", config(tmp_path, {"name": "blob2d", "params": ["x"]}, [study]), "--out",
                  tmp_path / "run")
    assert rc == 2 and len(errors(err)) == 1, err
    line = errors(err)[0]
    assert "estimators[0]: surrogate: step" in line and f"above the ceiling of {MAX_GRID}" in line, line
    assert not (tmp_path / "run").exists()


def test_the_estimate_counts_each_renders_store_write_so_many_cheap_renders_need_yes(tmp_path, capsys, monkeypatch):
    """A measured rate has two parts: per pixel-sample and per render (the bank's task and its store's fsynced write,
    timed through a bank with a store, > 0). A plan of 5·10⁴ cheap renders (a grid-search of that many points at
    1 spp on edge1d, a few ms of samples) whose per-render cost is set to 0.1 s in rates.json is estimated above an
    hour: exit 2 naming its renders and their cost, nothing written."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    study = {**TRIALS, "estimators": [{"name": "grid-search", "options": {"num": 50000, "spp": 1, "refine": False}}]}
    cfg = config(tmp_path, EDGE, [{**BOUNDS, "spp": 10 ** 12}])  # measures the rate, refused
    assert cli(capsys, "run", cfg, "--out", tmp_path / "first")[0] == 2
    rates = tmp_path / "xdg" / "nlosbench" / "rates.json"
    ((key, kept),) = json.loads(rates.read_text()).items()
    assert 0 < kept["seconds_per_render"] < 1, kept
    cfg = config(tmp_path, EDGE, [study], "grid.yaml")
    rates.write_text(json.dumps({key: {**kept, "seconds_per_render": 0.1}}))
    rc, err = cli(capsys, "run", cfg, "--out", tmp_path / "run")
    assert rc == 2 and "pass --yes to run it" in errors(err)[0] and "renders at 100 ms each" in errors(err)[0], err
    assert not (tmp_path / "run").exists()


def test_a_render_plan_above_the_ceiling_is_refused_naming_the_study(tmp_path, capsys, monkeypatch):
    """A study that plans more renders than `runner.MAX_PLAN_RENDERS` (here lowered to 20; the bounds study plans 27):
    exit 2 at config time, one line naming the study, its renders and the ceiling; nothing written."""
    from nlosbench.experiment import runner

    monkeypatch.setattr(runner, "MAX_PLAN_RENDERS", 20)
    rc, err = cli(capsys, "run", config(tmp_path, EDGE, [BOUNDS]), "--out", tmp_path / "run")
    assert rc == 2 and len(errors(err)) == 1, err
    assert "00-bounds: plans 27 renders, above the ceiling of 20" in errors(err)[0], err
    assert not (tmp_path / "run").exists()


def test_a_dask_worker_with_a_changed_copy_of_the_code_is_refused_naming_it(tmp_path, capsys, scheduler):
    """A Dask worker whose import path holds a changed copy of nlosbench (one line added to forward/model.py, as
    an out-of-date checkout on a cluster node leaves it): exit 1 with one line naming that worker, that its code
    differs, and how to resume; none of its results is used (no render in the run's store)."""
    import shutil

    copy = tmp_path / "elsewhere"
    shutil.copytree(ROOT / "nlosbench", copy / "nlosbench", ignore=shutil.ignore_patterns("__pycache__"))
    with open(copy / "nlosbench" / "forward" / "model.py", "a") as f:
        f.write("\nCHANGED = True\n")
    address = scheduler.scheduler_address
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--no-nanny",
                               "--nthreads", "1", "--no-dashboard"], env={**os.environ, "PYTHONPATH": str(copy)},
                              cwd=copy, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        scheduler.wait_for_workers(1, timeout=60)
        (name,) = scheduler.scheduler_info["workers"]
        cfg = config(tmp_path, EDGE, [BOUNDS], executor={"type": "dask", "address": address, "worker_timeout": 30})
        run = tmp_path / "run"
        rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    finally:
        worker.kill()
        worker.wait()
    assert rc == 1 and len(errors(err)) == 1, err
    line = errors(err)[0]
    assert f"Dask worker {name} computes with other code" in line and "(differs: code" in line, line
    assert line.endswith(f"resume with: nlosbench run {cfg} --out {run} --resume"), line
    assert not list((run / "renders").rglob("*.npc"))


@pytest.mark.parametrize("damage", ["torn trials.jsonl", "edited bounds.csv"])
def test_a_torn_log_line_or_an_edited_table_value_is_rebuilt_on_resume(two_studies, tmp_path, capsys, damage):
    """A finished run whose trials.jsonl ends in a torn line (half a record, as a copy cut short leaves it; exit 2
    before), or whose bounds.csv had one value edited in place (same rows; not detected before): `--resume` warns
    naming the file and rebuilds that study, and the table is the uninterrupted run's again, byte for byte."""
    import shutil

    cfg, full, files = two_studies
    run = tmp_path / "run"
    shutil.copytree(full, run)
    if damage == "torn trials.jsonl":
        name, table = "01-trials/trials.jsonl", "01-trials/summary.csv"
        log = run / name
        log.write_bytes(log.read_bytes() + log.read_bytes().splitlines(keepends=True)[0][:20])
        why = "ends in a torn record"
    else:
        name = table = "00-bounds/bounds.csv"
        text = (run / name).read_text()
        header, first, rest = text.split("\n", 2)
        cells = first.split(",")
        cells[-1] = "0" if cells[-1] != "0" else "1"
        (run / name).write_text("\n".join([header, ",".join(cells), rest]))
        why = "was changed after it was written"
    with pytest.warns(UserWarning) as caught:
        rc, err = cli(capsys, "run", cfg, "--out", run, "--resume", "--quiet")
    assert rc == 0, err
    rebuilt = [str(w.message) for w in caught if "rebuilding the study" in str(w.message)]
    assert len(rebuilt) == 1 and f"{run / name} {why}" in rebuilt[0], rebuilt
    if table.endswith("bounds.csv"):
        assert (run / table).read_bytes() == files[table]
    else:
        estimates = [[(r["trial"], r["theta_hat"]) for r in RecordLog(d / name).read()] for d in (full, run)]
        assert estimates[0] == estimates[1] and len(estimates[0]) == TRIALS["n"]


def test_the_code_hash_is_the_python_files_and_the_fingerprint_names_scipy(tmp_path, monkeypatch):
    """An editor's swap file, a backup and a data file beside the package's modules (a package laid out in a
    temporary folder) leave `sources.digests` as it was, so a resume is not refused as a code change; a .py file
    added changes it. The fingerprint's versions name scipy (the surrogate's bounded Brent search) and the other
    numeric packages, with their installed versions."""
    from importlib import metadata

    from nlosbench import sources
    from nlosbench.experiment import rundir

    fp = rundir.fingerprint({}, {}, {})
    assert fp["versions"]["scipy"] == metadata.version("scipy")
    assert {"python", "numpy", "torch", "mitsuba", "drjit"} <= set(fp["versions"])
    pkg = tmp_path / "pkg"
    (pkg / "forward").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "forward" / "model.py").write_text("X = 1\n")
    monkeypatch.setattr(sources, "PACKAGE", pkg)
    sources.digests.cache_clear()
    try:
        before = sources.digests()
        for junk in (".model.py.swp", "model.py~", "notes.txt"):
            (pkg / "forward" / junk).write_text("edited")
        sources.digests.cache_clear()
        assert sources.digests() == before == {name: sources.digests()[name] for name in
                                               ("__init__.py", "forward/model.py")}
        (pkg / "forward" / "extra.py").write_text("Y = 2\n")
        sources.digests.cache_clear()
        assert set(sources.digests()) == {"__init__.py", "forward/model.py", "forward/extra.py"}
    finally:
        monkeypatch.undo()
        sources.digests.cache_clear()


def test_poisson_noise_with_analytic_rendering_noise_is_refused_unless_clipped(tmp_path, capsys):
    """blob2d with render_noise 2 (at 16 spp a third of its background pixels render negative) and Poisson noise:
    exit 2 at config time, one line naming scene.options.render_noise_clip, nothing written (exit 3 mid-run
    before: a negative Poisson mean); with render_noise_clip: true the run finishes and its renders are >= 0."""
    import nlosbench as nb

    scene = {"name": "blob2d", "options": {"render_noise": 2.0, "width": 0.15}, "params": ["x"]}
    study = {**BOUNDS, "grid": {"start": 0.2, "stop": 0.8, "num": 3}}
    poisson = [{"model": "poisson", "scale": 100.0}]
    rc, err = cli(capsys, "run", config(tmp_path, scene, [study], noise=poisson), "--out", tmp_path / "run")
    assert rc == 2 and len(errors(err)) == 1 and "scene.options.render_noise_clip: Poisson noise" in err, err
    assert not (tmp_path / "run").exists()
    clipped = {**scene, "options": {**scene["options"], "render_noise_clip": True}}
    rc, err = cli(capsys, "run", config(tmp_path, clipped, [study], "clip.yaml", noise=poisson), "--out",
                  tmp_path / "clip", "--quiet")
    assert rc == 0, err
    model = nb.scenes.get("blob2d", render_noise=2.0, width=0.15, render_noise_clip=True)
    assert min(float(model.render([0.5, 0.5], 16, s).min()) for s in range(4)) == 0.0


def test_a_finished_dask_result_lost_with_its_worker_does_not_wait_for_ever():
    """A future that `wait` returned as finished whose worker then leaves (the scheduler puts the task back to
    waiting, "lose already computed task(s)": seen as a run that hung in the all-workers-lost test above) and no
    worker left: fetching its result gives up after `worker_timeout` with `WorkersLost` instead of blocking."""
    pytest.importorskip("distributed", reason="dask.distributed is not installed (the 'dask' extra)")
    from nlosbench.executors import DaskExecutor, WorkersLost

    class Waiting:  # a future whose task went back to waiting
        def result(self, timeout=None):
            time.sleep(timeout)
            raise TimeoutError

    ex = DaskExecutor({}, address="tcp://127.0.0.1:1", worker_timeout=0.3)
    ex._client = types.SimpleNamespace(nthreads=dict, scheduler=types.SimpleNamespace(address="tcp://127.0.0.1:1"))
    t0 = time.perf_counter()
    with pytest.raises(WorkersLost, match="no Dask worker left at the scheduler tcp://127.0.0.1:1 for 0.3 s"):
        ex._fetch(Waiting(), 0.05)
    assert 0.3 <= time.perf_counter() - t0 < 5


def test_a_lost_dask_scheduler_is_one_line_naming_it_with_the_details_in_dask_log(tmp_path, capsys, scheduler,
                                                                                  monkeypatch):
    """The Dask scheduler closed mid-run (once the first renders are back; each task takes 0.3 s),
    `executor.connect_timeout: 2` (how long the client tries to reconnect): exit 1 with one line on stderr naming
    the scheduler's address, RUN/dask.log and how to resume (36 lines with two distributed.client tracebacks
    before); Dask's messages, the client's included, are in RUN/dask.log."""
    import threading

    from nlosbench import executors

    monkeypatch.setattr(executors, "_call", _slow_call)
    scheduler.scale(1)
    scheduler.wait_for_workers(1, timeout=30)
    address = scheduler.scheduler_address
    cfg = config(tmp_path, EDGE, [BOUNDS], executor={"type": "dask", "address": address, "connect_timeout": 2})
    run = tmp_path / "run"

    def lose_scheduler() -> None:
        wait_for(lambda: any((run / "renders").rglob("*.npc")), timeout=60, every=0.02)
        scheduler.sync(scheduler.scheduler.close)

    threading.Thread(target=lose_scheduler, daemon=True).start()
    rc, err = cli(capsys, "run", cfg, "--out", run, "--quiet")
    lines = [line for line in err.splitlines() if line.strip()]
    # which the client meets first (one or several cancelled futures, or the closed comm) depends on timing
    assert rc == 1 and len(lines) == 1 and re.fullmatch(
        re.escape(f"nlosbench: error: lost the Dask scheduler at {address} mid-run (") + "(Futures?CancelledError|"
        "CommClosedError)" + re.escape(f"); finished work is kept: restart the scheduler and its workers; Dask's "
                                       f"messages are in {run / 'dask.log'}; resume with: nlosbench run {cfg} --out "
                                       f"{run} --resume"), lines[0]), err
    log = (run / "dask.log").read_text()
    assert "distributed.client" in log and "distributed.scheduler" in log
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # not 30 s trying the closed scheduler
        scheduler.close()
