"""
Reading a report
================

``nlosbench run CONFIG`` writes a run directory: the resolved ``config.yaml``, ``fingerprint.json``,
``results.json`` (every study's summary), a folder per study with CSV tables, PNG plots (and EXR images
where a study keeps them) and ``report.md``, which says what was run, how long it took and what was
found. Here a seconds-long config on the ``edge1d`` toy (a hard shadow edge, whose likelihood has kinks):
bounds over a grid, then an estimator in Monte Carlo trials at two θ*.
"""

# %%
# The config and the run
# ----------------------
import contextlib
import csv
import io
import json
import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from nlosbench import cli

CONFIG = """
name: edge-tutorial
seed: 0
scene: {name: edge1d, options: {pixels: 32}}
noise: [{model: awgn, sigma: 0.05}]
executor: {type: serial}
studies:
  - type: bounds
    grid: {start: 0.3, stop: 0.7, num: 17}
    spp: 1
  - type: trials
    theta: [0.4, 0.55]
    n: 12
    estimators: [{name: grid-search, options: {num: 41, spp: 1}}]
"""
folder = Path(tempfile.mkdtemp())
(folder / "edge.yaml").write_text(CONFIG)
with contextlib.redirect_stdout(io.StringIO()):  # its last line names the temporary folder
    code = cli.main(["run", str(folder / "edge.yaml"), "--out", str(folder / "run"), "--quiet"])
run = folder / "run"
files = sorted(p.relative_to(run).as_posix() for p in run.rglob("*") if p.is_file())
print("exit code", code)
print("\n".join(f for f in files if not f.startswith(("renders/", ".")) and not f.endswith(".exr")))
print(f"+ {sum(f.endswith('.exr') for f in files)} EXR images; {sum(f.startswith('renders/') for f in files)} renders "
      "kept in renders/ (checksummed), so a resumed run renders nothing twice")

# %%
# report.md
# ---------
# The report is made from the saved tables only, so ``nlosbench report RUN_DIR`` re-makes it (and the
# plots) without rendering. Its first lines:
print("\n".join((run / "report.md").read_text().splitlines()[:24]))

# %%
# The tables
# ----------
# ``00-bounds/bounds.csv`` has a row per noise model and θ: ``log10_hcr`` (the HCR interval's lower end, the
# value to quote), ``hcr_lower`` / ``hcr_upper`` (log10 of its one-sided confidence ends; ``inf``: an open
# end), the CRLB columns and the flags that say why a number is what it is. ``01-trials/summary.csv`` has
# a row per θ* and estimator: MSE with its standard error, the bias with its test, the bounds at θ* and
# the verdicts.
with open(run / "00-bounds" / "bounds.csv", newline="") as f:
    bounds = list(csv.DictReader(f))
print({k: bounds[8][k] for k in ("theta_edge", "log10_hcr", "hcr_lower", "hcr_upper", "log10_crlb", "hcr_flags")})
with open(run / "01-trials" / "summary.csv", newline="") as f:
    for row in csv.DictReader(f):
        print({k: row[k] for k in ("theta_edge", "estimator", "n", "mse", "mse_se", "bias", "hcr", "crlb", "vs_hcr")})
print("results.json keys:", list(json.loads((run / "results.json").read_text())))

# %%
# The plots
# ---------
fig, ax = plt.subplots(figsize=(8, 5))
ax.imshow(plt.imread(run / "00-bounds" / "bounds.png"))
ax.axis("off")
fig.tight_layout()

# %%
# The run folder here was a temporary one, removed now; a run of yours goes to ``runs/NAME`` (or ``--out``)
# and stays.
shutil.rmtree(folder)
