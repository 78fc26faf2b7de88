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

# One math thread per test process: two workers with a thread per core each would oversubscribe the cores.
test: install
	$(BIN)/ruff check .
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest tests studies -n auto --dist loadfile

bench: install
	$(BIN)/python bench/sim_throughput.py
	$(BIN)/python bench/model_throughput.py

# Shipped predictors on skills they never trained on -> studies/acceptance/reports/acceptance.md. Generates
# its files once (about 3 min): the held-out wavelike skill and the acceptance skills, recorded as
# `sim`/`diverse` record their demos (8 s) and as the *_contact presets do (12 s, leading demonstrator), and
# the held-out line; the 12 s files once more on the 192 x 192 bowl grid of diverse_contact_fine, where the
# force has converged.
acceptance: install
	test -f data/test_wavelike.h5 || $(BIN)/python -m dcm.data.generate dataset=sim "skills=[wavelike]" out=data/test_wavelike.h5
	test -f data/acceptance.h5 || $(BIN)/python -m dcm.data.generate --config-dir studies/conf dataset=acceptance
	test -f data/test_wavelike_contact.h5 || $(BIN)/python -m dcm.data.generate dataset=diverse_contact "skills=[wavelike]" out=data/test_wavelike_contact.h5
	test -f data/test_line_contact.h5 || $(BIN)/python -m dcm.data.generate dataset=diverse_contact "skills=[line]" out=data/test_line_contact.h5
	test -f data/acceptance_contact.h5 || $(BIN)/python -m dcm.data.generate --config-dir studies/conf dataset=acceptance dataset.duration_s=12.0 +dataset.demo_lead=true out=data/acceptance_contact.h5
	test -f data/test_wavelike_fine.h5 || $(BIN)/python -m dcm.data.generate --config-dir studies/conf dataset=diverse_contact_fine "skills=[wavelike]" out=data/test_wavelike_fine.h5
	test -f data/test_line_fine.h5 || $(BIN)/python -m dcm.data.generate --config-dir studies/conf dataset=diverse_contact_fine "skills=[line]" out=data/test_line_fine.h5
	test -f data/acceptance_fine.h5 || $(BIN)/python -m dcm.data.generate --config-dir studies/conf dataset=acceptance dataset.duration_s=12.0 +dataset.demo_lead=true +dataset.bowl.hfield_res=192 out=data/acceptance_fine.h5
	$(BIN)/python -m studies.acceptance.acceptance

# One command per model study (studies/conf/experiment/<name>.yaml; cost in its header), e.g.
# `make study-realistic`: a Hydra multirun into outputs/studies/<name> (re-running skips finished runs), then
# studies/model_study/reports/study_<name>/.
study-%: install
	$(BIN)/python train.py -m --config-dir studies/conf +experiment=$*
	$(BIN)/python -m studies.model_study outputs/studies/$* --out studies/model_study/reports/study_$*

# The tuning study (paper Figs. 10-11) with the demo's predictors (trained on `diverse_contact`): 16 seeds on
# the wavelike skill, recorded as their training demos were (12 s, leading demonstrator). PREDICTORS=diverse:
# the 8 s predictors; PREDICTORS=sim: the paper's protocol, predictors trained on spirals only. Every
# *_contact* preset (diverse_contact_wide, ...) records at 12 s with the lead; the *_fine ones also wipe the
# wavelike skill's bowl on their 192 x 192 grid.
PREDICTORS ?= diverse_contact
FINE_BOWL := 'demo.bowl={hfield_res:192,name:medium_192}'
RECORDING ?= $(if $(findstring _contact,$(PREDICTORS)),demo.duration_s=12.0 +demo.lead=true) \
	$(if $(findstring _fine,$(PREDICTORS)),$(FINE_BOWL))
study-tuning: install
	$(BIN)/python -m studies.tuning_study.study ckpt=models/dcm_$(PREDICTORS).ckpt baseline_ckpt=models/baseline_$(PREDICTORS).ckpt \
		reference_json=models/stiffness_ridge_$(PREDICTORS).json seeds=16 $(RECORDING) hydra.run.dir=outputs/studies/tuning_$(PREDICTORS)
