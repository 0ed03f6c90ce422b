# Two commands do everything: `make demo` and `make test` (both run the idempotent set-up first).
VENV ?= .venv
PY := $(VENV)/bin/python
CONFIG ?= configs/quick.yaml

.PHONY: setup demo test lint bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	rm -rf runs/demo
	$(PY) -m nlosbench.cli run $(CONFIG) --out runs/demo
	@echo "report: runs/demo/report.md"

test: setup lint
	$(PY) -m pytest -q

# the layers contract (import-linter) and the rule set (ruff), both configured in pyproject.toml
lint: setup
	$(VENV)/bin/lint-imports
	$(VENV)/bin/ruff check nlosbench tests scripts examples

bench: setup
	$(PY) -m nlosbench.cli bench

clean:
	rm -rf runs .pytest_cache
