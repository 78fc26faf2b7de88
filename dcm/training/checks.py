"""The training command's argument checks that need no training library, so a wrong ``data=``, ``resume=`` or
``dataset.<key>=`` fails in one line before torch and Lightning are imported (:mod:`dcm.training.cli`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from dcm.configs import check_integer
from dcm.control.objectives import TaskObjective
from dcm.data.schema import TARGET_FIELDS, target_layout
from dcm.training import run_dir as rd

# lightning.Trainer's integer settings and their smallest value; Lightning finds a wrong one only after the
# model and data are built, in a traceback, or not at all (max_epochs=0 trains nothing and exits 0).
TRAINER_INTEGERS = {"max_epochs": 1, "min_epochs": 0, "max_steps": 1, "check_val_every_n_epoch": 1,
                    "log_every_n_steps": 1, "num_sanity_val_steps": -1, "num_nodes": 1, "accumulate_grad_batches": 1}
# The value each setting may also take, and what it means to Lightning.
TRAINER_SPECIAL = {"max_epochs": (-1, "no limit: until trainer.max_time"), "max_steps": (-1, "no limit"),
                   "min_epochs": (None, "none"), "check_val_every_n_epoch": (None, "by val_check_interval only")}


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


def check_trainer(trainer: Mapping[str, Any], monitor: str) -> None:
    """Refuse a trainer setting Lightning cannot run, or one under which a run selecting on ``monitor`` (a
    ``val/`` metric) would end before its first validation, before anything is built."""
    for key, minimum in TRAINER_INTEGERS.items():
        if key not in trainer:
            continue
        value = trainer[key]
        special, meaning = TRAINER_SPECIAL.get(key, (None, None))
        if meaning is not None and (value is None if special is None else type(value) is int and value == special):
            continue
        note = f", or {'null' if special is None else special} ({meaning})" if meaning is not None else ""
        check_integer(value, f"trainer.{key}", minimum, TrainConfigError, note)
    epochs, every = trainer.get("max_epochs"), trainer.get("check_val_every_n_epoch")
    if monitor.startswith("val/") and every is not None and epochs is not None and 0 < epochs < every:
        raise TrainConfigError(f"trainer.max_epochs={epochs} ends before the first validation "
                               f"(trainer.check_val_every_n_epoch={every}), so no checkpoint could be selected on "
                               f"{monitor}; set trainer.check_val_every_n_epoch={epochs} or more epochs")


def run_objective(cfg: Mapping[str, Any]) -> TaskObjective:
    """The ``objective`` group of a training config (the paper's for a config saved before it existed), refused
    in one line when the model the config builds cannot predict what it counts (``model.target_fields``).
    A run from ``init_from`` is checked once the checkpoint's target is read."""
    try:
        objective = TaskObjective.from_config(cfg.get("objective"))
    except ValueError as err:
        raise TrainConfigError(str(err)) from None
    if cfg.get("init_from"):
        return objective
    target_fields = (cfg.get("model") or {}).get("target_fields", "force")
    if target_fields not in TARGET_FIELDS:
        raise TrainConfigError(f"model.target_fields={target_fields} is not one of {', '.join(TARGET_FIELDS)}")
    if problem := target_layout(target_fields).objective_problem(objective):
        raise TrainConfigError(problem)
    return objective
