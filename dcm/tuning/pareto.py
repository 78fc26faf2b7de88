"""Pareto sets and the hypervolume indicator I_H for two minimised objectives (L_task, L_comp)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from botorch.utils.multi_objective.box_decompositions.dominated import DominatedPartitioning
from botorch.utils.multi_objective.pareto import is_non_dominated


def pareto_mask(objectives: np.ndarray) -> np.ndarray:
    """Boolean mask (N,) of the non-dominated rows of minimised objectives (N, M); duplicates kept once."""
    objectives = np.asarray(objectives, dtype=np.float64)
    if objectives.size == 0:
        return np.zeros(0, dtype=bool)
    # botorch maximises: negate.
    return is_non_dominated(-torch.as_tensor(objectives), deduplicate=True).numpy()


def hypervolume(objectives: np.ndarray, reference: np.ndarray) -> float:
    """Area dominated by minimised objectives (N, M) and bounded by ``reference`` (M,); 0 if none beat it."""
    objectives = np.asarray(objectives, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if objectives.ndim != 2 or objectives.shape[1] != reference.shape[0]:
        raise ValueError(f"objectives {objectives.shape} and reference point {reference.shape} do not match")
    inside = np.all(objectives < reference, axis=1)
    if not inside.any():
        return 0.0
    partitioning = DominatedPartitioning(
        ref_point=-torch.as_tensor(reference), Y=-torch.as_tensor(objectives[inside])
    )
    return float(partitioning.compute_hypervolume())


def reference_point(*objective_sets: np.ndarray, margin: float = 0.1) -> np.ndarray:
    """A shared reference point: the worst value of each objective over all sets, pushed out by ``margin``.

    Hypervolumes of different methods compare only against one reference point, so it is taken over the union.
    """
    stacked = np.concatenate([np.asarray(s, dtype=np.float64) for s in objective_sets if len(s)], axis=0)
    worst, best = stacked.max(axis=0), stacked.min(axis=0)
    return worst + margin * np.maximum(worst - best, 1e-9)


def pick_spread(objectives: np.ndarray, count: int) -> np.ndarray:
    """Indices of up to ``count`` Pareto-optimal rows spread evenly along the front (sorted by L_comp)."""
    finite = np.flatnonzero(np.isfinite(objectives).all(axis=1))
    front = finite[pareto_mask(objectives[finite])]
    front = front[np.argsort(objectives[front, 1])]
    if len(front) <= count:
        return front
    return front[np.unique(np.round(np.linspace(0, len(front) - 1, count)).astype(int))]


def solution_record(phase_stiffness: np.ndarray, validated: np.ndarray, **measured: np.ndarray) -> dict[str, Any]:
    """One solution as a ``results.json`` lists it: its per-phase stiffness, its other (L_task, L_comp) by name
    (``predicted`` by a model, ``observed`` in a search's trial) and its validated ones."""
    pair = lambda v: {"L_task_N": v[0], "L_comp_kNpm": v[1]}  # noqa: E731
    return {"phase_stiffness_Npm": np.asarray(phase_stiffness).tolist(),
            **{name: pair(value) for name, value in measured.items()},
            "validated": {**pair(validated), "failed": bool(np.isnan(validated).any())}}
