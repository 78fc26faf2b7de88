"""The dataset format: round trip, atomic write and clear errors on damaged files (hand-made files, no sim)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from dcm.data.schema import FIELDS, FORMAT_VERSION, DatasetError, load_dataset, write_dataset

H = 12


def _trajectory(rng: np.random.Generator, demo_id: int, failed: bool = False) -> dict:
    traj = {f: rng.normal(size=(H, 6)).astype(np.float32) for f in FIELDS if f != "contact"}
    traj["K"] = np.abs(traj["K"]) * 500 + 100
    traj["contact"] = rng.random(H) > 0.3
    traj.update(L_task=float(rng.random()), L_comp=float(rng.random()), demo_id=demo_id, seed=7,
                demo={"family": "spiral", "turns": 2}, failed=failed,
                failure_reason="diverged" if failed else "")
    return traj


@pytest.fixture()
def hand_made(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    trajs = [_trajectory(rng, demo_id=i // 2, failed=(i == 3)) for i in range(6)]
    path = tmp_path / "hand.h5"
    write_dataset(path, trajs, masks={"train": ["traj_000000", "traj_000001", "traj_000002", "traj_000003"],
                                      "valid": ["traj_000004"], "test": ["traj_000005"]},
                  attrs={"control_hz": 20.0, "embodiment": "tool", "config": "seed: 0\n"})
    return path


def test_round_trip_and_stats(hand_made: Path) -> None:
    train = load_dataset(hand_made, split="train", expect_control_hz=20)
    assert train.names == ["traj_000000", "traj_000001", "traj_000002"]  # failed traj_000003 dropped from mask
    assert train.arrays["F_obs"].shape == (3, H, 6) and train.arrays["F_obs"].dtype == np.float32
    assert train.arrays["contact"].shape == (3, H)
    assert train.horizon == H and train.control_hz == 20.0
    assert train.attrs["format_version"] == FORMAT_VERSION and train.attrs["channels"]["K"][0] == "Kx_Npm"
    assert train.meta[0]["demo"] == {"family": "spiral", "turns": 2}
    # The numerics that wrote it: a changed draw can then be told from a changed library.
    assert train.attrs["packages"]["numpy"] == np.__version__
    assert set(train.attrs["packages"]) == {"python", "numpy", "mujoco", "robosuite"}
    np.testing.assert_array_equal(train.demo_ids, [0, 0, 1])
    np.testing.assert_allclose(train.stats["F_obs"]["mean"], train.arrays["F_obs"].reshape(-1, 6).mean(0), rtol=1e-5)
    everything = load_dataset(hand_made)
    assert "traj_000003" not in everything.names and len(everything) == 5
    assert len(load_dataset(hand_made, include_failed=True)) == 6
    with h5py.File(hand_made) as f:
        assert f["data/traj_000003"].attrs["failure_reason"] == "diverged"
    assert not list(hand_made.parent.glob("*.tmp"))  # no leftover temp file


def test_write_rejects_nan(tmp_path: Path) -> None:
    traj = _trajectory(np.random.default_rng(1), 0)
    traj["F_obs"][2, 1] = np.nan
    with pytest.raises(DatasetError, match=r"traj_000000.*F_obs.*NaN"):
        write_dataset(tmp_path / "x.h5", [traj], {"train": ["traj_000000"]}, {"control_hz": 20.0})
    assert not (tmp_path / "x.h5").exists() and not list(tmp_path.iterdir())


def test_write_rejects_non_positive_stiffness(tmp_path: Path) -> None:
    traj = _trajectory(np.random.default_rng(1), 0)
    traj["K"][4, 2] = 0.0
    with pytest.raises(DatasetError, match=r"traj_000000.*field K.*stiffness must be positive, got 0 .*\[4, 2\]"):
        write_dataset(tmp_path / "x.h5", [traj], {"train": ["traj_000000"]}, {"control_hz": 20.0})
    assert not list(tmp_path.iterdir())


def _copy(src: Path, tmp_path: Path, name: str) -> Path:
    dst = tmp_path / name
    shutil.copy(src, dst)
    return dst


def test_truncated_file(hand_made: Path, tmp_path: Path) -> None:
    broken = _copy(hand_made, tmp_path, "trunc.h5")
    size = broken.stat().st_size
    with open(broken, "r+b") as f:
        f.truncate(size // 2)
    with pytest.raises(DatasetError, match="trunc.h5.*(truncated|corrupt)"):
        load_dataset(broken, split="train")


def test_garbage_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.h5"
    junk.write_bytes(os.urandom(4096))
    with pytest.raises(DatasetError, match="junk.h5"):
        load_dataset(junk)


def test_nan_on_load(hand_made: Path, tmp_path: Path) -> None:
    broken = _copy(hand_made, tmp_path, "nan.h5")
    with h5py.File(broken, "r+") as f:
        f["data/traj_000001/x_attr"][5, 2] = np.inf
    with pytest.raises(DatasetError, match=r"nan.h5.*traj_000001.*x_attr.*NaN or inf.*\[5, 2\]"):
        load_dataset(broken, split="train")


def test_negative_stiffness_on_load(hand_made: Path, tmp_path: Path) -> None:
    broken = _copy(hand_made, tmp_path, "soft.h5")
    with h5py.File(broken, "r+") as f:
        f["data/traj_000002/K"][7, 0] = -150.0
    with pytest.raises(DatasetError, match=r"soft.h5.*traj_000002.*field K.*positive, got -150 .*\[7, 0\]"):
        load_dataset(broken, split="train")


def test_missing_key(hand_made: Path, tmp_path: Path) -> None:
    broken = _copy(hand_made, tmp_path, "missing.h5")
    with h5py.File(broken, "r+") as f:
        del f["data/traj_000002/K"]
    with pytest.raises(DatasetError, match=r"missing.h5.*traj_000002.*field K.*missing"):
        load_dataset(broken, split="train")
    with h5py.File(broken, "r+") as f:
        del f["data/traj_000000"]
    with pytest.raises(DatasetError, match=r"traj_000000.*missing from /data"):
        load_dataset(broken, split="train")


def test_wrong_shape(hand_made: Path, tmp_path: Path) -> None:
    broken = _copy(hand_made, tmp_path, "shape.h5")
    with h5py.File(broken, "r+") as f:
        del f["data/traj_000004/F_demo"]
        f["data/traj_000004/F_demo"] = np.zeros((H - 1, 6), np.float32)
    with pytest.raises(DatasetError, match=r"traj_000004.*F_demo.*shape \(11, 6\), expected \(12, 6\)"):
        load_dataset(broken, split="valid")


def test_version_rate_and_split(hand_made: Path, tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"control_hz.*20.0 Hz, expected 50 Hz"):
        load_dataset(hand_made, split="train", expect_control_hz=50)
    with pytest.raises(DatasetError, match=r"no split 'bogus'"):
        load_dataset(hand_made, split="bogus")
    empty = _copy(hand_made, tmp_path, "empty.h5")
    with h5py.File(empty, "r+") as f:
        del f["mask/test"]
        f["mask/test"] = np.array([], dtype="S")
    with pytest.raises(DatasetError, match=r"mask/test.*empty"):
        load_dataset(empty, split="test")
    future = _copy(hand_made, tmp_path, "future.h5")
    with h5py.File(future, "r+") as f:
        f.attrs["format_version"] = "99"
    with pytest.raises(DatasetError, match=r"future.h5.*format_version.*'99'"):
        load_dataset(future)


def test_config_attribute_reads_back_as_written(tmp_path: Path) -> None:
    """One writer and one reader own the ``config`` root attribute, whoever wrote the file."""
    from dcm.data.schema import read_config, read_root_attrs

    rng = np.random.default_rng(2)
    config = {"log_dir": "/logs", "lowpass_hz": 5.0, "nested": {"a": [1, 2]}}
    path = tmp_path / "c.h5"
    write_dataset(path, [_trajectory(rng, 0)], {"train": ["traj_000000"]}, {"control_hz": 20.0, "config": config})
    assert read_config(read_root_attrs(path), path) == config
    assert read_config(load_dataset(path).attrs, path) == config
    with h5py.File(path, "a") as f:  # a file written with the config as JSON text reads the same
        f.attrs["config"] = '{"log_dir": "/logs", "lowpass_hz": 5.0, "nested": {"a": [1, 2]}}'
    assert read_config(read_root_attrs(path), path) == config
    with h5py.File(path, "a") as f:
        f.attrs["config"] = "- not\n- a mapping\n"
    with pytest.raises(DatasetError, match=rf"file {path}, field config: .*mapping"):
        read_config(read_root_attrs(path), path)
