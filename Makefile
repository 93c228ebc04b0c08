# Two commands set everything up on a fresh machine:
#   make train   creates .venv, installs bfc, and runs the default (JD-CSS-TDTS) training
#   make test    creates .venv, installs bfc with its dev (and joblib, onnx, ray, submitit, optuna, rotorpy,
#                video) extras and, as root where they are missing, Mesa's EGL (videos) and a Cortex-M4
#                cross-compiler and emulator (the C export on the Crazyflie's instruction set), and runs the tests
PYTHON ?= python3
VENV ?= .venv
BIN = $(VENV)/bin
# The CPU build of torch: pip takes it from the local wheel cache where there is one.
TORCH ?= torch==2.13.0

.PHONY: venv install gl m4 train test bench lint

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

# The Crazyflie's instruction set: a Cortex-M4F cross-compiler and an emulated board for the C
# export's parity and cost on the target (tests/cortex_m4.py); installed where we may (root).
m4:
	@command -v arm-none-eabi-gcc >/dev/null && command -v qemu-system-arm >/dev/null || { [ "$$(id -u)" = 0 ] \
		&& command -v apt-get >/dev/null && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
		gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm >/dev/null; } \
		|| echo "note: no Cortex-M4 toolchain; its tests skip (apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm)"

install: $(VENV)/.installed

train: install
	$(BIN)/python train.py $(ARGS)

test: install gl m4
	$(BIN)/python -m pytest -p no:cacheprovider $(ARGS)

bench: install
	$(BIN)/python bench/env_throughput.py

lint: install
	$(BIN)/ruff check .
	$(BIN)/lint-imports
