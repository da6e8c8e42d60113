# Self-installing entry points: every target builds .venv from a fresh clone when needed.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.mocapgraph-installed
BUILD_INPUTS := $(wildcard native/*.cpp native/*.h) CMakeLists.txt pyproject.toml

.PHONY: install demo test test-all test-video bench lint clean

install: $(STAMP)

$(STAMP): $(BUILD_INPUTS)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "installing mocapgraph into $(VENV) (first time: a few minutes)"
	$(PY) -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install --quiet --disable-pip-version-check "scikit-build-core>=0.10" "nanobind>=2.0"
	$(PY) -m pip install --quiet --disable-pip-version-check --no-build-isolation -e '.[test]'
	@touch $(STAMP)

# MediaPipe lives in its own venv layered on .venv: its declared dependencies (opencv-contrib,
# jax, protobuf<5) would clash with .venv's; pose detection needs only these pins.
VIDEO_VENV := .venv-video
VIDEO_STAMP := $(VIDEO_VENV)/.mocapgraph-video-installed
VIDEO_PINS := mediapipe==0.10.14 absl-py==2.5.1 attrs==26.1.0 flatbuffers==25.12.19 protobuf==4.25.9
SITE := lib/python3.11/site-packages

$(VIDEO_STAMP): $(STAMP)
	@test -x $(VIDEO_VENV)/bin/python || $(PYTHON) -m venv $(VIDEO_VENV)
	echo "import site; site.addsitedir('$(abspath $(VENV))/$(SITE)')" > $(VIDEO_VENV)/$(SITE)/zz-mocapgraph-main-venv.pth
	$(VIDEO_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps $(VIDEO_PINS)
	@touch $(VIDEO_STAMP)

test-video: $(VIDEO_STAMP)
	$(VIDEO_VENV)/bin/python -m pytest -q tests/test_detect_video.py tests/test_importers.py

# Unused names and import order: the checks every change passes before it is committed.
lint: install
	$(VENV)/bin/ruff check --select F,I --line-length 200 mocapgraph tests

demo: install
	$(VENV)/bin/mocapgraph demo

# The suite runs in two processes (pytest-xdist), a test file each at a time: most tests are
# single-threaded, so two workers use this machine's two cores; TEST_WORKERS=0 runs it serially.
TEST_WORKERS ?= 2
PYTEST := $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test: install
	$(PYTEST)

test-all: install
	$(PYTEST) -m "slow or not slow"

# Speed and accuracy targets live here, not in timed tests; aircap takes about 15 minutes, priors
# (which reads the held-out CMU takes of ../shared/motion/cmu_train) a few, smartmocap about ten, airpose
# two, real (the clip in tests/data/real, both pipelines on both people) about three.
bench: install
	$(VENV)/bin/mocapgraph bench body --json
	$(VENV)/bin/mocapgraph bench aircap --duration 60
	$(VENV)/bin/mocapgraph bench priors --json
	$(VENV)/bin/mocapgraph bench smartmocap --json
	$(VENV)/bin/mocapgraph bench airpose --json
	$(VENV)/bin/mocapgraph bench real --json
	$(VENV)/bin/mocapgraph bench faults --json

clean:
	rm -rf build $(VENV) $(VIDEO_VENV) .pytest_cache
