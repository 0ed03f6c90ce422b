"""The docstrings' `>>>` examples, run by `make docs` (`pytest --doctest-modules nlosbench/...`), see the
package as `nb`, as they are written (tests/test_api_docs.py gives them the same name)."""
import pytest


@pytest.fixture(autouse=True)
def _nb_in_doctests(doctest_namespace):
    import nlosbench

    doctest_namespace["nb"] = nlosbench
