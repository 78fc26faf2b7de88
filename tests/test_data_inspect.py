"""The inspection command: summary text and both plots from the tiny dataset."""

from __future__ import annotations

from pathlib import Path

from dcm.data.inspect import main


def test_inspect_summary_and_plots(tiny_dataset_path: Path, tmp_path: Path, capsys) -> None:
    traj_png, demo_png = tmp_path / "traj.png", tmp_path / "demo.png"
    assert main([str(tiny_dataset_path), "--plot", str(traj_png), "--traj", "traj_000004",
                 "--demo-plot", "0", "--out", str(demo_png)]) == 0
    text = capsys.readouterr().out
    assert "trajectories 15 (0 failed), demos 5" in text and "horizon H=40" in text
    assert "train         9      3" in text and "F_obs   Fz_N" in text
    assert traj_png.stat().st_size > 10_000 and demo_png.stat().st_size > 10_000
    assert main([str(tmp_path / "missing.h5")]) == 1
