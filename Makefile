# Two commands do everything: `make demo` and `make test` (both run the idempotent set-up first).
VENV ?= .venv
PY := $(VENV)/bin/python
CONFIG ?= configs/quick.yaml

# examples/own_scene.py's run: made by the test suite, shown by the documentation's own-scene tutorial
OWN_SCENE ?= runs/own_scene
# -W --keep-going: every warning is an error, all reported; -n: every cross-reference must resolve; -j auto: pages
# read and written on every core (80 s against 88 s on 2 cores)
SPHINX := $(PY) -m sphinx -W --keep-going -n -q -j auto

.PHONY: setup demo test test-slow lint docs docs-check docs-build bench bench-gpu clean

setup:
	@bash scripts/setup.sh

demo: setup
	rm -rf runs/demo
	$(PY) -m nlosbench.cli run $(CONFIG) --out runs/demo
	@echo "report: runs/demo/report.md"

# the suite on TEST_WORKERS processes (pytest-xdist); with --dist loadgroup tests/conftest.py schedules: a file with
# module-scoped fixtures runs in one process (made once; the own-scene run is written by one process), other tests
# go one by one to whichever process is free. The 20 slowest are listed: all of `make test` has 12 min on 2 cores.
# `make test` leaves out the tests marked `slow` (coverage over 1000 seeds and the stopping rule's over many,
# every shipped config's smoke run but the demo's, estimator efficiency and the prediction at the demo's settings,
# the longest signal, kill and resume tests); `make test-slow` runs only those; CI runs both
TEST_WORKERS ?= 2
PYTEST := $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=20

test: setup lint
	NLOSBENCH_OWN_SCENE_OUT=$(OWN_SCENE) $(PYTEST) -m "not slow"
	@$(MAKE) --no-print-directory docs-check

test-slow: setup
	$(PYTEST) -m slow

# the modules whose docstrings hold `>>>` examples (tests/test_api_docs.py checks that none is left out)
DOCTESTS := nlosbench/api.py nlosbench/bank.py nlosbench/noise.py nlosbench/params.py nlosbench/forward \
	nlosbench/diagnostics nlosbench/scenes/__init__.py nlosbench/bounds nlosbench/estimators nlosbench/cli.py \
	nlosbench/variant.py nlosbench/schema.py

# the site into docs/_build/html (offline, its gallery executed), then the docstrings' examples as doctests
# (the root conftest.py gives them `nb`); `make test` runs the same target
docs: setup docs-check

docs-check: docs-build
	$(PY) -m pytest -q -p no:cacheprovider --doctest-modules $(DOCTESTS)

# the API pages are generated afresh: a name taken out of an `__all__` leaves no stale page behind
docs-build: $(OWN_SCENE)/run/report.md
	rm -rf docs/reference/generated
	NLOSBENCH_OWN_SCENE_RUN=$(OWN_SCENE) $(SPHINX) -b html docs docs/_build/html

$(OWN_SCENE)/run/report.md:
	rm -rf $(OWN_SCENE)
	$(PY) examples/own_scene.py $(OWN_SCENE)

# the layers contract (import-linter) and the rule set (ruff), both configured in pyproject.toml
lint: setup
	$(VENV)/bin/lint-imports
	$(VENV)/bin/ruff check nlosbench tests scripts examples docs

bench: setup
	$(PY) -m nlosbench.cli bench

# the forward and estimator benchmarks on cuda_ad_rgb. No set-up step, so that it runs on an offline GPU
# machine with whatever Python has nlosbench's requirements (`make setup` first on a networked one)
GPU_PY ?= $(if $(wildcard $(PY)),$(PY),python3)
bench-gpu:
	NLOSBENCH_VARIANT=cuda_ad_rgb $(GPU_PY) -m nlosbench.cli bench forward estimators

clean:
	rm -rf runs .pytest_cache docs/_build docs/auto_tutorials docs/reference/generated docs/reference/api.md \
		docs/reference/config.md docs/_generated
