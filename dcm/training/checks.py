"""The training command's argument checks that need no training library, so a wrong ``data=``, ``resume=`` or
``dataset.<key>=`` fails in one line before torch and Lightning are imported (:mod:`dcm.training.cli`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from dcm.training import run_dir as rd


class TrainConfigError(ValueError):
    """An inconsistent training configuration (stage, init_from, resume, data.path ...)."""


def check_dataset_overrides(overrides: Sequence[str]) -> None:
    """Refuse ``dataset.<key>=...``: a preset is generated and read as it is, so a changed field would be
    recorded in config.yaml without being what the file holds."""
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        if key.startswith("dataset."):
            raise TrainConfigError(
                f"{override}: the dataset preset is used as it is; to train on a variant, generate it "
                f"(python -m dcm.data.generate dataset=<name> {override} out=<file.h5>) and pass data.path=<file.h5>")


def check_data_argument(argv: Sequence[str]) -> None:
    """Name the replacement of ``data=<preset>``, a form the train commands in model cards may record."""
    for arg in argv:
        if arg.startswith("data="):
            value = arg.split("=", 1)[1]
            fix = "data.path=<file.h5>" if value == "path" else f"dataset={value}"
            raise TrainConfigError(f"{arg}: the dataset preset is chosen with dataset=<name> (conf/dataset/), an "
                                   f"existing file with data.path=<file.h5>; here: {fix}")


def check_resume_dir(run_dir: Path) -> Path:
    """The run directory to resume, refused unless it holds a saved config and its last checkpoint."""
    if not run_dir.is_dir():
        raise TrainConfigError(f"resume={run_dir}: no such directory")
    if not rd.config_path(run_dir).is_file():
        raise TrainConfigError(f"resume={run_dir}: no {rd.CONFIG_FILE} there (is it a train.py run directory?)")
    if not rd.last_checkpoint(run_dir).is_file():
        raise TrainConfigError(f"resume={run_dir}: no {rd.CHECKPOINT_DIR}/{rd.LAST_CHECKPOINT} to resume from")
    return run_dir


def check_resume_argument(argv: Sequence[str]) -> None:
    """Check ``resume=<dir>`` before Hydra starts, so a wrong folder leaves no new outputs/train/<time>/ behind."""
    for arg in argv:
        if arg.startswith("resume="):
            value = arg.split("=", 1)[1].strip("'\"")
            if value and value != "null":
                check_resume_dir(Path(value).expanduser().absolute())
