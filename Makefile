# Quick start: `make run` and `make test` work on a fresh machine with only Python 3.11.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test lint bench validate clean venv

# --no-compile: Python compiles a module's bytecode when it is first imported, so the set-up
# does not compile every installed file (test suites and modules the project never imports).
$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "Python 3.11 is required (python3.11 not found)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet --no-compile -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

run: $(STAMP)
	$(VENV)/bin/pcvfe simulate

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# One worker per core (pytest-xdist); worksteal hands half of a busy worker's queue to an idle
# one, so a module's fixture is mostly made once while the long workbench proofs still spread.
test: lint
	$(VENV)/bin/pytest -q -n auto --dist worksteal

# Timed claims and peers. The peers: pyproject extra `peers`, sysidentpy without its numpy cap.
bench: $(STAMP)
	$(PY) -m pip install --quiet -e ".[peers]"
	$(PY) -m pip install --quiet --no-deps sysidentpy==0.9.0
	$(PY) benchmarks/run_all.py

# The accuracy checks, each against its target (VALIDATE_ARGS=--quick for a shorter pass).
validate: $(STAMP)
	$(PY) validation/run_all.py $(VALIDATE_ARGS)

clean:
	rm -rf $(VENV) build *.egg-info runs
