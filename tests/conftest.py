"""Shared fixtures. ``tiny_dataset_path`` generates the ``tiny`` preset once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering backend; must precede any robosuite import


@pytest.fixture(autouse=True)
def _torch_threads_restored():
    """A test that runs tune(torch_threads=...) in-process changes torch's thread count for the whole process;
    restore it, so no test's numbers depend on which tests ran before it."""
    import torch

    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def tiny_dataset_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ``tiny`` dataset (tool embodiment, 5 demos x 3 trials, H = 40) in a session temp dir."""
    from dcm.data.generate import ensure_dataset

    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    return ensure_dataset("tiny", path, overrides=["workers=1", "progress=false"])


def train_tiny(cls: type, dataset_path: Path, out_path: Path, steps: int, **config) -> Path:
    """Train a small ``cls`` (DCM or Baseline) for ``steps`` on a tiny dataset and save its checkpoint."""
    import lightning as L

    from dcm.data.datamodule import DCMDataModule

    dm = DCMDataModule(dataset_path, batch_size=4, expect_control_hz=20.0)
    dm.setup("fit")
    L.seed_everything(0)
    model = cls(net={"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2},
                data_spec=dm.data_spec, **config)
    model.fit_normalizers(*dm.train_arrays())
    trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=steps, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    trainer.save_checkpoint(out_path)
    return out_path


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small DCM (T = 5) trained for a few steps: enough to exercise tuning, not to be accurate."""
    from dcm.models.dcm import DCM

    return train_tiny(DCM, tiny_dataset_path, tmp_path_factory.mktemp("tiny_ckpt") / "dcm.ckpt", 5,
                      diffusion_steps=5)


def short_wave_demo(tmp_path: Path, **changes) -> Path:
    """The wavelike demo cut to 2 s (0.4 s approach), with ``changes`` to its spec: a tune run in seconds."""
    spec = yaml.safe_load((Path(__file__).resolve().parents[1] / "data/demos/wavelike.yaml").read_text())
    spec["duration_s"], spec["approach_s"] = 2.0, 0.4
    spec.update(changes)
    demo = tmp_path / f"short_wave{len(changes)}.yaml"
    demo.write_text(yaml.safe_dump(spec))
    return demo
