# Two entry points a fresh clone needs: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test lint typecheck venv clean eval bench interop-env

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

## Main job on the built-in simulated default: simulate the paper's TS/T45/T90 flights
## and print the evaluation table.
run: $(STAMP)
	$(BIN)/tcm-companion demo

lint: $(STAMP)
	$(BIN)/ruff check tcm_companion tests tools
	$(BIN)/ruff format --check tcm_companion tests tools

typecheck: $(STAMP)
	$(BIN)/mypy tcm_companion/core

## MAVProxy's own venv (.venv-interop) for tests/test_interop.py: built once, then cached.
interop-env: $(STAMP)
	$(BIN)/python tools/interop_env.py --quiet

test: lint typecheck
	$(BIN)/python -m pytest -n 2 -q

eval: $(STAMP)
	$(BIN)/tcm-companion eval --sim TS T45 T90 --out out/eval

bench: $(STAMP)
	$(BIN)/tcm-companion bench

clean:
	rm -rf $(VENV) .venv-interop .pytest_cache .mypy_cache .ruff_cache out
