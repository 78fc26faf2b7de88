"""Impedance-control math shared by the simulator, the datasets and the tuner (pure numpy).

Frames and units, defined once for the whole project:

* **Bowl frame**: world axes (z up), origin at the centre of the bowl at the lowest point of its surface.
* **Pose** ``x`` (6,): tool-tip position [m] in the bowl frame, then the tool orientation as a rotation
  vector [rad] relative to the nominal "tool pointing straight down" orientation, in bowl-frame axes.
* **Stiffness** ``K`` (6,): the diagonal of the Cartesian stiffness, ``[Kx, Ky, Kz]`` in N/m along the axes of
  its frame (``world``: bowl axes; ``surface``: two tangents and the normal along the demo,
  :class:`StiffnessSchedule`) and ``[Krx, Kry, Krz]`` in N·m/rad about bowl axes. Damping is ``D = 2·sqrt(m K)``: ``m = 1`` (the
  paper's) or the embodiment's apparent Cartesian mass (critical damping for the arm; the default).
* **Wrench** ``F`` (6,): the contact wrench the environment exerts *on* the tool, force [N] in bowl-frame
  axes and torque [N·m] about the tool-tip centre, tool weight removed. Pressing down gives ``F_z > 0``.

The controller every embodiment executes is ``F_cmd = K (x_attr - x) - D xdot`` plus gravity and bias
compensation, with stiffness changes low-pass filtered as a real Franka controller does.
"""

from dcm.control.impedance import (
    DAMPING_MODES,
    StiffnessFilter,
    StiffnessLimits,
    StiffnessOutOfRange,
    attractor_from_demo,
    damping_from_stiffness,
    damping_mass,
    filter_schedule,
)
from dcm.control.objectives import TASK_LOSSES, compliance_loss, task_loss, task_loss_over_samples
from dcm.control.schedule import (
    FRAMES,
    StiffnessFrameError,
    StiffnessSchedule,
    changepoint_phases,
    check_frame,
    equal_time_phases,
    filter_in_frame,
    frame_axes,
    frame_diagonal,
    phase_boundaries,
    schedule_from_phases,
    surface_axes,
)

__all__ = [
    "DAMPING_MODES",
    "FRAMES",
    "StiffnessFrameError",
    "StiffnessSchedule",
    "check_frame",
    "filter_in_frame",
    "frame_axes",
    "frame_diagonal",
    "surface_axes",
    "TASK_LOSSES",
    "StiffnessFilter",
    "StiffnessLimits",
    "StiffnessOutOfRange",
    "attractor_from_demo",
    "changepoint_phases",
    "compliance_loss",
    "damping_from_stiffness",
    "damping_mass",
    "equal_time_phases",
    "filter_schedule",
    "phase_boundaries",
    "schedule_from_phases",
    "task_loss",
    "task_loss_over_samples",
]
