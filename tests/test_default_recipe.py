"""`python train.py` with no overrides trains the shipped DCM's recipe, `model=baseline` the shipped baseline's.

The recipe is what the shipped checkpoint's card records as its training config; settings of the run rather
than of the recipe (the seed, a replicate; paths; devices; Hydra's) are left out of the comparison.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml
from hydra import compose, initialize_config_dir

from dcm.configs import config_diff
from dcm.training.train import LEGACY_DATA_KEYS, planned_config, with_added_option_defaults

REPO = Path(__file__).resolve().parents[1]
RUN_ONLY = ("seed", "resume", "data.path", "hydra", "study", "dataset",  # the dataset is compared by name below
            "trainer.accelerator", "trainer.devices", "trainer.strategy", "trainer.num_nodes",
            "trainer.enable_progress_bar", "metrics.n_plot", "metrics.plot_every_n_evals")
# Settings added after the shipped runs, at the value that trains as those runs did.
ADDED_SINCE = {"data": {"skill_group": 0}, "metrics": {"task_from_s": 0.0}}


def _shipped_config(name: str) -> tuple[dict, dict]:
    raw = torch.load(REPO / "models" / name, map_location="cpu", weights_only=True)
    card = raw["dcm_card"]
    return yaml.safe_load(card["config"]), card


def _planned(overrides: list[str]) -> dict:
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return planned_config(compose("train", overrides=overrides))


@pytest.mark.parametrize(("overrides", "shipped"), [([], "dcm_diverse_contact.ckpt"),
                                                     (["model=baseline"], "baseline_diverse_contact.ckpt")])
def test_the_default_config_is_the_shipped_recipe(overrides: list[str], shipped: str) -> None:
    saved, card = _shipped_config(shipped)
    planned = _planned(overrides)
    assert planned["dataset"]["name"] == saved["data"]["preset"] == card["dataset"]["dataset"]

    saved = with_added_option_defaults(saved, planned)  # model and net options the checkpoint predates
    saved["data"] = {k: v for k, v in saved["data"].items() if k not in LEGACY_DATA_KEYS}
    for group, added in ADDED_SINCE.items():
        for key, value in added.items():
            saved[group].setdefault(key, value)
    assert config_diff(saved, planned, ignore=RUN_ONLY, limit=50) == []


def test_the_baseline_takes_no_dcm_only_option() -> None:
    """input_scaling belongs to the DCM's config: the baseline's recipe has none to differ in."""
    planned = _planned(["model=baseline"])
    assert "input_scaling" not in planned["model"] and planned["model"]["normalization"] == "zscore"
    assert _planned([])["model"]["input_scaling"] == "signal"


def test_a_run_saved_before_the_dataset_group_is_the_same_config(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A sweep re-run over run directories saved with a `data.preset` block skips them instead of refusing
    them as another config (the shipped card's config is such a directory's config.yaml)."""
    from dcm.training.train import with_dataset_group

    monkeypatch.chdir(tmp_path)  # data.path as the old run resolved it: the preset's own file
    saved, _ = _shipped_config("dcm_diverse_contact.ckpt")
    saved["data"]["path"] = str(tmp_path / "data" / "diverse_contact.h5")
    for group, added in ADDED_SINCE.items():
        for key, value in added.items():
            saved[group].setdefault(key, value)
    planned = _planned(["seed=1"])
    old = with_added_option_defaults(with_dataset_group(saved, planned), planned)
    assert config_diff(old, planned, ignore=("resume", "study")) == []
    assert config_diff(old, _planned(["seed=1", "dataset=sim"]), ignore=("resume", "study"))
