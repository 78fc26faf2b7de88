"""What a contact predictor says a stiffness schedule does: the wrench the tool feels and, for a predictor of
the pose, where the tool goes. Plain arrays (numpy or torch), so every predictor returns the same thing."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class ContactPrediction:
    """Means and spreads over a prediction's samples (the spread is 0 for a deterministic predictor).

    ``force_mean`` / ``force_std``: the wrench F_obs (B, H, 6) [N, N·m]. ``x_mean`` / ``x_std``: the tool's
    translation x_obs (B, H, 3) [m], bowl frame, absolute (x_demo plus the predicted deviation); None when
    the predictor predicts only the force.
    """

    force_mean: Any
    force_std: Any
    x_mean: Any | None = None
    x_std: Any | None = None

    @property
    def has_pose(self) -> bool:
        return self.x_mean is not None


__all__ = ["ContactPrediction"]
