# Two commands a new user needs: `make demo` and `make test`.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SETUP := host/pyproject.toml target/camera/pyproject.toml simulator/pyproject.toml requirements-dev.txt

.PHONY: demo test lint bench clean flash-stage

$(STAMP): $(SETUP)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e 'target/camera[fast,v4l2]' -e host -e simulator -r requirements-dev.txt
	touch $@

demo: $(STAMP)
	$(BIN)/python -m elphel_sim.demo --out out

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# pytest exits 5 when it collected no tests; make treats that as a failure, as it should.
# Four pytest-xdist workers on two cores: most of the suite's wall time is tests waiting on
# real time (daemons starting, frame clocks, stage moves), and four workers halve it.
# --max-worker-restart=0: a worker that dies (killed for memory, a crash) fails the run at
# once (pytest-xdist 3.8 can hang for ever after replacing a dead worker,
# pytest-dev/pytest-xdist#1323, #1378).
# Two runs: the daemon's tests first, then the rest in fresh workers, so that the rest's
# rigs (child processes) never run beside the schemathesis runs' peaks (up to 3 GB a
# worker). tests/conftest.py fails a test that leaves a simulated board open or a thread
# it started running: a leak is a failed test, not a machine out of memory.
# --maxschedchunk 1: the tests marked slow are collected first (tests/conftest.py), and
# each worker takes the next test as it frees up, so the long ones spread over the
# workers at the start (by default the first worker's first chunk would hold them all).
test: $(STAMP) lint
	$(BIN)/pytest -n 4 --max-worker-restart=0 tests/camd
	$(BIN)/pytest -n 4 --max-worker-restart=0 --maxschedchunk 1 --durations 15 --ignore=tests/camd

bench: $(STAMP)
	@for b in bench/[!_]*.py; do echo "== $$b" >&2; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) out .mypy_cache .ruff_cache .pytest_cache

# Copy the stage firmware onto an ESP8266 that already runs MicroPython:
#   make flash-stage PORT=/dev/ttyUSB0 [CONFIG=stage.json]   (see docs/stage.md)
MPREMOTE ?= mpremote
STAGE_FW := $(filter-out target/esp8266/stage.json.example,$(wildcard target/esp8266/*.py))
flash-stage:
	@test -n "$(PORT)" || { echo "usage: make flash-stage PORT=/dev/ttyUSB0 [CONFIG=stage.json]" >&2; exit 2; }
	$(MPREMOTE) connect $(PORT) cp $(STAGE_FW) : $(if $(CONFIG),+ cp $(CONFIG) :stage.json) + reset
