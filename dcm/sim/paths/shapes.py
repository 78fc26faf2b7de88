"""The geometric path families: spiral, wavelike and line, sized relative to the bowl's rim by default."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from dcm.sim.paths.errors import DemoSpecError
from dcm.sim.paths.family import PathFamily, PathSpec


class Spiral(PathFamily):
    """Archimedean spiral from ``min_radius_m`` out to ``max_radius_m`` (default 0.7 x rim), ``turns`` turns
    in ``direction`` ``ccw`` or ``cw``."""

    name = "spiral"
    params: ClassVar[dict[str, Any]] = {"turns": 2.0, "direction": "ccw", "max_radius_m": None, "min_radius_m": 0.01}

    def check_params(self, spec: PathSpec) -> None:
        if spec.params.get("direction", "ccw") not in ("cw", "ccw"):
            raise DemoSpecError(f"{spec.source}: spiral direction = {spec.params['direction']!r}; "
                                "expected 'cw' or 'ccw'")

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        r_max = self.param(spec, "max_radius_m") or 0.7 * spec.bowl.rim_radius_m
        r_min = float(self.param(spec, "min_radius_m"))
        sign = 1.0 if self.param(spec, "direction") == "ccw" else -1.0
        radius = r_min + (r_max - r_min) * u
        angle = sign * 2.0 * np.pi * float(self.param(spec, "turns")) * u
        return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


class Wavelike(PathFamily):
    """Sine wave of ``cycles`` periods along a line through the centre at ``angle_deg``: ``length_m``
    (default 1.2 x rim), ``amplitude_m`` (default 0.25 x rim)."""

    name = "wavelike"
    params: ClassVar[dict[str, Any]] = {"length_m": None, "amplitude_m": None, "cycles": 2.0, "angle_deg": 0.0}

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        rim = spec.bowl.rim_radius_m
        length = self.param(spec, "length_m") or 1.2 * rim
        amplitude = self.param(spec, "amplitude_m")
        amplitude = 0.25 * rim if amplitude is None else float(amplitude)
        along = (u - 0.5) * length
        across = amplitude * np.sin(2.0 * np.pi * float(self.param(spec, "cycles")) * u)
        angle = math.radians(float(self.param(spec, "angle_deg")))
        c, s = math.cos(angle), math.sin(angle)
        return np.stack([c * along - s * across, s * along + c * across], axis=1)


class Line(PathFamily):
    """Straight stroke from ``start_xy_m`` to ``end_xy_m`` (default across the bowl along x, 0.6 x rim each
    side)."""

    name = "line"
    params: ClassVar[dict[str, Any]] = {"start_xy_m": None, "end_xy_m": None}

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        rim = spec.bowl.rim_radius_m
        start = np.asarray(self.param(spec, "start_xy_m") or (-0.6 * rim, 0.0), dtype=np.float64)
        end = np.asarray(self.param(spec, "end_xy_m") or (0.6 * rim, 0.0), dtype=np.float64)
        if start.shape != (2,) or end.shape != (2,):
            raise DemoSpecError(f"{spec.source}: line start_xy_m / end_xy_m need 2 values each")
        return start[None, :] + (end - start)[None, :] * u[:, None]
