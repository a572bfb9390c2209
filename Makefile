# pfem2x — the two README commands are `make demo` and `make test`.
# Both are idempotent: they install what is missing (Debian packages with
# apt-get, which needs root or sudo; a venv at .venv) and then do their job.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
VENV      ?= .venv
VENV011   ?= .venv-011
PY        := $(VENV)/bin/python
PY011     := $(VENV011)/bin/python
NP        ?= 2
# OpenMPI refuses root without this flag; harmless otherwise.
MPIRUN    ?= mpirun $(shell [ "$$(id -u)" = 0 ] && mpirun --version 2>/dev/null | grep -q "Open MPI" && echo --allow-run-as-root --oversubscribe)
PYTEST_ARGS ?=
LINT_DIRS := $(wildcard pfem2x tests demos benchmarks)

.PHONY: help setup demo test lint format test-serial test-mpi setup-011 test-011 clean

help:
	@echo "make demo      set up (apt + .venv) and run the default scene into runs/demo"
	@echo "make test      set up and run lint + the test suite (serial and mpirun -n $(NP))"
	@echo "make test-011  the same on DOLFINx 0.11 (PyPI wheel, Python 3.12 venv at $(VENV011))"

# setup also compiles the particle kernels into numba's cache (minutes once, after
# install or a change of the kernels; otherwise a file-time check of a fraction of a second).
setup: $(VENV)/.stamp
	@$(PY) -m pfem2x.jit --if-cold

$(VENV)/.stamp: pyproject.toml .ci/setup-system.sh .ci/setup-venv.sh
	bash .ci/setup-system.sh
	bash .ci/setup-venv.sh $(VENV)
	touch $@

demo: setup
	$(VENV)/bin/pfem2x run gaussian-hill --set method.frame=lagrangian --out runs/demo --overwrite

lint: setup
	$(VENV)/bin/ruff check $(LINT_DIRS)
	$(VENV)/bin/ruff format --check $(LINT_DIRS)

test-serial: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

test-mpi: setup
	$(MPIRUN) -n $(NP) $(PY) -m pytest -q -m mpi -p no:cacheprovider $(PYTEST_ARGS)

test: lint test-serial test-mpi

setup-011: $(VENV011)/.stamp
	@$(PY011) -m pfem2x.jit --if-cold

$(VENV011)/.stamp: pyproject.toml .ci/setup-venv-011.sh
	bash .ci/setup-system.sh
	bash .ci/setup-venv-011.sh $(VENV011)
	touch $@

test-011: setup-011
	$(PY011) -m pytest -q $(PYTEST_ARGS)
	$(VENV011)/bin/mpirun -n $(NP) $(PY011) -m pytest -q -m mpi -p no:cacheprovider $(PYTEST_ARGS)

format: setup
	$(VENV)/bin/ruff format $(LINT_DIRS)
	$(VENV)/bin/ruff check --fix $(LINT_DIRS)

clean:
	rm -rf $(VENV) $(VENV011) runs .pytest_cache
