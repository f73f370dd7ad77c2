# Two entry points a fresh clone needs: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Every package the venv gets, pinned with hashes: the dependencies and the dev extra of
# pyproject.toml plus pip and setuptools (its `bootstrap` group). `make lock` writes it.
LOCK   := requirements.lock
UV     := uv==0.13.9

.PHONY: run demo test test-fast test-adversarial test-tools lint typecheck venv lock lua32 clean eval bench interop-env

venv: $(STAMP)

## The locked versions, then the package itself (editable, no dependencies of its own).
## pip's own output is the progress: one line per package collected, then the install.
## (The editable step takes 2 s and is quiet: it would only print setuptools' notice
## about editable installs.)
$(STAMP): pyproject.toml $(LOCK)
	@echo "make: installing the packages pinned in $(LOCK) into $(VENV) (~50 packages, ~800 MB: about a minute)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --disable-pip-version-check --require-hashes --no-deps -r $(LOCK)
	@echo "make: installing tcm-companion itself (editable)"
	$(BIN)/python -m pip install --disable-pip-version-check --quiet --no-deps --no-build-isolation -e .
	@# Byte-compile the package now: an editable install leaves that to the first import,
	@# which a PYTHONDONTWRITEBYTECODE environment never does, and compiling the generated
	@# MAVLink dialect costs 0.6-0.8 s at every start (replay, sitl, run).
	$(BIN)/python -m compileall -q tcm_companion
	@$(BIN)/python -m pip check || { echo "make: $(LOCK) does not satisfy pyproject.toml: run 'make lock'" >&2; exit 1; }
	touch $(STAMP)
	@echo "make: $(VENV) is ready"

## Re-resolve $(LOCK) from pyproject.toml's ranges with uv (in a throwaway venv), for every
## platform and Python >= 3.11, keeping the pinned versions that still fit. To move to newer
## releases: make lock LOCK_FLAGS=--upgrade (or LOCK_FLAGS='--upgrade-package numpy').
## Changing numpy, scipy or opencv-python-headless changes results in the last digits:
## re-record the reference logs (tools/update_refs.py, tests/data/logs/README.md).
lock:
	@echo "make: resolving $(LOCK) from pyproject.toml with $(UV) (~10 s)"
	@tmp=$$(mktemp -d) && trap 'rm -rf "$$tmp"' EXIT && \
	$(PYTHON) -m venv "$$tmp" && "$$tmp/bin/python" -m pip install --quiet '$(UV)' && \
	"$$tmp/bin/uv" pip compile pyproject.toml --extra dev --extra tools --group bootstrap \
	    --universal --fork-strategy fewest --python-version 3.11 --generate-hashes \
	    --custom-compile-command 'make lock' --quiet $(LOCK_FLAGS) -o $(LOCK)

## Main job on the built-in simulated default: the daemon in SITL (mock autopilot +
## simulated camera over loopback UDP) for 20 s, then accuracy, latency and faults.
run: $(STAMP)
	$(BIN)/tcm-companion sitl --duration 20

## The paper's evaluation: simulate TS/T45/T90 and print the tables (about 3 minutes of
## one core; up to 9 on a busy machine).
demo: $(STAMP)
	$(BIN)/tcm-companion demo

lint: $(STAMP)
	$(BIN)/ruff check tcm_companion tests tools
	$(BIN)/ruff format --check tcm_companion tests tools
	$(BIN)/lint-imports --no-logo

## What mypy checks by name (and whatever that imports): the science, the daemon and its
## SITL runs, the command line, the camera sources.
TYPED := tcm_companion/core tcm_companion/service tcm_companion/sitl tcm_companion/cli \
         tcm_companion/flight_log_setup.py tcm_companion/flightlog/docs.py tcm_companion/flightlog/handle.py \
         tcm_companion/bench/daemon.py tcm_companion/io/cameras tcm_companion/io/sdnotify.py \
         tcm_companion/sim/sources.py tcm_companion/sim/scene/truth_camera.py

typecheck: $(STAMP)
	$(BIN)/mypy $(TYPED)

## MAVProxy's own venv (.venv-interop) for tests/test_interop.py: built once, then cached.
interop-env: $(STAMP)
	$(BIN)/python tools/interop_env.py --quiet

## ArduPilot's kind of Lua (32-bit integers and floats), for the applet's tests: Lua 5.4
## from PyPI's lupa sdist (pinned by hash), compiled with LUA_32BITS (~15 s, once).
lua32: $(BIN)/lua5.4-32

$(BIN)/lua5.4-32: tools/ardupilot/build_lua32.py | $(STAMP)
	$(BIN)/python tools/ardupilot/build_lua32.py --out $@

## What the tests use besides Python, as CI has it (.ci/run): socat (a real pty pair),
## lua5.4 and ArduPilot's 32-bit Lua (the applet), MAVProxy's venv (interop). Installed when
## this machine lets us (root, or sudo without a password); otherwise one line says what
## will be skipped and the command that installs it.
test-tools: $(STAMP)
	@missing=""; for t in socat lua5.4; do command -v $$t >/dev/null 2>&1 || missing="$$missing $$t"; done; \
	if [ -n "$$missing" ]; then \
	    if [ "$$(id -u)" -eq 0 ]; then sudo=""; elif sudo -n true 2>/dev/null; then sudo="sudo"; else sudo=none; fi; \
	    if [ "$$sudo" != none ]; then \
	        echo "make: installing$$missing (apt)"; \
	        $$sudo apt-get update -qq >/dev/null && \
	        $$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null || \
	        echo "make: could not install$$missing (apt): the pty and Lua tests will skip; install with: $${sudo:+$$sudo }apt-get install$$missing"; \
	    else \
	        echo "make: missing$$missing: the pty and Lua tests will skip; install with: sudo apt-get install$$missing"; \
	    fi; \
	fi
	@$(MAKE) -s interop-env || echo "make: MAVProxy's venv could not be built: the MAVProxy interop tests will skip; retry with: make interop-env"
	@$(MAKE) -s lua32 || echo "make: no 32-bit Lua (offline?): the applet's 32-bit checks will skip; retry with: make lua32"

## pytest without PYTHONDONTWRITEBYTECODE: with it set (some images set it) pytest
## rewrites every test module's asserts again in each worker at every run (12 s of the
## fast lane's collection, measured), and the package's .pyc files are never refreshed.
PYTEST := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest

## compileall first: an environment with PYTHONDONTWRITEBYTECODE never refreshes a stale
## .pyc, and a regenerated MAVLink dialect then compiles again in every test's subprocess
## (0.75 s each; measured: the suite 10 min instead of 5).
test: lint typecheck test-tools
	$(BIN)/python -m compileall -q tcm_companion
	$(PYTEST) -n 2 --dist loadgroup -q

## The fast lane while working: every test but the slow ones (real time, subprocesses,
## socat, ArduCopter SITL, more than ~0.5 s of CPU: tests/conftest.py), in under a minute on
## two cores. No lint, no type check, no tool installs; make test stays what CI runs.
## (compileall: as for make test, above.)
test-fast: $(STAMP)
	$(BIN)/python -m compileall -q tcm_companion
	$(PYTEST) -n 2 -m "not slow" -q

## What an attacker or a careless user tries, each asserting nothing was lost: outputs over
## inputs, devices, FIFOs and symlinks; signals mid-write; a full disk; two flights in one
## directory; a spoofing peer on the link (and beside ArduCopter SITL when it is built);
## hostile box datagrams. 71 s on two cores (also part of make test).
test-adversarial: $(STAMP)
	$(PYTEST) -m adversarial -n 2 --dist loadgroup -q

eval: $(STAMP)
	$(BIN)/tcm-companion eval --sim TS T45 T90 --out out/eval

bench: $(STAMP)
	$(BIN)/tcm-companion bench

clean:
	rm -rf $(VENV) .venv-interop .pytest_cache .mypy_cache .ruff_cache .grimp_cache out
