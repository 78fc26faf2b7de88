"""Load any force-model checkpoint without knowing its class, and check a dataset against it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from dcm.models.configuration import CheckpointKindError
from dcm.models.dcm import DCM, ForceModel, _checkpoint_kind


def model_class(kind: str) -> type[ForceModel]:
    """The LightningModule class of a model kind ("dcm" or "baseline")."""
    from dcm.models.baseline import Baseline

    classes: dict[str, type[ForceModel]] = {"dcm": DCM, "baseline": Baseline}
    if kind not in classes:
        raise CheckpointKindError(f"unknown model kind {kind!r}; known: {sorted(classes)}")
    return classes[kind]


def checkpoint_kind(path: str | Path) -> str:
    """The model kind a checkpoint was written by; raises if it is not a dcm force-model checkpoint."""
    kind, _ = _checkpoint_kind(path)
    if kind is None:
        raise CheckpointKindError(f"checkpoint {path} was not written by a dcm force model (no model kind)")
    return str(kind)


def load_model(path: str | Path, map_location: Any = "cpu") -> ForceModel:
    """Load a DCM or Baseline checkpoint, in eval mode."""
    model = model_class(checkpoint_kind(path)).load_from_checkpoint(path, map_location=map_location)
    model.eval()
    return model
