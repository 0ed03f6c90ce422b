# Two commands do everything: `make demo` and `make test` (both run the idempotent set-up first).
VENV ?= .venv
PY := $(VENV)/bin/python
CONFIG ?= configs/quick.yaml
# -n 2 spreads the suite over both cores when pytest-xdist is present; plain pytest otherwise.
PYTEST_ARGS ?=

.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) -m nlosbench.cli run $(CONFIG) --out runs/demo

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

bench: setup
	$(PY) scripts/bench.py

clean:
	rm -rf runs .pytest_cache
