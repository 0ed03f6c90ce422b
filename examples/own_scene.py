"""Bring your own scene: from a plain Mitsuba XML file to bounds, a Fisher map and estimators against them.

    python examples/own_scene.py OUT        # about a minute on 2 busy CPU cores; everything goes under OUT

The scene, `examples/own_scene/room.xml`, is an ordinary Mitsuba 3 file (a room, a ceiling light, a camera
and a crate on the floor) with no nlosbench markup. The question: how well can the crate's position along
the room (x, in metres) be estimated from one noisy 32 × 24 image, and how close do two estimators get?

Steps (each is a function below; examples/README.md tells the same story in prose):
  1. find the names nlosbench needs: list the scene's `mi.traverse` keys (shape ids, colour keys);
  2. write the scene spec, `room.yaml`, next to a copy of the XML: one `params:` entry per θ component;
  3. check it: `nlosbench render` (one image) and `nlosbench check-scene` (does each binding move what it
     claims? image change per step, a PNG grid, warnings);
  4. write an experiment config and dry-run it with `nlosbench run CONFIG --smoke` (seconds);
  5. run it: the HCR / CRLB / Ziv–Zakai curve over a uniform grid of θ (`bounds`), a per-pixel Fisher map
     (`fisher-maps`), grid-search and Gauss–Newton at two θ* against the HCR interval and CRLB (`trials`,
     local; their bounds at θ* to a precision asked for, ±25 % within a budget) and grid-search over the prior
     against the ZZB (`trials`, bayesian);
  6. read the numbers back from the run directory and print them.

Scaled down to seconds (say so when you quote the numbers): 32 × 24 px, path depth 3, 32 spp per bound
render (3 replicate sets), a 41-point grid, 5 trials per θ* and estimator, 10 Bayesian trials, renders in
this process (executor `serial`: spawning worker processes costs more than these tiny renders). For a real
study raise spp, the grid, the trials and use `executor: {type: local, workers: N}`.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
XML = HERE / "own_scene" / "room.xml"

# -- step 2: the scene spec (written as text so its comments reach the file) ----------------------------
SPEC = """\
# room.yaml: nlosbench's scene spec for room.xml (a plain Mitsuba 3 file, next to this one).
# Every entry of `params:` binds one component of θ to the scene through a `mi.traverse` key:
#   translate    move shape `object` along `axis` by θ metres from its position in the XML
#   path         put the centre of `object` on the polyline `points` at arc length θ metres
#   radius       scale `object` about its centre so its radius (sphere) or half of its largest bounding-box
#                side (mesh) is θ metres
#   reflectance  set channel `channel` (0, 1, 2) of the colour at `key` to θ, or scale the colour by θ
#                when no channel is given (units "1")
#   radiance     the same for an emitter's radiance at `key`
# `object` is a shape's id in the XML; `key` a full traverse key. Each entry needs lower / upper (the
# bounds Θ, in `units`) and default (used when a study varies another parameter).
file: room.xml
description: a room with a ceiling light and a crate on the floor; θ = crate position, size and paint
defines: {resx: 32, resy: 24, max_depth: 3}   # the XML's own <default> values, overridden for nlosbench
smoke: {defines: {resx: 16, resy: 12}}        # `nlosbench run CONFIG --smoke` renders at this size
params:
  - name: crate_x
    kind: translate
    object: crate                 # <shape type="cube" id="crate"> (traverse key crate.vertex_positions)
    axis: [1, 0, 0]
    lower: -0.4                   # 0.4 m towards the green wall ...
    upper: 0.6                    # ... to 0.6 m towards the white one: the crate stays on the floor, in view
    default: 0.0                  # where the XML puts it (x = -0.2 m in world coordinates)
    units: m
    description: crate offset along x from its position in room.xml
  - name: crate_size
    kind: radius
    object: crate
    lower: 0.25
    upper: 0.4
    default: 0.3415               # the XML's 0.5 m cube turned by 30°: its bounding box is 0.683 m wide
    units: m
    description: half of the crate's largest bounding-box side (scaled about its centre)
  - name: crate_paint
    kind: reflectance
    key: crate.bsdf.reflectance.value   # the crate's diffuse colour (listed by mi.traverse)
    lower: 0.5
    upper: 1.3
    default: 1.0                  # no channel: θ scales the XML's colour (0.7, 0.35, 0.1)
    units: "1"
    description: scale of the crate's paint colour
"""

# -- step 4: the experiment (a relative scene spec path is read from the config's folder)
CONFIG = """\
# The crate's position from one noisy image: bounds, a Fisher map and two estimators (scaled to seconds).
name: own-scene
seed: 0
scene:
  name: {spec}
  params: [crate_x]              # study θ = crate_x; crate_size and crate_paint stay at their defaults
noise:
  - {{model: awgn, sigma: 0.3}}    # a dim, noisy camera: σ = 0.3 against a mean radiance of 0.18
executor: {{type: serial}}        # renders of 32 × 24 px are faster than starting worker processes
studies:
  - type: bounds                 # HCR interval (with its Δ → 0 term), CRLB and the ZZB over the grid's range
    grid: {{start: -0.4, stop: 0.6, num: 41}}   # uniform (the ZZB needs that), 2.5 cm apart
    spp: 32
    replicates: 3
    seeds: common
    save_images: false
  - type: fisher-maps            # where in the image the information about crate_x lives
    at: [0.0]
    labels: [centre]
    spp: 64
    fd_step: 0.02
  - type: trials                 # local: fixed θ*, estimators against the HCR interval and the CRLB
    theta: [0.0, 0.4]
    n: 5
    n_eff: 128
    bound_spp: 32
    hcr_grid: 21
    bounds: [hcr, crlb]
    precision: 0.25              # the bounds at θ* to ±25 % if 6e6 pixel-samples (about 240 renders) allow it;
    precision_budget: 6000000    # each run says what it reached and what more would cost
    start_width: 0.2             # grid-search ignores starts; gauss-newton starts at the profile minimum
    estimators:
      - name: grid-search
        options: {{num: 21, spp: 32, refine_evals: 10, xtol: 0.002}}
      - name: gauss-newton
        options: {{start: profile, iterations: 4, spp: 32, tol: 0.001}}
        gradient: {{method: fd, step: 0.02}}
  - type: trials                 # bayesian: θ* drawn from the uniform prior, the MSE against the ZZB
    id: bayes
    mode: bayesian
    n: 10
    n_eff: 128
    bound_spp: 32
    hcr_grid: 41
    estimators:
      - name: grid-search
        options: {{num: 21, spp: 32, refine_evals: 10, xtol: 0.002}}
"""


def list_keys(xml: Path) -> list[str]:
    """Step 1: the scene's `mi.traverse` keys, loaded as nlosbench loads it (optimize=False: otherwise
    Mitsuba merges shapes that share a BSDF into one mesh with a made-up id)."""
    import nlosbench as nb

    nb.variant.select()  # the variant nlosbench renders with (CUDA when a GPU works): mi.load_file needs one
    import mitsuba as mi

    return list(mi.traverse(mi.load_file(str(xml), optimize=False)).keys())


def cli(*args: str) -> None:
    """Run one `nlosbench` command in this process; stop the example if it fails."""
    from nlosbench.cli import main

    print(f"\n$ nlosbench {' '.join(args)}", flush=True)
    rc = main(list(args))
    if rc != 0:
        sys.exit(f"`nlosbench {' '.join(args)}` failed with exit status {rc}")


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def exp10(s: str) -> str:
    """A log10 CSV cell as a value with 3 significant digits (∞ for +inf, 0 for −inf)."""
    v = float(s)
    return f"{10 ** v:.3g}" if math.isfinite(v) else ("∞" if v > 0 else "0")


def report(run: Path) -> dict:
    """Step 6: print the bounds, the Fisher map's CRLB and the estimators' MSE against the bounds; return them."""
    b = rows(run / "00-bounds" / "bounds.csv")
    z = rows(run / "00-bounds" / "zzb.csv")[0]
    print("\nBounds on the MSE of crate_x [m²] (HCR: lower end of its 95 % interval, the value to quote):")
    print(f"  {'θ [m]':>6}  {'HCR':>9}  {'CRLB [95 % ends]':>30}")
    for r in b[::8]:
        print(f"  {float(r['theta_crate_x']):>6.3f}  {exp10(r['log10_hcr']):>9}  {exp10(r['log10_crlb']):>9} "
              f"[{exp10(r['crlb_lower'])}, {exp10(r['crlb_upper'])}]")
    hcr = [float(r["log10_hcr"]) for r in b]
    print(f"  HCR lower end over Θ: {10 ** min(hcr):.3g} … {10 ** max(hcr):.3g} m² "
          f"(RMS error ≥ {10 ** (min(hcr) / 2) * 100:.2g} … {10 ** (max(hcr) / 2) * 100:.2g} cm for an unbiased "
          "estimator)")
    print(f"  Ziv–Zakai bound on the Bayesian MSE (uniform prior on Θ, any estimator): {exp10(z['log10_zzb'])} m² "
          f"[upper end {exp10(z['zzb_upper'])}; prior variance {float(z['prior_variance']):.3g}]"
          + (f" — flags: {z['zzb_flags']}" if z["zzb_flags"] else ""))
    if "grid-limited" in z["zzb_flags"]:
        print(f"  (grid-limited: halving the grid spacing moves it by {float(z['halved']):+.2f} decades — the grid "
              "samples the error probability only at its points; quote it with that, or refine the grid)")
    f = rows(run / "01-fisher-maps" / "fisher.csv")[0]
    print(f"\nFisher map at crate_x = 0 (01-fisher-maps/fisher_maps.png): total information "
          f"{float(f['fisher_total']):.4g} m⁻², CRLB {exp10(f['log10_crlb'])} m²")
    prec = rows(run / "02-trials" / "bounds.csv")
    print("\nPrecision of the bounds at θ* (target ±25 %, within 6e6 pixel-samples; 02-trials/bounds.csv):")
    for r in prec:
        extra = float(r["precision_extra_pixel_samples"])
        print(f"  θ* = {float(r['theta_crate_x']):.2f}: reached ±{100 * float(r['precision_reached']):.3g} % "
              f"after {float(r['precision_pixel_samples']):.3g} pixel-samples"
              + (f"; ≈ {extra:.3g} more would meet it" if extra > 0 else ""))
    local = rows(run / "02-trials" / "summary.csv")
    print("\nEstimators at fixed θ* (n trials each), MSE against the bounds at θ* [m²]:")
    print(f"  {'θ* [m]':>6}  {'estimator':<13} {'n':>2} {'MSE ± SE':>20}  {'|bias| [m]':>10}  {'HCR':>9}  "
          f"{'CRLB':>9}  verdict")
    for r in local:
        print(f"  {float(r['theta_crate_x']):>6.2f}  {r['estimator']:<13} {r['n']:>2} {float(r['mse']):>9.3g} ± "
              f"{float(r['mse_se']):<8.2g}  {float(r['bias']):>10.3g}  {float(r['hcr']):>9.3g}  "
              f"{float(r['crlb']):>9.3g}  hcr {r['vs_hcr']}, crlb {r['vs_crlb']}")
    bayes = rows(run / "bayes" / "summary.csv")
    print("\nOver the prior (θ* uniform on Θ, a start anywhere in Θ), Bayesian MSE against the ZZB [m²]:")
    for r in bayes:
        print(f"  {r['estimator']:<13} n = {r['n']}: {float(r['bayes_mse']):.3g} ± {float(r['bayes_mse_se']):.2g} "
              f"(ZZB {float(r['zzb']):.3g}, MSE / ZZB = {float(r['mse_over_zzb']):.2g}): {r['vs_zzb']}")
    return {"hcr_log10": hcr, "zzb_log10": float(z["log10_zzb"]), "fisher_total": float(f["fisher_total"]),
            "precision_reached": [float(r["precision_reached"]) for r in prec],
            "local": [{k: r[k] for k in ("theta_crate_x", "estimator", "mse", "mse_se", "hcr", "crlb", "vs_hcr",
                                         "vs_crlb")} for r in local],
            "bayes": [{k: r[k] for k in ("estimator", "bayes_mse", "bayes_mse_se", "zzb", "vs_zzb")} for r in bayes]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="output folder (made if missing; an earlier run there is resumed, not redone)")
    out = Path(ap.parse_args(argv).out).resolve()
    t0 = time.perf_counter()

    # step 1: names for the spec
    keys = list_keys(XML)
    print("mi.traverse keys of room.xml (shape ids are the part before the first dot):")
    print("  movable shapes:", ", ".join(k for k in keys if k.endswith((".to_world", ".vertex_positions"))))
    print("  colours:       ", ", ".join(k for k in keys if k.endswith(("reflectance.value", "radiance.value"))))

    # step 2: the spec next to (a copy of) the XML
    scene_dir = out / "scene"
    scene_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy(XML, scene_dir / XML.name)
    spec = scene_dir / "room.yaml"
    spec.write_text(SPEC)
    print(f"\nwrote {spec} (next to {scene_dir / XML.name})")

    # step 3: check it
    cli("render", str(spec), "--spp", "64", "--out", str(out / "render"))
    cli("check-scene", str(spec), "--spp", "64", "--out", str(out / "check"))

    # step 4: the experiment, dry run first
    config = out / "experiment.yaml"
    config.write_text(CONFIG.format(spec=spec.relative_to(out)))  # scene/room.yaml
    again = ["--resume"] if (out / "smoke" / "results.json").exists() else []  # a second run keeps finished work
    cli("run", str(config), "--smoke", "--quiet", "--out", str(out / "smoke"), *again)

    # step 5: the real (small) run
    again = ["--resume"] if (out / "run" / "results.json").exists() else []
    cli("run", str(config), "--quiet", "--out", str(out / "run"), *again)

    # step 6: what it found
    found = report(out / "run")
    seconds = time.perf_counter() - t0
    (out / "found.json").write_text(json.dumps({**found, "seconds": seconds}, indent=1))
    print(f"\nreport: {out / 'run' / 'report.md'}; figures: {out / 'check' / 'check.png'}, "
          f"{out / 'run' / '00-bounds' / 'bounds.png'}; {seconds:.0f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
