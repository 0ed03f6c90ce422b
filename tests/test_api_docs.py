"""The public API's docstrings, checked the way the documentation build checks them, in seconds.

Every public name of `nlosbench`, `nb.bounds`, `nb.estimators` and `nb.noise` (their `__all__`), and every
public method a class defines itself, passes numpydoc's validation for the checks `docs/conf.py` enables
(GL08 a docstring, PR01/PR02 every parameter documented and none invented, RT01 a Returns section), with
the same exclusions. `make docs` runs the same checks inside Sphinx, with warnings as errors; this test
names every failure at once, before the slower site build. Every function and class the API reference lists has
an Examples section with a `>>>` example, and every module holding one is in the Makefile's DOCTESTS, whose
examples run once, in `make docs-check` (the target `make docs` and `make test` both end with), not here.
"""
from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
from pathlib import Path

import pytest

numpydoc_validate = pytest.importorskip("numpydoc.validate")

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("nlosbench_docs", ROOT / "docs" / "_ext" / "nlosbench_docs.py")
docs_ext = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(docs_ext)
METHODS = (staticmethod, classmethod)
MODULES = ("nlosbench", "nlosbench.bounds", "nlosbench.estimators", "nlosbench.noise")


def _conf() -> dict:
    """docs/conf.py's numpydoc settings (the checks and the exclusion patterns), read from the file."""
    namespace: dict = {}
    text = (ROOT / "docs" / "conf.py").read_text()
    start = text.index("numpydoc_validation_checks")
    end = text.index("}", text.index("numpydoc_validation_exclude")) + 1
    exec(text[start:end], namespace)  # two literal assignments
    return namespace


def _objects() -> list[tuple[str, object]]:
    """(fully qualified name, object) of the public names, as the API page lists them (`__all__`, else what
    the module defines), and of each class's own public methods. Objects, not names: `nb.bounds.crlb` is
    also a submodule's name, and numpydoc would load the module."""
    out = []
    for module in MODULES:
        mod = importlib.import_module(module)
        for name in docs_ext._public(mod):
            obj = getattr(mod, name)
            if inspect.ismodule(obj):
                continue
            out.append((f"{module}.{name}", obj))
            if inspect.isclass(obj):
                out += [(f"{module}.{name}.{m}", getattr(obj, m)) for m, v in vars(obj).items()
                        if not m.startswith("_") and (inspect.isfunction(v) or isinstance(v, METHODS))]
    return out


def test_every_public_name_has_numpydoc_parameters_and_returns():
    conf = _conf()
    checks, exclude = conf["numpydoc_validation_checks"], [re.compile(p) for p in conf["numpydoc_validation_exclude"]]
    failures = []
    for name, obj in _objects():
        if any(p.search(name) for p in exclude):
            continue
        doc = numpydoc_validate.get_doc_object(obj)
        errors = [f"{code} {msg}" for code, msg in numpydoc_validate.validate(doc)["errors"] if code in checks]
        if errors:
            failures.append(f"{name}: " + "; ".join(errors))
    assert not failures, f"{len(failures)} public names fail numpydoc validation:\n" + "\n".join(failures)


def test_every_public_function_and_class_has_an_example():
    missing = docs_ext.without_examples()
    assert not missing, (f"{len(missing)} public names have no Examples section with a >>> example (add a short one "
                         "that checks what it shows; `python docs/_ext/nlosbench_docs.py` lists them):\n"
                         + "\n".join(missing))


def _doctest_paths() -> list[Path]:
    """The Makefile's DOCTESTS: the files and folders whose docstrings `make docs-check` runs."""
    text = (ROOT / "Makefile").read_text().replace("\\\n", " ")
    [line] = [ln for ln in text.splitlines() if ln.startswith("DOCTESTS :=")]
    return [ROOT / w for w in line.split(":=", 1)[1].split()]


def test_every_module_with_examples_runs_them_in_docs_check():
    paths = _doctest_paths()
    assert all(p.exists() for p in paths), [str(p) for p in paths if not p.exists()]
    with_examples = [f for f in sorted((ROOT / "nlosbench").rglob("*.py")) if ">>>" in f.read_text()]
    left_out = [str(f.relative_to(ROOT)) for f in with_examples if not any(f == p or p in f.parents for p in paths)]
    assert not left_out, f"modules with >>> examples that make docs-check leaves out (add them to DOCTESTS): {left_out}"

