"""Demonstrations: small reproducible specs of a wiping path, and the recorded (pose, force) trajectories.

A ``DemoSpec`` describes a path over a bowl (spiral, wavelike, line, a seeded random smooth curve, the same
curve wiped at a different drawn speed in each segment of the demo, or a user's waypoint file) with a pressing
depth. ``Simulator.record_demo`` executes it with a *demonstration controller* (fixed stiffness
``stiffness_Npm``; attractor = surface point pushed ``press`` below along the surface normal; a smooth
approach from ``hover_m`` above the surface during the first ``approach_s``) and records the observed pose and
contact wrench as a ``Demo``: ``x_demo (H, 6)`` and ``force_demo (H, 6)``.

Each path family is one class in ``dcm.sim.paths``, registered there by name: its parameters with their
defaults and meaning, their validation and its path. ``DemoSpec`` looks its ``family`` up and adds what every
family shares (the approach, the check against the rim, the recording options, the file format).

Timing: at the simulator's control rate, ``H = round(duration_s * control_hz)`` steps, sample ``k`` at
``t = k dt``. A waypoint file (``dcm.sim.paths.waypoints``) sets its own duration and press depth, so a
``waypoints`` path with another family, or a ``duration_s`` or ``press_m`` the file does not have, is refused
rather than ignored; a waypoint spec's ``duration_s`` is the file's span ``t_last - t_first`` (what a saved
spec records).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dcm.configs import CONF_DIR
from dcm.sim.geometry import BowlSpec, BowlSpecError
from dcm.sim.paths import FAMILIES, PATH_FAMILIES, find_family, registered_family, seeded_families
from dcm.sim.paths.curve import (
    CURVE_EXTENT,
    CURVE_GRID,
    CURVE_HARMONICS,
    CURVE_SEED_MAX,
    CURVE_SPEED_MPS,
    PACED_BLEND_S,
    PACED_SEGMENTS,
    PacedCurve,
    SeededCurve,
)
from dcm.sim.paths.errors import DemoSpecError, PathOutsideBowlError, WaypointFileError, WaypointOutsideBowlError
from dcm.sim.paths.family import DEFAULT_DURATION_S, DEFAULT_PRESS_M, PRESS_RANGE_M, PathFamily, design_timing, smoothstep
from dcm.sim.paths.waypoints import (
    DURATION_MATCH_S,
    MIN_WAYPOINT_ROWS,
    WAYPOINT_HEADER,
    load_waypoints_csv,
    save_waypoints_csv,
    waypoint_horizon,
    waypoint_span_s,
)

# Each family's parameters and their defaults (their meaning: the family's class in dcm.sim.paths).
FAMILY_PARAMS: dict[str, dict[str, Any]] = {name: family.params for name, family in PATH_FAMILIES.items()}

__all__ = [
    "CURVE_EXTENT", "CURVE_GRID", "CURVE_HARMONICS", "CURVE_SEED_MAX", "CURVE_SPEED_MPS", "DEFAULT_DURATION_S",
    "DEFAULT_PRESS_M", "DURATION_MATCH_S", "FAMILIES", "FAMILY_PARAMS", "MIN_WAYPOINT_ROWS", "PACED_BLEND_S",
    "PACED_SEGMENTS", "PRESS_RANGE_M", "WAYPOINT_HEADER", "Demo", "DemoSpec", "DemoSpecError",
    "PathOutsideBowlError", "WaypointFileError", "WaypointOutsideBowlError", "load_waypoints_csv",
    "save_waypoints_csv", "waypoint_horizon", "waypoint_span_s",
]


def _bowl_from(value: Any, where: str) -> BowlSpec:
    """A bowl given inline (mapping), as a preset name in ``conf/bowl``, or as a ``BowlSpec``."""
    if isinstance(value, BowlSpec):
        return value
    if isinstance(value, str):
        preset = CONF_DIR / "bowl" / f"{value}.yaml"
        if not preset.is_file():
            known = sorted(p.stem for p in (CONF_DIR / "bowl").glob("*.yaml"))
            raise DemoSpecError(f"{where}: bowl preset {value!r} not found in {CONF_DIR / 'bowl'}; known: {known}")
        return BowlSpec.load(str(preset))
    if isinstance(value, dict):
        try:
            return BowlSpec.from_dict(value, where=f"{where}.bowl")
        except TypeError as err:
            raise DemoSpecError(f"{where}.bowl: {err}") from None
    raise DemoSpecError(f"{where}: bowl must be a mapping or a preset name, got {type(value).__name__}")


@dataclass
class DemoSpec:
    """A reproducible demonstration: path family + parameters + pressing depth + the bowl it runs on."""

    family: str = "spiral"
    params: dict[str, Any] = field(default_factory=dict)
    press_m: float | None = None  # None: DEFAULT_PRESS_M; a waypoint file's press column sets its own
    duration_s: float | None = None  # None: DEFAULT_DURATION_S; a waypoint file's span sets its own
    bowl: BowlSpec = field(default_factory=BowlSpec)
    waypoints: str | None = None
    stiffness_Npm: tuple[float, float, float] = (800.0, 800.0, 800.0)
    approach_s: float = 1.0
    hover_m: float = 0.01
    name: str = ""
    # The demonstrator leads the tool by the impedance lag (``Simulator.record_demo``), as a person guiding
    # the arm puts the tool where they mean it; without it the demo controller trails the path.
    lead: bool = False
    # Where the spec came from, used in error messages; not serialised and not compared.
    source: str = field(default="DemoSpec", compare=False, repr=False)

    def __post_init__(self) -> None:
        self.bowl = _bowl_from(self.bowl, self.source)
        self.params = dict(self.params or {})
        self.stiffness_Npm = tuple(float(v) for v in self.stiffness_Npm)  # type: ignore[assignment]
        # The family's timing first (a waypoint file sets its own); an unknown family gets a designed path's
        # here and is named by validate().
        family = find_family(self.family)
        self.duration_s, self.press_m = family.resolve_timing(self) if family else design_timing(self)
        self.validate()

    @property
    def path_family(self) -> PathFamily:
        """The registered family of this spec (``dcm.sim.paths``)."""
        return registered_family(self.family, self.source)

    # -- validation / io -------------------------------------------------------------------------
    def validate(self) -> None:
        where = self.source
        family = self.path_family
        family.check(self)
        designed = not family.timed_by_file  # a waypoint file sets its own duration and press depth
        checks = {
            **({"press_m": (self.press_m, *PRESS_RANGE_M)} if designed else {}),
            "duration_s": (self.duration_s, 0.5 if designed else 0.0, 120.0),
            "approach_s": (self.approach_s, 0.0, 10.0),
            "hover_m": (self.hover_m, 0.0, 0.1),
        }
        for key, (value, low, high) in checks.items():
            if not isinstance(value, (int, float)) or not math.isfinite(value) or not (low <= value <= high):
                raise DemoSpecError(f"{where}: {key} = {value!r} is outside [{low}, {high}]")
        if designed and self.approach_s >= self.duration_s:  # type: ignore[operator]
            raise DemoSpecError(f"{where}: approach_s = {self.approach_s} must be shorter than "
                                f"duration_s = {self.duration_s}")
        if len(self.stiffness_Npm) != 3 or not all(50.0 <= k <= 3000.0 for k in self.stiffness_Npm):
            raise DemoSpecError(f"{where}: stiffness_Npm = {self.stiffness_Npm} needs 3 values in [50, 3000] N/m")
        if not isinstance(self.lead, bool):
            raise DemoSpecError(f"{where}: lead = {self.lead!r} must be true or false")

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "family": self.family,
            "params": dict(self.params),
            "press_m": None if self.press_m is None else float(self.press_m),
            "duration_s": float(self.duration_s),  # type: ignore[arg-type]
            "approach_s": float(self.approach_s),
            "hover_m": float(self.hover_m),
            "stiffness_Npm": list(self.stiffness_Npm),
            "waypoints": self.waypoints,
            "bowl": self.bowl.to_dict(),
            # Written only when set, so a spec without it serialises, and seeds its demos, as if it did not exist.
            **({"lead": True} if self.lead else {}),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "DemoSpec") -> DemoSpec:
        if not isinstance(data, dict):
            raise DemoSpecError(f"{where}: expected a mapping, got {type(data).__name__}")
        allowed = {"name", "family", "params", "press_m", "duration_s", "approach_s", "hover_m",
                   "stiffness_Npm", "waypoints", "bowl", "lead"}
        extra = set(data) - allowed
        if extra:
            raise DemoSpecError(f"{where}: unknown field(s) {sorted(extra)}; known: {sorted(allowed)}")
        kwargs = dict(data)
        kwargs.setdefault("bowl", BowlSpec())
        try:
            return cls(**kwargs, source=where)
        except BowlSpecError as err:
            raise DemoSpecError(f"{where}: {err}") from None

    @classmethod
    def load(cls, path: str | Path) -> DemoSpec:
        """Read a spec from YAML or JSON. A relative ``waypoints`` path is resolved against the spec's folder
        when it does not exist relative to the working directory."""
        import yaml

        path = Path(path)
        if not path.is_file():
            raise DemoSpecError(f"{path}: demo spec file not found")
        with path.open() as fh:
            data = json.load(fh) if path.suffix == ".json" else yaml.safe_load(fh)
        if isinstance(data, dict) and data.get("waypoints"):
            wp = Path(data["waypoints"])
            if not wp.is_absolute() and not wp.exists() and (path.parent / wp).exists():
                data["waypoints"] = str(path.parent / wp)
        return cls.from_dict(data, where=str(path))

    def save(self, path: str | Path) -> None:
        import yaml

        path = Path(path)
        with path.open("w") as fh:
            if path.suffix == ".json":
                json.dump(self.to_dict(), fh, indent=2)
            else:
                yaml.safe_dump(self.to_dict(), fh, sort_keys=False)

    # -- the path --------------------------------------------------------------------------------
    def horizon(self, control_hz: float = 20.0) -> int:
        """Number of control steps H of the recorded demo."""
        return len(self.path(control_hz))

    def path(self, control_hz: float = 20.0) -> np.ndarray:
        """The designed path sampled at the control rate: (H, 3) = [x, y, press] in m, bowl frame.

        Includes the approach: over the first ``approach_s`` the press depth ramps smoothly from
        ``-hover_m`` (above the surface) to the path's depth. Raises ``PathOutsideBowlError`` when any
        sample lies outside the rim.
        """
        dt = 1.0 / control_hz
        t, xy, press = self.path_family.sample(self, control_hz)
        if self.approach_s > 0:
            ramp = smoothstep(t / self.approach_s)
            press = -self.hover_m + (press + self.hover_m) * ramp
        outside = ~np.asarray(self.bowl.contains(xy[:, 0], xy[:, 1]))
        if outside.any():
            k = int(np.argmax(outside))
            raise PathOutsideBowlError(
                f"{self.source}: the {self.family} path leaves the bowl at step {k} (t = {k * dt:.2f} s): "
                f"(x, y) = ({xy[k, 0]:.4f}, {xy[k, 1]:.4f}) m, rim radius {self.bowl.rim_radius_m:g} m; "
                "reduce its size parameters"
            )
        return np.column_stack([xy, press])

    def curve_draws(self) -> dict[str, Any]:
        """The seeded draws of a ``curve`` or ``paced_curve`` spec: ``coeffs`` (harmonics, 4) = [cos x, sin x,
        cos y, sin y] of harmonic k = 1..n, ``speed_mps`` (mean wiping speed; one per segment for a
        ``paced_curve``) and ``press_m`` (press depth).

        Shape, speed and press come from independent streams of ``seed``, so changing one range keeps the
        other draws."""
        family = self.path_family
        if not isinstance(family, SeededCurve):
            names = " or ".join(repr(name) for name in seeded_families())
            raise DemoSpecError(f"{self.source}: curve_draws() needs family {names}, not {self.family!r}")
        return family.draws(self)

    def speed_profile(self, t: np.ndarray) -> np.ndarray:
        """A ``paced_curve``'s designed tool speed [m/s] at times ``t`` [s]: 0 until the approach ends, then each
        segment's drawn speed, blended over ``blend_s`` at segment edges and at the start and end of the wipe."""
        family = self.path_family
        if not isinstance(family, PacedCurve):
            raise DemoSpecError(f"{self.source}: speed_profile() needs family {PacedCurve.name!r}, "
                                f"not {self.family!r}")
        return family.speed_profile(self, t)

    def attractor_path(self, control_hz: float = 20.0) -> np.ndarray:
        """Demonstration controller's attractor (H, 6): surface point pushed ``press`` below along the normal."""
        path = self.path(control_hz)
        x, y, press = path[:, 0], path[:, 1], path[:, 2]
        surface = np.stack([x, y, self.bowl.height(x, y)], axis=1)
        attractor = np.zeros((len(path), 6))
        attractor[:, :3] = surface - press[:, None] * self.bowl.normal(x, y)
        return attractor

    def start_pose(self, control_hz: float = 20.0) -> np.ndarray:
        """Where the tool rests before the demo: ``hover_m`` above the surface at the path's first point."""
        x, y, _ = self.path(control_hz)[0]
        pose = np.zeros(6)
        pose[:3] = [x, y, self.bowl.height(x, y) + self.hover_m]
        return pose


@dataclass
class Demo:
    """A recorded demonstration (H steps at ``dt``): observed pose and contact wrench, bowl frame."""

    spec: DemoSpec
    dt: float
    x_demo: np.ndarray  # (H, 6) [m, rad]
    force_demo: np.ndarray  # (H, 6) [N, N·m]
    start_pose: np.ndarray | None = None  # (6,) pose before step 0; None -> the spec's start pose
    contact: np.ndarray | None = None  # (H,) bool

    @property
    def horizon(self) -> int:
        return int(self.x_demo.shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {
            "spec": self.spec.to_dict(),
            "dt": float(self.dt),
            "x_demo": np.asarray(self.x_demo).tolist(),
            "force_demo": np.asarray(self.force_demo).tolist(),
            "start_pose": None if self.start_pose is None else np.asarray(self.start_pose).tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Demo:
        return cls(
            spec=DemoSpec.from_dict(data["spec"]),
            dt=float(data["dt"]),
            x_demo=np.asarray(data["x_demo"], dtype=np.float64),
            force_demo=np.asarray(data["force_demo"], dtype=np.float64),
            start_pose=None if data.get("start_pose") is None else np.asarray(data["start_pose"], dtype=np.float64),
        )
