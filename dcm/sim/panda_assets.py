"""Assemble a Franka Panda with a wiping tool in plain MuJoCo (MjSpec) from robosuite's robot assets.

Why plain MuJoCo and not robosuite's environment: robosuite's OSC gain is an acceleration gain scaled by the
arm's inertia (not a stiffness in N/m), and its Python framework is slow at every physics step. Here the
Cartesian impedance law runs inside MuJoCo's own actuator model (see ``dcm.sim.panda``), and only the mesh and
kinematic/inertial data come from robosuite.

What is changed from robosuite's ``robot.xml`` and why:

* a small joint armature (robosuite's large one makes the tool feel many times heavier at the tip, far too
  heavy for unit-mass critical damping D = 2 sqrt(K));
* the joint motors are removed (the impedance actuators replace them) and each joint's total actuator torque is
  clamped to Franka's limits (``TORQUE_LIMITS_NM``);
* every arm body is gravity compensated (``gravcomp``), as the Franka's controller does;
* the arm's collision meshes are disabled: only the tool's sphere tip touches the bowl (a flat pad catches on
  heightfield facets, and arm contacts would only cost time);
* a wiping tool is welded to the flange, with a force/torque sensor site between flange and tool.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

JOINT_NAMES = tuple(f"joint{i}" for i in range(1, 8))
ARM_BODIES = ("link1", "link2", "link3", "link4", "link5", "link6", "link7", "right_hand")
# Franka Emika's documented joint torque limits [N·m].
TORQUE_LIMITS_NM = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
# A comfortable "elbow up, hand down" posture used as the IK seed and nullspace reference.
HOME_QPOS = np.array([0.0, 0.2, 0.0, -2.1, 0.0, 2.3, np.pi / 4])

# Names of the elements the controller uses.
TIP_SITE = "tool_tip"
FT_SITE = "ft_sensor"
TIP_GEOM = "tool_tip_geom"
TOOL_BODY = "tool"
ATTR_POS_BODY = "attractor_pos"
ATTR_ROT_BODY = "attractor_rot"
ATTR_POS_SITE = "attractor_pos_site"
ATTR_ROT_SITE = "attractor_rot_site"
FT_FORCE_SENSOR = "ft_force"
FT_TORQUE_SENSOR = "ft_torque"
IMPEDANCE_ACTUATORS = ("imp_x", "imp_y", "imp_z", "imp_rx", "imp_ry", "imp_rz")

# The tool frame (and the TCP site's frame) has z along the tool, pointing away from the flange. "Pointing
# straight down" means tool z = -world z with tool x = world x: a half turn about x. The TCP site keeps the tool
# body's orientation: MuJoCo's rotational site transmission (3.9) measures the error with a rotated site frame
# inconsistently with its own actuator velocity (a positive-feedback wrist), so the frames are kept equal.
NOMINAL_TOOL_QUAT = np.array([0.0, 1.0, 0.0, 0.0])


class PandaAssetError(ValueError):
    """robosuite's Panda assets are missing or a tool parameter is invalid."""


@dataclass(frozen=True)
class ToolSpec:
    """The wiping tool: a light shaft from the flange with a sphere tip.

    ``length_m`` runs from the flange (where the F/T sensor sits) to the centre of the tip sphere. The tool
    centre point (TCP, the pose the controller tracks) is the sphere's far end, one radius beyond the centre:
    the point that touches a flat surface when the tool points straight down (as in the ``tool`` embodiment).
    """

    length_m: float = 0.12
    tip_radius_m: float = 0.012
    mass_kg: float = 0.3
    shaft_radius_m: float = 0.012

    def __post_init__(self) -> None:
        for field in ("length_m", "tip_radius_m", "mass_kg", "shaft_radius_m"):
            value = getattr(self, field)
            if not np.isfinite(value) or value <= 0:
                raise PandaAssetError(f"ToolSpec.{field} must be positive and finite, got {value!r}")
        if self.tip_radius_m >= self.length_m:
            raise PandaAssetError(
                f"ToolSpec.tip_radius_m={self.tip_radius_m} must be smaller than length_m={self.length_m}"
            )


def robosuite_panda_xml() -> Path:
    """Path of robosuite's Panda ``robot.xml``, found without importing robosuite (slow, noisy import)."""
    found = importlib.util.find_spec("robosuite")
    if found is None or found.origin is None:
        raise PandaAssetError("robosuite is not installed; the panda embodiment needs its robot assets")
    path = Path(found.origin).parent / "models" / "assets" / "robots" / "panda" / "robot.xml"
    if not path.is_file():
        raise PandaAssetError(f"robosuite's Panda model is missing: {path}")
    return path


def _rod_inertia(mass: float, length: float, radius: float) -> list[float]:
    """Diagonal inertia of a solid cylinder along z about its centre of mass."""
    transverse = mass * (3 * radius**2 + length**2) / 12.0
    return [transverse, transverse, 0.5 * mass * radius**2]


def build_panda_spec(
    tool: ToolSpec,
    *,
    tool_gravcomp: float = 1.0,
    armature: float = 0.1,
    joint_damping: float | np.ndarray = 0.0,
    joint_frictionloss: float | np.ndarray = 0.0,
    tip_solref: tuple[float, float] | None = None,
    tip_solimp: tuple[float, ...] | None = None,
    visual: bool = True,
    timestep: float = 0.002,
) -> mujoco.MjSpec:
    """Panda + tool + two mocap attractor bodies + six impedance actuators (gains set later, per period).

    ``tool_gravcomp`` is the fraction of the tool's weight the controller compensates (configured tool mass over
    actual tool mass), so a wrongly configured tool load shows up as it would on the robot. The F/T sensor still
    reads the tool's full weight: compensation acts on the arm's joints, not between flange and tool.
    """
    spec = mujoco.MjSpec.from_file(str(robosuite_panda_xml()))
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.compiler.autolimits = True

    for actuator in list(spec.actuators):
        spec.delete(actuator)
    if not visual:
        for geom in list(spec.geoms):
            if geom.contype == 0 and geom.conaffinity == 0 and geom.type == mujoco.mjtGeom.mjGEOM_MESH:
                spec.delete(geom)
        for mesh in list(spec.meshes):
            if "vis" in mesh.name:
                spec.delete(mesh)
        for material in list(spec.materials):
            spec.delete(material)
    for geom in spec.geoms:
        if geom.name.endswith("_collision"):
            geom.contype = 0
            geom.conaffinity = 0

    damping = np.broadcast_to(np.asarray(joint_damping, dtype=float), (7,))
    friction = np.broadcast_to(np.asarray(joint_frictionloss, dtype=float), (7,))
    for i, name in enumerate(JOINT_NAMES):
        joint = spec.joint(name)
        joint.armature = armature
        joint.damping = [float(damping[i]), 0.0, 0.0]  # linear term only
        joint.frictionloss = float(friction[i])
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
        joint.actfrcrange = [-TORQUE_LIMITS_NM[i], TORQUE_LIMITS_NM[i]]
    for name in ARM_BODIES:
        spec.body(name).gravcomp = 1.0

    flange = spec.body("right_hand")
    # right_hand is turned -45° about z relative to link7 (robosuite's gripper mount); mount the tool on link7's
    # axis so that its x axis matches link7's, like a tool on the physical flange.
    tool_body = flange.add_body(name=TOOL_BODY, quat=[0.924, 0.0, 0.0, 0.383])
    tool_body.mass = tool.mass_kg
    tool_body.ipos = [0.0, 0.0, tool.length_m / 2]
    tool_body.inertia = _rod_inertia(tool.mass_kg, tool.length_m, tool.shaft_radius_m)
    tool_body.explicitinertial = True
    tool_body.gravcomp = float(tool_gravcomp)
    tool_body.add_site(name=FT_SITE, pos=[0, 0, 0], size=[0.02, 0, 0], rgba=[0.9, 0.2, 0.2, 1], group=2)
    shaft_len = tool.length_m - tool.tip_radius_m
    tool_body.add_geom(
        name="tool_shaft",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[tool.shaft_radius_m, shaft_len / 2, 0],
        pos=[0, 0, shaft_len / 2],
        contype=0,
        conaffinity=0,
        group=1,
        mass=0,
        rgba=[0.3, 0.3, 0.35, 1],
    )
    tip = tool_body.add_geom(
        name=TIP_GEOM,
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[tool.tip_radius_m, 0, 0],
        pos=[0, 0, tool.length_m],
        mass=0,
        condim=3,
        rgba=[0.1, 0.5, 0.9, 1],
    )
    # The bowl decides friction and softness: a lower priority hands the contact parameters to it.
    tip.priority = -1
    tip.friction = [0.0, 0.0, 0.0]
    if tip_solref is not None:
        tip.solref = list(tip_solref)
    if tip_solimp is not None:
        tip.solimp = list(tip_solimp)
    tool_body.add_site(
        name=TIP_SITE, pos=[0, 0, tool.length_m + tool.tip_radius_m], size=[0.004, 0, 0]
    )

    for body_name, site_name in ((ATTR_POS_BODY, ATTR_POS_SITE), (ATTR_ROT_BODY, ATTR_ROT_SITE)):
        body = spec.worldbody.add_body(name=body_name, mocap=True)
        body.add_site(name=site_name, size=[0.008, 0, 0], rgba=[0.2, 0.9, 0.2, 0.5], group=3)

    for axis, name in enumerate(IMPEDANCE_ACTUATORS):
        actuator = spec.add_actuator(name=name, target=TIP_SITE)
        actuator.trntype = mujoco.mjtTrn.mjTRN_SITE
        actuator.refsite = ATTR_POS_SITE if axis < 3 else ATTR_ROT_SITE
        gear = [0.0] * 6
        gear[axis] = 1.0
        actuator.gear = gear
        # Position servo: force = kp (ctrl - length) - kv velocity with ctrl = 0 and length = the tip's offset from
        # the attractor, i.e. K (x_attr - x) - D xdot. Gains are rewritten every control period.
        actuator.set_to_position(kp=1.0, kv=1.0)
        actuator.ctrlrange = [-1.0, 1.0]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE

    spec.add_sensor(
        name=FT_FORCE_SENSOR, type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FT_SITE
    )
    spec.add_sensor(
        name=FT_TORQUE_SENSOR, type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FT_SITE
    )
    return spec
