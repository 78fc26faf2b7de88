"""tune.py end to end on the fast tool embodiment: virtual trials, validation, hypervolume, resume."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir

from dcm.data.datamodule import DCMDataModule
from dcm.models.dcm import DCM
from dcm.tuning.compare import compare
from dcm.tuning.optimize import TrialLog
from dcm.tuning.run import tune

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_checkpoint(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small DCM trained for a few steps: enough to exercise the pipeline, not to be accurate."""
    dm = DCMDataModule(tiny_dataset_path, batch_size=4, expect_control_hz=20.0)
    dm.setup("fit")
    L.seed_everything(0)
    model = DCM(net={"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2}, diffusion_steps=5,
                data_spec={"control_hz": dm.control_hz})
    model.fit_normalizers(*dm.train_arrays())
    trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=5, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    path = tmp_path_factory.mktemp("tune_ckpt") / "dcm.ckpt"
    trainer.save_checkpoint(path)
    return path


def _config(ckpt: Path, demo: Path, out_dir: Path, robot_free_trials: int):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=None):
        return compose("tune", overrides=[
            f"ckpt={ckpt}", f"demo_file={demo}", "embodiment=tool", f"out_dir={out_dir}",
            f"robot_free.n_trials={robot_free_trials}", "robot_free.batch_size=8", "robot_free.n_validate=3",
            "robot_based.n_trials=4", "search.options.n_startup_trials=4",
        ])


def test_tune_validates_the_predicted_front_and_resumes(tiny_checkpoint: Path, tmp_path: Path):
    spec = yaml.safe_load((REPO / "data/demos/wavelike.yaml").read_text())
    spec["duration_s"], spec["approach_s"] = 2.0, 0.4
    demo = tmp_path / "short_wave.yaml"
    demo.write_text(yaml.safe_dump(spec))
    out_dir = tmp_path / "run"

    first = tune(_config(tiny_checkpoint, demo, out_dir, 16), out_dir)
    assert first["robot_free"]["n_virtual_trials"] == 16
    assert 1 <= first["robot_free"]["n_validated"] <= 3
    for solution in first["robot_free"]["solutions"]:
        assert np.all(np.array(solution["phase_stiffness_Npm"]) >= 100.0)
        assert solution["validated"]["L_comp_kNpm"] == pytest.approx(solution["predicted"]["L_comp_kNpm"])
    assert first["robot_based"]["n_trials"] == 4
    assert first["robot_free"]["hypervolume"] >= 0.0 and first["robot_based"]["hypervolume"] >= 0.0
    for name in ("results.json", "pareto.png", "solution_forces.png"):
        assert (out_dir / name).stat().st_size > 0

    # Extending the run replays the logged virtual trials and only evaluates the new ones.
    logged = TrialLog.load(out_dir / "robot_free_trials.npz").arrays()[0]
    second = tune(_config(tiny_checkpoint, demo, out_dir, 24), out_dir)
    extended = TrialLog.load(out_dir / "robot_free_trials.npz").arrays()[0]
    assert second["robot_free"]["n_virtual_trials"] == 24
    np.testing.assert_array_equal(extended[:16], logged)
    assert json.loads((out_dir / "results.json").read_text())["robot_free"]["n_virtual_trials"] == 24

    # Comparing runs uses one reference point over all of them; a single run reproduces its own numbers.
    report = compare([out_dir], robot_trials=[2, 4])
    assert report["robot_free"][str(out_dir)] == pytest.approx(second["robot_free"]["hypervolume"])
    assert report["robot_based"]["N=4"] == pytest.approx(second["robot_based"]["hypervolume"])
    assert report["robot_based"]["N=2"] <= report["robot_based"]["N=4"]
    with pytest.raises(ValueError, match="first 5"):
        compare([out_dir], robot_trials=[5])


def test_tune_refuses_a_checkpoint_of_another_control_rate(tiny_checkpoint: Path, tmp_path: Path):
    cfg = _config(tiny_checkpoint, REPO / "data/demos/line.yaml", tmp_path, 8)
    cfg.control_hz = 50.0
    with pytest.raises(ValueError, match="50.0 Hz"):
        tune(cfg, tmp_path)
