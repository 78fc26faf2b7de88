"""The errors of a demo description, shared by the spec and its path families (importable as
``dcm.sim.demos.DemoSpecError`` and so on)."""

from __future__ import annotations


class DemoSpecError(ValueError):
    """An invalid demo description: names the field (or file, row) and the value."""


class WaypointFileError(DemoSpecError):
    """A malformed waypoint CSV: names the file, the row (1-based, header = row 1) and the value."""


class PathOutsideBowlError(DemoSpecError):
    """A demo path leaves the usable bowl surface."""


class WaypointOutsideBowlError(WaypointFileError, PathOutsideBowlError):
    """A waypoint row lies outside the bowl's rim."""
