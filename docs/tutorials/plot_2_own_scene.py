"""
Your own scene
==============

You have a Mitsuba 3 scene file and want to know how well one of its unknowns can be estimated from a
noisy image. ``examples/own_scene.py`` starts from ``examples/own_scene/room.xml`` — a plain Mitsuba file
with no nlosbench markup: a room, a ceiling light, a camera and a crate on the floor — and asks how well
the crate's position along the room can be estimated from one 32 × 24 image with AWGN σ = 0.3::

    python examples/own_scene.py runs/own_scene    # about a minute on 2 CPU cores

The test suite runs it (``tests/test_examples.py``); this page shows what that run wrote, read back from
its folder (``make docs`` runs the example first when no run is there). Each step below is a function or
a block of the example's ``main()``.
"""

# %%
# 1. Find the names
# -----------------
# A binding names a shape by its ``id`` and a colour by its full ``mi.traverse`` key. List them the way
# nlosbench loads the scene: ``mi.traverse(mi.load_file("room.xml", optimize=False)).keys()``, after
# ``nlosbench.variant.select()``. Without ``optimize=False`` Mitsuba merges shapes that share a material
# into one mesh with a made-up id. Movable shapes end in ``.to_world`` or ``.vertex_positions``; colours
# in ``reflectance.value`` / ``radiance.value``.
import importlib.util
import os
import time
from pathlib import Path

import matplotlib.pyplot as plt

ROOT = next(p for p in [Path.cwd(), *Path.cwd().parents] if (p / "examples" / "own_scene.py").is_file())
NAME = os.environ.get("NLOSBENCH_OWN_SCENE_RUN", "runs/own_scene")
RUN = ROOT / NAME  # relative to the repository
if not (RUN / "run" / "report.md").is_file():
    raise FileNotFoundError(f"no finished run of examples/own_scene.py in {RUN}: run "
                            f"`python examples/own_scene.py {RUN}` first (`make docs` does)")
made = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime((RUN / "run" / "report.md").stat().st_mtime))
print(f"the run of examples/own_scene.py shown here was made {made} in {NAME}; the next build makes it again "
      "once that folder is deleted (make clean)")
spec = importlib.util.spec_from_file_location("own_scene", ROOT / "examples" / "own_scene.py")
own_scene = importlib.util.module_from_spec(spec)
spec.loader.exec_module(own_scene)

# %%
# 2. Write the scene spec
# -----------------------
# One ``params:`` entry per component of θ: ``kind`` (``translate``, ``path``, ``radius``, ``reflectance``,
# ``radiance``), ``object`` or ``key``, the bounds Θ (``lower``, ``upper``), a ``default`` (used while a
# study varies another parameter) and ``units``. ``defines`` sets the XML's ``<default>`` values (image
# size, path depth); ``smoke`` gives the tiny size used by ``--smoke``. Keep the film's
# ``<rfilter type="box"/>``: other filters make identical renders differ, which breaks finite differences
# with common random numbers (nlosbench warns). The spec the example wrote:
print((RUN / "scene" / "room.yaml").read_text())

# %%
# 3. Check it
# -----------
# ``nlosbench render SPEC`` shows one image at the defaults; ``nlosbench check-scene SPEC`` renders each
# parameter at Θ's lower end, mid-point and upper end with one seed, reports the image change per step
# and draws this grid (rows: parameters; columns: the three renders and the two difference images). It
# warns for a binding that moves nothing, a half of Θ where nothing changes, an object whose bounding box
# leaves the frame, a non-box pixel filter and renders that are not reproducible.
def show(png: Path, title: str) -> None:
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.imshow(plt.imread(png))
    ax.set_title(title)
    ax.axis("off")
    fig.tight_layout()


show(RUN / "check" / "check.png", "nlosbench check-scene room.yaml")

# %%
# 4. Dry-run, 5. run
# ------------------
# ``nlosbench run experiment.yaml --smoke`` runs the same studies shrunk to seconds, so a mistake in the
# config shows before the real run. Then ``nlosbench run experiment.yaml``: ``bounds`` (the HCR interval
# with its Δ → 0 term, the CRLB and the Ziv–Zakai bound over a 41-point grid on Θ), ``fisher-maps``
# (where in the image the information about the crate's position lives), ``trials`` (local: grid-search
# and Gauss–Newton at θ* = 0 and 0.4 m against the HCR interval and the CRLB, with their bias) and
# ``trials`` (bayesian: grid-search over the uniform prior against the ZZB). The config:
print((RUN / "experiment.yaml").read_text())

# %%
show(RUN / "run" / "00-bounds" / "bounds.png", "bounds on the crate's position")

# %%
# 6. Read the numbers back
# ------------------------
# The example's ``report`` reads the run directory's CSV tables (``00-bounds/bounds.csv``, ``zzb.csv``,
# ``01-fisher-maps/fisher.csv``, ``02-trials/summary.csv``, ``bayes/summary.csv``); the run's
# ``report.md`` has the same with plots.
found = own_scene.report(RUN / "run")

# %%
# The example is scaled to seconds: 32 × 24 px, path depth 3, 32 spp × 3 replicate render sets for the
# bounds, 5 trials per θ* and estimator, 10 Bayesian trials, renders in one process
# (``executor: serial``). So the HCR's upper ends are mostly open (too few samples to resolve λ at small
# Δ), the ZZB is flagged grid-limited, and the MSE standard errors are wide. For a real study raise spp,
# the grid and the trials, and use ``executor: {type: local, workers: N}``.
