"""Demonstrations: small reproducible specs of a wiping path, and the recorded (pose, force) trajectories.

A ``DemoSpec`` describes a path over a bowl (spiral, wavelike, line, a seeded random smooth curve, the same
curve wiped at a different drawn speed in each segment of the demo, or a user's waypoint file) with a pressing
depth. ``Simulator.record_demo`` executes it with a *demonstration controller* (fixed stiffness
``stiffness_Npm``; attractor = surface point pushed ``press`` below along the surface normal; a smooth
approach from ``hover_m`` above the surface during the first ``approach_s``) and records the observed pose and
contact wrench as a ``Demo``: ``x_demo (H, 6)`` and ``force_demo (H, 6)``.

Timing: at the simulator's control rate, ``H = round(duration_s * control_hz)`` steps, sample ``k`` at
``t = k dt``. Waypoint files define their own duration: ``H = floor((t_last - t_first) * control_hz) + 1``.

Waypoint CSV: header ``t,x,y,press``; ``t`` [s] strictly increasing, ``x, y`` [m] in the bowl frame,
``press`` [m] the pressing depth below the surface (negative = above it). Rows are linearly resampled to
the control rate.

A waypoint file is a family of its own: a spec is what its fields say, so a ``waypoints`` path with another
family, or a ``duration_s`` or ``press_m`` the file does not have, is refused rather than ignored. A waypoint
spec's ``duration_s`` is the file's span ``t_last - t_first`` (what a saved spec records); its recording
options (``lead``, ``hover_m``, ``approach_s``, ``stiffness_Npm``, ``bowl``) apply as to any family.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dcm.sim.geometry import BowlSpec, BowlSpecError

FAMILIES = ("spiral", "wavelike", "line", "curve", "paced_curve", "waypoints")
WAYPOINT_HEADER = ("t", "x", "y", "press")
MIN_WAYPOINT_ROWS = 2
PRESS_RANGE_M = (-0.05, 0.05)
DEFAULT_DURATION_S = 8.0
DEFAULT_PRESS_M = 0.01
DURATION_MATCH_S = 1e-6  # a waypoint spec's duration_s must be its file's span (a saved spec round-trips)
CONF_DIR = Path(__file__).resolve().parents[2] / "conf"

# Family parameters and their meaning; ``None`` defaults are resolved relative to the bowl's rim.
FAMILY_PARAMS: dict[str, dict[str, Any]] = {
    # Archimedean spiral from min_radius_m out to max_radius_m (default 0.7 x rim).
    "spiral": {"turns": 2.0, "direction": "ccw", "max_radius_m": None, "min_radius_m": 0.01},
    # Sine wave along a line through the centre: length (default 1.2 x rim), amplitude (0.25 x rim).
    "wavelike": {"length_m": None, "amplitude_m": None, "cycles": 2.0, "angle_deg": 0.0},
    # Straight stroke from start_xy_m to end_xy_m (default across the bowl along x, 0.6 x rim each side).
    "line": {"start_xy_m": None, "end_xy_m": None},
    # Seeded random smooth closed curve (a Fourier series of `harmonics` low frequencies in x and y, amplitude
    # ~1/k), scaled so its farthest point is `extent` x the rim (normalised radius, so elliptic bowls too),
    # traversed from rest for an arc length of (mean speed x wipe time): less than one loop is an open
    # stroke, more loops around. Mean speed [m/s] is drawn in `speed_mps`; the press depth [m] is drawn in
    # `press_range_m`, or is the spec's press_m when that is null.
    "curve": {"seed": 0, "harmonics": 3, "extent": 0.7, "speed_mps": [0.02, 0.10], "press_range_m": None},
    # The curve of the same seed (same shape stream), wiped at a speed that changes: the demo's duration is cut
    # into `n_segments` equal-time segments (the approach lies in the first), each with its own speed [m/s]
    # drawn log-uniformly in `speed_mps`; the speed blends between segments over `blend_s` seconds and rises
    # from and falls to rest the same way. A segment's speed is its mean over a loop of the curve: as on a curve,
    # the tool slows down in bends and speeds up on the straights. With `fast_speed_mps` set (null = off), one
    # segment, drawn uniformly per skill, gets its speed log-uniformly in that range instead: every skill then has
    # a fast stroke and slow ones, at a place that differs between skills.
    "paced_curve": {"seed": 0, "harmonics": 3, "extent": 0.7, "speed_mps": [0.02, 0.20], "n_segments": 3,
                    "blend_s": 0.8, "press_range_m": None, "fast_speed_mps": None},
    "waypoints": {},
}
# Allowed values of the curve parameters (inclusive).
CURVE_SEED_MAX = 2**32 - 1
CURVE_HARMONICS = (1, 8)
CURVE_EXTENT = (0.05, 0.95)
CURVE_SPEED_MPS = (0.005, 0.3)
CURVE_GRID = 4096  # samples per loop for scaling and arc length
PACED_SEGMENTS = (1, 8)
PACED_BLEND_S = (0.05, 5.0)


class DemoSpecError(ValueError):
    """An invalid demo description: names the field (or file, row) and the value."""


class WaypointFileError(DemoSpecError):
    """A malformed waypoint CSV: names the file, the row (1-based, header = row 1) and the value."""


class PathOutsideBowlError(DemoSpecError):
    """A demo path leaves the usable bowl surface."""


class WaypointOutsideBowlError(WaypointFileError, PathOutsideBowlError):
    """A waypoint row lies outside the bowl's rim."""


def waypoint_horizon(span_s: float, control_hz: float) -> int:
    """Steps H of a waypoint file spanning ``span_s``: its first row is step 0 and its last row step H - 1."""
    return int(math.floor(span_s * control_hz + 1e-9)) + 1


def waypoint_span_s(horizon: int, control_hz: float) -> float:
    """The span t_last - t_first a waypoint file needs to give ``horizon`` steps (the inverse of
    :func:`waypoint_horizon`): a 12 s demo of 240 steps at 20 Hz is a file spanning 11.95 s."""
    return (int(horizon) - 1) / control_hz


def _smooth_progress(s: np.ndarray) -> np.ndarray:
    """Cycloidal 0 -> 1 progress with zero velocity at both ends (no jerk at start and stop)."""
    s = np.clip(s, 0.0, 1.0)
    return s - np.sin(2.0 * np.pi * s) / (2.0 * np.pi)


def _smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def load_waypoints_csv(path: str | Path) -> np.ndarray:
    """Read and validate a waypoint CSV; returns rows (N, 4) = [t, x, y, press] in s, m, m, m."""
    path = Path(path)
    if not path.is_file():
        raise WaypointFileError(f"{path}: waypoint file not found")
    with path.open(newline="") as fh:
        rows = [r for r in csv.reader(fh) if any(cell.strip() for cell in r)]
    if not rows:
        raise WaypointFileError(f"{path}: empty file; expected header {','.join(WAYPOINT_HEADER)}")
    header = tuple(cell.strip().lower() for cell in rows[0])
    if header != WAYPOINT_HEADER:
        raise WaypointFileError(
            f"{path}, row 1: header {','.join(header)!r} must be exactly {','.join(WAYPOINT_HEADER)!r}"
        )
    values = []
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != len(WAYPOINT_HEADER):
            raise WaypointFileError(f"{path}, row {i}: expected 4 values (t,x,y,press), got {len(row)}: {row}")
        parsed = []
        for name, cell in zip(WAYPOINT_HEADER, row):
            try:
                value = float(cell)
            except ValueError:
                raise WaypointFileError(f"{path}, row {i}, column {name}: {cell.strip()!r} is not a number") from None
            if not math.isfinite(value):
                raise WaypointFileError(f"{path}, row {i}, column {name}: value {cell.strip()!r} is not finite")
            parsed.append(value)
        values.append(parsed)
    if len(values) < MIN_WAYPOINT_ROWS:
        raise WaypointFileError(
            f"{path}: {len(values)} waypoint row(s); at least {MIN_WAYPOINT_ROWS} are needed to define a path"
        )
    table = np.asarray(values, dtype=np.float64)
    dt = np.diff(table[:, 0])
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise WaypointFileError(
            f"{path}, row {i + 3}: t = {table[i + 1, 0]:g} s does not increase (previous {table[i, 0]:g} s)"
        )
    bad = (table[:, 3] < PRESS_RANGE_M[0]) | (table[:, 3] > PRESS_RANGE_M[1])
    if bad.any():
        i = int(np.argmax(bad))
        raise WaypointFileError(f"{path}, row {i + 2}: press = {table[i, 3]:g} m is outside {PRESS_RANGE_M} m")
    return table


def save_waypoints_csv(path: str | Path, table: np.ndarray) -> None:
    """Write rows (N, 4) = [t, x, y, press] with the standard header."""
    with Path(path).open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(WAYPOINT_HEADER)
        for row in np.asarray(table, dtype=np.float64):
            writer.writerow([f"{v:.6g}" for v in row])


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
        self._resolve_timing()
        self.validate()

    def _resolve_timing(self) -> None:
        """Fill ``duration_s`` and ``press_m``: the defaults, or for a waypoint file its own span and none."""
        where = self.source
        if self.family != "waypoints":
            if self.waypoints:
                raise DemoSpecError(
                    f"{where}: family = {self.family!r} with waypoints = {str(self.waypoints)!r}: a waypoint file "
                    "is wiped only by family 'waypoints' (demo=waypoints demo.waypoints=<file>); drop one of them")
            self.duration_s = DEFAULT_DURATION_S if self.duration_s is None else self.duration_s
            self.press_m = DEFAULT_PRESS_M if self.press_m is None else self.press_m
            return
        if not self.waypoints:
            raise DemoSpecError(f"{where}: family 'waypoints' needs a 'waypoints' CSV path")
        if self.press_m is not None:
            raise DemoSpecError(f"{where}: press_m = {self.press_m!r} does not apply to a waypoint file, whose "
                                f"press column sets the depth ({self.waypoints}); leave press_m out (null)")
        table = load_waypoints_csv(self.waypoints)
        span = float(table[-1, 0] - table[0, 0])
        if self.duration_s is None:
            self.duration_s = span
        elif not isinstance(self.duration_s, (int, float)) or abs(self.duration_s - span) > DURATION_MATCH_S:
            shown = f"{self.duration_s:g} s" if isinstance(self.duration_s, (int, float)) else repr(self.duration_s)
            raise DemoSpecError(
                f"{where}: duration_s = {shown}, but the waypoint file {self.waypoints} spans {span:g} s "
                f"(t = {table[0, 0]:g} to {table[-1, 0]:g} s): a waypoint file sets its own duration; leave "
                "duration_s out (null) or retime the file")
        else:
            self.duration_s = span

    # -- validation / io -------------------------------------------------------------------------
    def validate(self) -> None:
        where = self.source
        if self.family not in FAMILIES:
            raise DemoSpecError(f"{where}: family = {self.family!r}; expected one of {FAMILIES}")
        unknown = set(self.params) - set(FAMILY_PARAMS[self.family])
        if unknown:
            raise DemoSpecError(f"{where}: unknown {self.family} parameter(s) {sorted(unknown)}; "
                                f"known: {sorted(FAMILY_PARAMS[self.family])}")
        if self.family == "spiral" and self.params.get("direction", "ccw") not in ("cw", "ccw"):
            raise DemoSpecError(f"{where}: spiral direction = {self.params['direction']!r}; expected 'cw' or 'ccw'")
        if self.family in ("curve", "paced_curve"):
            self._check_curve_params()
        checks = {
            **({} if self.family == "waypoints" else {"press_m": (self.press_m, *PRESS_RANGE_M)}),
            "duration_s": (self.duration_s, 0.0 if self.family == "waypoints" else 0.5, 120.0),
            "approach_s": (self.approach_s, 0.0, 10.0),
            "hover_m": (self.hover_m, 0.0, 0.1),
        }
        for key, (value, low, high) in checks.items():
            if not isinstance(value, (int, float)) or not math.isfinite(value) or not (low <= value <= high):
                raise DemoSpecError(f"{where}: {key} = {value!r} is outside [{low}, {high}]")
        if self.approach_s >= self.duration_s and self.family != "waypoints":
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

    def _check_curve_params(self) -> None:
        """Validate the curve parameters (errors name the parameter and its allowed range); ranges become lists
        of floats so YAML/JSON round trips compare equal."""
        where = self.source

        def integer(key: str, low: int, high: int) -> None:
            value = self._param(key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
                raise DemoSpecError(f"{where}: curve params.{key} = {value!r} must be an integer in [{low}, {high}]")

        def value_range(key: str, low: float, high: float, unit: str) -> None:
            value = self._param(key)
            pair = list(value) if isinstance(value, (list, tuple)) else None
            ok = pair is not None and len(pair) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pair)
            if not ok or not low <= pair[0] <= pair[1] <= high:
                raise DemoSpecError(f"{where}: curve params.{key} = {value!r} must be [low, high] {unit} with "
                                    f"{low} <= low <= high <= {high}")
            if key in self.params:
                self.params[key] = [float(pair[0]), float(pair[1])]

        integer("seed", 0, CURVE_SEED_MAX)
        integer("harmonics", *CURVE_HARMONICS)
        extent = self._param("extent")
        if isinstance(extent, bool) or not isinstance(extent, (int, float)) or not (
                CURVE_EXTENT[0] <= extent <= CURVE_EXTENT[1]):
            raise DemoSpecError(f"{where}: curve params.extent = {extent!r} must be a number in {list(CURVE_EXTENT)} "
                                "(fraction of the rim radius)")
        value_range("speed_mps", *CURVE_SPEED_MPS, "m/s")
        if self._param("press_range_m") is not None:
            value_range("press_range_m", *PRESS_RANGE_M, "m")
        if self.family == "paced_curve" and self._param("fast_speed_mps") is not None:
            value_range("fast_speed_mps", *CURVE_SPEED_MPS, "m/s")
        if self.family == "paced_curve":
            integer("n_segments", *PACED_SEGMENTS)
            blend = self._param("blend_s")
            if isinstance(blend, bool) or not isinstance(blend, (int, float)) or not (
                    PACED_BLEND_S[0] <= blend <= PACED_BLEND_S[1]):
                raise DemoSpecError(f"{where}: paced_curve params.blend_s = {blend!r} must be a number in "
                                    f"{list(PACED_BLEND_S)} s")

    # -- the path --------------------------------------------------------------------------------
    def _param(self, key: str) -> Any:
        value = self.params.get(key, FAMILY_PARAMS[self.family][key])
        return value

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
        rim = self.bowl.rim_radius_m
        if self.family == "waypoints":
            table = load_waypoints_csv(self.waypoints)  # type: ignore[arg-type]
            outside = ~np.asarray(self.bowl.contains(table[:, 1], table[:, 2]))
            if outside.any():
                i = int(np.argmax(outside))
                raise WaypointOutsideBowlError(
                    f"{self.waypoints}, row {i + 2}: (x, y) = ({table[i, 1]:g}, {table[i, 2]:g}) m lies outside "
                    f"the bowl (rim radius {rim:g} m, shape {self.bowl.shape})"
                )
            t_rel = table[:, 0] - table[0, 0]
            horizon = waypoint_horizon(t_rel[-1], control_hz)
            if horizon < MIN_WAYPOINT_ROWS:
                raise WaypointFileError(f"{self.waypoints}: spans {t_rel[-1]:g} s, shorter than one control period")
            t = np.arange(horizon) * dt
            xy = np.stack([np.interp(t, t_rel, table[:, 1]), np.interp(t, t_rel, table[:, 2])], axis=1)
            press = np.interp(t, t_rel, table[:, 3])
        else:
            horizon = int(round(self.duration_s * control_hz))
            t = np.arange(horizon) * dt
            wipe_s = max(self.duration_s - self.approach_s - dt, dt)
            u = _smooth_progress((t - self.approach_s) / wipe_s)
            xy = self._design_xy(u, rim, wipe_s)
            if self.family == "paced_curve":
                xy = self._paced_xy(t)
            drawn = self.family in ("curve", "paced_curve")
            press = np.full(horizon, self.curve_draws()["press_m"] if drawn else float(self.press_m))
        if self.approach_s > 0:
            ramp = _smoothstep(t / self.approach_s)
            press = -self.hover_m + (press + self.hover_m) * ramp
        outside = ~np.asarray(self.bowl.contains(xy[:, 0], xy[:, 1]))
        if outside.any():
            k = int(np.argmax(outside))
            raise PathOutsideBowlError(
                f"{self.source}: the {self.family} path leaves the bowl at step {k} (t = {k * dt:.2f} s): "
                f"(x, y) = ({xy[k, 0]:.4f}, {xy[k, 1]:.4f}) m, rim radius {rim:g} m; reduce its size parameters"
            )
        return np.column_stack([xy, press])

    def curve_draws(self) -> dict[str, Any]:
        """The seeded draws of a ``curve`` spec: ``coeffs`` (harmonics, 4) = [cos x, sin x, cos y, sin y] of
        harmonic k = 1..n, ``speed_mps`` (mean wiping speed) and ``press_m`` (press depth).

        Shape, speed and press come from independent streams of ``seed``, so changing one range keeps the
        other draws."""
        if self.family not in ("curve", "paced_curve"):
            raise DemoSpecError(f"{self.source}: curve_draws() needs family 'curve' or 'paced_curve', "
                                f"not {self.family!r}")
        shape_rng, speed_rng, press_rng = (np.random.default_rng(s) for s in
                                           np.random.SeedSequence(int(self._param("seed"))).spawn(3))
        k = np.arange(1, int(self._param("harmonics")) + 1, dtype=np.float64)
        coeffs = shape_rng.standard_normal((len(k), 4)) / k[:, None]  # 1/k: low frequencies dominate, smooth
        if self.family == "paced_curve":  # one speed per segment, log-uniform: slow and fast strokes alike
            low, high = np.log(self._param("speed_mps"))
            speed = np.exp(speed_rng.uniform(low, high, int(self._param("n_segments"))))
            fast_range = self._param("fast_speed_mps")
            if fast_range is not None:  # drawn after the slow speeds, so the option leaves their stream as it was
                fast_low, fast_high = np.log(fast_range)
                speed[int(speed_rng.integers(len(speed)))] = np.exp(speed_rng.uniform(fast_low, fast_high))
        else:
            speed = float(speed_rng.uniform(*self._param("speed_mps")))
        press_range = self._param("press_range_m")
        press = float(self.press_m) if press_range is None else float(press_rng.uniform(*press_range))
        return {"coeffs": coeffs, "speed_mps": speed, "press_m": press}

    def _curve_loop(self) -> tuple[Any, float, np.ndarray, np.ndarray]:
        """The seeded closed curve: a function of phase (loops) -> unscaled (N, 2), its scale to the bowl, and
        the arc length [m] of one scaled loop at the grid's phases."""
        coeffs = self.curve_draws()["coeffs"]
        k = np.arange(1, len(coeffs) + 1, dtype=np.float64)
        semi_axes = np.asarray(self.bowl.semi_axes_m)

        def unit_xy(phase: np.ndarray) -> np.ndarray:
            angle = 2.0 * np.pi * np.outer(phase, k)
            cos, sin = np.cos(angle), np.sin(angle)
            return np.stack([cos @ coeffs[:, 0] + sin @ coeffs[:, 1], cos @ coeffs[:, 2] + sin @ coeffs[:, 3]], axis=1)

        grid = np.arange(CURVE_GRID + 1) / CURVE_GRID
        loop = unit_xy(grid)
        scale = float(self._param("extent")) / float(np.max(np.linalg.norm(loop, axis=1)))
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(loop * scale * semi_axes, axis=0), axis=1))])
        return unit_xy, scale, grid, arc

    def speed_profile(self, t: np.ndarray) -> np.ndarray:
        """A ``paced_curve``'s designed tool speed [m/s] at times ``t`` [s]: 0 until the approach ends, then each
        segment's drawn speed, blended over ``blend_s`` at segment edges and at the start and end of the wipe."""
        speeds = np.asarray(self.curve_draws()["speed_mps"], dtype=np.float64)
        blend = float(self._param("blend_s"))
        duration, start = float(self.duration_s), float(self.approach_s)
        edges = duration * np.arange(1, len(speeds)) / len(speeds)
        speed = np.full(np.shape(t), speeds[0])
        for edge, before, after in zip(edges, speeds[:-1], speeds[1:]):
            speed = speed + (after - before) * _smoothstep((t - edge + blend / 2) / blend)
        envelope = _smoothstep((t - start) / blend) * _smoothstep((duration - t) / blend)
        return speed * envelope

    def _paced_xy(self, t: np.ndarray) -> np.ndarray:
        """(x, y) of a ``paced_curve`` at times ``t``: the curve's phase advances at the speed profile over one loop's
        length, so each segment's speed is its mean over a loop, and, like ``curve``, the tool slows down where the
        curve bends sharply and speeds up where it runs straight."""
        unit_xy, scale, grid, arc = self._curve_loop()
        speed = self.speed_profile(t)
        dt = np.diff(t, prepend=t[0])
        length = np.cumsum(0.5 * (speed + np.roll(speed, 1)) * dt) if len(t) > 1 else np.zeros(1)
        return unit_xy(length / arc[-1]) * scale * np.asarray(self.bowl.semi_axes_m)

    def _curve_xy(self, u: np.ndarray, wipe_s: float) -> np.ndarray:
        """Progress ``u`` in [0, 1] -> (x, y) on the seeded curve, covering speed x wipe_s of arc length."""
        unit_xy, scale, grid, arc = self._curve_loop()
        length = self.curve_draws()["speed_mps"] * wipe_s
        loops, rest = divmod(length, arc[-1])
        end_phase = loops + float(np.interp(rest, arc, grid))
        # Uniform in phase (not arc length): the tool slows down where the curve bends sharply, like a hand.
        return unit_xy(end_phase * u) * scale * np.asarray(self.bowl.semi_axes_m)

    def _design_xy(self, u: np.ndarray, rim: float, wipe_s: float) -> np.ndarray:
        if self.family == "paced_curve":  # timed by its speed profile in ``path``, not by progress
            return np.zeros((len(u), 2))
        if self.family == "curve":
            return self._curve_xy(u, wipe_s)
        if self.family == "spiral":
            r_max = self._param("max_radius_m") or 0.7 * rim
            r_min = float(self._param("min_radius_m"))
            sign = 1.0 if self._param("direction") == "ccw" else -1.0
            radius = r_min + (r_max - r_min) * u
            angle = sign * 2.0 * np.pi * float(self._param("turns")) * u
            return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
        if self.family == "wavelike":
            length = self._param("length_m") or 1.2 * rim
            amplitude = self._param("amplitude_m")
            amplitude = 0.25 * rim if amplitude is None else float(amplitude)
            along = (u - 0.5) * length
            across = amplitude * np.sin(2.0 * np.pi * float(self._param("cycles")) * u)
            angle = math.radians(float(self._param("angle_deg")))
            c, s = math.cos(angle), math.sin(angle)
            return np.stack([c * along - s * across, s * along + c * across], axis=1)
        start = np.asarray(self._param("start_xy_m") or (-0.6 * rim, 0.0), dtype=np.float64)
        end = np.asarray(self._param("end_xy_m") or (0.6 * rim, 0.0), dtype=np.float64)
        if start.shape != (2,) or end.shape != (2,):
            raise DemoSpecError(f"{self.source}: line start_xy_m / end_xy_m need 2 values each")
        return start[None, :] + (end - start)[None, :] * u[:, None]

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
