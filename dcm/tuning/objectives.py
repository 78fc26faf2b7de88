"""The two ways to score a batch of per-phase stiffness proposals for one skill.

``ModelObjective`` is robot-free: a predictor (force model, or the stiffness-only reference) predicts L_task
through :func:`dcm.models.predict.predict_task_loss`.
``SimulatorObjective`` is robot-based: every proposal is a simulator rollout. Both return (B, 2) arrays of
(L_task [N], L_comp [kN/m]), with NaN rows for failed trials, so one optimisation loop serves both.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dcm.control import compliance_loss, schedule_from_phases


@dataclass
class Skill:
    """A recorded demo plus how proposals become stiffness schedules and attractors for it."""

    x_demo: np.ndarray  # (H, 6) bowl frame
    force_demo: np.ndarray  # (H, 6) N, N·m
    boundaries: np.ndarray  # (P + 1,) phase boundaries in control steps
    rot_Nmprad: float

    def schedules(self, proposals: np.ndarray) -> np.ndarray:
        """(B, P, 3) per-phase stiffness in N/m -> (B, H, 6) schedules."""
        return np.stack([schedule_from_phases(p, self.boundaries, self.rot_Nmprad) for p in proposals])


class ModelObjective:
    """L_task predicted by any predictor :func:`dcm.models.predict.load_model` returns; L_comp is exact."""

    def __init__(self, model: Any, skill: Skill, attractor: Any, n_samples: int = 1):
        self.model = model
        self.skill = skill
        self.attractor = attractor  # callable (H, 6) stiffness -> (H, 6) attractor, as the simulator computes it
        self.n_samples = n_samples

    def inputs(self, proposals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Raw predictor inputs (x_demo, F_demo, x_attr, K), each (B, H, 6), for (B, P, 3) proposals."""
        stiffness = self.skill.schedules(proposals)
        x_attr = np.stack([self.attractor(k) for k in stiffness])
        batch = len(proposals)
        x_demo = np.repeat(self.skill.x_demo[None], batch, axis=0)
        force_demo = np.repeat(self.skill.force_demo[None], batch, axis=0)
        return x_demo, force_demo, x_attr, stiffness

    def predict(self, proposals: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Schedules (B, H, 6), predicted mean force (B, H, 6) [N] and its spread; None for a predictor
        without forces (the stiffness-only reference)."""
        x_demo, force_demo, x_attr, stiffness = self.inputs(proposals)
        if not hasattr(self.model, "predict_forces"):
            return stiffness, None, None
        mean, std = self.model.predict_forces(x_demo, force_demo, x_attr, stiffness, n_samples=self.n_samples)
        return stiffness, np.asarray(mean), np.asarray(std)

    def __call__(self, proposals: np.ndarray) -> np.ndarray:
        from dcm.models.predict import predict_task_loss  # torch-heavy: only when a model is used

        x_demo, force_demo, x_attr, stiffness = self.inputs(proposals)
        L_task = predict_task_loss(self.model, x_demo, force_demo, x_attr, stiffness, n_samples=self.n_samples)
        return np.stack([L_task, compliance_loss(stiffness)], axis=1)


class SimulatorObjective:
    """Every proposal is a simulated rollout; failed rollouts score NaN and are kept with their reason."""

    def __init__(self, simulator: Any, demo: Any, skill: Skill):
        self.simulator = simulator
        self.demo = demo
        self.skill = skill
        self.trials: list[Any] = []

    def __call__(self, proposals: np.ndarray) -> np.ndarray:
        scores = []
        for stiffness in self.skill.schedules(proposals):
            trial = self.simulator.rollout(self.demo, stiffness)
            self.trials.append(trial)
            scores.append([np.nan, np.nan] if trial.failed else [trial.L_task, trial.L_comp])
        return np.asarray(scores, dtype=np.float64)
