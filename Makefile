# robocal — make help lists the targets.
SHELL := /bin/bash
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the stages' `python` (dvc.yaml cmd) must be the virtual environment's
export PATH := $(abspath $(BIN)):$(PATH)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1
export DVC_NO_ANALYTICS := 1
export MLFLOW_DISABLE_TELEMETRY := 1
export DO_NOT_TRACK := 1
UI_PORT ?= 5000

.DEFAULT_GOAL := help

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  make %-10s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml requirements.lock
	@command -v $(PY) >/dev/null || { echo "needs $(PY) on PATH"; exit 1; }
	@echo "setting up $(VENV): robocal and its tools, pinned by requirements.lock (~1.9 GB, about 1-3 min; pip shows its progress)"
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --progress-bar on -r requirements.lock | grep -v '^Requirement already satisfied' || true
	$(BIN)/pip install --quiet --no-deps -e .
	@$(BIN)/python -c "import robocal" || { echo "setup failed: see pip's output above"; exit 1; }
	touch $(STAMP)

setup: $(STAMP) ## create .venv and install robocal with its tools

run: $(STAMP) ## set up, then run the default pipeline end to end (dvc repro)
	$(BIN)/dvc repro
	@$(BIN)/python -m robocal.tracking flush >/dev/null
	@echo
	@echo "reports (stages that skipped have none; reports/<stage>/result.json says why):"
	@for r in geometric thermal screen validate compliance discovery compare_optimizers; do \
		test -f reports/$$r/report.html && echo "  $(CURDIR)/reports/$$r/report.html"; done; true
	@echo "metrics: $(BIN)/dvc metrics show    compare experiments: make exps    runs: make ui"

test: $(STAMP) ## set up, then run the test suite
	$(BIN)/pytest -q

lint: $(STAMP) ## ruff and mypy
	$(BIN)/ruff check src tests stages
	$(BIN)/ruff format --check src tests stages
	$(BIN)/mypy

lock: $(STAMP) ## re-pin requirements.lock from pyproject.toml (uv), after changing a dependency; then make setup
	$(BIN)/uv pip compile pyproject.toml --extra dev --python-version 3.11 --universal --no-header --quiet \
		-o requirements.lock
	@echo "requirements.lock re-pinned: commit it; make setup installs exactly it"

e2e: $(STAMP) ## the pipeline end to end in a copy of the repository (dvc repro, dvc exp run; ~5 min; CI runs it)
	$(BIN)/pytest -q -m e2e

repro-check: $(STAMP) ## the default pipeline under two BLAS kernels in fresh copies: same bytes as dvc.lock (~8 min)
	$(BIN)/pytest -q -m repro tests/pipeline/test_same_bytes.py

docs: $(STAMP) ## build the documentation (docs/, API reference from the docstrings) into site/, offline
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	@echo "site: $(CURDIR)/site/index.html"

params: $(STAMP) ## regenerate params.yaml from conf/ (DVC's Hydra composition)
	$(BIN)/python -m robocal.pipeline params

ui: $(STAMP) ## MLflow UI on http://127.0.0.1:$(UI_PORT) over the repository's mlflow.db (prints the runs table's address)
	$(BIN)/python -m robocal.tracking ui --port $(UI_PORT)

exps: $(STAMP) ## compare the DVC experiments: headline metrics, then what differs (all columns: dvc exp show)
	@json="$$($(BIN)/dvc exp show --no-pager --json)" && printf '%s' "$$json" | $(BIN)/python -m robocal.exps

compare: $(STAMP) ## the thermal paper's optimizer comparison (~2 min; off in make run): a DVC experiment
	$(BIN)/dvc exp run -S compare.run=true
	@echo "report: $(CURDIR)/reports/compare_optimizers/report.html"

bench: $(STAMP) ## time the full default pipeline (dvc repro --force), then a second repro (nothing to do)
	@TIMEFORMAT='full default dvc repro --force: %R s'; time $(BIN)/dvc repro --force >/dev/null
	@TIMEFORMAT='second dvc repro (nothing to do): %R s'; time $(BIN)/dvc repro >/dev/null

sweep: $(STAMP) ## example sweeps: three noise settings in parallel (joblib), then gn vs lm
	$(BIN)/dvc repro prepare
	$(BIN)/python stages/geometric_fit.py -m calibration.noise_mm=0.01,0.015,0.02 hydra/launcher=joblib
	$(BIN)/python stages/geometric_fit.py -m optimizer=gn,lm
	@echo "results: reports/sweeps/geometric_fit/; compare the nested runs with: make ui"

.PHONY: help setup run test lint docs e2e lock repro-check params ui exps compare bench sweep
