"""Per-phase stiffness values recovered from a commanded schedule K (H, 6), and regression features of them.

The stiffness-only reference must work wherever a force model works: in ``dcm.evaluate`` on dataset
trajectories and in the tuner, which only hands over schedules built by
:func:`dcm.control.schedule_from_phases`. Both give the *commanded* schedule, piecewise constant over the
phases, so the per-phase values are read from K alone by **detecting its constant segments** (rows where
any translational channel changes start a new segment). This works for equal-time and change-point
phases and for any horizon; it does not need the phase boundaries.

With ``P`` phases, a schedule has at most ``P`` segments: fewer when consecutive phases share a value, in
which case the phases are shared out among the segments in proportion to their length (each segment gets
at least one; for equal-time phases this is exact). More than ``P`` segments means K is not a ``P``-phase
commanded schedule (e.g. a filtered or logged stiffness) and is refused.
"""

from __future__ import annotations

import numpy as np

FEATURE_SPEC = "phase_stiffness_v1"
AXES = ("x", "y", "z")
CHANGE_TOL_NPM = 1e-3  # float32 storage of <= 1e4 N/m is exact to ~1e-3 N/m


class StiffnessScheduleError(ValueError):
    """A stiffness schedule is not the piecewise-constant P-phase schedule the reference expects."""


def _allocate(lengths: np.ndarray, n_phases: int) -> np.ndarray:
    """Phases per segment: one each, the remaining ones by largest remainder of each segment's time share."""
    extra = n_phases - len(lengths)
    share = np.clip(lengths / lengths.sum() * n_phases - 1.0, 0.0, None)  # sums to >= extra > 0
    share = share / share.sum() * extra
    counts = np.floor(share).astype(int)
    counts[np.argsort(-(share - counts), kind="stable")[: extra - counts.sum()]] += 1
    return counts + 1


def phase_values(K: np.ndarray, n_phases: int, where: str = "K") -> np.ndarray:
    """Per-phase translational stiffness (P, 3) [N/m] of one commanded schedule K (H, >=3).

    See the module docstring for the rule; ``where`` names the schedule in errors.
    """
    K = np.asarray(K, dtype=np.float64)
    if K.ndim != 2 or K.shape[1] < 3 or K.shape[0] < n_phases:
        raise StiffnessScheduleError(f"{where}: expected a (H, 6) stiffness schedule with H >= {n_phases}, "
                                     f"got shape {K.shape}")
    Kt = K[:, :3]
    changes = np.flatnonzero(np.any(np.abs(np.diff(Kt, axis=0)) > CHANGE_TOL_NPM, axis=1)) + 1
    starts = np.concatenate([[0], changes])
    if len(starts) > n_phases:
        raise StiffnessScheduleError(
            f"{where}: {len(starts)} constant segments (first changes at steps {changes[:5].tolist()}), but the "
            f"reference expects a commanded schedule of at most {n_phases} phases; a filtered or logged "
            "stiffness cannot be read as per-phase values")
    values = Kt[starts]
    if len(starts) < n_phases:
        lengths = np.diff(np.concatenate([starts, [K.shape[0]]])).astype(np.float64)
        values = np.repeat(values, _allocate(lengths, n_phases), axis=0)
    return values


def batch_phase_values(K: np.ndarray, n_phases: int, names: list[str] | None = None) -> np.ndarray:
    """(B, P, 3) per-phase values of a batch of schedules (B, H, 6) or one (H, 6)."""
    K = np.asarray(K)
    if K.ndim == 2:
        K = K[None]
    return np.stack([phase_values(k, n_phases, where=names[i] if names else f"K[{i}]") for i, k in enumerate(K)])


def feature_names(n_phases: int) -> list[str]:
    """Names of :func:`features`' columns, in order."""
    names = [f"K{a}_p{p}/1000" for p in range(n_phases) for a in AXES]
    names += [f"1000/K{a}_p{p}" for p in range(n_phases) for a in AXES]
    names += [f"dK{a}_p{p}{p + 1}/1000" for p in range(n_phases - 1) for a in AXES]
    names += [f"|dK{a}_p{p}{p + 1}|/1000" for p in range(n_phases - 1) for a in AXES]
    return names


def features(values: np.ndarray) -> np.ndarray:
    """Regression features (B, F) of per-phase stiffness (B, P, 3) [N/m], per axis.

    Per phase: K/1000 and 1000/K (stiffer tracks better, with diminishing returns); between consecutive
    phases: the signed and absolute jump /1000 (the controller's stiffness filter lags a commanded jump
    while the attractor assumes it, which is where most of the L_task spread of the simulator comes from).
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 3 or v.shape[2] != 3:
        raise StiffnessScheduleError(f"per-phase stiffness must be (B, P, 3), got shape {v.shape}")
    if np.any(v <= 0):
        raise StiffnessScheduleError(f"per-phase stiffness must be > 0 N/m, got a minimum of {v.min():.3g}")
    B = v.shape[0]
    jumps = np.diff(v, axis=1) / 1000.0
    return np.concatenate([(v / 1000.0).reshape(B, -1), (1000.0 / v).reshape(B, -1), jumps.reshape(B, -1),
                           np.abs(jumps).reshape(B, -1)], axis=1)


__all__ = ["CHANGE_TOL_NPM", "FEATURE_SPEC", "StiffnessScheduleError", "batch_phase_values", "feature_names",
           "features", "phase_values"]
