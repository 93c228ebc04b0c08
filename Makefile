# Two commands set everything up on a fresh machine:
#   make train   creates .venv, installs bfc, and runs the default (JD-CSS-TDTS) training
#   make test    creates .venv, installs bfc with its dev (and joblib, onnx, ray, submitit, optuna) extras, and runs the tests
PYTHON ?= python3
VENV ?= .venv
BIN = $(VENV)/bin
# The CPU build of torch: pip takes it from the local wheel cache where there is one.
TORCH ?= torch==2.13.0

.PHONY: venv install train test bench lint

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet "$(TORCH)"
	$(BIN)/pip install --quiet -e ".[dev,joblib,onnx,ray,submitit,optuna]"
	touch $@

install: $(VENV)/.installed

train: install
	$(BIN)/python train.py $(ARGS)

test: install
	$(BIN)/python -m pytest -p no:cacheprovider $(ARGS)

bench: install
	$(BIN)/python bench/env_throughput.py

lint: install
	$(BIN)/ruff check .
	$(BIN)/lint-imports
