"""Import of real Franka logs: synthetic logs with jitter, other rates, a bias and noise match the clean signal.

The logs are written by the product's robot-log writer (dcm.data.log_writer, also behind dcm-sim-logs) from
analytic signals with rotations, which the simulated tool's trials lack."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from dcm.data.import_logs import LogFormatError, import_logs
from dcm.data.log_writer import RobotConventions, TrialSignals
from dcm.data.schema import load_dataset
from dcm.data.sim_logs import write_episode as write_log_episode
from dcm.models.references import main as references_main

CONTROL_HZ = 20.0
START_S, END_S = 0.2, 6.2  # demo reference span -> H = 121
BIAS = np.array([1.0, -0.7, 2.5, 0.10, -0.05, 0.02])  # base frame, N and N·m
NOISE_STD = np.array([0.5, 0.5, 0.5, 0.02, 0.02, 0.02])


def _ramp(t: np.ndarray) -> np.ndarray:
    """0 before 1 s (free motion), smooth rise to 1 at 2 s."""
    s = np.clip(t - 1.0, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * s)


def clean_pose(t: np.ndarray) -> np.ndarray:
    """Tool-tip pose in the bowl frame: a slow circle, a small tilt."""
    pos = np.stack([0.05 * np.cos(0.8 * t), 0.05 * np.sin(0.8 * t), 0.01 + 0.002 * np.sin(0.3 * t)], axis=1)
    rotvec = np.stack([0.1 * np.sin(0.5 * t), 0.05 + 0 * t, 0.02 * np.cos(0.4 * t)], axis=1)
    return np.column_stack([pos, rotvec])


def clean_wrench(t: np.ndarray) -> np.ndarray:
    """Contact wrench on the tool, bowl axes, torque about the tip; zero in free motion."""
    r = _ramp(t)
    return np.stack([1.5 * np.sin(0.7 * t) * r, -1.0 * np.cos(0.4 * t) * r, 6.0 * r,
                     0.05 * np.sin(t) * r, 0.03 * r, 0.02 * r], axis=1)


def write_episode(root: Path, name: str, rng: np.random.Generator, base_frame: str = "panda_link0") -> None:
    """A synthetic trial written as a Franka logs it: 500 Hz state with ±0.2 ms jitter, the bowl turned 90° in
    the base frame, a 0.1 m tool, O_F_ext_hat_K with a bias and noise, three stiffness phases (Kx != Ky in the
    bowl frame, to check the axis permutation) and a 20 Hz demo reference."""
    obs_t = np.arange(0.0, 6.5, 1e-3)
    demo_t = np.arange(START_S, END_S + 1e-9, 1 / CONTROL_HZ)
    signals = TrialSignals(
        obs_t_s=obs_t, pose=clean_pose(obs_t), wrench=clean_wrench(obs_t),
        command_t_s=np.array([0.0, 2.0, 4.0]), attractor=None,
        stiffness=np.array([[900, 300, 500, 20, 20, 20], [400, 1200, 800, 20, 20, 20], [600, 600, 200, 20, 20, 20.0]]),
        demo_t_s=demo_t, demo=np.column_stack([clean_pose(demo_t), clean_wrench(demo_t) * 1.1]),
        meta={"demo_id": 0, "trial": int(name[-1]), "split": "train" if name[-1] != "2" else "test", "skill": "spiral",
              "free_motion_s": [0.0, 0.9]})
    conventions = RobotConventions(base_frame=base_frame, state_hz=500.0, bias=tuple(BIAS), noise_std=tuple(NOISE_STD))
    write_log_episode(root / name, signals, "csv", conventions, rng)


def _to_row_major(pose_csv: Path) -> None:
    """Rewrite O_T_EE row-major, the mistake the importer must catch."""
    with pose_csv.open() as handle:
        rows = list(csv.reader(handle))
    table = np.array(rows[1:], dtype=np.float64)
    flat = table[:, 1:].reshape(-1, 4, 4, order="F").reshape(-1, 16)
    with pose_csv.open("w", newline="") as handle:
        csv.writer(handle).writerows([rows[0]] + np.column_stack([table[:, 0], flat]).tolist())


def test_import_matches_clean_signal(tmp_path: Path) -> None:
    """Tolerances, from the synthetic noise: the 5 Hz zero-phase 2nd-order Butterworth passes ~5.5 Hz of the
    500 Hz stream's white noise, so 0.5 N becomes ~0.5·sqrt(11/500) ≈ 0.075 N; the bias estimate over 450 samples
    adds ~0.5/sqrt(450) ≈ 0.024 N; the filter's gain error on the < 1 Hz signal is < 0.2 %. Hence force RMSE
    < 0.15 N and max error < 0.4 N (≈ 5 σ), against 0.5 N of raw noise and 2.5 N of bias. Poses are linear
    interpolations of a 1 kHz stream of a slow path: errors < 1e-5 m / rad; the 1e-4 bound leaves margin."""
    rng = np.random.default_rng(0)
    for i in range(3):
        write_episode(tmp_path / "logs", f"episode_{i}", rng)
    out = tmp_path / "real.h5"
    assert import_logs(tmp_path / "logs", out, control_hz=CONTROL_HZ) == 3
    train = load_dataset(out, split="train", expect_control_hz=CONTROL_HZ)
    assert len(train) == 2 and len(load_dataset(out, split="test")) == 1
    grid = START_S + np.arange(train.horizon) / CONTROL_HZ
    assert train.horizon == 121
    expected_force, expected_pose = clean_wrench(grid), clean_pose(grid)
    for k in range(len(train)):
        force_err = train.arrays["F_obs"][k] - expected_force
        assert np.sqrt((force_err[:, :3] ** 2).mean(axis=0)).max() < 0.15
        assert np.abs(force_err[:, :3]).max() < 0.4
        assert np.abs(force_err[:, 3:]).max() < 0.03  # torque: 0.02 N·m noise, same reasoning (≈ 0.003 N·m σ)
        np.testing.assert_allclose(train.arrays["x_obs"][k], expected_pose, atol=1e-4)
    K = train.arrays["K"][0]
    np.testing.assert_allclose(K[grid < 2.0 - 1e-9][0], [900, 300, 500, 20, 20, 20])  # base y -> bowl x
    np.testing.assert_allclose(K[(grid >= 2.0) & (grid < 4.0)][0], [400, 1200, 800, 20, 20, 20])
    np.testing.assert_allclose(train.arrays["F_demo"][0], clean_wrench(grid) * 1.1, atol=1e-5)
    assert train.attrs["import_lowpass_hz"] == 5.0 and train.attrs["import_lowpass_order"] == 2
    assert train.arrays["contact"][0][grid > 2.0].all() and not train.arrays["contact"][0][grid < 0.9].any()
    np.testing.assert_allclose(train.meta[0]["bias_removed"], BIAS, atol=0.1)


def test_import_rejects_bad_frames(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    write_episode(tmp_path / "rowmajor", "episode_0", rng)
    _to_row_major(tmp_path / "rowmajor" / "episode_0" / "pose.csv")
    with pytest.raises(LogFormatError, match=r"episode_0.*pose.*not a rigid transform.*column-major"):
        import_logs(tmp_path / "rowmajor", tmp_path / "x.h5")
    write_episode(tmp_path / "mixed", "episode_0", rng)
    write_episode(tmp_path / "mixed", "episode_1", rng, base_frame="world")
    with pytest.raises(LogFormatError, match="different base frames"):
        import_logs(tmp_path / "mixed", tmp_path / "y.h5")


def test_a_stiffness_reference_fits_on_imported_logs(tmp_path: Path) -> None:
    """The importer's settings are stored as every reader reads a dataset's config."""
    rng = np.random.default_rng(3)
    for i in range(3):
        write_episode(tmp_path / "logs", f"episode_{i}", rng)
    out = tmp_path / "real.h5"
    import_logs(tmp_path / "logs", out, control_hz=CONTROL_HZ)
    ref = references_main(["fit", "--dataset", str(out), "--out", str(tmp_path / "ref.json"), "--n-phases", "3"])
    saved = json.loads(Path(ref).read_text())
    assert saved["phases"]["n_phases"] == 3 and saved["phases"]["method"] is None
