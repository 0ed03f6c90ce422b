# Two commands do everything: `make demo` and `make test` (both run the idempotent set-up first).
VENV ?= .venv
PY := $(VENV)/bin/python
CONFIG ?= configs/quick.yaml

.PHONY: setup demo test lint bench bench-gpu clean

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

# the forward and estimator benchmarks on cuda_ad_rgb. No set-up step: the GPU machine is offline, so
# this runs with whatever Python has nlosbench's requirements (`.device/prelude.sh`, see
# ../shared/device/README.md, or `make setup` first on a networked GPU machine)
GPU_PY ?= $(if $(wildcard $(PY)),$(PY),python3)
bench-gpu:
	NLOSBENCH_VARIANT=cuda_ad_rgb $(GPU_PY) -m nlosbench.cli bench forward estimators

clean:
	rm -rf runs .pytest_cache
