"""train.py and the shared CLI helpers: user errors fail at start, in one line, leaving nothing behind."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from dcm.configs import JSONFileError, config_diff, load_json
from dcm.devices import DeviceError, check_accelerator, resolve_device

REPO = Path(__file__).resolve().parents[1]
TINY = ["trainer=fast", "trainer.max_epochs=1", "net.d_model=32", "net.n_layers=1", "net.n_heads=2",
        "data.batch_size=8", "model.warmup_steps=2", "metrics.n_plot=1"]


def _train(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONWARNINGS="ignore", MUJOCO_GL="egl")
    return subprocess.run([sys.executable, str(REPO / "train.py"), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


def _error_line(proc: subprocess.CompletedProcess) -> str:
    """Exit code 2, no traceback, and the last stderr line is the ``error: ...`` message."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout[-1500:], proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr[-3000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: "), proc.stderr[-1500:]
    return line


def test_resume_of_a_missing_folder_fails_in_one_line_and_creates_nothing(tmp_path: Path) -> None:
    proc = _train(["resume=runs/gone"], cwd=tmp_path)
    assert proc.stderr.strip() == f"error: resume={tmp_path / 'runs' / 'gone'}: no such directory"
    assert proc.returncode == 2
    assert list(tmp_path.iterdir()) == []  # no outputs/train/<time>/ from Hydra
    (tmp_path / "run").mkdir()
    line = _error_line(_train([f"resume={tmp_path / 'run'}"], cwd=tmp_path))
    assert "no config.yaml there" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_nan_in_the_test_split_fails_before_fitting(tiny_dataset_path: Path, tmp_path: Path) -> None:
    data = tmp_path / "nan.h5"
    shutil.copy(tiny_dataset_path, data)
    with h5py.File(data, "r+") as f:
        name = f["mask"]["test"][-1].decode()
        force = f["data"][name]["F_obs"]
        values = force[()]
        values[7, 2] = np.nan
        force[...] = values
    run = tmp_path / "run"
    line = _error_line(_train([f"data.path={data}", *TINY, f"hydra.run.dir={run}"], cwd=tmp_path))
    assert line == f"error: file {data}, trajectory {name}, field F_obs: contains NaN or inf (first at index [7, 2])"
    assert line in (run / "train.log").read_text()  # the run directory says why it stopped
    assert not (run / "checkpoints").exists()  # nothing was fitted
    # without the test pass, the test split is not read and the run goes through
    proc = _train([f"data.path={data}", *TINY, "test_after_fit=false", f"hydra.run.dir={run}"],
                  cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_a_data_preset_argument_names_its_replacement_and_creates_nothing(tmp_path: Path) -> None:
    """Model cards of earlier runs record `data=<preset>`; the command says what to type instead."""
    proc = _train(["model=dcm", "data=diverse_contact", "trainer.max_epochs=80"], cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().endswith("here: dataset=diverse_contact"), proc.stderr
    assert list(tmp_path.iterdir()) == []
    line = _error_line(_train(["data=path", "data.path=/abs/logs.h5"], cwd=tmp_path))
    assert line.endswith("here: data.path=<file.h5>")


def test_a_named_data_path_that_does_not_exist_is_an_error_never_generated(tmp_path: Path) -> None:
    """Only a preset's own file (data/<name>.h5) is generated; a path the user named must exist."""
    missing = tmp_path / "elsewhere" / "tiny.h5"
    line = _error_line(_train(["dataset=tiny", f"data.path={missing}", *TINY, f"hydra.run.dir={tmp_path / 'run'}"],
                              cwd=tmp_path))
    assert line.startswith(f"error: data.path={missing} does not exist")
    assert not missing.exists() and not (tmp_path / "elsewhere").exists() and not (tmp_path / "data").exists()


def test_a_changed_dataset_preset_field_is_refused(tmp_path: Path) -> None:
    """A preset is used as it is: a changed field would be recorded without being what the file holds."""
    line = _error_line(_train(["dataset=tiny", "dataset.duration_s=4.0", *TINY, f"hydra.run.dir={tmp_path / 'run'}"],
                              cwd=tmp_path))
    assert line.startswith("error: dataset.duration_s=4.0: the dataset preset is used as it is")
    assert "out=<file.h5>" in line and not (tmp_path / "data").exists()


def test_a_checkpoint_name_on_another_metric_than_the_monitor_is_refused(tiny_dataset_path: Path,
                                                                         tmp_path: Path) -> None:
    """Named after a metric the run does not select on, a checkpoint can be called ...-Rwnan.ckpt."""
    run = tmp_path / "run"
    line = _error_line(_train([f"data.path={tiny_dataset_path}", *TINY, "checkpoint.monitor=val/R_pooled",
                               "checkpoint.filename='epoch{epoch:03d}-Rw{val/R_within:.3f}'",
                               f"hydra.run.dir={run}"], cwd=tmp_path))
    assert "names val/R_within but checkpoint.monitor is val/R_pooled" in line
    assert not (run / "checkpoints").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_an_absent_gpu_fails_in_one_line(tiny_dataset_path: Path, tmp_path: Path) -> None:
    line = _error_line(_train([f"data.path={tiny_dataset_path}", *TINY, "trainer.accelerator=gpu",
                               f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path))
    assert line.startswith("error: trainer.accelerator=gpu: CUDA is not available on this machine")
    line = _error_line(_train([f"data.path={tiny_dataset_path}", *TINY, "stage=finetune",
                               f"hydra.run.dir={tmp_path / 'run2'}"], cwd=tmp_path))
    assert "needs init_from" in line  # a TrainConfigError, in one line


# ------------------------------------------------------------------------------------------- dcm.devices
@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_resolve_device_names_the_option() -> None:
    assert resolve_device("auto").type in ("cpu", "mps")
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(DeviceError, match=r"^device=cuda: CUDA is not available on this machine .*use device=cpu"):
        resolve_device("cuda")
    with pytest.raises(DeviceError, match=r"^tuner.device=cuda:1: CUDA is not available"):
        resolve_device("cuda:1", option="tuner.device")
    with pytest.raises(DeviceError, match=r"^device=gpu0: not a device; use auto, cpu, cuda"):
        resolve_device("gpu0")
    check_accelerator("auto")
    check_accelerator("cpu")
    with pytest.raises(DeviceError, match=r"^trainer.accelerator=gpu: CUDA is not available"):
        check_accelerator("gpu")


def test_load_json_names_file_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "meta.json"
    path.write_text('{\n  "demo_id": 3,\n  "split": "train",,\n}\n')
    with pytest.raises(JSONFileError) as info:
        load_json(path)
    assert str(info.value) == (f"{path}, line 3, column 20: invalid JSON "
                               "(Expecting property name enclosed in double quotes)")
    with pytest.raises(JSONFileError, match="cannot read"):
        load_json(tmp_path / "absent.json")
    path.write_text('{"a": [1, 2]}')
    assert load_json(path) == {"a": [1, 2]}


def test_config_diff() -> None:
    old = {"seed": 0, "out": "a.h5", "stiffness": {"max_Npm": 1500.0, "n_phases": 3}, "skills": None}
    new = {"seed": 3, "out": "b.h5", "stiffness": {"max_Npm": 1500.0, "n_phases": 4}, "skills": ["spiral"]}
    assert config_diff(old, new, ignore=("out",)) == ['seed: 0 -> 3', 'skills: None -> ["spiral"]',
                                                       "stiffness.n_phases: 3 -> 4"]
    assert config_diff(old, old) == []


def test_an_epoch_count_lightning_cannot_run_fails_in_one_line(tmp_path: Path) -> None:
    """max_epochs=0 would exit 0 with no checkpoint; the run's folder keeps only its log, which says why."""
    run = tmp_path / "run"
    line = _error_line(_train(["trainer.max_epochs=0", f"hydra.run.dir={run}"], cwd=tmp_path))
    assert line.startswith("error: trainer.max_epochs = 0 must be an integer >= 1")
    assert not (run / "checkpoints").exists() and line in (run / "train.log").read_text()


@pytest.mark.parametrize(("trainer", "message"), [
    ({"max_epochs": -2}, "trainer.max_epochs = -2 must be an integer >= 1, or -1 (no limit: until trainer.max_time)"),
    ({"max_epochs": 2.5}, "trainer.max_epochs = 2.5 must be an integer >= 1"),
    ({"check_val_every_n_epoch": 0}, "trainer.check_val_every_n_epoch = 0 must be an integer >= 1"),
    ({"max_epochs": 3, "check_val_every_n_epoch": 4},
     "trainer.max_epochs=3 ends before the first validation (trainer.check_val_every_n_epoch=4)"),
])
def test_trainer_settings_are_checked_before_anything_is_built(trainer: dict, message: str) -> None:
    from dcm.training.checks import TrainConfigError, check_trainer

    with pytest.raises(TrainConfigError) as err:
        check_trainer(trainer, "val/R_within")
    assert str(err.value).startswith(message)


def test_trainer_settings_lightning_takes_pass() -> None:
    from dcm.training.checks import check_trainer

    for trainer in ({"max_epochs": -1}, {"max_epochs": 4, "check_val_every_n_epoch": 4},
                    {"check_val_every_n_epoch": None, "max_epochs": 1}, {"min_epochs": None}):
        check_trainer(trainer, "val/R_within")
    check_trainer({"max_epochs": 3, "check_val_every_n_epoch": 4}, "train/loss")  # selects without validating
