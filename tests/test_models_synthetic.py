"""A small synthetic dataset in the real HDF5 format, for model unit tests that must not need MuJoCo.

The wrench follows a learnable rule: a tool pressed along z with stiffness K_z against a surface at
the demo height, so F_obs_z = K_z * penetration of the attractor, with a little friction on x/y.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dcm.data.schema import load_dataset, write_dataset


def write_synthetic_dataset(path: str | Path, n_train: int = 24, n_valid: int = 6, n_test: int = 6,
                            horizon: int = 16, control_hz: float = 20.0, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, horizon)
    trajectories = []
    for i in range(n_train + n_valid + n_test):
        radius = rng.uniform(0.02, 0.06)
        x_demo = np.zeros((horizon, 6), np.float32)
        x_demo[:, 0] = radius * np.cos(4 * t + i)
        x_demo[:, 1] = radius * np.sin(4 * t + i)
        x_demo[:, 2] = 0.5 * (x_demo[:, 0] ** 2 + x_demo[:, 1] ** 2) / 0.1
        F_demo = np.zeros((horizon, 6), np.float32)
        F_demo[:, 2] = rng.uniform(3.0, 8.0)
        K = np.zeros((horizon, 6), np.float32)
        K[:, :3] = rng.uniform(100, 1500, size=3)[None]
        K[horizon // 2:, :3] = rng.uniform(100, 1500, size=3)[None]
        K[:, 3:] = 20.0
        x_attr = x_demo.copy()
        x_attr[:, 2] -= F_demo[:, 2] / K[:, 2]
        F_obs = np.zeros((horizon, 6), np.float32)
        F_obs[:, 2] = np.minimum(K[:, 2] * (x_demo[:, 2] - x_attr[:, 2]), 2.0 + 0.004 * K[:, 2])
        F_obs[:, 0] = -0.3 * F_obs[:, 2] * np.sign(np.gradient(x_demo[:, 0]))
        F_obs[:, 1] = -0.3 * F_obs[:, 2] * np.sign(np.gradient(x_demo[:, 1]))
        F_obs[:, :3] += rng.normal(0, 0.05, size=(horizon, 3))
        L_task = float(np.sqrt(np.mean((F_obs[:, :3] - F_demo[:, :3]) ** 2)))
        trajectories.append(dict(x_demo=x_demo, F_demo=F_demo, x_attr=x_attr, K=K, x_obs=x_demo, F_obs=F_obs,
                                 contact=np.ones(horizon, np.uint8), L_task=L_task,
                                 L_comp=float(np.linalg.norm(K[:, :3], axis=1).mean() / 1000), demo_id=i))
    names = [f"traj_{i:06d}" for i in range(len(trajectories))]
    masks = {"train": names[:n_train], "valid": names[n_train:n_train + n_valid],
             "test": names[n_train + n_valid:]}
    write_dataset(path, trajectories, masks, {"control_hz": control_hz, "embodiment": "synthetic"})
    return Path(path)


def test_synthetic_dataset_loads(tmp_path: Path) -> None:
    path = write_synthetic_dataset(tmp_path / "synth.h5", horizon=12)
    loaded = load_dataset(path, "valid", expect_control_hz=20.0)
    assert len(loaded) == 6 and loaded.arrays["F_obs"].shape == (6, 12, 6)
