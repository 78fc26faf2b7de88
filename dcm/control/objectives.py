"""The two objectives of stiffness learning. Both are minimised; both accept numpy arrays or torch tensors."""

from __future__ import annotations

import math
from typing import Any

# how k force samples give a predicted L_task: of their mean force, or over the samples (spread included)
TASK_LOSSES = ("of_mean", "over_samples")


def task_loss(force_obs: Any, force_demo: Any, from_step: int = 0) -> Any:
    """L_task [N]: RMSE of the observed against the demonstrated contact force over time and the 3 force axes.

    Torques are left out because their unit differs. Leading batch dimensions are kept; time is the second
    to last axis. ``from_step``: count the steps from this one on (:func:`task_window_start`).
    """
    err = (force_obs[..., from_step:, :3] - force_demo[..., from_step:, :3]) ** 2
    return err.mean(-1).mean(-1) ** 0.5


def task_window_start(task_from_s: float, control_hz: float, horizon: int) -> int:
    """The first control step that L_task counts when scoring from ``task_from_s`` seconds on.

    Every demo starts with an approach (``DemoSpec.approach_s``): the tool descends onto the bowl and F_demo
    jumps from 0 to the press force within a step or two. A rollout that touches down a step earlier or later,
    or overshoots on impact, errs by newtons there, and those few steps can hold most of a trajectory's
    squared error. Scoring from the approach's end ranks schedules by how they track the force while wiping.
    Raises ValueError naming ``task_from_s`` unless 0 <= it < the horizon.
    """
    seconds = float(task_from_s)
    start = int(round(seconds * float(control_hz))) if math.isfinite(seconds) else -1
    if start < 0 or start >= int(horizon):
        raise ValueError(f"task_from_s = {task_from_s} s must be >= 0 and before the end of the "
                         f"{int(horizon) / float(control_hz):g} s trajectories")
    return start


def task_loss_over_samples(force_mean: Any, force_std: Any, force_demo: Any) -> Any:
    """The root mean square over k force samples of their L_task [N], from the samples' mean and population
    std alone: ``sqrt(mean_t,axes((mean - F_demo)^2 + std^2))``.

    Unlike :func:`task_loss` of the mean force, it counts the spread: a force that is uncertain (say, by the
    stiffness times an unknown surface offset) tracks the demo worse on average than its mean does. With
    ``std = 0`` it is ``task_loss(force_mean, force_demo)``.
    """
    err = (force_mean[..., :3] - force_demo[..., :3]) ** 2 + force_std[..., :3] ** 2
    return err.mean(-1).mean(-1) ** 0.5


def compliance_loss(stiffness: Any) -> Any:
    """L_comp [kN/m]: the mean over time of the Euclidean norm of the translational stiffness.

    This is the paper's sum_t |K_t| divided by the horizon, so that demos of different lengths compare.
    """
    norm = ((stiffness[..., :3] ** 2).sum(-1)) ** 0.5
    return norm.mean(-1) / 1000.0
