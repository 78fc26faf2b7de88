"""Stiffness schedules: split a demo into phases and hold one stiffness per phase."""

from __future__ import annotations

import numpy as np


def equal_time_phases(horizon: int, n_phases: int) -> np.ndarray:
    """Phase boundaries (n_phases + 1,) that cut ``horizon`` steps into equal-time phases."""
    if n_phases < 1 or horizon < n_phases:
        raise ValueError(f"cannot split a horizon of {horizon} steps into n_phases={n_phases} phases")
    return np.round(np.linspace(0, horizon, n_phases + 1)).astype(int)


def changepoint_phases(signal: np.ndarray, n_phases: int, min_size: int = 5) -> np.ndarray:
    """Data-driven phase boundaries: the ``n_phases - 1`` strongest change points of a demo signal.

    ``signal`` (H, C) is typically the demo force or path; each channel is standardised first so that
    newtons and metres weigh alike. Uses ruptures' exact dynamic-programming segmentation (L2 cost).
    """
    import ruptures

    signal = np.asarray(signal, dtype=np.float64)
    if signal.ndim == 1:
        signal = signal[:, None]
    horizon = signal.shape[0]
    if n_phases < 1 or horizon < n_phases * min_size:
        raise ValueError(
            f"cannot segment a signal of {horizon} steps into n_phases={n_phases} phases of >= {min_size} steps"
        )
    if n_phases == 1:
        return np.array([0, horizon])
    std = signal.std(axis=0)
    scaled = (signal - signal.mean(axis=0)) / np.where(std > 1e-12, std, 1.0)
    ends = ruptures.Dynp(model="l2", min_size=min_size, jump=1).fit(scaled).predict(n_bkps=n_phases - 1)
    return np.array([0, *ends], dtype=int)


def schedule_from_phases(
    phase_stiffness: np.ndarray, boundaries: np.ndarray, rot_stiffness: float = 20.0
) -> np.ndarray:
    """Expand per-phase stiffness (P, 3) or (P, 6) into a schedule K_{1:H} (H, 6) held constant per phase.

    With 3 columns the rotational stiffness is ``rot_stiffness`` N·m/rad on every axis.
    """
    phase_stiffness = np.atleast_2d(np.asarray(phase_stiffness, dtype=np.float64))
    boundaries = np.asarray(boundaries, dtype=int)
    n_phases = phase_stiffness.shape[0]
    if phase_stiffness.shape[1] not in (3, 6):
        raise ValueError(f"phase stiffness must have 3 or 6 columns, got shape {phase_stiffness.shape}")
    if boundaries.shape != (n_phases + 1,) or boundaries[0] != 0 or np.any(np.diff(boundaries) <= 0):
        raise ValueError(
            f"phase boundaries {boundaries.tolist()} must start at 0 and increase, one more than {n_phases} phases"
        )
    if phase_stiffness.shape[1] == 3:
        rot = np.full((n_phases, 3), float(rot_stiffness))
        phase_stiffness = np.concatenate([phase_stiffness, rot], axis=1)
    return np.repeat(phase_stiffness, np.diff(boundaries), axis=0)


def phase_boundaries(method: str, n_phases: int, force_demo: np.ndarray) -> np.ndarray:
    """Phase boundaries of a demo by ``method``: ``equal_time``, or ``changepoint`` of the demo force (H, >=3)."""
    force_demo = np.asarray(force_demo)
    if method == "equal_time":
        return equal_time_phases(force_demo.shape[0], n_phases)
    if method == "changepoint":
        return changepoint_phases(force_demo[:, :3], n_phases)
    raise ValueError(f"phase method {method!r} is unknown; expected 'equal_time' or 'changepoint'")
