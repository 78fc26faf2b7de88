"""A force model's L_task ranking blended with the stiffness-only ridge: a prior where the model cannot resolve.

A learned model ranks a skill's schedules well where they differ in L_task by more than it errs, and no better
than chance where they differ by less; the stiffness-only ridge knows nothing of the path but orders
schedules by what stiffness usually does (studies/record.md, "Which skills can be ranked"). The blend is a
weighted geometric mean, ``L = L_model ** (1 - w) * L_ridge ** w``: in log space the ridge adds the same
stiffness preference to every skill, which reorders the schedules of a skill whose predicted L_task barely
varies and leaves alone those of a skill whose predicted L_task varies a lot. ``w = 0`` is the model, ``w = 1``
the ridge. Choose ``w`` on a validation split (``python -m studies.model_study.model_table ...
--prior <ridge.json> --prior-weight w`` for a few w) and use it with ``dcm.evaluate prior=... prior_weight=...`` or
``tune.py prior=... prior_weight=...``.
"""

from __future__ import annotations

import math
import warnings
from typing import Any, ClassVar

import numpy as np

from dcm.models.configuration import ModelInputError
from dcm.models.references import StiffnessRegression

PRIOR_BLEND = "prior_blend"


def check_weight(weight: Any) -> float:
    """``prior_weight`` as a float in [0, 1]; a :class:`ModelInputError` naming it otherwise."""
    try:
        value = float(weight)
    except (TypeError, ValueError):
        value = math.nan
    if not 0.0 <= value <= 1.0:  # also refuses NaN
        raise ModelInputError(f"prior_weight = {weight!r} must be a number in [0, 1] (0: the model alone, 1: the "
                              "stiffness prior alone)")
    return value


class PriorWeightWarning(UserWarning):
    """A prior given at ``prior_weight = 0``: the blend ranks with the model alone."""


def check_prior(prior: Any, weight: Any) -> float:
    """``prior_weight`` checked (:func:`check_weight`) together with ``prior``, before any model is loaded.

    A weight without a prior is refused: the run would rank with the model alone while the user asked for a
    blend. A prior at weight 0 is the model alone too, but that is the w = 0 point of a weight sweep, so it
    only warns (:class:`PriorWeightWarning`)."""
    value = check_weight(weight)
    given = prior is not None and str(prior) != ""
    if value > 0.0 and not given:
        raise ModelInputError(f"prior_weight = {weight} needs prior=<stiffness reference JSON> to blend with; "
                              "without it the model ranks alone (prior_weight=0)")
    if given and value == 0.0:
        warnings.warn(f"prior = {prior} at prior_weight = 0 ranks with the model alone; set prior_weight in "
                      "(0, 1] to blend it in", PriorWeightWarning, stacklevel=2)
    return value


class PriorBlend:
    """``L_task = L_model^(1 - weight) * L_prior^weight`` for a force model and a stiffness ridge."""

    model_kind: ClassVar[str] = PRIOR_BLEND
    ranks_schedules: ClassVar[bool] = True

    def __init__(self, model: Any, prior: StiffnessRegression, weight: float) -> None:
        """``prior`` must be a stiffness ridge (:func:`dcm.models.predict.with_prior` checks it, naming the file)."""
        self.model = model
        self.prior = prior
        self.weight = check_weight(weight)

    @property
    def data_spec(self) -> Any:
        return self.model.data_spec

    @property
    def objective(self) -> Any:
        """The force model's L_task (the prior was fitted for the same one: :func:`dcm.models.predict.with_prior`)."""
        return self.model.objective

    @property
    def predicts_pose(self) -> bool:
        return bool(self.model.predicts_pose)

    @property
    def device(self) -> Any:
        """The force model's device, so that callers seed its sampling as they would the model's own."""
        return self.model.device

    def check_phases(self, n_phases: int | None, source: str) -> None:
        self.prior.check_phases(n_phases, source)

    def check_window(self, task_from_s: float, source: str) -> None:
        self.prior.check_window(task_from_s, source)

    def combine(self, L_model: np.ndarray, L_prior: np.ndarray) -> np.ndarray:
        """The blended L_task [N] of the model's and the prior's (B,) predictions."""
        L_model = np.asarray(L_model, dtype=np.float64)
        if self.weight == 0.0:
            return L_model
        floor = np.finfo(np.float64).tiny  # a model may predict L_task = 0 exactly (a perfect copy of F_demo)
        return np.exp((1.0 - self.weight) * np.log(np.maximum(L_model, floor))
                      + self.weight * np.log(np.asarray(L_prior, dtype=np.float64)))

    def describe(self) -> dict[str, Any]:
        return {"prior": self.prior.path or "fitted in memory", "prior_weight": self.weight}
