# Two commands for a new user (README "Quick start"):
#   make demo   - set up a virtual environment (CPU torch first) and run the demo
#   make test   - set up the same environment and run the test suite
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH_VERSION ?= 2.13.0
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow test-all stress bench reproduce lint clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# The CPU build of torch first: a bare `torch` requirement would pull GBs of CUDA wheels.
	$(BIN)/python -m pip install -q "torch==$(TORCH_VERSION)"
	$(BIN)/python -m pip install -q -e ".[dev,plot]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/torchtof demo --out demo_out

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m "not slow"

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

stress: $(STAMP)
	$(BIN)/python -m pytest -q tests/stress

bench: $(STAMP)
	$(BIN)/torchtof bench operators
	$(BIN)/torchtof bench recon --quick

reproduce: $(STAMP)
	$(BIN)/torchtof reproduce --quick --out reproduce_out

lint: $(STAMP)
	$(BIN)/ruff check torchtof tests examples export benchmarks

clean:
	rm -rf $(VENV) demo_out reproduce_out bench_out .pytest_cache
