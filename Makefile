# bptsb_ros: two commands do everything on a fresh machine (Debian, Python 3.11, no ROS installed):
#   make demo   train a small agent, run it, write plots and an animation
#   make test   lint and the test suite
# Both bootstrap .venv on their first run (torch first, then the package with its dependencies and
# ROS 2 Jazzy from the ros-jazzy-* wheels) and skip that step on later runs.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help
.DELETE_ON_ERROR:

PYTHON ?= python3
PYTEST_ARGS ?=
# pytest-xdist processes for make test; whole test files go to one process (--dist loadfile), so a module's shared
# launch or trained agent is made once. TEST_WORKERS=0 runs the suite in this one process.
TEST_WORKERS ?= 2
MUTATION_ARGS ?=
TORCH_VERSION := 2.13.0
VENV := .venv
VENV_ABS := $(abspath $(VENV))
VPY := $(VENV)/bin/python
PIP := $(VPY) -m pip
STAMP := $(VENV)/.bptsb-install.stamp
# The package is installed editable: code changes need no reinstall, but changes to what gets installed do.
INSTALL_INPUTS := Makefile pyproject.toml setup.py setup.cfg MANIFEST.in package.xml resource/bptsb_ros \
	$(wildcard launch/*.launch.py) $(wildcard config/*.yaml) $(wildcard config/*.json)

# DDS discovery stays on this host; the domain can be overridden (tests pick their own private one).
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42
# The venv is an ament prefix (see setup.py): let ament_index find bptsb_ros there, as a sourced ROS install would.
export AMENT_PREFIX_PATH := $(VENV_ABS)$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))
export PIP_DISABLE_PIP_VERSION_CHECK := 1
export PIP_PROGRESS_BAR := off

# This machine's pip config names local package indexes that lack most projects; pip warns once per project.
PIP_FILTER := sed -u -e "/Location 'file:.*' is ignored/d"

.PHONY: help venv test lint mutation demo bench docs check-install clean distclean

help:
	@echo "make demo       train a small Lissajous agent, simulate it, write plots and an animation"
	@echo "make test       ruff + pytest on 2 processes (bootstraps .venv on the first run; PYTEST_ARGS='-x -k name' narrows it)"
	@echo "make venv       create/refresh .venv (torch $(TORCH_VERSION), bptsb_ros[train,ros,dask,dev])"
	@echo "make lint       ruff check"
	@echo "make mutation   apply each listed one-line bug to a temporary copy and check that the tests catch it"
	@echo "make bench      speed benchmark -> bench.json"
	@echo "make docs       build the documentation site (mkdocs, warnings are errors) -> site/"
	@echo "make check-install  build the wheel and sdist, install them into fresh venvs, use them from elsewhere"
	@echo "make clean      remove build outputs and caches; make distclean also removes .venv and runs/"

venv: $(STAMP)

$(STAMP): $(INSTALL_INPUTS)
	@if [ ! -x $(VPY) ]; then echo "creating $(VENV) with $$($(PYTHON) --version)"; $(PYTHON) -m venv $(VENV); fi
	$(PIP) install "torch==$(TORCH_VERSION)" 2>&1 | $(PIP_FILTER)
	$(PIP) install -e ".[train,ros,dask,dev]" 2>&1 | $(PIP_FILTER)
	$(VPY) -c "import torch, rclpy, bptsb_ros; print('venv ready: torch', torch.__version__)"
	@touch $@

lint: venv
	$(VENV)/bin/ruff check .

test: venv
	$(VENV)/bin/ruff check .
	$(VPY) -m pytest -ra -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS) tests/

# Mutants and their tests are listed in scripts/mutation_check.py (MUTANTS); exit 1 if one survives.
mutation: venv
	$(VPY) scripts/mutation_check.py $(MUTATION_ARGS)

demo: venv
	bash scripts/demo.sh

bench: venv
	$(VENV)/bin/bptsb bench --out bench.json

# mkdocs.yml at the root, pages in docs/, the API reference from the docstrings (mkdocstrings reads the source
# statically: nothing is imported). NO_MKDOCS_2_WARNING silences mkdocs-material's banner about MkDocs 2.0.
docs: venv
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

# The package as a user installs it: wheel + sdist (twine check), fresh venvs (training route with the CPU torch,
# light route without torch), the README's example and a smoke reproduction from another folder; prints sizes.
check-install: venv
	bash scripts/check_install.sh

clean:
	rm -rf build install log dist .eggs *.egg-info .pytest_cache .ruff_cache bench.json site
	find . -path ./$(VENV) -prune -o -type d -name __pycache__ -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV) runs
