# vibro: two commands do everything on a fresh machine.
#   make demo   synthesize a recording and run the whole analysis on it
#   make test   run the test suite
# Both set up what they need first (idempotent; a second run skips what is done).

SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
DEPS_STAMP := $(VENV)/.deps-$(shell cat requirements.txt requirements-nodeps.txt | sha256sum | cut -c1-16)
PTH := $(VENV)/lib/python3.11/site-packages/vibro_src.pth
PACKAGES := vibro_model vibro_io vibro_ros vibro_dic vibro_fit vibro_sim vibro_discrepancy vibro_foxglove vibro_eval vibro_app vibro_bringup
DEMO_DIR ?= demo
PYTEST_ARGS ?=
# test processes (pytest-xdist); each test file runs whole in one worker (module fixtures made once). Three on
# two cores: the multi-process ROS tests wait on streams and discovery part of their time, and a third
# worker fills it. The files run heaviest first (tests/conftest.py, tests/file_costs.json); xdist's own reorder (by
# number of tests per file) is off, as it put the long files with few tests last.
TEST_WORKERS ?= 3

.PHONY: setup demo test lint msgs kernels clean bench FORCE

setup: $(DEPS_STAMP) $(PTH) msgs kernels

$(PY):
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "vibro needs Python 3.11 (ROS 2 Jazzy wheels are cp311); found " + sys.version' 
	$(PYTHON) -m venv $(VENV)

$(DEPS_STAMP): requirements.txt requirements-nodeps.txt | $(PY)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements.txt
	$(PY) -m pip install --disable-pip-version-check -q --no-deps -r requirements-nodeps.txt
	rm -f $(VENV)/.deps-* && touch $@

# Development install of the ament_python packages: their source folders on sys.path
# (a lab PC uses `colcon build` instead; see README). Rewritten whenever the list differs.
PTH_LINES := $(foreach p,$(PACKAGES),$(CURDIR)/src/$(p))
$(PTH): FORCE | $(PY)
	@printf '%s\n' $(PTH_LINES) | cmp -s - $@ 2>/dev/null || printf '%s\n' $(PTH_LINES) > $@

FORCE:

msgs: $(DEPS_STAMP)
	@scripts/build_msgs.sh

# the DIC tracker's numba kernels, compiled once into their cache (loaded in ~0.3 s by every process after)
kernels: $(DEPS_STAMP) $(PTH)
	@$(PY) -c 'from vibro_dic.tracker import compile_kernels; print(f"DIC kernels: ready ({compile_kernels():.1f} s)")'

demo: setup
	@scripts/demo.sh $(DEMO_DIR)

test: setup
	@. scripts/env.sh && $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --durations=15 $(PYTEST_ARGS) tests

# ruff (pyproject.toml): lint, import order, docstring convention; .ci/run runs it before the tests
lint: $(DEPS_STAMP)
	@$(VENV)/bin/ruff check .

BENCH_STAMP := $(VENV)/.bench-$(shell cat requirements-bench.txt | sha256sum | cut -c1-16)

$(BENCH_STAMP): requirements-bench.txt | $(PY)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements-bench.txt
	rm -f $(VENV)/.bench-* && touch $@

bench: setup $(BENCH_STAMP)
	@. scripts/env.sh && for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf build install log $(DEMO_DIR)
