# Set-up on a fresh machine needs only Python >= 3.11 and make:
#   make demo   # creates .venv, installs reflecto, runs the main job on shipped data
#   make test   # same bootstrap, then the test suite
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/demo
SHARED ?= ../shared/data

.PHONY: all demo test test-slow fuzz bench sysdeps clean docs

all: demo

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev,render]'
	@$(MAKE) --no-print-directory sysdeps
	@# compile the Numba kernels into their cache once, so that no timing a user reads includes it
	@echo "compiling the kernels (once)"
	@$(BIN)/reflecto simulate examples/ggx-plastic.json --device as-built --tilt 2 -o $(VENV)/warm-up/capture -q
	@$(BIN)/reflecto reconstruct $(VENV)/warm-up/capture --nominal -o $(VENV)/warm-up/model.reflecto -q >/dev/null
	@$(BIN)/reflecto simulate examples/brushed-asymmetric.toml -o $(VENV)/warm-up/brushed -q
	@$(BIN)/reflecto reconstruct $(VENV)/warm-up/brushed -o $(VENV)/warm-up/brushed.reflecto -q >/dev/null
	@rm -rf $(VENV)/warm-up
	@# and reflecto's bytecode: where PYTHONDONTWRITEBYTECODE is set (CI images) every process
	@# would otherwise compile the sources again (about 0.3 s of each command's start)
	@$(BIN)/python -m compileall -q src >/dev/null
	@touch $(STAMP)

# Optional system packages, never fatal:
# - LLVM >= 16 lets Mitsuba 3 use its vectorised llvm_ad_rgb variant (else scalar_rgb);
# - Chromium runs the HTML report's browser test (skipped without it).
APT_INSTALL = DEBIAN_FRONTEND=noninteractive apt-get install -y -qq
sysdeps:
	@if ls /usr/lib/*/libLLVM-1[6-9]*.so* >/dev/null 2>&1 || ls /usr/lib/*/libLLVM-2[0-9]*.so* >/dev/null 2>&1; then \
	  echo "LLVM >= 16 found"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing libllvm19 (optional, for Mitsuba llvm_ad_rgb)"; \
	  ( $(APT_INSTALL) libllvm19 >/dev/null 2>&1 || \
	    ( apt-get update -qq >/dev/null 2>&1 && $(APT_INSTALL) libllvm19 >/dev/null 2>&1 ) ) \
	  || echo "warning: libllvm19 not installed; Mitsuba will use scalar_rgb"; \
	else \
	  echo "note: no LLVM >= 16 and no root apt-get; Mitsuba will use scalar_rgb"; \
	fi
	@if command -v chromium >/dev/null || command -v chromium-browser >/dev/null; then \
	  echo "Chromium found"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing chromium (optional, for the HTML report test)"; \
	  ( $(APT_INSTALL) chromium >/dev/null 2>&1 || \
	    ( apt-get update -qq >/dev/null 2>&1 && $(APT_INSTALL) chromium >/dev/null 2>&1 ) ) \
	  || echo "warning: chromium not installed; the report's browser test will be skipped"; \
	else \
	  echo "note: no chromium and no root apt-get; the report's browser test will be skipped"; \
	fi

demo: $(STAMP)
	@mkdir -p $(OUT)
	$(BIN)/reflecto info examples/ggx-plastic.json
	$(BIN)/reflecto info $(SHARED)/rgl/vch_golden_yellow_rgb.bsdf
	$(BIN)/reflecto info $(SHARED)/merl-nbrdf/alum-bronze.h5
	$(BIN)/reflecto tabulate $(SHARED)/merl-nbrdf/alum-bronze.h5 -o $(OUT)/alum-bronze.binary
	$(BIN)/reflecto info $(OUT)/alum-bronze.binary
	$(BIN)/python examples/model_demo.py $(OUT)
	$(BIN)/reflecto layout --plot $(OUT)/layout-coverage.png
	$(BIN)/reflecto simulate examples/ggx-plastic.json --device as-built --tilt 3 --seed 1 -o $(OUT)/capture -q
	$(BIN)/reflecto simulate-calibration --device as-built -o $(OUT)/calib -q
	$(BIN)/reflecto calibrate $(OUT)/calib -o $(OUT)/as-built.npz
	$(BIN)/reflecto reconstruct $(OUT)/capture --calibration $(OUT)/as-built.npz -o $(OUT)/ggx-plastic.reflecto
	$(BIN)/reflecto info $(OUT)/ggx-plastic.reflecto
	$(BIN)/reflecto simulate examples/brushed-asymmetric.toml -o $(OUT)/brushed -q
	$(BIN)/reflecto reconstruct $(OUT)/brushed -o $(OUT)/brushed.reflecto
	$(BIN)/reflecto simulate examples/ggx-plastic.json -o $(OUT)/flat -q
	$(BIN)/reflecto reconstruct $(OUT)/flat -o $(OUT)/flat.reflecto
	$(BIN)/reflecto export $(OUT)/ggx-plastic.reflecto -o $(OUT)/ggx-plastic.bsdf
	$(BIN)/reflecto render $(OUT)/ggx-plastic.bsdf --scene teapot-env --title "ggx-plastic, reconstructed from a hand-held as-built capture: Mitsuba 3, studio map" -o $(OUT)/ggx-plastic-teapot.png
	$(BIN)/reflecto report $(OUT)/ggx-plastic.reflecto --ref examples/ggx-plastic.json -o $(OUT)/report
	@echo "demo done: open $(OUT)/report/index.html"

# lint (ruff: pycodestyle, pyflakes, isort, bugbear, pydocstyle) and types (mypy) first:
# pyproject.toml holds their settings; the tests run on two worker processes (pytest-xdist)
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -q -n 2 -m "not slow"

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# Fuzz campaign over every loader and file-reading command: prints the
# input kind × outcome table; exits 1 on any traceback, crash, hang, memory blow-up,
# corrupt input accepted or message that does not name the file. ~2-4 min on 2 cores.
FUZZ_CASES ?= 600
FUZZ_SEED ?= 1
fuzz: $(STAMP)
	$(BIN)/python tests/test_fuzz.py --cases $(FUZZ_CASES) --seed $(FUZZ_SEED) --work out/fuzz

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_model.py
	$(BIN)/python benchmarks/bench_instrument.py
	$(BIN)/python benchmarks/bench_reconstruct.py
	$(BIN)/python benchmarks/bench_render.py

clean:
	rm -rf $(VENV) out .pytest_cache

# The numbers README.md and docs/ quote, rewritten from the result files (docs/sweep-*.csv)
docs: $(STAMP)
	$(BIN)/python studies/docs_numbers.py
