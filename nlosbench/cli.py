"""`nlosbench` command line: run experiments, render scenes, list plug-ins, re-make reports, benchmark."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

BAD_INPUT = 2

EPILOG = """examples:
  nlosbench run configs/quick.yaml                      # the demo: bounds, Fisher maps, MLE trials
  nlosbench run configs/quick.yaml --set seed=3 --set studies.0.spp=256 --out runs/try
  nlosbench run configs/quick.yaml --out runs/try --resume   # continue a killed run
  nlosbench run configs/paper_pi_trials.yaml --smoke --out runs/check   # seconds-long dry run
  nlosbench render cornell_ball --theta 0.1 0.3 0.8 --spp 256 --out runs/render
  nlosbench check-scene my_scene.yaml --out runs/check   # does each θ binding move what it claims?
  nlosbench list                                         # every kind: scenes, estimators, noise, studies
  nlosbench list estimators                              # one kind
  nlosbench report runs/try                              # re-make plots and report.md from saved data
  nlosbench bench --reduced"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nlosbench", description="Renderer-backed estimation bounds (HCR, CRLB, "
                                "Barankin) and ML estimators for plenoptic / NLOS imaging.",
                                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    r = sub.add_parser("run", help="run the studies of a YAML config")
    r.add_argument("config", help="experiment config (YAML)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set seed=3 --set studies.0.spp=64 (repeatable)")
    r.add_argument("--out", help="run directory (default: OUTPUT/NAME from the config)")
    r.add_argument("--resume", action="store_true", help="continue a run in --out, keeping finished work")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.add_argument("--smoke", action="store_true", help="a seconds-long run of the same config: tiny image, grids, "
                   "spp and trials (checks a paper-scale config before it runs for days)")
    d = sub.add_parser("render", help="render a scene at θ and write EXR + PNG")
    d.add_argument("scene", help="scene name (see `nlosbench list scenes`) or a scene spec .yaml")
    d.add_argument("--theta", type=float, nargs="+", help="θ values in parameter order (default: defaults)")
    d.add_argument("--spp", type=int, default=256)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default, e.g. --define res=64 (repeatable)")
    d.add_argument("--out", default="runs/render", help="output folder")
    c = sub.add_parser("check-scene", help="render each parameter at Θ's ends and mid-point: does each binding "
                       "move what it claims? (image change per step, a PNG grid, warnings)")
    c.add_argument("scene", help="scene spec .yaml (or a registered scene name)")
    c.add_argument("--spp", type=int, default=64, help="samples per pixel of every render (one seed for all)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--define", action="append", default=[], metavar="KEY=VALUE",
                   help="scene XML default, e.g. --define resx=64 (repeatable)")
    c.add_argument("--out", default="runs/check-scene", help="output folder (check.png, check.json)")
    ls = sub.add_parser("list", help="list scenes, estimators, noise models and studies (or one kind of them)")
    ls.add_argument("what", nargs="?", choices=LIST_KINDS, help="one kind only (default: every kind, one "
                    "section each)")
    rep = sub.add_parser("report", help="re-make plots and report.md of a finished run from its saved data")
    rep.add_argument("run_dir")
    b = sub.add_parser("bench", help="run the benchmarks side by side and print ratios")
    b.add_argument("--reduced", action="store_true", help="tiny sizes (seconds), as in the test suite")
    b.add_argument("names", nargs="*", help="benchmark modules to run (default: all)")
    return p


def _render(args) -> None:
    import numpy as np

    from . import io, scenes

    defines = dict(kv.split("=", 1) for kv in args.define)
    model = scenes.get(args.scene, **({"defines": defines} if defines else {}))
    theta = model.params.default if args.theta is None else np.array(args.theta)
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


LIST_KINDS = ("scenes", "estimators", "noise", "studies")


def _list(what: str | None) -> None:
    if what is None:  # every kind, one section each under a heading
        print("\n\n".join(f"{kind}:\n" + "\n".join(f"  {item}" for item in _items(kind)) for kind in LIST_KINDS))
    else:
        print("\n".join(_items(what)))


def _items(what: str) -> list[str]:
    if what == "scenes":
        from . import scenes

        items = scenes.available()
    elif what == "noise":
        from . import noise

        items = noise.available()
    elif what == "studies":
        from . import studies

        items = studies.available()
    else:
        from . import estimators

        items = [f"{name}: {text}" for name, text in estimators.describe().items()]
    return items


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from .schema import ConfigError

    try:
        if args.command == "run":
            from .experiment.runner import run

            run_dir = run(args.config, args.overrides, args.out, args.resume, args.quiet, args.smoke)
            print(f"done: {run_dir}/report.md")
        elif args.command == "render":
            _render(args)
        elif args.command == "check-scene":
            from .scenes.check import check_scene, format_report

            print(format_report(check_scene(args.scene, args.spp, args.seed,
                                            dict(kv.split("=", 1) for kv in args.define), args.out)))
        elif args.command == "list":
            _list(args.what)
        elif args.command == "report":
            from .experiment.report import make_report

            print(make_report(args.run_dir))
        elif args.command == "bench":
            from .benchmarks import run_all

            run_all(args.names, reduced=args.reduced)
    except (ConfigError, KeyError, ValueError, FileNotFoundError, FileExistsError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        print(
            f"nlosbench: error: {msg}".splitlines()[0] if not isinstance(e, ConfigError) else f"nlosbench: error: {e}",
            file=sys.stderr,
        )
        return BAD_INPUT
    return 0


if __name__ == "__main__":
    sys.exit(main())
