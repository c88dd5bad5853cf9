# vdm-aero developer entry points. Every target builds or refreshes .venv from a fresh clone.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
OUT     ?= out

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

demo: $(STAMP)
	$(BIN)/vdm-aero demo --out $(OUT)/demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

test: lint typecheck
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	mkdir -p $(OUT)/bench
	$(BIN)/python -m bench.run_all --out $(OUT)/bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
