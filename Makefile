# vdm-aero developer entry points. Every target builds or refreshes .venv from a fresh clone.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
OUT     ?= out
QUICK   ?=

.PHONY: demo test lint typecheck bench bytecode clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first, by exact version: it resolves to the local CPU wheel, never the CUDA build
	$(BIN)/pip install --quiet "torch==2.13.0"
	$(BIN)/pip install --quiet -e ".[sim,train,dask,sitl,dev]"
	# MAVProxy (a third-party peer in the SITL tests) declares vtk/opencv (~640 MB) for GUI modules its
	# routing daemon never loads: install it alone, its daemon's real needs come with the 'sitl' extra
	$(BIN)/pip install --quiet --no-deps "MAVProxy==1.8.75"
	touch $(STAMP)

# the project's own modules byte-compiled once: a checkout has no .pyc, and where PYTHONDONTWRITEBYTECODE is set
# (this machine's image does) every process the tests start would compile them again (~0.4 s of CPU each, ~80 of them)
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q -j 0 vdm_aero vdm_aero_cli sim firmware_bridge bench

# QUICK=1: a first look in about a minute, every stage at reduced size, in $(OUT)/demo-quick
demo: bytecode
	$(BIN)/vdm-aero demo $(if $(QUICK),--quick --out $(OUT)/demo-quick,--out $(OUT)/demo)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

# two workers: the end-to-end tests wait on real-time flights while the other core computes; a module stays on
# one worker (its fixtures are built once), session fixtures are built once for both, and the real-time
# flights start first, in the order tests/conftest.py's REAL_TIME_FIRST gives (loadscope's own reordering off).
# One OpenBLAS thread per process: the workers and the flights' processes already fill both cores, and numpy's
# second BLAS thread only competes with them (the whole suite, one pair of runs: 969 s of CPU against 1,019 s,
# 8 min 31 s against 8 min 53 s; docs/performance.md, "The test suite's time")
test: lint typecheck bytecode
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadscope --no-loadscope-reorder

bench: bytecode
	mkdir -p $(OUT)/bench
	$(BIN)/python -m bench.run_all --out $(OUT)/bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
