"""The inspection command: summary text and both plots from the tiny dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dcm.data.inspect import approach_share, force_step_change, main, within_demo_spread


def test_inspect_summary_and_plots(tiny_dataset_path: Path, tmp_path: Path, capsys) -> None:
    traj_png, demo_png = tmp_path / "traj.png", tmp_path / "demo.png"
    assert main([str(tiny_dataset_path), "--plot", str(traj_png), "--traj", "traj_000004",
                 "--demo-plot", "0", "--out", str(demo_png)]) == 0
    text = capsys.readouterr().out
    assert "trajectories 15 (0 failed), demos 5" in text and "horizon H=40" in text
    assert "train         9      3" in text and "F_obs   Fz_N" in text and "force step change" in text
    assert "the approach (each demo's approach_s):" in text
    assert traj_png.stat().st_size > 10_000 and demo_png.stat().st_size > 10_000
    assert main([str(tmp_path / "missing.h5")]) == 1


def test_within_demo_spread_is_p90_over_p10_per_demo() -> None:
    demo_ids = np.repeat([0, 1], 11)
    L_task = np.concatenate([np.linspace(1.0, 2.0, 11), np.full(11, 0.5)])  # 1.9/1.1 and a flat demo
    assert within_demo_spread(L_task, demo_ids) == "1.36 [1.00–1.73]"
    assert within_demo_spread(L_task[:2], demo_ids[:2]) == "–"  # under 3 trials: no spread


def test_force_step_change_is_the_mean_jump_of_the_force_vector() -> None:
    wrench = np.zeros((3, 5, 6))
    wrench[0, :, 2] = [0.0, 3.0, 0.0, 3.0, 0.0]  # a force alternating by 3 N, as on facet edges
    wrench[1, :, 0], wrench[1, :, 1] = np.arange(5) * 3.0, np.arange(5) * 4.0  # a 5 N ramp per step
    wrench[2, :, 3:] = 100.0 * np.arange(5)[:, None]  # torques do not count
    assert force_step_change(wrench) == 3.0  # median of 3, 5 and 0


def test_approach_share_when_the_touch_down_decides_the_ranking() -> None:
    """Four trials of one demo: the touch-down errs 4, 3, 2, 1 N, the wipe after it 0.1, 0.2, 0.3, 0.4 N."""
    F_demo, F_obs = np.zeros((4, 10, 6)), np.zeros((4, 10, 6))
    F_obs[:, 1, 2] = [4.0, 3.0, 2.0, 1.0]
    F_obs[:, 2:, 2] = np.array([0.1, 0.2, 0.3, 0.4])[:, None]
    share, rho = approach_share(F_obs, F_demo, np.full(4, 2), np.zeros(4, int))
    shares = np.array([16 / 16.08, 9 / 9.32, 4 / 4.72, 1 / 2.28])
    # the whole-demo L_task orders the trials backwards
    assert np.isclose(share, np.median(shares)) and np.isclose(rho, -1.0)
    _, same = approach_share(F_obs, F_demo, np.zeros(4, int), np.zeros(4, int))  # no approach: the same ranking
    assert np.isclose(same, 1.0)
