"""Sphinx configuration of the nlosbench documentation (`make docs`: warnings are errors, offline)."""
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path[:0] = [str(DOCS.parent), str(DOCS / "_ext")]

import nlosbench  # noqa: E402

project = "nlosbench"
author = "The nlosbench developers"
copyright = "2026, The nlosbench developers"
release = version = nlosbench.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "sphinxarg.ext",
    "nlosbench_docs",  # docs/_ext: the config-key reference and the API pages, generated from the code
    "nlosbench_results",  # docs/_ext: {result}`FILE[SELECTOR] EXPRESSION :FORMAT`, a number read from results/
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "pypi.md", "tutorials/README.rst", "tutorials/*.py", "tutorials/*.md"]
templates_path = ["_templates"]
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
# quotes and ellipses only: no dashes, so `--set` and `--out` stay two hyphens in option text and code
smartquotes_action = "qe"
suppress_warnings = ["myst.header"]  # pages moved from the README start at level 2 under their own title

html_theme = "furo"
html_title = f"nlosbench {release}"
html_static_path: list[str] = []

# -- API reference: autosummary pages for the public names, numpydoc sections, validated ---------------------
autosummary_generate = True
autodoc_default_options = {"members": True, "inherited-members": False, "show-inheritance": True}
autodoc_typehints = "none"  # types are in the numpydoc Parameters / Returns sections
autodoc_member_order = "bysource"
numpydoc_show_class_members = False  # autodoc's :members: documents the methods; no second table
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
# Every public name of nlosbench, nb.bounds, nb.estimators and nb.noise: a docstring (GL08), every parameter
# documented and none invented (PR01, PR02), a Returns section (RT01). Other modules are listed, not validated.
numpydoc_validation_checks = {"GL08", "PR01", "PR02", "RT01"}
numpydoc_validation_exclude = {
    r"\._[^.]*$",  # private names
    r"^nlosbench\.(scenes|diagnostics|variant|forward)\.",
    r"\.__init__$",
    # a class attribute whose value is None has no __doc__ for numpydoc to validate; its `#:` comment is what
    # autodoc renders on the class's page
    r"^nlosbench\.estimators\.(base\.)?Estimator\.grid_seeds$",
}

# -- offline, nitpicky: names from other packages are not linked (no intersphinx download) ---------------
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(torch|numpy|np|scipy|mitsuba|mi|drjit|dr|pathlib|collections|typing|abc|dataclasses|enum|"
               r"concurrent|argparse|os|io|json|yaml|matplotlib|dask|distributed)(\..*)?"),
    (r"py:.*", r"(int|float|str|bool|dict|list|tuple|set|object|callable|None|Exception|ValueError|KeyError|"
               r"TypeError|RuntimeError|OSError|Path|ndarray|Tensor|Generator|array_like|array-like|optional|"
               r"sequence|iterable|mapping|type|ABC|ClassVar|Callable|Any|Iterable|Sequence|Mapping)"),
    # BoundService's bases, one per question: their methods are on BoundService's own page (inherited-members)
    (r"py:class", r"nlosbench\.bounds\.service\.(curve|at|fisher|interval|renders)\.\w+"),
]

# -- the tutorials: an executed gallery at toy size --------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": ["tutorials"],
    "gallery_dirs": ["auto_tutorials"],
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "show_signature": False,
    "reference_url": {},
    "image_scrapers": ("matplotlib",),
    "min_reported_time": 1,
    "write_computation_times": False,  # each page states its own running time
    "run_stale_examples": True,  # every build runs every page again: its numbers are this build's
}
