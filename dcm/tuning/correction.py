"""Correct a predictor's L_task on one skill from the few robot trials observed on it.

A force model trained on other skills is biased on a new one in ways that depend on the schedule (the demo's
tilted front: the model expects stiffer schedules to track better, the simulator disagrees). The trials the
robot ran are the only ground truth, and there are few of them (5 to 15), so every correction here is a
residual ``observed - predicted`` L_task over the per-phase log-stiffness with a strong pull towards the
model: where no trial was run, the model's own prediction stands. L_comp is exact and never corrected.

``none``: the model as it is. ``offset``: one constant (moves the whole front; cannot change which schedules
are Pareto-optimal, only how far the prediction is from the observation). ``ridge``: a linear residual in the
normalised log-stiffness, ridge penalty ``ridge_alpha``. ``gp``: the mean of a Gaussian process with zero prior
mean (kernel ridge regression with an RBF kernel of ``lengthscale`` in normalised log-stiffness and noise
``noise_ratio`` relative to its signal variance), on top of the observed mean offset; far from every trial it
returns to that offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

CORRECTIONS = ("none", "offset", "ridge", "gp")


@dataclass
class Correction:
    """A fitted residual of L_task [N] over (B, P, 3) per-phase stiffness in N/m."""

    kind: str
    log_low: float  # log(min_Npm) of the search space: features are (log K - log_low) / log_span
    log_span: float
    lengthscale: float = 0.3
    noise_ratio: float = 0.1
    ridge_alpha: float = 1.0
    offset: float = 0.0
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def features(self, phase_stiffness: np.ndarray) -> np.ndarray:
        k = np.asarray(phase_stiffness, dtype=np.float64)
        return ((np.log(k) - self.log_low) / self.log_span).reshape(len(k), -1)

    def _kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        squared = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
        return np.exp(-0.5 * squared / self.lengthscale**2)

    def fit(self, phase_stiffness: np.ndarray, residual_N: np.ndarray) -> Correction:
        """Fit on the finite residuals of the observed trials; returns self."""
        residual = np.asarray(residual_N, dtype=np.float64)
        keep = np.isfinite(residual)
        z, y = self.features(np.asarray(phase_stiffness)[keep]), residual[keep]
        self.offset, self.weights, self.anchors = 0.0, np.zeros(0), np.zeros((0, z.shape[1] if z.ndim == 2 else 0))
        if self.kind == "none" or not len(y):
            return self
        self.offset = float(y.mean())
        if self.kind == "ridge":
            centred = z - z.mean(axis=0)
            gram = centred.T @ centred + self.ridge_alpha * np.eye(z.shape[1])
            self.weights = np.linalg.solve(gram, centred.T @ (y - self.offset))
            self.anchors = z.mean(axis=0, keepdims=True)
        elif self.kind == "gp":
            gram = self._kernel(z, z) + self.noise_ratio * np.eye(len(y))
            self.weights = np.linalg.solve(gram, y - self.offset)
            self.anchors = z
        return self

    def __call__(self, phase_stiffness: np.ndarray) -> np.ndarray:
        """The L_task correction [N] (B,) to add to the model's prediction."""
        batch = len(phase_stiffness)
        if self.kind == "none":
            return np.zeros(batch)
        if self.kind == "offset" or not len(self.weights):
            return np.full(batch, self.offset)
        z = self.features(phase_stiffness)
        if self.kind == "ridge":
            return self.offset + (z - self.anchors) @ self.weights
        return self.offset + self._kernel(z, self.anchors) @ self.weights

    def describe(self) -> dict[str, Any]:
        """What ``loop.json`` records of the fitted correction."""
        out: dict[str, Any] = {"kind": self.kind, "offset_N": self.offset}
        if self.kind == "gp":
            out.update(lengthscale=self.lengthscale, noise_ratio=self.noise_ratio)
        if self.kind == "ridge":
            out.update(ridge_alpha=self.ridge_alpha)
        return out


def make_correction(kind: str, min_Npm: float, max_Npm: float, **options: float) -> Correction:
    """An unfitted correction of ``kind`` for a search space of [min_Npm, max_Npm]."""
    if kind not in CORRECTIONS:
        raise ValueError(f"correction {kind!r}; expected one of {', '.join(CORRECTIONS)}")
    low = float(np.log(min_Npm))
    return Correction(kind, low, max(float(np.log(max_Npm)) - low, 1e-9), **options)


__all__ = ["CORRECTIONS", "Correction", "make_correction"]
