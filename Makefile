# Two commands for a new user (README "Quick start"):
#   make demo   - set up a virtual environment (CPU torch first) and run the demo
#   make test   - set up the same environment and run the test suite
#
# TORCH_INDEX: the pip index of the torch wheel, passed as --index-url when set. On a normal
# machine the CPU build is `make demo TORCH_INDEX=https://download.pytorch.org/whl/cpu`
# (a bare `pip install torch` on Linux pulls the CUDA build, several GB). Left empty, pip's
# configured index is used (this machine provides a local CPU wheel).
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH_VERSION ?= 2.13.0
TORCH_INDEX ?=
STAMP := $(VENV)/.installed
# modules byte-compiled at install (the rest compile on first import), in two processes at
# once: what imports torch, and what does not
WARM_TORCH := torch torch.onnx torchtof torchtof.recon torchtof.operators torchtof.sensor \
	torchtof.adaptive torchtof.apps.demo torchtof.cli onnx onnxruntime kornia
WARM_REST := skimage scipy.stats matplotlib.pyplot pytest xdist hypothesis zarr
WARM_PY := import sys, importlib as i, importlib.util as u; \
	[i.import_module(m) for m in sys.argv[1:] if u.find_spec(m.split('.')[0])]
PYTEST := $(BIN)/python -m pytest -q

.PHONY: demo test test-slow test-all doctest check-core stress bench reproduce docs lint clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	# TORCH_INDEX set: torch first from that index, so that the extras do not pull another
	# build; unset: one pip call with torch pinned (one resolve instead of two: 43 s, where the
	# two calls took 49 s on a 2-core machine)
	$(if $(TORCH_INDEX),$(BIN)/python -m pip install -q --no-compile "torch==$(TORCH_VERSION)" --index-url $(TORCH_INDEX))
	$(BIN)/python -m pip install -q --no-compile $(if $(TORCH_INDEX),,"torch==$(TORCH_VERSION)") -e ".[dev,all]"
	# byte-compile once what the package, its demo and its tests import (pip compiles every
	# file of every package, one at a time: 41 s of the install on a 2-core machine; one
	# process importing them all: 19 s; these two at once: 9 s)
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -c "$(WARM_PY)" $(WARM_TORCH) & a=$$!; \
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -c "$(WARM_PY)" $(WARM_REST) & b=$$!; \
	wait $$a && wait $$b
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/torchtof demo --out demo_out

# the default suite and the package's doctests in one run of two workers (slow tests: make
# test-slow). Each worker runs torch on one thread (tests/conftest.py): two threads per worker
# oversubscribe a 2-core machine. PYTHONDONTWRITEBYTECODE is cleared so that the subprocesses
# the tests start (CLI, examples, README) import the package's compiled modules.
test: $(STAMP)
	PYTHONDONTWRITEBYTECODE= $(PYTEST) -n 2 --dist worksteal -m "not slow" --doctest-modules tests torchtof

doctest: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTEST) --doctest-modules torchtof

test-slow: $(STAMP)
	$(PYTEST) -n 2 -m slow tests

test-all: $(STAMP)
	$(PYTEST) -n 2 tests
	OMP_NUM_THREADS=1 $(PYTEST) --doctest-modules torchtof

# `import torchtof` in a fresh venv holding only the core dependencies (no extras)
check-core:
	rm -rf .venv-core
	$(PY) -m venv .venv-core
	.venv-core/bin/python -m pip install -q "torch==$(TORCH_VERSION)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	.venv-core/bin/python -m pip install -q .
	cd /tmp && $(CURDIR)/.venv-core/bin/python -c "import torchtof, torchtof.cli; \
		torchtof.cli.build_parser(); print('import torchtof with the core dependencies: ok')"

stress: $(STAMP)
	$(PYTEST) tests/stress

bench: $(STAMP)
	$(BIN)/torchtof bench operators
	$(BIN)/torchtof bench recon --quick

reproduce: $(STAMP)
	$(BIN)/torchtof reproduce --quick --out reproduce_out

# rerun the documented commands and rewrite the README's generated tables from their JSON
docs: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python docs/build.py --run

lint: $(STAMP)
	$(BIN)/ruff check torchtof tests examples export benchmarks

clean:
	rm -rf $(VENV) .venv-core demo_out reproduce_out bench_out export_out .pytest_cache
