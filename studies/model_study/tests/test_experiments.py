"""Every study in studies/conf/experiment/ composes for each value it sweeps, and builds the model it would train.

A typo in a sweep (``model.cond_encodng``, a missing net config) would otherwise surface only after the
sweep's earlier runs had spent their hours.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from dcm.training.train import new_model

REPO = Path(__file__).resolve().parents[3]
STUDY_CONF = REPO / "studies" / "conf"
EXPERIMENTS = sorted(p.stem for p in (STUDY_CONF / "experiment").glob("*.yaml"))
# train.yaml is the product's; the experiments join it from the studies' conf dir, as `--config-dir` does
SEARCH_PATH = f"hydra.searchpath=['file://{STUDY_CONF}']"


def _sweep_overrides(name: str) -> list[str]:
    """One override per swept value, each on its own (the sweep's product is these, combined)."""
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("train", overrides=[SEARCH_PATH, f"+experiment={name}"], return_hydra_config=True)
    params = cfg.hydra.sweeper.params or {}
    return [f"{key}={value}" for key, values in params.items() for value in str(values).split(",")]


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_sweep_values_build_their_model(name: str) -> None:
    overrides = _sweep_overrides(name)
    assert overrides, f"studies/conf/experiment/{name}.yaml sweeps nothing"
    for override in overrides:
        with initialize_config_dir(config_dir=str(REPO / "conf")):
            cfg = compose("train", overrides=[SEARCH_PATH, f"+experiment={name}", override])
        assert cfg.study.name == name
        new_model(cfg)  # as train.py builds it: validates every field (unknown keys, bad values), builds the net
