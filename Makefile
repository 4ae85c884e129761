# Two set-up commands: `make demo` and `make test` (both create .venv and install on first use).
# `make test` runs `make lint` (ruff, pinned in the dev extra and configured in pyproject.toml; the docs' names checked
# by scripts/check_doc_names.py) before pytest. Its property tests (hypothesis) run derandomised: the same examples on
# every run (the "ci" profile, tests/conftest.py). `make fuzz` runs only the property tests, with random seeds and
# FUZZ_FACTOR (default 10) times their examples; pin what it finds with @example (a failure prints @reproduce_failure).
PY ?= python3
VENV ?= .venv
VPY := $(VENV)/bin/python
# On the CPU box these resolve to wheels already on disk; an unpinned torch would pull a multi-GB
# CUDA build. On a CUDA workstation override, e.g. `make test TORCH_SPEC=` to keep the venv's torch.
TORCH_SPEC ?= torch==2.14.1 torchvision==0.29.1
NERFSTUDIO_SPEC ?= nerfstudio==1.1.5
PIP := $(VPY) -m pip --disable-pip-version-check
PYTEST_ARGS ?=
# one pytest worker per core; the headless-Chromium tests run on one worker, one after another (tests/_xdist.py)
PYTEST_PARALLEL ?= -n auto --dist loadgroup

FUZZ_FACTOR ?= 10
# Python's default: cache compiled modules (and pytest's assertion-rewritten tests) in __pycache__. Some sandboxes
# export PYTHONDONTWRITEBYTECODE=1; then every pytest worker and every CLI subprocess a test starts compiles all its
# modules again (benchmarks/RESULTS.md, "make test time, fourth pass").
unexport PYTHONDONTWRITEBYTECODE

.PHONY: install demo lint test test-fast fuzz bench clean-venv

$(VPY):
	$(PY) -m venv $(VENV)

$(VENV)/.installed: pyproject.toml Makefile | $(VPY)
	@if [ -n "$(TORCH_SPEC)" ]; then $(PIP) install -q $(TORCH_SPEC); fi
	# nerfstudio 1.1.5 pins gsplat/viser/timm older than what it runs with (see README):
	# install it without its pins, then our own dependency set (pyproject.toml).
	$(PIP) install -q --no-deps $(NERFSTUDIO_SPEC)
	$(PIP) install -q -e ".[dev]"
	$(VPY) -c "import cinenerf_ns, nerfstudio, gsplat, viser, open_clip, cvxpy, osqp, clarabel; print('cinenerf_ns installed')"
	@touch $@

install: $(VENV)/.installed

demo: install
	$(VPY) -m cinenerf_ns.cli.demo

lint: install
	$(VPY) -m ruff check cinenerf_ns tests benchmarks scripts
	$(VPY) scripts/check_doc_names.py docs/ARCHITECTURE.md README.md docs/PLANNER_DEFAULTS.md cinenerf_ns/planner/__init__.py \
		cinenerf_ns

test: install lint
	$(VPY) -m pytest $(PYTEST_PARALLEL) $(PYTEST_ARGS)

test-fast: install
	$(VPY) -m pytest $(PYTEST_PARALLEL) -m "not slow and not browser" $(PYTEST_ARGS)

fuzz: install
	FUZZ_FACTOR=$(FUZZ_FACTOR) $(VPY) -m pytest $(PYTEST_PARALLEL) -m "hypothesis and not slow and not browser" \
		--hypothesis-profile=fuzz $(PYTEST_ARGS)

bench: install
	$(VPY) benchmarks/bench_planner.py

clean-venv:
	rm -rf $(VENV)
