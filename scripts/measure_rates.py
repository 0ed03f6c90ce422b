"""Measure this machine's render rates for every shipped config into results/rates.json, from which the
performance page's cost table predicts each config's time on this machine.

    python scripts/measure_rates.py              # every configs/*.yaml
    python scripts/measure_rates.py quick.yaml   # some, kept beside the others already in the file

Per config (one measurement per distinct scene model: configs that load the same scene with the same options
share it): seconds per pixel-sample and seconds per render beside its samples, by the functions `nlosbench run`
uses for the estimate it prints before a run (`nlosbench.studies.estimate.measure` and `measure_overhead`),
each the least of `--repeats` measurements (other work on the machine only slows a measurement down). The file
records the machine (as results/*/machine.json does), its load average before the measurements, the date and
the command. Run it on an otherwise idle machine, the one the committed results/ were made on.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RATES = ROOT / "results" / "rates.json"


def measure(paths: list[Path], repeats: int) -> dict:
    """{config stem: {scene, seconds_per_sample, seconds_per_render}} for the configs at `paths`."""
    from nlosbench.experiment.runner import forecast
    from nlosbench.studies import estimate

    out, seen = {}, {}
    for path in paths:
        ctx, _ = forecast(path)
        key = json.dumps(ctx.model.content_key(), sort_keys=True, default=repr)
        if key not in seen:
            sample = min(estimate.measure(ctx.model) for _ in range(repeats))
            render = min(estimate.measure_overhead(ctx.model, sample) for _ in range(repeats))
            seen[key] = {"scene": ctx.model.name, "seconds_per_sample": sample, "seconds_per_render": render}
        out[path.stem] = seen[key]
        print(f"{path.name}: {seen[key]['seconds_per_sample'] * 1e9:.4g} ns per pixel-sample, "
              f"{seen[key]['seconds_per_render'] * 1e3:.3g} ms per render", flush=True)
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("configs", nargs="*", help="config file names under configs/ (default: all)")
    p.add_argument("--repeats", type=int, default=3, help="measurements per rate, the least kept (default: 3)")
    a = p.parse_args(argv)
    sys.path[:0] = [str(ROOT)]
    from nlosbench.experiment.machine import host

    paths = [ROOT / "configs" / c for c in a.configs] or sorted((ROOT / "configs").glob("*.yaml"))
    load = os.getloadavg()[0]
    rates = measure(paths, a.repeats)
    kept = json.loads(RATES.read_text())["configs"] if a.configs and RATES.is_file() else {}
    record = {"machine": host() | {"load_average": round(load, 2)}, "date": datetime.date.today().isoformat(),
              "command": "python scripts/measure_rates.py" + "".join(f" {c}" for c in a.configs),
              "configs": dict(sorted((kept | rates).items()))}
    RATES.write_text(json.dumps(record, indent=2) + "\n")
    print(RATES)


if __name__ == "__main__":
    main()
