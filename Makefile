# Two entry points for a fresh clone (see README):  `make repro`  and  `make test`.
# Both create .venv when missing and install the pinned versions from requirements.lock.
# torch is pinned to the CPU build 2.13.0; GPU users: see README "Installing for a GPU".

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  ?= torch==2.13.0
STAMP  := $(VENV)/.installed
# DVC stage commands call `python`: make it the venv's.
export PATH := $(abspath $(VENV))/bin:$(PATH)

.PHONY: install repro test lint bench gpu-check paper cpu clean-venv mlflow-compare

$(STAMP): pyproject.toml requirements.lock
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q --no-compile "$(TORCH)"
	$(BIN)/python -m pip install -q --no-compile -r requirements.lock
	@# the bytecode pip would write one file at a time, on every core (a failure skips that file, as in pip),
	@# but not of the packages' own test suites (a fifth of the files), which nothing here imports
	$(BIN)/python -c "import compileall, re, sys; compileall.compile_dir(sys.argv[1], quiet=2, workers=0, \
	  rx=re.compile('/tests?/'))" $(VENV)/lib
	@# Open3D (TSDF fusion for `f2depth reconstruct`) loads libusb-1.0 from the system.
	@ldconfig -p | grep -q libusb-1.0 || { if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	  else echo "NOTE: install libusb-1.0 (Debian/Ubuntu: sudo apt-get install libusb-1.0-0) for f2depth reconstruct"; fi; }
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	@touch $(STAMP)

install: $(STAMP)

repro: $(STAMP)
	$(BIN)/dvc repro
	@# dvc repro leaves the new outputs as copies beside the cache: link them to it (one copy on disk)
	$(BIN)/dvc checkout --relink --quiet

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -n 2 --maxschedchunk 2 --durations=15

bench: $(STAMP)
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# CUDA correctness, throughput and a projected `make paper` time on one GPU (reports/benchmarks/).
gpu-check: $(STAMP)
	$(BIN)/python benchmarks/gpu_check.py --device cuda --out reports/benchmarks

# MLflow's compare view of the latest pipeline's evaluate runs -> docs/images/mlflow_compare.png (headless
# Chromium; `python tools/mlflow_compare.py --serve` opens the UI on the runs instead).
mlflow-compare: $(STAMP)
	$(BIN)/python tools/mlflow_compare.py

paper: $(STAMP)
	$(BIN)/python -m f2depth.profile paper

cpu: $(STAMP)
	$(BIN)/python -m f2depth.profile cpu

clean-venv:
	rm -rf $(VENV)
