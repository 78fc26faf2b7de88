"""Loading never runs code from a file: every path that reads a checkpoint refuses one whose unpickling would
call something (here: create a marker file), in one line naming the file, and the marker stays absent."""

from __future__ import annotations

import os
import pathlib
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch
from omegaconf import OmegaConf

from dcm.models.checkpoint import checkpoint_card, checkpoint_kind, export_checkpoint, read_checkpoint
from dcm.models.configuration import CheckpointUnsafeError, ModelInputError
from dcm.models.dcm import DCM
from dcm.models.predict import load_model, trained_on
from dcm.models.references import load_reference


class _Touch:
    """Unpickles as ``Path.touch(marker)``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return pathlib.Path.touch, (self.marker,)


class _System:
    """Unpickles as ``os.system("touch marker")``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return os.system, (f"touch {self.marker}",)


def _torch_file(payload: type, path: Path, marker: Path) -> None:
    """A Lightning-like checkpoint (torch's zip format) with the payload among its hyper-parameters."""
    torch.save({"state_dict": {}, "dcm_model_kind": "dcm", "hyper_parameters": {"lr": payload(marker)}}, path)


def _plain_pickle(payload: type, path: Path, marker: Path) -> None:
    """The same as a bare pickle (torch's legacy format)."""
    with path.open("wb") as f:
        pickle.dump({"state_dict": {}, "dcm_model_kind": "dcm", "hyper_parameters": {"lr": payload(marker)}}, f)


CRAFTED = {"touch-zip": (_Touch, _torch_file), "system-zip": (_System, _torch_file),
           "system-pickle": (_System, _plain_pickle)}


@pytest.fixture(params=sorted(CRAFTED))
def crafted(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[Path, Path]:
    """A crafted checkpoint and the marker file its unpickling would create."""
    payload, write = CRAFTED[request.param]
    marker, path = tmp_path / "marker", tmp_path / "crafted.ckpt"
    write(payload, path, marker)
    assert not marker.exists()
    return path, marker


def _refuses(load: Callable[[], Any], path: Path, marker: Path, error: type = ModelInputError) -> str:
    with pytest.raises(error) as err:
        load()
    message = str(err.value)
    assert not marker.exists(), "the file's code ran"
    assert isinstance(err.value, ValueError) and "\n" not in message and str(path) in message, message
    return message


def test_the_checkpoint_reader_refuses_a_file_that_would_run_code(crafted: tuple[Path, Path]) -> None:
    path, marker = crafted
    message = _refuses(lambda: read_checkpoint(path), path, marker, CheckpointUnsafeError)
    assert message.startswith(f"{path}: not a plain-data dcm checkpoint (would unpickle ")
    assert message.endswith("); refusing to load it")
    for read in (checkpoint_card, checkpoint_kind, trained_on):  # the card and kind, as tune.py and train.py read them
        _refuses(lambda read=read: read(path), path, marker, CheckpointUnsafeError)


def test_the_reader_names_what_the_file_would_call(tmp_path: Path) -> None:
    marker, path = tmp_path / "marker", tmp_path / "system.ckpt"
    _torch_file(_System, path, marker)
    message = _refuses(lambda: read_checkpoint(path), path, marker, CheckpointUnsafeError)
    assert f"would unpickle {os.system.__module__}.system" in message


def test_model_loading_refuses_it(crafted: tuple[Path, Path]) -> None:
    """load_model is what evaluate and tune call; DCM.load_from_checkpoint is what users and fine-tuning call."""
    path, marker = crafted
    _refuses(lambda: load_model(path), path, marker, CheckpointUnsafeError)
    _refuses(lambda: DCM.load_from_checkpoint(path), path, marker, CheckpointUnsafeError)


def test_training_refuses_it_as_init_from_and_as_the_checkpoint_to_resume(crafted: tuple[Path, Path],
                                                                          tmp_path: Path) -> None:
    from dcm.training import train

    path, marker = crafted
    cfg = OmegaConf.create({"init_from": str(path), "model": {"_target_": "dcm.models.dcm.DCM"}})
    _refuses(lambda: train.init_checkpoint(cfg), path, marker, CheckpointUnsafeError)
    run_dir = tmp_path / "run"
    (run_dir / "checkpoints").mkdir(parents=True)
    last = run_dir / "checkpoints" / "last.ckpt"
    last.write_bytes(path.read_bytes())
    cfg = OmegaConf.create({"trainer": {"accelerator": "cpu"}, "resume": str(run_dir), "seed": 0})
    _refuses(lambda: train.train(cfg, run_dir), last, marker, CheckpointUnsafeError)


def test_the_export_refuses_it(crafted: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from dcm.training.export import main

    path, marker = crafted
    out = tmp_path / "out.ckpt"
    _refuses(lambda: export_checkpoint(path, out, verify=load_model), path, marker, CheckpointUnsafeError)
    assert main([str(path), str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: not a plain-data dcm checkpoint") and err.count("\n") == 1
    assert not marker.exists() and not out.exists()


def test_the_reference_loader_refuses_a_checkpoint_given_as_json(crafted: tuple[Path, Path], tmp_path: Path) -> None:
    path, marker = crafted
    as_json = tmp_path / "reference.json"
    as_json.write_bytes(path.read_bytes())
    _refuses(lambda: load_reference(as_json), as_json, marker)
    _refuses(lambda: load_model(as_json), as_json, marker)


def test_a_plain_checkpoint_still_loads(tiny_checkpoint: Path) -> None:
    assert read_checkpoint(tiny_checkpoint)["dcm_model_kind"] == "dcm"
    assert isinstance(load_model(tiny_checkpoint), DCM)
