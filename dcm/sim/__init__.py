"""Wiping simulator: bowls, embodiments under Cartesian impedance control, demos and rollouts.

One control period (``CONTROL_DT_S`` by default) runs several physics substeps (``PHYSICS_DT_S``); a demo of
``duration_s`` has ``H = duration_s / dt`` control steps. Frames and units are those documented in
``dcm.control``.

Heavy pieces (MuJoCo models, the ``Simulator``) are imported lazily so that light users (configs,
dataset readers) do not pay for them.
"""

from __future__ import annotations

from typing import Any

from dcm.sim.domain import DomainSpec, DomainSpecError
from dcm.sim.embodiment import CONTROL_DT_S, PHYSICS_DT_S, Embodiment, StepResult
from dcm.sim.geometry import BowlSpec, BowlSpecError

_LAZY = {
    "Demo": "dcm.sim.demos",
    "DemoSpec": "dcm.sim.demos",
    "DemoSpecError": "dcm.sim.demos",
    "WaypointFileError": "dcm.sim.demos",
    "PathOutsideBowlError": "dcm.sim.demos",
    "DivergenceBounds": "dcm.sim.rollout",
    "load_waypoints_csv": "dcm.sim.demos",
    "Simulator": "dcm.sim.rollout",
    "Trial": "dcm.sim.rollout",
    "SimulatorError": "dcm.sim.rollout",
    "EMBODIMENTS": "dcm.sim.rollout",
    "ToolEmbodiment": "dcm.sim.tool",
    "add_bowl": "dcm.sim.scene",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'dcm.sim' has no attribute {name!r}")


__all__ = [
    "CONTROL_DT_S",
    "PHYSICS_DT_S",
    "BowlSpec",
    "BowlSpecError",
    "DomainSpec",
    "DomainSpecError",
    "Embodiment",
    "StepResult",
    *sorted(_LAZY),
]
