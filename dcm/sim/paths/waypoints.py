"""A user's waypoint file as a path family: reading and checking the CSV, and the timing the file sets.

Waypoint CSV: header ``t,x,y,press``; ``t`` [s] strictly increasing, ``x, y`` [m] in the bowl frame,
``press`` [m] the pressing depth below the surface (negative = above it). Rows are linearly resampled to
the control rate: ``H = floor((t_last - t_first) * control_hz) + 1`` steps, the first row at step 0.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from dcm.shipped import shipped_path
from dcm.sim.paths.errors import DemoSpecError, WaypointFileError, WaypointOutsideBowlError
from dcm.sim.paths.family import PRESS_RANGE_M, PathFamily, PathSpec

WAYPOINT_HEADER = ("t", "x", "y", "press")
MIN_WAYPOINT_ROWS = 2
DURATION_MATCH_S = 1e-6  # a waypoint spec's duration_s must be its file's span (a saved spec round-trips)


def waypoint_horizon(span_s: float, control_hz: float) -> int:
    """Steps H of a waypoint file spanning ``span_s``: its first row is step 0 and its last row step H - 1."""
    return int(math.floor(span_s * control_hz + 1e-9)) + 1


def waypoint_span_s(horizon: int, control_hz: float) -> float:
    """The span t_last - t_first a waypoint file needs to give ``horizon`` steps (the inverse of
    :func:`waypoint_horizon`): a 12 s demo of 240 steps at 20 Hz is a file spanning 11.95 s."""
    return (int(horizon) - 1) / control_hz


def _parse_row(path: Path, i: int, row: list[str]) -> list[float]:
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
    return parsed


def load_waypoints_csv(path: str | Path) -> np.ndarray:
    """Read and validate a waypoint CSV; returns rows (N, 4) = [t, x, y, press] in s, m, m, m."""
    path = Path(shipped_path(path))  # data/waypoints/example.csv from any directory, if not the user's own
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
    values = [_parse_row(path, i, row) for i, row in enumerate(rows[1:], start=2)]
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


class Waypoints(PathFamily):
    """A user's waypoint file (the spec's ``waypoints``): it sets the path, its duration (its span, which a
    saved spec records as ``duration_s``) and its press depth, so a ``duration_s`` other than the span or a
    ``press_m`` is refused rather than ignored. It has no parameters."""

    name = "waypoints"
    params: ClassVar[dict[str, Any]] = {}
    timed_by_file = True

    def resolve_timing(self, spec: PathSpec) -> tuple[float | None, float | None]:
        where = spec.source
        if not spec.waypoints:
            raise DemoSpecError(f"{where}: family 'waypoints' needs a 'waypoints' CSV path")
        if spec.press_m is not None:
            raise DemoSpecError(f"{where}: press_m = {spec.press_m!r} does not apply to a waypoint file, whose "
                                f"press column sets the depth ({spec.waypoints}); leave press_m out (null)")
        table = load_waypoints_csv(spec.waypoints)
        span = float(table[-1, 0] - table[0, 0])
        duration = spec.duration_s
        if duration is not None and (not isinstance(duration, (int, float)) or abs(duration - span) > DURATION_MATCH_S):
            shown = f"{duration:g} s" if isinstance(duration, (int, float)) else repr(duration)
            raise DemoSpecError(
                f"{where}: duration_s = {shown}, but the waypoint file {spec.waypoints} spans {span:g} s "
                f"(t = {table[0, 0]:g} to {table[-1, 0]:g} s): a waypoint file sets its own duration; leave "
                "duration_s out (null) or retime the file")
        return span, None

    def sample(self, spec: PathSpec, control_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The file's rows resampled at the control rate; a row outside the rim is refused naming it."""
        table = load_waypoints_csv(spec.waypoints)  # type: ignore[arg-type]
        outside = ~np.asarray(spec.bowl.contains(table[:, 1], table[:, 2]))
        if outside.any():
            i = int(np.argmax(outside))
            raise WaypointOutsideBowlError(
                f"{spec.waypoints}, row {i + 2}: (x, y) = ({table[i, 1]:g}, {table[i, 2]:g}) m lies outside "
                f"the bowl (rim radius {spec.bowl.rim_radius_m:g} m, shape {spec.bowl.shape})"
            )
        t_rel = table[:, 0] - table[0, 0]
        horizon = waypoint_horizon(t_rel[-1], control_hz)
        if horizon < MIN_WAYPOINT_ROWS:
            raise WaypointFileError(f"{spec.waypoints}: spans {t_rel[-1]:g} s, shorter than one control period")
        t = np.arange(horizon) * (1.0 / control_hz)
        xy = np.stack([np.interp(t, t_rel, table[:, 1]), np.interp(t, t_rel, table[:, 2])], axis=1)
        return t, xy, np.interp(t, t_rel, table[:, 3])
