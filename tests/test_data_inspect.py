"""The inspection command: summary text and both plots from the tiny dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dcm.data.inspect import main, within_demo_spread


def test_inspect_summary_and_plots(tiny_dataset_path: Path, tmp_path: Path, capsys) -> None:
    traj_png, demo_png = tmp_path / "traj.png", tmp_path / "demo.png"
    assert main([str(tiny_dataset_path), "--plot", str(traj_png), "--traj", "traj_000004",
                 "--demo-plot", "0", "--out", str(demo_png)]) == 0
    text = capsys.readouterr().out
    assert "trajectories 15 (0 failed), demos 5" in text and "horizon H=40" in text
    assert "train         9      3" in text and "F_obs   Fz_N" in text
    assert traj_png.stat().st_size > 10_000 and demo_png.stat().st_size > 10_000
    assert main([str(tmp_path / "missing.h5")]) == 1


def test_within_demo_spread_is_p90_over_p10_per_demo() -> None:
    demo_ids = np.repeat([0, 1], 11)
    L_task = np.concatenate([np.linspace(1.0, 2.0, 11), np.full(11, 0.5)])  # 1.9/1.1 and a flat demo
    assert within_demo_spread(L_task, demo_ids) == "1.36 [1.00–1.73]"
    assert within_demo_spread(L_task[:2], demo_ids[:2]) == "–"  # under 3 trials: no spread
