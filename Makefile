# Self-installing entry points: every target builds .venv from a fresh clone when needed.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.mocapgraph-installed
BUILD_INPUTS := $(wildcard native/*.cpp native/*.h) CMakeLists.txt pyproject.toml

.PHONY: install demo test test-all bench clean

install: $(STAMP)

$(STAMP): $(BUILD_INPUTS)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "installing mocapgraph into $(VENV) (first time: a few minutes)"
	$(PY) -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install --quiet --disable-pip-version-check "scikit-build-core>=0.10" "nanobind>=2.0"
	$(PY) -m pip install --quiet --disable-pip-version-check --no-build-isolation -e '.[test]'
	@touch $(STAMP)

demo: install
	$(VENV)/bin/mocapgraph demo

test: install
	$(PY) -m pytest -q

test-all: install
	$(PY) -m pytest -q -m "slow or not slow"

bench: install
	$(VENV)/bin/mocapgraph bench body --json

clean:
	rm -rf build $(VENV) .pytest_cache
