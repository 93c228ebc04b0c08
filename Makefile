# Two commands set everything up on a fresh machine:
#   make train   creates .venv, installs bfc, and runs the default (JD-CSS-TDTS) training
#   make test    creates .venv, installs bfc with its dev (and joblib, onnx, ray, submitit, optuna, rotorpy,
#                video) extras and, as root where it is missing, Mesa's EGL (videos), and runs the tests
PYTHON ?= python3
VENV ?= .venv
BIN = $(VENV)/bin
# The CPU build of torch: pip takes it from the local wheel cache where there is one.
TORCH ?= torch==2.13.0

.PHONY: venv install gl train test bench lint

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet "$(TORCH)"
	$(BIN)/pip install --quiet -e ".[dev,joblib,onnx,ray,submitit,optuna,rotorpy,video]"
	touch $@

# MuJoCo's headless renderer (videos) needs libEGL with Mesa's drivers; installed where we may (root).
gl:
	@ldconfig -p | grep -q 'libEGL.so.1 ' || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
		&& apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1-mesa-dri >/dev/null; } \
		|| echo "note: no libEGL; video tests skip (apt-get install -y libegl1 libgl1-mesa-dri)"

install: $(VENV)/.installed

train: install
	$(BIN)/python train.py $(ARGS)

test: install gl
	$(BIN)/python -m pytest -p no:cacheprovider $(ARGS)

bench: install
	$(BIN)/python bench/env_throughput.py

lint: install
	$(BIN)/ruff check .
	$(BIN)/lint-imports
