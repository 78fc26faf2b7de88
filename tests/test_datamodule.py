"""DataModule: channel layout, splits from masks, seeded usage rate, train-split statistics, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_models_synthetic import write_synthetic_dataset

from dcm.data.datamodule import DataModuleError, DCMDataModule
from dcm.data.schema import DatasetError, cond_channel_names, load_dataset, target_channel_names, write_dataset
from dcm.models.normalizer import ChannelNormalizer


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("dm") / "synth.h5", horizon=12)


def test_batches_hold_raw_conditions_in_documented_order(synth: Path) -> None:
    dm = DCMDataModule(synth, batch_size=5)
    dm.setup("fit")
    raw = load_dataset(synth, "train")
    batch = next(iter(dm.val_dataloader()))
    assert batch["cond"].shape[-1] == 24 and batch["target"].shape[-1] == 6
    train = dm.split("train")
    np.testing.assert_array_equal(train.cond[0, :, 18:].numpy(), raw.arrays["K"][0])
    np.testing.assert_array_equal(train.cond[0, :, 6:12].numpy(), raw.arrays["F_demo"][0])
    np.testing.assert_array_equal(train.target[0].numpy(), raw.arrays["F_obs"][0])
    assert len(cond_channel_names()) == 24 and cond_channel_names()[18] == "K.Kx_Npm"
    assert target_channel_names()[2] == "F_obs.Fz_N"
    assert len(dm.split("valid")) == 6 and len(dm.split("test")) == 6


def test_usage_rate_is_seeded_subset(synth: Path) -> None:
    a = DCMDataModule(synth, usage_rate=0.25, seed=3)
    b = DCMDataModule(synth, usage_rate=0.25, seed=3)
    c = DCMDataModule(synth, usage_rate=0.25, seed=4)
    names = [dm.split("train").names for dm in (a, b, c)]
    assert len(names[0]) == 6 and names[0] == names[1] and names[0] != names[2]
    assert set(names[0]) <= set(load_dataset(synth, "train").names)
    assert len(DCMDataModule(synth, usage_rate=1e-6).split("train")) == 1  # never empty


@pytest.mark.parametrize("rate", [0.0, -0.5, 1.5])
def test_bad_usage_rate(synth: Path, rate: float) -> None:
    with pytest.raises(DataModuleError, match="usage_rate"):
        DCMDataModule(synth, usage_rate=rate)


def test_normaliser_maps_train_split_to_unit_range(synth: Path) -> None:
    dm = DCMDataModule(synth)
    cond, _ = dm.train_arrays()
    flat = cond.reshape(-1, 24)
    c_lo, c_hi = flat.min(0).values.numpy(), flat.max(0).values.numpy()
    norm = ChannelNormalizer(24).fit_data(cond)
    y = norm.normalize(dm.split("train").cond)
    assert float(y.min()) >= -1 - 1e-5 and float(y.max()) <= 1 + 1e-5
    const = (c_hi - c_lo) < 1e-6  # e.g. rotational stiffness, tool orientation
    assert const.any() and torch.all(y[..., torch.as_tensor(const)] == 0)
    assert torch.allclose(norm.unnormalize(y), dm.split("train").cond, atol=1e-4)


def test_empty_split_and_control_rate_errors(tmp_path: Path, synth: Path) -> None:
    with pytest.raises(DatasetError, match="control rate"):
        DCMDataModule(synth, expect_control_hz=10.0).setup("fit")
    raw = load_dataset(synth, None)
    trajs = [dict({f: raw.arrays[f][i] for f in raw.arrays}, L_task=1.0, L_comp=1.0, name=n)
             for i, n in enumerate(raw.names)]
    empty = tmp_path / "novalid.h5"
    write_dataset(empty, trajs, {"train": raw.names[:5], "valid": [], "test": raw.names[5:]}, {"control_hz": 20.0})
    with pytest.raises(DatasetError, match="'valid' is empty"):
        DCMDataModule(empty).setup("fit")


def test_bad_stage(synth: Path) -> None:
    with pytest.raises(DataModuleError, match="stage"):
        DCMDataModule(synth, stage="posttrain")
