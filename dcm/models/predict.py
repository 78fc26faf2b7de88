"""Load any predictor by path or name, check a dataset against it, and get predicted L_task from it.

A *predictor* is anything the evaluator and the tuner can score schedules with:

* a force model checkpoint (DCM or Baseline, ``.ckpt``): ``predict_contact`` -> forces (and, for a model
  trained with ``target_fields=force_and_pose``, the tool's pose), L_task from them;
* ``copy_demo`` (no file): ``predict_contact`` returns F_demo and x_demo;
* a stiffness reference JSON (``python -m dcm.models.references fit``): ``predict_task_loss`` directly.

Every predictor says which L_task it predicts (``objective``, a :class:`dcm.control.objectives.TaskObjective`)
and whether it predicts the tool's pose (``predicts_pose``). :func:`predict_task_loss` is the one call that
works for all of them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dcm.console import one_line
from dcm.control.objectives import TaskObjective
from dcm.models.checkpoint import checkpoint_card, checkpoint_kind
from dcm.models.configuration import CheckpointKindError, ModelInputError, check_objective_fits, check_objective_name
from dcm.models.contact import ContactPrediction
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
class ContactPredictor(Protocol):
    """Predicts the contact wrench and, where it can, the tool's pose (:class:`ContactPrediction`)."""

    def predict_contact(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                        generator: Any = None) -> ContactPrediction: ...


@runtime_checkable
class TaskLossPredictor(Protocol):
    """Predicts L_task (B,) [N] directly, without forces."""

    def predict_task_loss(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any) -> np.ndarray: ...


Predictor = ContactPredictor | ForcePredictor | TaskLossPredictor


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
    model.checkpoint_path = str(path)  # named by errors about what it was trained for
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


def predictor_source(predictor: Any) -> str:
    """How errors name a predictor: its file where known, else its kind."""
    if isinstance(predictor, PriorBlend):
        return predictor_source(predictor.model)
    path = getattr(predictor, "checkpoint_path", None) or getattr(predictor, "path", None)
    kind = getattr(predictor, "model_kind", type(predictor).__name__)
    return f"checkpoint {path}" if path else f"the {kind} predictor"


def predictor_objective(predictor: Any) -> TaskObjective:
    """The L_task a predictor predicts (its ``objective``; the paper's for one that names none)."""
    objective = getattr(predictor, "objective", None)
    return objective if isinstance(objective, TaskObjective) else TaskObjective()


def resolve_objective(predictor: Any, objective: TaskObjective | None) -> TaskObjective:
    """``objective``, checked against what ``predictor`` was trained or fitted for (None: its own). Another kind
    of objective than a checkpoint's, one a stiffness ridge was not fitted for, or one counting the path for a
    predictor of the force alone is a one-line :class:`ModelInputError` naming both and the file. Copy-the-demo
    learnt nothing, so any objective applies to it."""
    own = predictor_objective(predictor)
    if objective is None or isinstance(predictor, CopyDemo):
        return own if objective is None else objective
    source = predictor_source(predictor)
    if isinstance(predictor, StiffnessRegression):
        predictor.check_objective(objective, source)
        return objective
    check_objective_name(objective, own, source)
    if isinstance(predictor, (ForceModel, PriorBlend)):
        target_fields = "force_and_pose" if predictor.predicts_pose else "force"
        try:
            check_objective_fits(objective, target_fields)
        except ModelInputError as err:
            raise ModelInputError(f"{source}: {err}") from None
    if isinstance(predictor, PriorBlend):
        predictor.prior.check_objective(objective, predictor_source(predictor.prior))
    return objective


def predict_contact(predictor: Any, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                    generator: Any = None) -> ContactPrediction:
    """What any force predictor predicts for raw inputs: its ``predict_contact``, or for one that has only
    ``predict_forces`` the wrench without a pose."""
    kwargs = {"n_samples": n_samples} if generator is None else {"n_samples": n_samples, "generator": generator}
    inputs = (_numpy(x_demo), _numpy(F_demo), _numpy(x_attr), _numpy(K))
    if isinstance(predictor, ContactPredictor):
        return predictor.predict_contact(*inputs, **kwargs)
    if isinstance(predictor, ForcePredictor):
        return ContactPrediction(*predictor.predict_forces(*inputs, **kwargs))
    raise TypeError(f"{type(predictor).__name__} has neither predict_contact nor predict_forces")


def predict_task_loss(predictor: Any, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                      generator: Any = None, from_step: int = 0, objective: TaskObjective | None = None
                      ) -> np.ndarray:
    """Predicted L_task (B,) of any predictor for (B, H, 6) or (H, 6) raw inputs, of ``objective`` (None: the
    predictor's own, :func:`resolve_objective`), in its unit (N for the paper's).

    Force predictors: the objective's L_task of the (``n_samples``-averaged) predicted force, and where it
    counts the path of the predicted pose, against the demo's from step ``from_step`` on, or what a DCM's
    ``task_loss`` option makes of its samples (``ForceModel.predicted_task_loss``). Others: their
    ``predict_task_loss``, of the window and objective they were fitted on (``StiffnessRegression.check_window``,
    ``check_objective``).
    """
    objective = resolve_objective(predictor, objective)
    if isinstance(predictor, PriorBlend):
        L_model = predict_task_loss(predictor.model, x_demo, F_demo, x_attr, K, n_samples, generator, from_step,
                                    objective)
        return predictor.combine(L_model, predict_task_loss(predictor.prior, x_demo, F_demo, x_attr, K))
    if isinstance(predictor, (ContactPredictor, ForcePredictor)):
        contact = predict_contact(predictor, x_demo, F_demo, x_attr, K, n_samples, generator)
        mean, std, demo = (_numpy(a).astype(np.float64) for a in (contact.force_mean, contact.force_std, F_demo))
        poses: dict[str, Any] = {}
        if contact.has_pose:
            poses = {"x_mean": _numpy(contact.x_mean).astype(np.float64), "x_demo": _numpy(x_demo).astype(np.float64)}
        if isinstance(predictor, ForceModel):
            if contact.has_pose:
                poses["x_std"] = _numpy(contact.x_std).astype(np.float64)
            return np.atleast_1d(np.asarray(predictor.predicted_task_loss(mean, std, demo, from_step=int(from_step),
                                                                          objective=objective, **poses)))
        return np.atleast_1d(np.asarray(objective.task_loss(mean, demo, poses.get("x_mean"), poses.get("x_demo"),
                                                            int(from_step))))
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
            # as task_loss: named only where they are not the default, so earlier logs keep their fingerprint
            **({"target_fields": predictor.cfg.target_fields} if predictor.predicts_pose else {}),
            **({"objective": predictor.objective.to_dict()} if predictor.objective.name != "paper" else {}),
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
    ridge.check_objective(predictor.objective, f"{source}, prior = {prior}")  # both must rank the same L_task
    return PriorBlend(predictor, ridge, weight)  # checks the weight


__all__ = ["ContactPredictor", "ForcePredictor", "Predictor", "TaskLossPredictor", "check_dataset", "describe",
           "load_model", "model_class", "predict_contact", "predict_task_loss", "predictor_objective",
           "predictor_source", "resolve_objective", "trained_on", "trained_recording", "with_prior"]
