"""The checkpoint file: reading it, and what wrote it (model kind, code version).

Every dcm checkpoint is read here, so the checks on what a file holds are made in one place.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import torch

from dcm import __version__
from dcm.models.configuration import CheckpointIncompatibleError, CheckpointVersionWarning, ModelInputError

KIND_KEY = "dcm_model_kind"  # checkpoint key naming the class that wrote it
VERSION_KEY = "dcm_version"  # checkpoint key naming the code version that wrote it

def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """A checkpoint's raw dict, checked to be a Lightning checkpoint; one-line errors name ``path``."""
    path = Path(path)
    if not path.is_file():
        raise ModelInputError(f"checkpoint {path} does not exist")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means "not a usable checkpoint"
        raise ModelInputError(f"checkpoint {path} is not readable: {err}") from err
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise ModelInputError(f"checkpoint {path} is not a Lightning checkpoint (no state_dict)")
    return ckpt


def _checkpoint_kind(path: str | Path) -> tuple[str | None, dict[str, Any]]:
    """The model kind and hyper-parameters stored in a checkpoint, without building the model."""
    ckpt = read_checkpoint(path)
    return ckpt.get(KIND_KEY), dict(ckpt.get("hyper_parameters") or {})


def check_code_version(path: str | Path, written_by: str | None) -> None:
    """Warn when a checkpoint comes from another dcm version: it loads, but its numbers may differ."""
    if written_by != __version__:
        warnings.warn(f"checkpoint {path} was written by dcm {written_by or '(unknown, before 0.2.0)'}; "
                      f"this is dcm {__version__}", CheckpointVersionWarning, stacklevel=3)


def _incompatible(path: str | Path, written_by: str | None, err: RuntimeError) -> CheckpointIncompatibleError:
    """A clear error for parameter names that changed between code versions."""
    text = str(err)
    labels = {"Missing key(s)": "missing", "Unexpected key(s)": "unexpected"}
    names = [f"{labels[label]} {part.split(':', 1)[1].strip().rstrip('.')}" for part in text.split("\n\t")
             for label in labels if part.startswith(label)]
    detail = "; ".join(names)[:300] or " ".join(text.split())[:300]
    return CheckpointIncompatibleError(
        f"checkpoint {path} (dcm {written_by or 'unknown'}) does not fit this code (dcm {__version__}): "
        f"parameter names changed: {detail}. Retrain, or load it with the dcm version that wrote it")




__all__ = ["KIND_KEY", "VERSION_KEY", "check_code_version", "read_checkpoint"]
