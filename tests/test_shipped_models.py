"""The predictors shipped in models/: present, loadable by this code version, self-describing, and described
by a card that matches the files."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from dcm.data.recording import Recording, file_recording, preset_recording, recording
from dcm.models.checkpoint import card_markdown, checkpoint_card
from dcm.models.configuration import CheckpointVersionWarning
from dcm.models.predict import load_model, predict_task_loss, trained_on

MODELS = Path(__file__).resolve().parents[1] / "models"
RESEARCH_PRESETS = f"hydra.searchpath=[file://{MODELS.parent / 'studies' / 'conf'}]"  # studies/conf/dataset/
SHIPPED = ("dcm_diverse_contact.ckpt", "dcm_diverse_contact_one_step.ckpt", "baseline_diverse_contact.ckpt",
           "stiffness_ridge_diverse_contact.json", "dcm_realistic.ckpt")


def test_every_documented_predictor_is_shipped_and_the_card_matches_the_files() -> None:
    assert sorted(path.name for path in MODELS.iterdir()) == sorted([*SHIPPED, "README.md"])
    assert (MODELS / "README.md").read_text() == card_markdown(MODELS), \
        "models/README.md is stale: python -m dcm.models.checkpoint card models/"


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_predictor_loads_silently_and_scores_schedules(name: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", CheckpointVersionWarning)
        predictor = load_model(MODELS / name)
    if name.endswith(".ckpt"):
        card = checkpoint_card(MODELS / name)
        assert card["dataset"]["plan_fingerprint"] and card["train_command"].startswith("python train.py")
        assert (MODELS / name).stat().st_size < 8e6
    rng = np.random.default_rng(0)
    x_demo, F_demo, x_attr = (rng.normal(scale=0.01, size=(2, 160, 6)) for _ in range(3))
    K = np.full((2, 160, 6), 800.0)
    loss = predict_task_loss(predictor, x_demo, F_demo, x_attr, K)
    assert loss.shape == (2,) and np.isfinite(loss).all()


def _research_recording(name: str) -> Recording:
    """The recording of a research preset (studies/conf/dataset), which the product's conf/ does not hold."""
    from dcm.data.generate import compose_config

    return recording(compose_config(name, [RESEARCH_PRESETS]).dataset)


def test_every_shipped_predictor_names_the_recording_of_its_training_demos(tiny_dataset_path: Path) -> None:
    """What `make acceptance` pairs predictors with held-out files on, and what tune.py checks the new demo
    against: the *_contact presets record 12 s demos with a leading demonstrator, the others 8 s without; the
    *_fine ones wipe every bowl on a 192 x 192 grid, the others on each bowl's own."""
    for name in SHIPPED:
        expected = Recording(12.0, True) if "_contact" in name else Recording(8.0, False)
        assert preset_recording(trained_on(MODELS / name)) == expected, name
    assert _research_recording("diverse_contact_fine") == Recording(12.0, True, bowl_grid=192)
    assert file_recording(tiny_dataset_path) == preset_recording("tiny")
    assert preset_recording("no_such_preset") is None


@pytest.mark.parametrize("predictors", sorted({trained_on(MODELS / n) for n in SHIPPED if n.startswith("dcm_")}
                                              | {"diverse_contact_fine"}))  # + a preset on its own bowl grid
def test_make_study_tuning_records_the_skill_as_the_predictors_training_demos(predictors: str) -> None:
    import shutil
    import subprocess

    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    dry = subprocess.run(["make", "-n", "study-tuning", f"PREDICTORS={predictors}"], cwd=MODELS.parent,
                         capture_output=True, text=True, check=True).stdout
    trained = preset_recording(predictors) or _research_recording(predictors)
    assert ("demo.duration_s=12.0 +demo.lead=true" in dry) == (trained[:2] == (12.0, True)), dry
    assert ("'demo.bowl={hfield_res:192,name:medium_192}'" in dry) == (trained.bowl_grid == 192), dry
