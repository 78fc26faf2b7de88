"""Seeded random smooth curves: ``curve`` (one drawn mean speed) and ``paced_curve`` (a drawn speed per segment).

A curve is a Fourier series of ``harmonics`` low frequencies in x and y (amplitude ~1/k, so low frequencies
dominate and it is smooth), scaled so its farthest point is ``extent`` x the rim (normalised radius, so
elliptic bowls too). Shape, speed and press depth come from independent streams of ``seed``, so changing one
range keeps the other draws.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from dcm.sim.paths.errors import DemoSpecError
from dcm.sim.paths.family import PRESS_RANGE_M, PathFamily, PathSpec, smoothstep

# Allowed values of the curve parameters (inclusive).
CURVE_SEED_MAX = 2**32 - 1
CURVE_HARMONICS = (1, 8)
CURVE_EXTENT = (0.05, 0.95)
CURVE_SPEED_MPS = (0.005, 0.3)
CURVE_GRID = 4096  # samples per loop for scaling and arc length
PACED_SEGMENTS = (1, 8)
PACED_BLEND_S = (0.05, 5.0)


class SeededCurve(PathFamily):
    """What both curve families share: the validation of the curve parameters, the seeded draws and the loop."""

    def _integer(self, spec: PathSpec, key: str, low: int, high: int) -> None:
        value = self.param(spec, key)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
            raise DemoSpecError(f"{spec.source}: curve params.{key} = {value!r} must be an integer in "
                                f"[{low}, {high}]")

    def _number(self, spec: PathSpec, key: str, bounds: tuple[float, float], label: str, unit: str) -> None:
        value = self.param(spec, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not bounds[0] <= value <= bounds[1]:
            raise DemoSpecError(f"{spec.source}: {label} params.{key} = {value!r} must be a number in "
                                f"{list(bounds)} {unit}")

    def _value_range(self, spec: PathSpec, key: str, low: float, high: float, unit: str) -> None:
        """Check a [low, high] range; a given one becomes a list of floats, so YAML/JSON round trips compare equal."""
        value = self.param(spec, key)
        pair = list(value) if isinstance(value, (list, tuple)) else None
        ok = pair is not None and len(pair) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pair)
        if not ok or not low <= pair[0] <= pair[1] <= high:  # type: ignore[index]
            raise DemoSpecError(f"{spec.source}: curve params.{key} = {value!r} must be [low, high] {unit} with "
                                f"{low} <= low <= high <= {high}")
        if key in spec.params:
            spec.params[key] = [float(pair[0]), float(pair[1])]  # type: ignore[index]

    def check_params(self, spec: PathSpec) -> None:
        self._integer(spec, "seed", 0, CURVE_SEED_MAX)
        self._integer(spec, "harmonics", *CURVE_HARMONICS)
        self._number(spec, "extent", CURVE_EXTENT, "curve", "(fraction of the rim radius)")
        self._value_range(spec, "speed_mps", *CURVE_SPEED_MPS, "m/s")
        if self.param(spec, "press_range_m") is not None:
            self._value_range(spec, "press_range_m", *PRESS_RANGE_M, "m")

    def draws(self, spec: PathSpec) -> dict[str, Any]:
        """``coeffs`` (harmonics, 4) = [cos x, sin x, cos y, sin y] of harmonic k = 1..n, ``speed_mps`` and
        ``press_m`` (the spec's press_m when ``press_range_m`` is null)."""
        shape_rng, speed_rng, press_rng = (np.random.default_rng(s) for s in
                                           np.random.SeedSequence(int(self.param(spec, "seed"))).spawn(3))
        k = np.arange(1, int(self.param(spec, "harmonics")) + 1, dtype=np.float64)
        coeffs = shape_rng.standard_normal((len(k), 4)) / k[:, None]  # 1/k: low frequencies dominate, smooth
        speed = self.draw_speed(spec, speed_rng)
        press_range = self.param(spec, "press_range_m")
        press = float(spec.press_m) if press_range is None else float(press_rng.uniform(*press_range))
        return {"coeffs": coeffs, "speed_mps": speed, "press_m": press}

    def draw_speed(self, spec: PathSpec, rng: np.random.Generator) -> Any:
        """The mean wiping speed [m/s], uniform in ``speed_mps``."""
        return float(rng.uniform(*self.param(spec, "speed_mps")))

    def press_depth(self, spec: PathSpec) -> float:
        return self.draws(spec)["press_m"]

    def loop(self, spec: PathSpec) -> tuple[Callable[[np.ndarray], np.ndarray], float, np.ndarray, np.ndarray]:
        """The seeded closed curve: a function of phase (loops) -> unscaled (N, 2), its scale to the bowl, and
        the arc length [m] of one scaled loop at the grid's phases."""
        coeffs = self.draws(spec)["coeffs"]
        k = np.arange(1, len(coeffs) + 1, dtype=np.float64)
        semi_axes = np.asarray(spec.bowl.semi_axes_m)

        def unit_xy(phase: np.ndarray) -> np.ndarray:
            angle = 2.0 * np.pi * np.outer(phase, k)
            cos, sin = np.cos(angle), np.sin(angle)
            return np.stack([cos @ coeffs[:, 0] + sin @ coeffs[:, 1], cos @ coeffs[:, 2] + sin @ coeffs[:, 3]], axis=1)

        grid = np.arange(CURVE_GRID + 1) / CURVE_GRID
        loop = unit_xy(grid)
        scale = float(self.param(spec, "extent")) / float(np.max(np.linalg.norm(loop, axis=1)))
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(loop * scale * semi_axes, axis=0), axis=1))])
        return unit_xy, scale, grid, arc


class Curve(SeededCurve):
    """Traversed from rest for an arc length of (mean speed x wipe time): less than one loop is an open stroke,
    more loops around. Mean speed [m/s] is drawn in ``speed_mps``; the press depth [m] in ``press_range_m``,
    or is the spec's press_m when that is null."""

    name = "curve"
    params: ClassVar[dict[str, Any]] = {"seed": 0, "harmonics": 3, "extent": 0.7, "speed_mps": [0.02, 0.10],
                                        "press_range_m": None}

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        """Uniform in phase (not arc length): the tool slows down where the curve bends sharply, like a hand."""
        unit_xy, scale, grid, arc = self.loop(spec)
        length = self.draws(spec)["speed_mps"] * wipe_s
        loops, rest = divmod(length, arc[-1])
        end_phase = loops + float(np.interp(rest, arc, grid))
        return unit_xy(end_phase * u) * scale * np.asarray(spec.bowl.semi_axes_m)


class PacedCurve(SeededCurve):
    """The curve of the same seed (same shape stream), wiped at a speed that changes: the demo's duration is cut
    into ``n_segments`` equal-time segments (the approach lies in the first), each with its own speed [m/s] drawn
    log-uniformly in ``speed_mps``; the speed blends between segments over ``blend_s`` seconds and rises from
    and falls to rest the same way. A segment's speed is its mean over a loop of the curve: as on a curve, the
    tool slows down in bends and speeds up on the straights. With ``fast_speed_mps`` set (null = off), one
    segment, drawn uniformly per skill, gets its speed log-uniformly in that range instead: every skill then has
    a fast stroke and slow ones, at a place that differs between skills."""

    name = "paced_curve"
    params: ClassVar[dict[str, Any]] = {"seed": 0, "harmonics": 3, "extent": 0.7, "speed_mps": [0.02, 0.20],
                                        "n_segments": 3, "blend_s": 0.8, "press_range_m": None,
                                        "fast_speed_mps": None}

    def check_params(self, spec: PathSpec) -> None:
        super().check_params(spec)
        if self.param(spec, "fast_speed_mps") is not None:
            self._value_range(spec, "fast_speed_mps", *CURVE_SPEED_MPS, "m/s")
        self._integer(spec, "n_segments", *PACED_SEGMENTS)
        self._number(spec, "blend_s", PACED_BLEND_S, "paced_curve", "s")

    def draw_speed(self, spec: PathSpec, rng: np.random.Generator) -> Any:
        """One speed per segment, log-uniform: slow and fast strokes alike."""
        low, high = np.log(self.param(spec, "speed_mps"))
        speed = np.exp(rng.uniform(low, high, int(self.param(spec, "n_segments"))))
        fast_range = self.param(spec, "fast_speed_mps")
        if fast_range is not None:  # drawn after the slow speeds, so the option leaves their stream as it was
            fast_low, fast_high = np.log(fast_range)
            speed[int(rng.integers(len(speed)))] = np.exp(rng.uniform(fast_low, fast_high))
        return speed

    def speed_profile(self, spec: PathSpec, t: np.ndarray) -> np.ndarray:
        """The designed tool speed [m/s] at times ``t`` [s]: 0 until the approach ends, then each segment's drawn
        speed, blended over ``blend_s`` at segment edges and at the start and end of the wipe."""
        speeds = np.asarray(self.draws(spec)["speed_mps"], dtype=np.float64)
        blend = float(self.param(spec, "blend_s"))
        duration, start = float(spec.duration_s), float(spec.approach_s)  # type: ignore[arg-type]
        edges = duration * np.arange(1, len(speeds)) / len(speeds)
        speed = np.full(np.shape(t), speeds[0])
        for edge, before, after in zip(edges, speeds[:-1], speeds[1:]):
            speed = speed + (after - before) * smoothstep((t - edge + blend / 2) / blend)
        envelope = smoothstep((t - start) / blend) * smoothstep((duration - t) / blend)
        return speed * envelope

    def xy(self, spec: PathSpec, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        """Timed by the speed profile, not by progress: the curve's phase advances at the profile's speed over
        one loop's length, so each segment's speed is its mean over a loop."""
        unit_xy, scale, grid, arc = self.loop(spec)
        speed = self.speed_profile(spec, t)
        dt = np.diff(t, prepend=t[0])
        length = np.cumsum(0.5 * (speed + np.roll(speed, 1)) * dt) if len(t) > 1 else np.zeros(1)
        return unit_xy(length / arc[-1]) * scale * np.asarray(spec.bowl.semi_axes_m)
