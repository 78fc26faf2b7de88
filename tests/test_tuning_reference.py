"""tune.py with a reference predictor: the stiffness-only ridge tunes end to end; copy_demo is refused."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from dcm.models.references import main as references_main
from dcm.tuning.run import tune
from tests.conftest import short_wave_demo

REPO = Path(__file__).resolve().parents[1]
SMALL = ["embodiment=tool", "robot_free.n_trials=12", "robot_free.batch_size=6", "robot_free.n_validate=2",
         "robot_based.n_trials=5", "search.options.n_startup_trials=4"]


def test_tune_py_runs_robot_free_on_the_stiffness_reference(tiny_dataset_path: Path, tmp_path: Path) -> None:
    ref = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    run = tmp_path / "run"
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONWARNINGS="ignore", MUJOCO_GL="egl")
    proc = subprocess.run([sys.executable, str(REPO / "tune.py"), f"ckpt={ref}", f"demo_file={short_wave_demo(tmp_path)}",
                           *SMALL, f"hydra.run.dir={run}"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((run / "results.json").read_text())
    assert results["model"] == "StiffnessRegression" and results["robot_free"]["n_virtual_trials"] == 12
    predicted = [s["predicted"]["L_task_N"] for s in results["robot_free"]["solutions"]]
    assert predicted and all(p > 0 for p in predicted)
    assert (run / "solution_forces.png").stat().st_size > 0  # drawn without a predicted force curve


def test_tune_refuses_copy_demo(tmp_path: Path) -> None:
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("tune", overrides=["ckpt=copy_demo", f"demo_file={short_wave_demo(tmp_path)}",
                                         f"out_dir={tmp_path}", *SMALL])
    with pytest.raises(ValueError, match="ckpt=copy_demo cannot tune: .* cannot rank them"):
        tune(cfg, tmp_path)


def test_tune_refuses_a_reference_of_another_phase_count(tiny_dataset_path: Path, tmp_path: Path) -> None:
    ref = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("tune", overrides=[f"ckpt={ref}", f"demo_file={short_wave_demo(tmp_path)}", f"out_dir={tmp_path}",
                                         "stiffness.n_phases=2", *SMALL])
    with pytest.raises(ValueError, match="schedules have 2 phases, but .* fitted on 3-phase schedules"):
        tune(cfg, tmp_path)
