"""The interface every embodiment (``tool``, ``panda``) implements for the ``Simulator``.

An embodiment owns one MuJoCo model (the robot or tool plus the bowl from ``scene.add_bowl``) and executes
the Cartesian impedance law ``F_cmd = K (x_attr - x) - D xdot`` (+ gravity/bias compensation) at every
physics step. The ``Simulator`` calls ``step`` once per control period with an attractor and the already
filtered stiffness and its damping; everything shared by both embodiments (attractor, limits, filtering,
sensing noise, latency, divergence checks, objectives) lives in ``rollout.py``.

Frames: poses, velocities and the contact wrench are in the bowl frame (see ``dcm.control``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    import mujoco

    from dcm.sim.domain import DomainSpec
    from dcm.sim.geometry import BowlSpec

PHYSICS_DT_S = 0.002
CONTROL_DT_S = 0.05


@dataclass
class StepResult:
    """What one control period produced.

    ``force_contact`` and ``force_sensor`` are averages over the period's physics substeps: single substep
    readings of a sliding tip chatter between contact and no contact, their average is smooth.
    """

    pose: np.ndarray  # (6,) bowl frame, end of period
    velocity: np.ndarray  # (6,) end of period
    force_contact: np.ndarray  # (6,) contact wrench on the tool, bowl frame, tool weight removed, averaged
    force_sensor: np.ndarray  # (6,) F/T sensor reading in the sensor-site frame (incl. tool weight), averaged
    in_contact: bool  # the tool touched the bowl in any substep


@runtime_checkable
class Embodiment(Protocol):
    """A compliant end effector in contact with a bowl, commanded once per control period."""

    name: str
    model: mujoco.MjModel
    data: mujoco.MjData

    def __init__(
        self,
        bowl: BowlSpec,
        domain: DomainSpec,
        control_dt: float = CONTROL_DT_S,
        physics_dt: float = PHYSICS_DT_S,
    ) -> None: ...

    def reset(self, pose: np.ndarray) -> None:
        """Put the tool at ``pose`` (bowl frame), at rest, with the attractor at the same pose."""
        ...

    apparent_mass: tuple[float, ...]  # (6,) per-axis mass critical damping uses [kg, kg·m²]

    def step(self, attractor: np.ndarray, stiffness: np.ndarray, damping: np.ndarray | None = None,
             axes: np.ndarray | None = None) -> StepResult:
        """Run one control period pulling towards ``attractor`` (6,) with stiffness ``K`` (6,) and damping
        ``D`` (6,), default ``2 sqrt(K)``, along bowl axes or, for the translation, along the columns of the
        stiffness ``axes`` (3, 3)."""
        ...
