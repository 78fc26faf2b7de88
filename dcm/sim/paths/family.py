"""What a path family is: its parameters with their defaults, their validation, and the path it samples.

A family reads the spec it serves through :class:`PathSpec` (the fields of ``dcm.sim.demos.DemoSpec``), so
this package never imports the spec's module. The spec adds what every family shares: the approach ramp from
``hover_m`` and the check that the path stays inside the rim.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

import numpy as np

from dcm.sim.geometry import BowlSpec
from dcm.sim.paths.errors import DemoSpecError

PRESS_RANGE_M = (-0.05, 0.05)
DEFAULT_DURATION_S = 8.0
DEFAULT_PRESS_M = 0.01


class PathSpec(Protocol):
    """The fields of a demo spec that a family reads."""

    family: Any
    params: dict[str, Any]
    press_m: float | None
    duration_s: float | None
    bowl: BowlSpec
    waypoints: str | None
    approach_s: float
    hover_m: float
    source: str


def smooth_progress(s: np.ndarray) -> np.ndarray:
    """Cycloidal 0 -> 1 progress with zero velocity at both ends (no jerk at start and stop)."""
    s = np.clip(s, 0.0, 1.0)
    return s - np.sin(2.0 * np.pi * s) / (2.0 * np.pi)


def smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def design_timing(spec: PathSpec) -> tuple[float | None, float | None]:
    """(duration_s, press_m) of a designed path: the spec's, or the defaults. A waypoint file is refused
    here, since only its own family wipes it (a spec is what its fields say)."""
    if spec.waypoints:
        raise DemoSpecError(
            f"{spec.source}: family = {spec.family!r} with waypoints = {str(spec.waypoints)!r}: a waypoint file "
            "is wiped only by family 'waypoints' (demo=waypoints demo.waypoints=<file>); drop one of them")
    duration_s = DEFAULT_DURATION_S if spec.duration_s is None else spec.duration_s
    press_m = DEFAULT_PRESS_M if spec.press_m is None else spec.press_m
    return duration_s, press_m


class PathFamily:
    """A designed path: ``xy`` maps the wipe's progress to the bowl plane, at the spec's constant press depth.

    A family names its parameters and their defaults in ``params`` (``None`` defaults are resolved relative
    to the bowl's rim); a spec's unknown parameter is refused naming the known ones.
    """

    name: ClassVar[str]
    params: ClassVar[dict[str, Any]]
    # True when the path's duration and press depth come from a file, not from the spec's duration_s/press_m.
    timed_by_file: ClassVar[bool] = False

    def param(self, spec: PathSpec, key: str) -> Any:
        return spec.params.get(key, self.params[key])

    def check(self, spec: PathSpec) -> None:
        """Refuse unknown parameters, then the family's own checks."""
        unknown = set(spec.params) - set(self.params)
        if unknown:
            raise DemoSpecError(f"{spec.source}: unknown {self.name} parameter(s) {sorted(unknown)}; "
                                f"known: {sorted(self.params)}")
        self.check_params(spec)

    def check_params(self, spec: PathSpec) -> None:
        """The family's own parameter checks (errors name the parameter and its allowed values)."""

    def resolve_timing(self, spec: PathSpec) -> tuple[float | None, float | None]:
        """(duration_s, press_m) the spec keeps."""
        return design_timing(spec)

    def sample(self, spec: PathSpec, control_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times (H,) [s], (x, y) (H, 2) [m] and press depth (H,) [m] at the control rate, before the approach
        ramp: H = round(duration_s * control_hz); the wipe runs from rest after ``approach_s`` to rest at the end."""
        dt = 1.0 / control_hz
        horizon = int(round(spec.duration_s * control_hz))  # type: ignore[operator]
        t = np.arange(horizon) * dt
        wipe_s = max(spec.duration_s - spec.approach_s - dt, dt)  # type: ignore[operator]
        u = smooth_progress((t - spec.approach_s) / wipe_s)
        return t, self.xy(spec, t, u, wipe_s), np.full(horizon, self.press_depth(spec))

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        """(x, y) [m] in the bowl frame at times ``t`` with wipe progress ``u`` in [0, 1]."""
        raise NotImplementedError

    def press_depth(self, spec: PathSpec) -> float:
        return float(spec.press_m)  # type: ignore[arg-type]
