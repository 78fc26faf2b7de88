"""Shared fixtures. ``tiny_dataset_path`` generates the ``tiny`` preset once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering backend; must precede any robosuite import


@pytest.fixture(scope="session")
def tiny_dataset_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ``tiny`` dataset (tool embodiment, 5 demos x 3 trials, H = 40) in a session temp dir."""
    from dcm.data.generate import ensure_dataset

    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    return ensure_dataset("tiny", path, overrides=["workers=1", "progress=false"])


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small DCM (T = 5) trained for a few steps: enough to exercise tuning, not to be accurate."""
    import lightning as L

    from dcm.data.datamodule import DCMDataModule
    from dcm.models.dcm import DCM

    dm = DCMDataModule(tiny_dataset_path, batch_size=4, expect_control_hz=20.0)
    dm.setup("fit")
    L.seed_everything(0)
    model = DCM(net={"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2}, diffusion_steps=5,
                data_spec={"control_hz": dm.control_hz})
    model.fit_normalizers(*dm.train_arrays())
    trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=5, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    path = tmp_path_factory.mktemp("tiny_ckpt") / "dcm.ckpt"
    trainer.save_checkpoint(path)
    return path
