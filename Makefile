# Two commands do all the set-up on a fresh Debian machine:
#   make demo   set up, then render the Cornell box with every integrator (PNGs, contact sheet) and a walkthrough from one solve (GIF)
#   make test   set up, then run the test suite's default tier (two processes, a file each at a time, the longest first; 25 min on 2 cores where every kernel compiles anew, measured 2026-12-07: docs/testing.md)
#   make test-extended   the suite with its extended tier (further cells and cases: docs/testing.md)
# and: make quick (the quick verification table), make verify (the full one)
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup demo quick test test-extended verify benchmarks clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	bash .ci/ensure_llvm.sh
	bash .ci/ensure_browser.sh
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[all]"
	touch $@

demo: setup
	$(VENV)/bin/mi-plugins demo --out reports/demo

quick: setup
	$(VENV)/bin/mi-plugins verify --quick --report reports/quick

verify: setup
	$(VENV)/bin/mi-plugins verify --report reports/full

test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --durations=25

test-extended: setup
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --extended --durations=25

clean:
	rm -rf $(VENV) reports build *.egg-info
