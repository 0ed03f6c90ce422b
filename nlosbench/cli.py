"""`nlosbench` command line: run experiments, render scenes, list plug-ins, re-make reports, benchmark.

Exit codes: 0 done; 2 bad input, something the user can fix (config, overrides, scene spec or scene file, a
run folder held by another run or holding a different run or a damaged record, a run estimated above an
hour without --yes: nothing was written); 1 environment (disk full, read-only or missing path,
permissions, an unreachable Dask scheduler or one without workers, a full /dev/shm, a worker process that
died); 3 internal error (an exception the input did not cause, e.g. a ValueError raised by a study after the
config was checked: a bug in nlosbench; the full traceback goes to RUN/error.log, or to a temporary file when
no run folder exists, and the line names it); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 hung up
(SIGHUP): 128 + the signal's number, as a shell reports it; a second signal stops at once. Every error is one
line on stderr; after an environment error, an internal error or an interrupt during a run it says how to
resume."""
from __future__ import annotations

import argparse
import errno
import shlex
import signal
import sys
import threading
import warnings
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn

from .interrupts import STOPPING, Interrupted, deferred, interrupt_in, signum_of
from .records import RecordError
from .schema import ConfigError
from .variant import VariantError

OK, ENVIRONMENT, BAD_INPUT, INTERNAL, INTERRUPTED = 0, 1, 2, 3, 130  # a stop signal: 128 + its number

EPILOG = """examples:
  nlosbench run configs/quick.yaml                      # the demo: bounds, Fisher maps, MLE trials
  nlosbench run configs/quick.yaml --set seed=3 --set studies.0.spp=256 --out runs/try
  nlosbench run configs/quick.yaml --out runs/try --resume   # continue a killed run
  nlosbench run configs/paper_pi_trials.yaml --smoke --out runs/check   # seconds-long dry run
  nlosbench render cornell_ball --theta 0.1 0.3 0.8 --spp 256 --out runs/render
  nlosbench check-scene my_scene.yaml --out runs/check   # does each θ binding move what it claims?
  nlosbench init-scene room.xml                          # list its keys, write room.yaml (a scene spec)
  nlosbench bound blob2d --param x --at 0.5 --sigma 0.05   # one HCR interval and CRLB, one line
  nlosbench bound blob2d --param x --at 0.5 --sigma 0.05 --precision 0.1   # to ±10 %
  nlosbench list                                         # every kind: scenes, estimators, noise, studies
  nlosbench list estimators                              # one kind
  nlosbench list keys trials                             # a study's config keys with their help
  nlosbench report runs/try                              # re-make plots and report.md from saved data
  nlosbench compare runs/sigma05 runs/sigma10            # two runs of one question side by side
  nlosbench bench --reduced

exit codes: 0 done; 2 bad input (config, spec, overrides, run folder: nothing written); 1 environment (disk,
permissions, network, shared memory, a worker that died); 3 internal error (a bug: traceback in RUN/error.log
or a temporary file, named on the error line); 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (a second signal stops at
once). Errors are one line `nlosbench: error: ...`."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line `nlosbench: error: ...` (exit 2), like every other."""

    def error(self, message: str) -> NoReturn:
        sub = self.prog.removeprefix("nlosbench").strip()
        self.exit(BAD_INPUT, f"nlosbench: error: {' '.join(message.split())} (nlosbench {sub + ' ' if sub else ''}"
                             "--help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The `nlosbench` argument parser (also read by the documentation's CLI reference)."""
    from . import __version__

    p = _Parser(prog="nlosbench", description="Renderer-backed estimation bounds (HCR, CRLB, "
                "Barankin) and ML estimators for plenoptic / NLOS imaging.",
                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    r = sub.add_parser("run", help="run the studies of a YAML config")
    r.add_argument("config", help="experiment config (YAML)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set seed=3 --set studies.0.spp=64 (repeatable)")
    r.add_argument("--out", help="run directory (default: OUTPUT/NAME from the config)")
    r.add_argument("--resume", action="store_true", help="continue a run in --out, keeping finished work")
    r.add_argument("--resume-anyway", action="store_true", help="--resume even when nlosbench's code changed since "
                   "the run started (old and new work then mix; recorded in results.json and report.md)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.add_argument("--smoke", action="store_true", help="a seconds-long run of the same config: tiny image, grids, "
                   "spp and trials (checks a paper-scale config before it runs for days)")
    r.add_argument("--yes", action="store_true", help="run even when the estimated time is above an hour")
    d = sub.add_parser("render", help="render a scene at θ and write EXR + PNG")
    d.add_argument("scene", help="scene name (see `nlosbench list scenes`) or a scene spec .yaml")
    d.add_argument("--theta", type=float, nargs="+", help="θ values in parameter order (default: defaults)")
    d.add_argument("--spp", type=int, default=256, help="samples per pixel (default: 256)")
    d.add_argument("--seed", type=int, default=0, help="render seed: the same (θ, spp, seed) gives the same image "
                   "(default: 0)")
    d.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default, e.g. --define res=64 (repeatable)")
    d.add_argument("--out", default="runs/render", help="output folder")
    c = sub.add_parser("check-scene", help="render each parameter at Θ's ends and mid-point: does each binding "
                       "move what it claims? (image change per step, a PNG grid, warnings)")
    c.add_argument("scene", help="scene spec .yaml (or a registered scene name)")
    c.add_argument("--spp", type=int, default=64, help="samples per pixel of every render (one seed for all)")
    c.add_argument("--seed", type=int, default=0, help="render seed shared by every render (default: 0)")
    c.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default, e.g. --define resx=64 (repeatable)")
    c.add_argument("--out", default="runs/check-scene", help="output folder (check.png, check.json)")
    i = sub.add_parser("init-scene", help="list a Mitsuba XML file's mi.traverse keys and write a scene spec "
                       "skeleton for it (check it with check-scene)")
    i.add_argument("xml", help="a Mitsuba 3 scene file (.xml)")
    i.add_argument("--out", help="the spec to write (default: the XML's name with .yaml, beside it)")
    i.add_argument("--object", action="append", default=[], metavar="ID", help="a shape id to bind (translate x, y, "
                   "z; radius; its own colour); repeatable (default: the smallest shape that does not emit light)")
    i.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default while listing, e.g. --define res=16 (repeatable)")
    i.add_argument("--force", action="store_true", help="overwrite an existing spec")
    _bound_parser(sub)
    ls = sub.add_parser("list", help="list scenes, estimators, noise models and studies (or one kind of them), "
                        "or the config keys of a study")
    ls.add_argument("what", nargs="?", choices=(*LIST_KINDS, "keys"), help="one kind only (default: every kind, "
                    "one section each); keys: the config keys of STUDY, or of the top level without one")
    ls.add_argument("study", nargs="?", metavar="STUDY", help="with `keys`: a study type (see `nlosbench list "
                    "studies`)")
    rep = sub.add_parser("report", help="re-make plots and report.md of a finished run from its saved data")
    rep.add_argument("run_dir", metavar="RUN_DIR", help="a run directory written by `nlosbench run` (holds "
                     "results.json)")
    cmp = sub.add_parser("compare", help="two runs of the same question side by side: config differences, then "
                         "every bound and MSE with its limits in both, their ratio and whether the limits overlap")
    cmp.add_argument("run_a", metavar="RUN_A", help="a run directory written by `nlosbench run`")
    cmp.add_argument("run_b", metavar="RUN_B", help="another run of the same config, changed (e.g. another σ)")
    cmp.add_argument("--table", action="append", default=[], metavar="NAME", help="a table to compare, e.g. "
                     "00-bounds/bounds (repeatable; default: every table both runs have)")
    b = sub.add_parser("bench", help="run the benchmarks side by side and print ratios")
    b.add_argument("--reduced", action="store_true", help="tiny sizes (seconds), as in the test suite")
    b.add_argument("names", nargs="*", help="benchmark modules to run (default: all)")
    return p


def _bound_parser(sub) -> None:
    from .api import FD_STEP_FRACTION, MAX_HALVINGS, REPLICATES, SPP, STEP_TOL, TEST_GRID
    from .bounds.precision import CEILING

    b = sub.add_parser("bound", help="one parameter's HCR interval and CRLB at one θ*, in one line (no config file)",
                       description="The HCR interval and the CRLB (parameter units²) of one parameter at one θ*, the "
                       "others held at their defaults (or --fix), from replicate render sets through the bound "
                       "service, as a bounds study computes them. Exactly one noise: --sigma, --scale or --noise. "
                       "Where the FD step did not settle, an end is open or a precision target was not met, the "
                       "line says so and what would settle it.")
    b.add_argument("scene", help="scene name (see `nlosbench list scenes`) or a scene spec .yaml")
    b.add_argument("--param", help="the parameter bounded (default: the scene's only one)")
    b.add_argument("--at", type=float, help="θ*, in the parameter's units (default: its default)")
    b.add_argument("--sigma", type=float, help="AWGN standard deviation, radiance units")
    b.add_argument("--scale", type=float, help="Poisson noise: expected photons per unit radiance")
    b.add_argument("--noise", metavar="NAME", help="a registered noise model (see `nlosbench list noise`), with "
                   "its parameters as --noise-option")
    b.add_argument("--noise-option", action="append", default=[], metavar="KEY=VALUE",
                   help="a parameter of --noise, e.g. --noise-option scale=300 (repeatable)")
    b.add_argument("--spp", type=int, default=SPP, help=f"samples per pixel of every render (default: {SPP})")
    b.add_argument("--replicates", type=int, default=REPLICATES, help="independent replicate sets of every render "
                   f"(default: {REPLICATES}, the fewest that give confidence limits)")
    b.add_argument("--fd-step", type=float, help="first FD step ξ, parameter units (default: "
                   f"{FD_STEP_FRACTION * 100:.0f} %% of Θ's width)")
    b.add_argument("--max-halvings", type=int, default=MAX_HALVINGS, help="the most halvings of ξ while F has not "
                   f"settled within {STEP_TOL * 100:.0f} %% (default: {MAX_HALVINGS})")
    b.add_argument("--test-grid", type=int, default=TEST_GRID, help=f"HCR test points over Θ (default: {TEST_GRID}), "
                   "besides the offsets ±ξ·2^k")
    b.add_argument("--precision", type=float, help="target relative half-width of both intervals, e.g. 0.1 for ±10 %%: "
                   "replicate sets are added until it is met (default: one pilot of --replicates sets)")
    b.add_argument("--budget", type=float, help="with --precision: the most pixel-samples to spend, the pilot included "
                   f"(default: {CEILING} × what the pilot costs)")
    b.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="hold another parameter at VALUE (default: its default; repeatable)")
    b.add_argument("--seed", type=int, default=0, help="the seed every render seed derives from (default: 0)")
    b.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default, e.g. --define res=16 (repeatable)")


def _bound(args) -> None:
    import yaml

    from . import api, noise

    given = [k for k in ("sigma", "scale", "noise") if getattr(args, k) is not None]
    if len(given) != 1:
        raise ConfigError("noise", "give exactly one of --sigma (AWGN), --scale (Poisson) or --noise NAME, got "
                          + (", ".join(f"--{k}" for k in given) or "none"))
    if args.noise_option and args.noise is None:
        raise ConfigError("--noise-option", "goes with --noise NAME")
    name, kw = {"sigma": ("awgn", {"sigma": args.sigma}), "scale": ("poisson", {"scale": args.scale}),
                "noise": (args.noise, {k: yaml.safe_load(v) for k, v in _defines(args.noise_option).items()})}[given[0]]
    try:
        model = noise.get(name, **kw)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"--{given[0]}", " ".join(str(e).split())) from None
    fixed = {}
    for k, v in _defines(args.fix).items():
        try:
            fixed[k] = float(v)
        except ValueError:
            raise ConfigError("--fix", f"{k}: expected a number, got {v!r}") from None
    defines = _defines(args.define)
    budget = None if args.budget is None else int(args.budget)
    print(api.bound(args.scene, args.param, args.at, model, spp=args.spp,
                    replicates=args.replicates, fd_step=args.fd_step, max_halvings=args.max_halvings,
                    test_grid=args.test_grid, precision=args.precision, budget=budget, seed=args.seed, fixed=fixed,
                    options={"defines": defines} if defines else {}).line())


def _render(args) -> None:
    import numpy as np

    from . import io, scenes

    _check_spp_seed(args.spp, args.seed)
    defines = _defines(args.define)
    model = scenes.get(args.scene, **({"defines": defines} if defines else {}))
    try:
        theta = model.params.validate(model.params.default if args.theta is None else np.array(args.theta))
    except ValueError as e:
        raise ConfigError("--theta", str(e)) from None
    img = model.render(theta, args.spp, args.seed)
    out = Path(args.out)
    stem = f"{model.name}_spp{args.spp}_seed{args.seed}"
    io.write_exr(out / f"{stem}.exr", img)
    io.write_png(
        out / f"{stem}.png",
        img,
        title=f"{model.name} at {dict(zip(model.params.names, np.round(theta, 4).tolist(), strict=True))}",
    )
    print(
        f"{model.name}: θ = {dict(zip(model.params.names, theta.tolist(), strict=True))}, {args.spp} spp, "
        f"{model.stats.seconds:.3f} s → {out / stem}.exr, .png"
    )


def _defines(items: list[str]) -> dict[str, str]:
    """--define KEY=VALUE items as a mapping (ConfigError for an item without '=' or with an empty key)."""
    out = {}
    for kv in items:
        key, eq, value = kv.partition("=")
        if not eq or not key.strip():
            raise ConfigError("--define", f"expected KEY=VALUE (a scene XML default, e.g. res=64), got {kv!r}")
        out[key.strip()] = value
    return out


def _check_spp_seed(spp: int, seed: int) -> None:
    """ConfigError naming --spp / --seed unless spp >= 1 and seed >= 0 (a 32-bit render seed)."""
    if spp < 1:
        raise ConfigError("--spp", f"expected a positive integer, got {spp}")
    if not 0 <= seed < 2**32:
        raise ConfigError("--seed", f"expected an integer in [0, 2^32), got {seed}")


LIST_KINDS = ("scenes", "estimators", "noise", "studies")


def _list(what: str | None, study: str | None) -> None:
    if study is not None and what != "keys":
        raise ConfigError("list", f"a study name goes with `list keys` only, got `list {what} {study}`")
    if what == "keys":
        print(_keys(study))
    elif what is None:  # every kind, one section each under a heading
        print("\n\n".join(f"{kind}:\n" + "\n".join(f"  {item}" for item in _items(kind)) for kind in LIST_KINDS))
    else:
        print("\n".join(_items(what)))


def _items(what: str) -> list[str]:
    if what == "scenes":
        from . import scenes

        items = [f"{name}: {text}" for name, text in scenes.describe().items()]
    elif what == "noise":
        from . import noise

        def line(name: str) -> str:
            try:
                return _first_line(noise.model_class(name).__doc__)
            except (ImportError, ValueError) as e:  # a plug-in that does not load is listed with the reason
                return f"(fails to load: {e})"

        items = [f"{name}: {line(name)}" for name in noise.available()]
    elif what == "studies":
        from . import studies

        items = [f"{name}: {_first_line(studies.get(name).__doc__).removeprefix(f'Study `{name}`: ')}"
                 for name in studies.available()]
    else:
        from . import estimators

        items = [f"{name}: {text}" for name, text in estimators.describe().items()]
    return items


def _first_line(doc: str | None) -> str:
    """A docstring's first sentence, on one line (what `list` prints beside a name)."""
    text = " ".join((doc or "").strip().split("\n\n")[0].split())
    return text.split(". ")[0].rstrip(".") if text else "(no description)"


def _keys(study: str | None) -> str:
    """The config keys of a study block (or of the top level), one per line: path, kind, default, help."""
    from .experiment.config import TOP, study_schema
    from .schema import describe

    if study is None:
        rows, title = describe(TOP), "top-level config keys (each study's: nlosbench list keys STUDY)"
    else:
        from . import studies

        try:
            mod = studies.get(study)
        except KeyError as e:
            raise ConfigError("STUDY", e.args[0]) from None
        rows, title = describe(study_schema(mod)), f"keys of a `type: {study}` study block"
    width = max(len(r.path) for r in rows)
    lines = [f"{title}:"]
    for r in rows:
        default = "; required" if r.default == "required" else f"; default {r.default}" if r.default else ""
        lines.append(f"  {r.path:<{width}}  {r.kind}{default}" + (f" — {r.help}" if r.help else ""))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run one `nlosbench` command, as the console script does; `nb.run` is the call for a run from Python.

    Parameters
    ----------
    argv : list of str, optional
        The command and its options, without the program name (``["list", "noise"]``). Default: ``sys.argv``;
        then the process's stop signals stay handled to its end.

    Returns
    -------
    int
        The exit status: 0 when the command did what it was asked; after a one-line message, 1 for the
        environment (a library, a render, a disk), 2 for bad input, 3 for an internal error, 128 + N for stop
        signal N.

    Examples
    --------
    >>> from nlosbench import cli
    >>> cli.main(["list", "noise"])  # doctest: +ELLIPSIS
    awgn: Additive white Gaussian noise ...
    poisson: Photon counts ...
    0
    """
    resume = ""  # how to resume, once a run has started writing its folder
    prepared = None  # the checked run (its folder gets error.log after an internal error)
    try:
        with _one_line_warnings(), _interrupts(keep=argv is None):  # first: before torch or Mitsuba is imported
            with deferred():  # the parser imports torch (pybind11: an exception raised inside aborts the process)
                parser = build_parser()
            args = parser.parse_args(argv)
            if args.command == "run":
                from .experiment.runner import prepare

                prepared = prepare(args.config, args.overrides, args.out, args.resume or args.resume_anyway, args.quiet,
                                   args.smoke, args.yes, args.resume_anyway)
                resume = _resume_command(args, prepared.dir)
                run_dir = prepared.execute()
                print(f"done: {run_dir}/report.md")
            elif args.command == "render":
                _render(args)
            elif args.command == "init-scene":
                from .scenes.init import init_scene

                keys, spec = init_scene(args.xml, args.out, args.object, _defines(args.define), args.force)
                from .scenes import read_spec

                names = ", ".join(q["name"] for q in read_spec(spec)["params"])
                print(f"{keys.listing()}\nwrote {spec}: θ = ({names}); set Θ's ends to your question, then check "
                      f"it: nlosbench check-scene {spec}")
            elif args.command == "bound":
                _bound(args)
            elif args.command == "check-scene":
                from .scenes.check import check_scene, format_report

                _check_spp_seed(args.spp, args.seed)
                print(format_report(check_scene(args.scene, args.spp, args.seed, _defines(args.define), args.out)))
            elif args.command == "list":
                _list(args.what, args.study)
            elif args.command == "report":
                from .experiment.report import make_report

                if not (Path(args.run_dir) / "results.json").is_file():
                    raise ConfigError("run_dir", f"{args.run_dir} holds no run (no results.json)")
                print(make_report(args.run_dir))
            elif args.command == "compare":
                from .api import compare

                print(compare(args.run_a, args.run_b, args.table))
            elif args.command == "bench":
                from .benchmarks import run_all

                run_all(args.names, reduced=args.reduced)
    except KeyboardInterrupt as e:
        return _interrupted(e, resume)
    except (ConfigError, RecordError) as e:  # input the user can fix (a damaged record log included)
        return _fail(BAD_INPUT, str(e))
    except FileNotFoundError as e:
        if e.errno is None:  # raised by nlosbench for a path given to it (a scene or spec that does not exist)
            return _fail(BAD_INPUT, str(e))
        return _fail(ENVIRONMENT, _describe(e), resume)
    except BrokenPipeError:  # the reader stopped reading (`nlosbench list | head`): not an error of ours
        _quiet_stdout()
        return OK
    except OSError as e:  # disk full, read-only or missing path, permissions, an unreachable scheduler
        return _fail(ENVIRONMENT, _describe(e), resume)
    except BrokenProcessPool as e:
        return _fail(ENVIRONMENT, f"a worker process died ({e}; out of memory?)", resume)
    except VariantError as e:
        return _fail(ENVIRONMENT, str(e))
    except ImportError as e:  # an optional dependency that is not installed (dask for executor: dask)
        return _fail(ENVIRONMENT, str(e), resume)
    except Exception as e:  # noqa: BLE001 - not caused by the input: a bug, reported with its traceback kept
        stop = interrupt_in(e)  # a Ctrl-C that Dr.Jit re-raised as its own error (a frozen function, a symbolic loop)
        if stop is not None:
            return _interrupted(stop, resume)
        return _fail(INTERNAL, _internal(e, prepared.dir if prepared is not None else None), resume)
    return OK


def _interrupted(e: KeyboardInterrupt, resume) -> int:
    """Exit 128 + the signal, with the line "interrupted" (naming a signal other than SIGINT) and how to resume."""
    signum = signum_of(e)
    name = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
    return _fail(128 + signum, f"interrupted{name}", resume)


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush into a closed pipe raises nothing."""
    import os

    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor (stdout replaced, e.g. under a test's capture)
        pass


def _internal(e: BaseException, run_dir: Path | None) -> str:
    """The line for an internal error: what was raised, and where its full traceback was written (RUN/error.log
    when the run folder exists, else a temporary file)."""
    import tempfile
    import traceback

    text = "".join(traceback.format_exception(type(e), e, e.__traceback__))
    try:
        if run_dir is not None and run_dir.is_dir():
            log = run_dir / "error.log"
            log.write_text(text)
        else:
            fd, name = tempfile.mkstemp(prefix="nlosbench-error-", suffix=".log")
            with open(fd, "w") as f:
                f.write(text)
            log = Path(name)
        where = f"full traceback in {log}"
    except OSError as w:
        where = f"the traceback could not be written ({w})"
    return (f"internal error (a bug in nlosbench, not in your input: please report it): {type(e).__name__}: {e}; "
            f"{where}")


def _fail(code: int, message: str, resume: str = "") -> int:
    """Print one line `nlosbench: error: ...` (with how to resume, where a run was under way); return `code`."""
    line = " ".join(str(message).split())  # one line, whatever the message held
    if resume:
        line += f"; resume with: {resume}"
    print(f"nlosbench: error: {line}", file=sys.stderr)
    return code


_HINTS = {errno.ENOSPC: "free space on that disk or use another --out",
          errno.EDQUOT: "free space (disk quota) or use another --out",
          errno.EROFS: "that file system is read-only: use another --out",
          errno.EACCES: "no permission: check the folder's owner and mode, or use another --out",
          errno.EPERM: "no permission: check the folder's owner and mode, or use another --out",
          errno.ENOENT: "a folder on that path is missing (removed while running?)",
          errno.ENOTDIR: "a part of that path is a file, not a folder"}


def _describe(e: OSError) -> str:
    """An OSError as one line naming the path (or address) and what to do."""
    if e.errno is None:  # e.g. ConnectionError raised by nlosbench with a message naming the address
        return str(e)
    name = errno.errorcode.get(e.errno, str(e.errno))
    where = f": {e.filename}" + (f" → {e.filename2}" if e.filename2 else "") if e.filename else ""
    hint = _HINTS.get(e.errno)
    return f"{e.strerror or e} ({name}){where}" + (f" — {hint}" if hint else "")


def _resume_command(args, run_dir: Path) -> str:
    """The command that resumes this run: same config, overrides and --smoke, its folder, --resume."""
    again = "--resume-anyway" if args.resume_anyway else "--resume"
    cmd = ["nlosbench", "run", args.config, "--out", str(run_dir), again]
    for item in args.overrides:
        cmd += ["--set", item]
    return shlex.join(cmd + (["--smoke"] if args.smoke else []) + (["--yes"] if args.yes else []))


@contextmanager
def _interrupts(keep: bool = False):
    """The first stop signal — Ctrl-C (SIGINT), SIGTERM or SIGHUP — raises `Interrupted` (the run stops its
    workers and says how to resume; exit 128 + the signal's number); it also sets the default action of all
    three, which stays for the rest of the process (the cleanup after this block included), so a second one
    ends the process at once. Without a signal the previous handlers return, or with `keep` (a process that
    only exits after this block) the signals are ignored from then on: the work is done, exit 0 stands."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = False

    def first(signum, frame):
        nonlocal fired
        fired = True
        for s in STOPPING:
            signal.signal(s, signal.SIG_DFL)
        again = "Ctrl-C again" if signum == signal.SIGINT else f"{signal.Signals(signum).name}; a second signal"
        print(f"nlosbench: stopping ({again} to stop at once)", file=sys.stderr, flush=True)
        raise Interrupted(signum)

    previous = {s: signal.signal(s, first) for s in STOPPING}
    try:
        yield
    finally:
        if not fired:  # restoring Python's handler here would turn the second Ctrl-C into a slow exit
            for s, handler in previous.items():
                signal.signal(s, signal.SIG_IGN if keep else handler)


@contextmanager
def _one_line_warnings():
    """nlosbench's own warnings (torn records cut, cache failures, ...) as `nlosbench: warning: ...` lines."""
    fmt = warnings.formatwarning

    def one_line(message, category, filename, lineno, line=None):
        if "/nlosbench/" in str(filename).replace("\\", "/"):
            return f"nlosbench: warning: {message}\n"
        return fmt(message, category, filename, lineno, line)

    warnings.formatwarning = one_line
    try:
        yield
    finally:
        warnings.formatwarning = fmt


if __name__ == "__main__":
    sys.exit(main())
