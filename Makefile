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

.PHONY: install demo rollout test bench acceptance study-tuning
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

# Shipped predictors on skills they never trained on -> reports/acceptance.md (generates data/acceptance.h5 once).
acceptance: install
	test -f data/acceptance.h5 || $(BIN)/python -m dcm.data.generate dataset=acceptance
	$(BIN)/python bench/acceptance.py

# One command per model study (conf/experiment/<name>.yaml; cost in its header), e.g. `make study-realistic`:
# a Hydra multirun into outputs/studies/<name> (re-running skips finished runs), then reports/study_<name>/.
study-%: install
	$(BIN)/python train.py -m +experiment=$*
	$(BIN)/python -m dcm.model_study outputs/studies/$* --out reports/study_$*

# The tuning study (paper Figs. 10-11) with the demo's predictors (trained on `diverse`): 16 seeds on the
# wavelike skill (~25 min). The paper's protocol, predictors trained on spirals only: PREDICTORS=sim.
PREDICTORS ?= diverse
study-tuning: install
	$(BIN)/python -m dcm.tuning.study ckpt=models/dcm_$(PREDICTORS).ckpt baseline_ckpt=models/baseline_$(PREDICTORS).ckpt \
		reference_json=models/stiffness_ridge_$(PREDICTORS).json seeds=16 hydra.run.dir=outputs/studies/tuning_$(PREDICTORS)
