"""The two objectives of stiffness learning. Both are minimised; both accept numpy arrays or torch tensors."""

from __future__ import annotations

from typing import Any


def task_loss(force_obs: Any, force_demo: Any) -> Any:
    """L_task [N]: RMSE of the observed against the demonstrated contact force over time and the 3 force axes.

    Torques are left out because their unit differs. Leading batch dimensions are kept.
    """
    err = (force_obs[..., :3] - force_demo[..., :3]) ** 2
    return err.mean(-1).mean(-1) ** 0.5


def compliance_loss(stiffness: Any) -> Any:
    """L_comp [kN/m]: the mean over time of the Euclidean norm of the translational stiffness.

    This is the paper's sum_t |K_t| divided by the horizon, so that demos of different lengths compare.
    """
    norm = ((stiffness[..., :3] ** 2).sum(-1)) ** 0.5
    return norm.mean(-1) / 1000.0
