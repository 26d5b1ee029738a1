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

.PHONY: install repro test lint bench paper cpu clean-venv

$(STAMP): pyproject.toml requirements.lock
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH)"
	$(BIN)/python -m pip install -q -r requirements.lock
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	@touch $(STAMP)

install: $(STAMP)

repro: $(STAMP)
	$(BIN)/dvc repro

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -n 2 --durations=15

bench: $(STAMP)
	$(BIN)/python -m benchmarks

paper: $(STAMP)
	$(BIN)/python -m f2depth.profile paper

cpu: $(STAMP)
	$(BIN)/python -m f2depth.profile cpu

clean-venv:
	rm -rf $(VENV)
