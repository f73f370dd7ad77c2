# Two entry points a fresh clone needs: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run demo test lint typecheck venv clean eval bench interop-env

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

## Main job on the built-in simulated default: the daemon in SITL (mock autopilot +
## simulated camera over loopback UDP) for 20 s, then accuracy, latency and faults.
run: $(STAMP)
	$(BIN)/tcm-companion sitl --duration 20

## The paper's evaluation: simulate TS/T45/T90 and print the tables.
demo: $(STAMP)
	$(BIN)/tcm-companion demo

lint: $(STAMP)
	$(BIN)/ruff check tcm_companion tests tools
	$(BIN)/ruff format --check tcm_companion tests tools

typecheck: $(STAMP)
	$(BIN)/mypy tcm_companion/core tcm_companion/service tcm_companion/io/cameras tcm_companion/io/sdnotify.py

## MAVProxy's own venv (.venv-interop) for tests/test_interop.py: built once, then cached.
interop-env: $(STAMP)
	$(BIN)/python tools/interop_env.py --quiet

test: lint typecheck
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q

eval: $(STAMP)
	$(BIN)/tcm-companion eval --sim TS T45 T90 --out out/eval

bench: $(STAMP)
	$(BIN)/tcm-companion bench

clean:
	rm -rf $(VENV) .venv-interop .pytest_cache .mypy_cache .ruff_cache out
