"""The stiffness-level rule: its sign comes from the fit split, and it is scored on another."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dcm.data.schema import write_dataset
from studies.wipe_model.level_rule import level_rule


def write_level_dataset(path: Path, sign: float, n_skills: int = 6, per_skill: int = 6, horizon: int = 8) -> Path:
    """Skills whose L_task is ``sign`` x the stiffness level (plus a skill offset): the rule ranks them exactly."""
    rng = np.random.default_rng(0)
    trajectories = []
    for skill in range(n_skills):
        for level in rng.permutation(np.linspace(200.0, 1400.0, per_skill)):
            K = np.full((horizon, 6), 20.0, np.float32)
            K[:, :3] = level
            x = np.zeros((horizon, 6), np.float32)
            force = np.zeros((horizon, 6), np.float32)
            trajectories.append(dict(x_demo=x, F_demo=force, x_attr=x, K=K, x_obs=x, F_obs=force,
                                     contact=np.ones(horizon, np.uint8), demo_id=skill,
                                     L_task=1.0 + skill + sign * level / 1000.0, L_comp=level * 3 ** 0.5 / 1000))
    names = [f"traj_{i:06d}" for i in range(len(trajectories))]
    half = len(names) // 2
    write_dataset(path, trajectories, {"train": names[:half], "valid": names[half:]},
                  {"control_hz": 20.0, "embodiment": "synthetic"})
    return path


def test_the_level_rule_takes_its_sign_from_the_fit_split(tmp_path: Path) -> None:
    for sign in (1.0, -1.0):
        result = level_rule(write_level_dataset(tmp_path / f"level{sign:+.0f}.h5", sign), "valid", "train")
        assert result["sign"] == sign and result["train_spearman_L_comp"] == sign
        assert result["R_within_spearman"] == 1.0 and result["top3_regret"] == 0.0 and result["n_skills"] == 3
