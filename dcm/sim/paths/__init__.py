"""The path families a demo spec can wipe, registered by name.

Each family is one class (its parameters with their defaults and meaning, their validation, and its path);
``dcm.sim.demos.DemoSpec`` looks its ``family`` up here. To add a family, subclass
:class:`~dcm.sim.paths.family.PathFamily` in a module of this package (``name``, ``params``, ``check_params``
and ``xy``, or ``sample`` for a path with its own timing) and add an instance to ``PATH_FAMILIES`` below.
"""

from __future__ import annotations

from typing import Any

from dcm.sim.paths.curve import Curve, PacedCurve, SeededCurve
from dcm.sim.paths.errors import DemoSpecError
from dcm.sim.paths.family import PathFamily
from dcm.sim.paths.shapes import Line, Spiral, Wavelike
from dcm.sim.paths.waypoints import Waypoints

PATH_FAMILIES: dict[str, PathFamily] = {
    family.name: family for family in (Spiral(), Wavelike(), Line(), Curve(), PacedCurve(), Waypoints())
}
FAMILIES = tuple(PATH_FAMILIES)


def find_family(name: Any) -> PathFamily | None:
    """The family registered as ``name``, or None (also for a value that is not a name at all)."""
    return PATH_FAMILIES.get(name) if isinstance(name, str) else None


def registered_family(name: Any, where: str) -> PathFamily:
    """The family registered as ``name``; an unknown one is refused naming the registered families."""
    family = find_family(name)
    if family is None:
        raise DemoSpecError(f"{where}: family = {name!r}; expected one of {tuple(PATH_FAMILIES)}")
    return family


def seeded_families() -> tuple[str, ...]:
    """The families whose path comes from seeded draws (``DemoSpec.curve_draws``)."""
    return tuple(name for name, family in PATH_FAMILIES.items() if isinstance(family, SeededCurve))
