"""Check a viewpoint search against a committed 31 × 31 map of the same scene: the search's cost against the map's,
the upper limit of the found view's fresh A-optimal score against the map's 5 % quantile of that score, and seeded
replays of the search on the map's interpolant with its measured noise (success: the returned view's interpolated
score within the map's 5 % quantile), with the Clopper–Pearson interval.

    python scripts/viewpoint_check.py results/paper_hallway_viewpoint_map results/paper_hallway_viewpoint_search

Writes search_check.json into the map's folder (the docs read it) and prints a summary. Both runs must be published
(`scripts/publish_result.py`) and use one θ, camera target, axes, FD step and scene (checked from their configs).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nlosbench.io import read_csv
from nlosbench.studies import bayesopt, viewpoint_search


def _block(run: Path, kind: str) -> tuple[dict, dict, Path]:
    """`viewpoint_search.run_study`, its error as the script's."""
    try:
        return viewpoint_search.run_study(run, kind)
    except ValueError as e:
        raise SystemExit(str(e)) from None


def _pixel_samples(run: Path, cfg: dict, block: dict, study: Path) -> int:
    """The study's renders (machine.json) × spp × pixels: every render of both studies has the study's spp."""
    renders = json.loads((run / "machine.json").read_text())["studies"][study.name]["renders"]
    d = cfg["scene"]["options"]["defines"]
    return int(renders * block["spp"] * d["width"] * d["height"])


def check(map_run: Path, search_run: Path, replays: int, quantile: float, seed: int) -> dict:
    mcfg, grid, gdir = _block(map_run, "viewpoints")
    scfg, search, sdir = _block(search_run, "viewpoint-search")
    differ = [k for k in viewpoint_search.GRID_KEYS if grid[k] != search[k]]
    if differ or mcfg["scene"] != scfg["scene"] or mcfg["noise"] != scfg["noise"]:
        raise SystemExit(f"the map and the search differ in {', '.join(differ) or 'scene or noise'}")
    conf = read_csv(sdir / "confirmed.csv")
    noise = json.loads((search_run / "results.json").read_text())["studies"][sdir.name]["results"]["noises"][
        search["noise"]]
    u0, u1, val, se = bayesopt.read_grid(gdir / "viewpoints.csv", noise)
    cut = float(np.quantile(val[np.isfinite(val)], quantile))
    found = next(r for r in conf if r["confirm"] == "search" and r["noise"] == noise)
    upper = float(found["score_upper"])
    r = bayesopt.grid_replays(gdir / "viewpoints.csv", noise, replays, search["evaluations"], search["initial"],
                              quantile, seed, search["batch"])
    lo, hi = r.interval()
    px_map, px_search = _pixel_samples(map_run, mcfg, grid, gdir), _pixel_samples(search_run, scfg, search, sdir)
    return {"noise": noise, "quantile": quantile, "map_quantile_log10": cut, "map_best_log10": float(np.nanmin(val)),
            "found_offsets": found["offsets"], "found_log10": float(found["log10_score"]), "found_upper_log10": upper,
            "found_within": bool(upper <= cut), "map_pixel_samples": px_map, "search_pixel_samples": px_search,
            "search_share": px_search / px_map, "replays": len(r.success), "replay_successes": int(r.success.sum()),
            "replay_rate": r.rate, "replay_lower": lo, "replay_upper": hi, "replay_seed": seed,
            "replay_evaluations": search["evaluations"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("map_run", type=Path)
    ap.add_argument("search_run", type=Path)
    ap.add_argument("--replays", type=int, default=50)
    ap.add_argument("--quantile", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    out = check(a.map_run, a.search_run, a.replays, a.quantile, a.seed)
    (a.map_run / "search_check.json").write_text(json.dumps(out, indent=2) + "\n")
    q = out["quantile"] * 100
    print(f"search: {out['search_pixel_samples']:.3g} pixel-samples, {out['search_share'] * 100:.3g} % of the map's "
          f"{out['map_pixel_samples']:.3g}")
    print(f"found view {out['found_offsets']}: log10 tr F⁻¹ {out['found_log10']:.3f}, upper limit "
          f"{out['found_upper_log10']:.3f} against the map's {q:g} % quantile {out['map_quantile_log10']:.3f} "
          f"({'within' if out['found_within'] else 'not within'}); the map's best {out['map_best_log10']:.3f}")
    lo, hi = out["replay_lower"], out["replay_upper"]
    print(f"replays: {out['replay_successes']} of {out['replays']} within the {q:g} % quantile "
          f"({out['replay_rate'] * 100:.3g} %, 95 % interval [{lo * 100:.3g}, {hi * 100:.3g}] %)")


if __name__ == "__main__":
    main()
