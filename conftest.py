"""The docstrings' `>>>` examples, run by `make docs` and `make test` (`pytest --doctest-modules nlosbench/...`),
see the package as `nb`, as they are written."""
import pytest


@pytest.fixture(autouse=True)
def _nb_in_doctests(doctest_namespace):
    import nlosbench

    doctest_namespace["nb"] = nlosbench
