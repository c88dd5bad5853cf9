# vdm-aero developer entry points. Every target builds or refreshes .venv from a fresh clone.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
OUT     ?= out
QUICK   ?=

.PHONY: demo test lint typecheck bench clean

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

# QUICK=1: a first look in about a minute, every stage at reduced size, in $(OUT)/demo-quick
demo: $(STAMP)
	$(BIN)/vdm-aero demo $(if $(QUICK),--quick --out $(OUT)/demo-quick,--out $(OUT)/demo)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

# two workers: the end-to-end tests wait on real-time flights while the other core computes; a module stays on
# one worker (its fixtures are built once), session fixtures are built once for both, and the real-time
# flights start first, in the order tests/conftest.py's REAL_TIME_FIRST gives (loadscope's own reordering off)
test: lint typecheck
	$(BIN)/python -m pytest -q -n 2 --dist loadscope --no-loadscope-reorder

bench: $(STAMP)
	mkdir -p $(OUT)/bench
	$(BIN)/python -m bench.run_all --out $(OUT)/bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
