# Two commands do everything: `make demo` and `make test` (both run the idempotent set-up first).
VENV ?= .venv
PY := $(VENV)/bin/python
CONFIG ?= configs/quick.yaml

.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	rm -rf runs/demo
	$(PY) -m nlosbench.cli run $(CONFIG) --out runs/demo
	@echo "report: runs/demo/report.md"

test: setup
	$(PY) -m pytest -q

bench: setup
	$(PY) -m nlosbench.cli bench

clean:
	rm -rf runs .pytest_cache
