"""The within-skill L_task term a force model can add to its training loss (``task_weight`` > 0).

The tuner asks a model which of one skill's stiffness schedules track the demo better. Within a skill the
schedules' L_task can differ by about as much as a model errs per step, so a force loss alone can fit
every trajectory closely and still order a skill's trials by its own noise. This term scores what the
tuner uses: each trial's L_task minus the mean of its skill's trials in the batch, predicted against true.
Batches must hold several trials per skill (``data.skill_group``).
"""

from __future__ import annotations

import torch

__all__ = ["centered_by_group", "within_skill_task_error"]


def centered_by_group(values: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """``values`` (B,) minus the mean of the values sharing their label in ``groups`` (B,)."""
    _, member = torch.unique(groups, return_inverse=True)
    n = int(member.max()) + 1 if member.numel() else 0
    sums = values.new_zeros(n).index_add(0, member, values)
    counts = values.new_zeros(n).index_add(0, member, torch.ones_like(values))
    return values - (sums / counts)[member]


def within_skill_task_error(L_pred: torch.Tensor, L_true: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """Mean squared error of the within-skill deviations of L_task, over the trials whose skill has at least
    two trials in the batch (0 when none has): what ranking one skill's schedules gets wrong, whatever the
    skill's level. A model that is right up to a per-skill offset scores 0."""
    _, member, counts = torch.unique(groups, return_inverse=True, return_counts=True)
    shared = counts[member] > 1
    if not bool(shared.any()):
        return L_pred.sum() * 0.0  # keeps the graph (and DDP's unused-parameter check) intact
    err = centered_by_group(L_pred - L_true, groups)  # centring is linear: one pass for both
    return (err[shared] ** 2).mean()
