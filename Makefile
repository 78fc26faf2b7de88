# Two entry points: `make demo` (main job) and `make test` (the suite). Each creates .venv when absent.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
export MUJOCO_GL ?= egl

$(BIN)/dcm-installed: pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch first, pinned to the CPU wheel, so no dependency resolution pulls a CUDA build.
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"
	touch $@

.PHONY: install demo rollout test bench
install: $(BIN)/dcm-installed

# The main job: the shipped DCM tunes a path it never saw, robot-free, and the simulator validates the result.
demo: install
	$(BIN)/python tune.py --config-name quickstart

# One simulated rollout of the Panda wiping a bowl, as a picture.
rollout: install
	$(BIN)/python -m dcm.sim.render --out docs/demo_rollout.png

test: install
	$(BIN)/python -m pytest tests

bench: install
	$(BIN)/python bench/sim_throughput.py
	$(BIN)/python bench/model_throughput.py
