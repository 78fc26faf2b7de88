"""Load any predictor by path or name, check a dataset against it, and get predicted L_task from it.

A *predictor* is anything the evaluator and the tuner can score schedules with:

* a force model checkpoint (DCM or Baseline, ``.ckpt``): ``predict_forces`` -> forces, L_task from them;
* ``copy_demo`` (no file): ``predict_forces`` returns F_demo;
* a stiffness reference JSON (``python -m dcm.models.references fit``): ``predict_task_loss`` directly.

:func:`predict_task_loss` is the one call that works for all of them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dcm.cli import one_line
from dcm.control.objectives import task_loss
from dcm.models.checkpoint import checkpoint_card, checkpoint_kind
from dcm.models.configuration import CheckpointKindError, ModelInputError
from dcm.models.dcm import DCM
from dcm.models.force_model import ForceModel
from dcm.models.prior_blend import PriorBlend
from dcm.models.references import COPY_DEMO, CopyDemo, StiffnessRegression, load_reference


@runtime_checkable
class ForcePredictor(Protocol):
    """Predicts the contact wrench (B, H, 6) [N, N·m] and its spread for raw inputs."""

    def predict_forces(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                       generator: Any = None) -> tuple[Any, Any]: ...


@runtime_checkable
class TaskLossPredictor(Protocol):
    """Predicts L_task (B,) [N] directly, without forces."""

    def predict_task_loss(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any) -> np.ndarray: ...


Predictor = ForcePredictor | TaskLossPredictor


def model_class(kind: str) -> type[ForceModel]:
    """The LightningModule class of a model kind ("dcm" or "baseline")."""
    from dcm.models.baseline import Baseline

    classes: dict[str, type[ForceModel]] = {"dcm": DCM, "baseline": Baseline}
    if kind not in classes:
        raise CheckpointKindError(f"unknown model kind {kind!r}; known: {sorted(classes)}")
    return classes[kind]


def load_model(path: str | Path, map_location: Any = "cpu") -> Any:
    """Load a predictor: a DCM/Baseline checkpoint (in eval mode), a reference JSON, or ``copy_demo``.

    Anything else raises a :class:`ModelInputError` (a ValueError) whose one-line message names ``path``.
    """
    if str(path) == COPY_DEMO:
        return CopyDemo()
    path = Path(path)
    if not path.exists():
        raise ModelInputError(f"{path}: no such file; expected a .ckpt checkpoint, a reference .json "
                              f"(python -m dcm.models.references fit) or the name {COPY_DEMO!r}")
    if path.suffix.lower() == ".json":
        return load_reference(path)
    try:
        model = model_class(checkpoint_kind(path)).load_from_checkpoint(path, map_location=map_location)
    except ModelInputError as err:
        raise type(err)(one_line(err)) from None  # one line, whatever torch.load said
    model.eval()
    return model


def trained_on(path: str | Path) -> str | None:
    """The dataset preset a predictor file learned from (an exported checkpoint's card, a reference's fit
    record); None for ``copy_demo``, a training checkpoint or a file that does not say."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return ((json.loads(path.read_text()).get("fit") or {}).get("dataset") or {}).get("attrs", {}).get("dataset")
    if path.suffix.lower() == ".ckpt":
        return (checkpoint_card(path).get("dataset") or {}).get("dataset")
    return None


def trained_recording(path: str | Path) -> Any:
    """How the demos a predictor file learned from were recorded: what its card or fit record stores, else the
    recording of the product preset it names; None when neither says (``copy_demo``, imported robot logs).
    Returns a :class:`dcm.data.recording.Recording`."""
    from dcm.data.recording import Recording, preset_recording

    path = Path(path)
    identity: dict[str, Any] = {}
    if path.suffix.lower() == ".json":
        identity = (json.loads(path.read_text()).get("fit") or {}).get("dataset") or {}
    elif path.suffix.lower() == ".ckpt":
        identity = checkpoint_card(path).get("dataset") or {}
    if identity.get("recording"):
        return Recording(**identity["recording"])
    return preset_recording(trained_on(path))


def check_dataset(predictor: Any, cond_channels: list[str], target_channels: list[str], control_hz: float,
                  source: str) -> None:
    """Raise if a dataset's channels or control rate differ from the predictor's (copy_demo accepts any)."""
    spec = getattr(predictor, "data_spec", None)
    if spec is not None:
        spec.check(cond_channels, target_channels, control_hz, source=source)


def _numpy(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def predict_task_loss(predictor: Any, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                      generator: Any = None, from_step: int = 0) -> np.ndarray:
    """Predicted L_task (B,) [N] of any predictor for (B, H, 6) or (H, 6) raw inputs.

    Force predictors: :func:`dcm.control.objectives.task_loss` of the (``n_samples``-averaged) predicted
    force against F_demo from step ``from_step`` on, or what a DCM's ``task_loss`` option makes of its
    samples (``ForceModel.predicted_task_loss``). Others: their ``predict_task_loss``, of the window they
    were fitted on (``StiffnessRegression.check_window``).
    """
    if isinstance(predictor, PriorBlend):
        L_model = predict_task_loss(predictor.model, x_demo, F_demo, x_attr, K, n_samples, generator, from_step)
        return predictor.combine(L_model, predict_task_loss(predictor.prior, x_demo, F_demo, x_attr, K))
    if isinstance(predictor, ForcePredictor):
        kwargs = {"n_samples": n_samples} if generator is None else {"n_samples": n_samples, "generator": generator}
        mean, std = predictor.predict_forces(_numpy(x_demo), _numpy(F_demo), _numpy(x_attr), _numpy(K), **kwargs)
        window = (Ellipsis, slice(int(from_step), None), slice(None))
        mean, std, demo = (_numpy(a).astype(np.float64)[window] for a in (mean, std, F_demo))
        if isinstance(predictor, ForceModel):
            return np.atleast_1d(np.asarray(predictor.predicted_task_loss(mean, std, demo)))
        return np.atleast_1d(np.asarray(task_loss(mean, demo)))
    if isinstance(predictor, TaskLossPredictor):
        return np.atleast_1d(np.asarray(predictor.predict_task_loss(x_demo, F_demo, x_attr, K), dtype=np.float64))
    raise TypeError(f"{type(predictor).__name__} has neither predict_forces nor predict_task_loss")


def describe(predictor: Any, n_samples: int | None = None) -> dict[str, Any]:
    """What produced a prediction, for result files: kind, and for force models T, sampler, samples, net."""
    if isinstance(predictor, ForceModel):
        is_dcm = isinstance(predictor, DCM)
        k = (predictor.default_samples if n_samples is None else int(n_samples)) if is_dcm else 1
        return {
            "model": predictor.model_kind,
            "T": int(predictor.cfg.diffusion_steps) if is_dcm else 1,
            "sampler": predictor.cfg.sampler if is_dcm else "single-pass",
            "sampling_steps": (predictor.cfg.sampling_steps or predictor.cfg.diffusion_steps) if is_dcm else 1,
            "n_samples": k,
            "net": predictor.cfg.net.get("name"),
            # named only when it is not the default, so a log of the default's fingerprint does not depend on it
            **({"task_loss": predictor.cfg.task_loss} if is_dcm and predictor.cfg.task_loss != "of_mean" else {}),
            # as task_loss: named only where samples share steps, so other logs keep their fingerprint
            **({"shared_steps": predictor.resolved_shared_steps}
               if is_dcm and k > 1 and predictor.resolved_shared_steps > 0 else {}),
            **({"precision": predictor.inference_precision}
               if getattr(predictor, "inference_precision", "float32") != "float32" else {}),
        }
    if isinstance(predictor, PriorBlend):
        return {**describe(predictor.model, n_samples), **predictor.describe()}
    if hasattr(predictor, "describe"):
        return predictor.describe()
    return {"model": type(predictor).__name__}


def with_prior(predictor: Any, prior: str | Path | None, weight: float, source: str) -> Any:
    """``predictor`` blended with the stiffness ridge in the JSON file ``prior`` at ``weight``
    (:class:`dcm.models.prior_blend.PriorBlend`); the predictor itself when ``prior`` is None. ``source``
    names the setting in errors."""
    if prior is None or str(prior) == "":
        return predictor
    if not isinstance(predictor, ForceModel):
        raise ModelInputError(f"{source}: prior applies to a DCM or baseline checkpoint, not to "
                              f"{describe(predictor).get('ckpt', type(predictor).__name__)}")
    ridge = load_model(prior)
    if not isinstance(ridge, StiffnessRegression):
        raise ModelInputError(f"{source}: prior = {prior} is not a stiffness reference JSON "
                              "(python -m dcm.models.references fit)")
    return PriorBlend(predictor, ridge, weight)  # checks the weight


__all__ = ["ForcePredictor", "Predictor", "TaskLossPredictor", "check_dataset", "describe", "load_model", "model_class",
           "predict_task_loss", "trained_on", "trained_recording", "with_prior"]
