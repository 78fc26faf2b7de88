"""The box every stiffness search explores, and the ask/tell interface every strategy implements.

One home for both dataset generation (:mod:`dcm.data.generate`, the paper's robot-based trials) and tuning
(:mod:`dcm.tuning.optimize`), so a strategy added here is available to both.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

# The searched stiffness per phase, by frame: the bowl's axes, or one tangential and one normal value.
FRAME_AXES = {"world": ("x", "y", "z"), "surface": ("t", "n")}
AXES = FRAME_AXES["world"]


@dataclass(frozen=True)
class SearchSpace:
    """Box of per-phase translational stiffness: ``n_phases`` × (3 bowl axes, or tangent and normal for the
    ``surface`` frame) values in [min_Npm, max_Npm]."""

    n_phases: int = 3
    min_Npm: float = 100.0
    max_Npm: float = 1500.0
    log: bool = False  # sample log-uniformly (spreads trials over the soft end too)
    frame: str = "world"  # dcm.control.FRAMES

    def __post_init__(self) -> None:
        if self.n_phases < 1:
            raise ValueError(f"search space n_phases={self.n_phases} must be >= 1")
        if not 0 < self.min_Npm < self.max_Npm:
            raise ValueError(f"stiffness bounds must satisfy 0 < min_Npm < max_Npm, got {self.min_Npm}, {self.max_Npm}")
        from dcm.control import check_frame

        check_frame(self.frame)

    @property
    def axes(self) -> tuple[str, ...]:
        return FRAME_AXES[self.frame]

    @property
    def dim(self) -> int:
        """Number of searched values (P × axes)."""
        return self.n_phases * len(self.axes)

    def param_names(self) -> list[str]:
        return [f"K{axis}_phase{p}" for p in range(self.n_phases) for axis in self.axes]

    def to_array(self, params: dict[str, float]) -> np.ndarray:
        return np.array([params[name] for name in self.param_names()],
                        dtype=np.float64).reshape(self.n_phases, len(self.axes))

    def diagonal(self, values: np.ndarray) -> np.ndarray:
        """(..., P, axes) searched values -> (..., P, 3) diagonal along the frame's axes (surface: t, t, n)."""
        from dcm.control import frame_diagonal

        return frame_diagonal(values, self.frame)

    def from_diagonal(self, diagonal: np.ndarray) -> np.ndarray:
        """(..., P, 3) diagonal along the frame's axes -> (..., P, axes) searched values (surface: t1 and n;
        a diagonal whose two tangents differ is none of this space's and raises ValueError)."""
        from dcm.control.schedule import frame_values

        return frame_values(diagonal, self.frame)

    def to_unit(self, stiffness: np.ndarray) -> np.ndarray:
        """(..., P, axes) N/m -> (..., P·axes) in [0, 1] (in log space when ``log``), for model-based strategies."""
        values = np.asarray(stiffness, dtype=np.float64).reshape(*np.shape(stiffness)[:-2], self.dim)
        low, high, values = self._scale(values)
        return (values - low) / (high - low)

    def from_unit(self, unit: np.ndarray) -> np.ndarray:
        """(..., P·axes) in [0, 1] -> (..., P, axes) N/m, clipped into the box."""
        unit = np.clip(np.asarray(unit, dtype=np.float64), 0.0, 1.0)
        low, high, _ = self._scale(np.zeros(0))
        values = low + unit * (high - low)
        if self.log:
            values = np.exp(values)
        values = np.clip(values, self.min_Npm, self.max_Npm)  # exp/log round-off must not leave the box
        return values.reshape(*unit.shape[:-1], self.n_phases, len(self.axes))

    def _scale(self, values: np.ndarray) -> tuple[float, float, np.ndarray]:
        if self.log:
            return float(np.log(self.min_Npm)), float(np.log(self.max_Npm)), np.log(values)
        return self.min_Npm, self.max_Npm, values


def space_from_settings(stiffness: Mapping[str, Any], error: type[Exception] = ValueError) -> SearchSpace:
    """The search space of a ``conf/stiffness`` mapping, checked against the controller's limits.

    Generation and tuning both call this before any work, so a value beyond the controller's limits fails at
    once, naming the setting and the limit (raised as ``error``)."""
    from dcm.configs import check_integer, check_number
    from dcm.control import DAMPING_MODES, StiffnessLimits, check_frame

    limits = StiffnessLimits()
    n_phases = check_integer(stiffness["n_phases"], "stiffness.n_phases", 1, error)
    low = check_number(stiffness["min_Npm"], "stiffness.min_Npm", error)
    high = check_number(stiffness["max_Npm"], "stiffness.max_Npm", error)
    rot = check_number(stiffness["rot_Nmprad"], "stiffness.rot_Nmprad", error)
    for key, value, lo, hi, unit in (("min_Npm", low, limits.trans_min_Npm, limits.trans_max_Npm, "N/m"),
                                     ("max_Npm", high, limits.trans_min_Npm, limits.trans_max_Npm, "N/m"),
                                     ("rot_Nmprad", rot, limits.rot_min_Nmprad, limits.rot_max_Nmprad, "N·m/rad")):
        if value > hi:
            raise error(f"stiffness.{key} = {value:g} is above the controller's limit {hi:g} {unit}")
        if value < lo:
            raise error(f"stiffness.{key} = {value:g} is below the controller's limit {lo:g} {unit}")
    if low >= high:
        raise error(f"stiffness.min_Npm = {low:g} must be below stiffness.max_Npm = {high:g}")
    if stiffness["damping"] not in DAMPING_MODES:
        raise error(f"stiffness.damping = {stiffness['damping']!r}; expected one of {', '.join(DAMPING_MODES)}")
    if not isinstance(stiffness["log"], bool):
        raise error(f"stiffness.log = {stiffness['log']!r} must be true or false")
    frame = stiffness.get("frame", "world")  # absent from the settings of datasets older than the frame
    try:
        check_frame(frame)
    except ValueError as err:
        raise error(str(err)) from None
    return SearchSpace(n_phases=n_phases, min_Npm=low, max_Npm=high, log=stiffness["log"], frame=frame)


class StiffnessSearch(Protocol):
    """ask() proposes (P, axes) stiffness in N/m; tell() reports (L_task, L_comp), or None for a failed trial.

    Asks may run ahead of tells (a batch is asked, evaluated together, then told in order); tell() always
    reports the oldest proposal not yet told.
    """

    def ask(self) -> np.ndarray: ...

    def tell(self, objectives: tuple[float, float] | None) -> None: ...
