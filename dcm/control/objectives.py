"""The two objectives of stiffness learning. Both are minimised; both accept numpy arrays or torch tensors."""

from __future__ import annotations

from typing import Any


# how k force samples give a predicted L_task: of their mean force, or over the samples (spread included)
TASK_LOSSES = ("of_mean", "over_samples")


def task_loss(force_obs: Any, force_demo: Any) -> Any:
    """L_task [N]: RMSE of the observed against the demonstrated contact force over time and the 3 force axes.

    Torques are left out because their unit differs. Leading batch dimensions are kept.
    """
    err = (force_obs[..., :3] - force_demo[..., :3]) ** 2
    return err.mean(-1).mean(-1) ** 0.5


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
