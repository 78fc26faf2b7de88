"""``tool``: a compliant wiping tool driven directly by the Cartesian impedance law in plain MuJoCo.

A light body on three world-aligned slide joints (x, y, z) carries, through a wrist force/torque sensor,
a sphere tip (a flat pad catches on heightfield facets). Orientation is fixed (tool pointing straight
down), so the rotational pose channels are 0 and rotational stiffness has no effect.

The impedance law runs at every physics step inside MuJoCo: each slide joint has a position-type actuator
with gain ``kp = K`` and bias ``-kp q - kv qdot`` (``kv = D`` from the ``Simulator``; critical damping for a
tool of about unit mass is the paper's ``2 sqrt(K)``) whose control input is the attractor. Python rewrites
gains and attractor once per control period, so the per-substep Python work is one ``mj_step`` and one vector
add (for the averaged wrench): the contact-rich heightfield step dominates the cost
(``python bench/sim_throughput.py`` measures it). The ``implicitfast`` integrator treats the actuator damping
implicitly, which keeps stiff settings stable at the physics step.

Frames: joint positions are the tool-tip point (TCP, the lowest point of the sphere) in the bowl frame,
because the bowl origin sits at the world origin here.
"""

from __future__ import annotations

import mujoco
import numpy as np

from dcm.control import damping_from_stiffness
from dcm.sim.domain import DomainSpec, DomainSpecError
from dcm.sim.embodiment import CONTROL_DT_S, PHYSICS_DT_S, StepResult
from dcm.sim.geometry import BowlSpec
from dcm.sim.scene import add_bowl

GRAVITY_MPS2 = 9.81
TIP_RADIUS_M = 0.012
# Distance from the sensor site down to the tip sphere's centre [m].
STEM_LENGTH_M = 0.05
BODY_MASS_KG = 0.8  # everything above the F/T sensor
TIP_MASS_KG = 0.2  # everything below it: the "tool weight" the sensor reads
ACTUATOR_FORCE_LIMIT_N = 400.0


def build_tool_spec(bowl: BowlSpec, domain: DomainSpec, physics_dt: float = PHYSICS_DT_S) -> mujoco.MjSpec:
    """The MuJoCo world of the tool embodiment: bowl + slide-jointed tool + sensors + actuators.

    Refuses ``domain.joint_friction``: it models the joints of an arm, which this tool does not have.
    """
    if domain.joint_friction != "none":
        raise DomainSpecError(f"domain.joint_friction = {domain.joint_friction!r} models an arm's joints, which "
                              "the tool embodiment has none of; use embodiment='panda'")
    spec = mujoco.MjSpec()
    spec.modelname = "dcm_tool"
    spec.option.timestep = physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.gravity = [0.0, 0.0, -GRAVITY_MPS2]
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    add_bowl(spec, bowl, domain, origin_world=(0.0, 0.0, 0.0))

    light = spec.worldbody.add_light()
    light.pos = [0.0, 0.0, 1.0]
    light.dir = [0.0, 0.0, -1.0]

    tool = spec.worldbody.add_body()
    tool.name = "tool"
    tool.mass = BODY_MASS_KG * domain.tool_mass_scale
    tool.ipos = [0.0, 0.0, TIP_RADIUS_M + STEM_LENGTH_M + 0.03]
    tool.inertia = [1e-3, 1e-3, 1e-3]
    tool.explicitinertial = True
    for axis_name, axis in zip("xyz", np.eye(3)):
        joint = tool.add_joint()
        joint.name = f"slide_{axis_name}"
        joint.type = mujoco.mjtJoint.mjJNT_SLIDE
        joint.axis = axis
        joint.damping = [domain.joint_damping, 0.0, 0.0]  # linear damping only
        joint.frictionloss = domain.joint_frictionloss
        joint.armature = 0.0
    flange = tool.add_geom()
    flange.type = mujoco.mjtGeom.mjGEOM_CYLINDER
    flange.size = [0.025, 0.015, 0.0]
    flange.pos = [0.0, 0.0, TIP_RADIUS_M + STEM_LENGTH_M + 0.015]
    flange.contype = flange.conaffinity = 0
    flange.rgba = [0.3, 0.3, 0.35, 1.0]

    tip = tool.add_body()
    tip.name = "tip"
    tip.pos = [0.0, 0.0, TIP_RADIUS_M + STEM_LENGTH_M]  # at the sensor, above the sphere
    tip.mass = TIP_MASS_KG * domain.tool_mass_scale
    tip.ipos = [0.0, 0.0, -STEM_LENGTH_M]  # mass at the sphere centre: weight exerts no torque there
    tip.inertia = [1e-4, 1e-4, 1e-4]
    tip.explicitinertial = True
    ft_site = tip.add_site()
    ft_site.name = "ft"
    stem = tip.add_geom()
    stem.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    stem.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, -STEM_LENGTH_M + TIP_RADIUS_M]
    stem.size = [0.004, 0.0, 0.0]
    stem.contype = stem.conaffinity = 0
    stem.rgba = [0.5, 0.5, 0.55, 1.0]
    ball = tip.add_geom()
    ball.name = "tip_sphere"
    ball.type = mujoco.mjtGeom.mjGEOM_SPHERE
    ball.size = [TIP_RADIUS_M, 0.0, 0.0]
    ball.pos = [0.0, 0.0, -STEM_LENGTH_M]
    ball.condim = 3
    ball.solref = list(bowl.solref)
    ball.solimp = list(bowl.solimp)
    ball.rgba = [0.85, 0.35, 0.2, 1.0]
    touch_site = tip.add_site()
    touch_site.name = "touch"
    touch_site.type = mujoco.mjtGeom.mjGEOM_SPHERE
    touch_site.size = [TIP_RADIUS_M + 0.003, 0.0, 0.0]
    touch_site.pos = [0.0, 0.0, -STEM_LENGTH_M]
    touch_site.rgba = [0.0, 0.0, 0.0, 0.0]

    for kind, name in (
        (mujoco.mjtSensor.mjSENS_FORCE, "ft_force"),
        (mujoco.mjtSensor.mjSENS_TORQUE, "ft_torque"),
    ):
        sensor = spec.add_sensor()
        sensor.name = name
        sensor.type = kind
        sensor.objtype = mujoco.mjtObj.mjOBJ_SITE
        sensor.objname = "ft"
    touch = spec.add_sensor()
    touch.name = "touch"
    touch.type = mujoco.mjtSensor.mjSENS_TOUCH
    touch.objtype = mujoco.mjtObj.mjOBJ_SITE
    touch.objname = "touch"

    for axis_name in "xyz":
        act = spec.add_actuator()
        act.name = f"imp_{axis_name}"
        act.target = f"slide_{axis_name}"
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = 500.0
        act.biasprm[:3] = [0.0, -500.0, -2.0 * np.sqrt(500.0)]
        act.forcelimited = True
        act.forcerange = [-ACTUATOR_FORCE_LIMIT_N, ACTUATOR_FORCE_LIMIT_N]
    # A stiffness frame that turns (stiffness.frame=surface): three site actuators along the axes of a mocap
    # attractor body, idle (zero gains) while the joint actuators above serve the world frame.
    tcp = tool.add_site()
    tcp.name = "tcp"
    frame = spec.worldbody.add_body()
    frame.name = "stiffness_frame"
    frame.mocap = True
    frame.add_site().name = "frame_attractor"
    for axis in range(3):
        act = spec.add_actuator()
        act.name = f"imp_frame_{axis}"
        act.target = "tcp"
        act.refsite = "frame_attractor"
        act.trntype = mujoco.mjtTrn.mjTRN_SITE
        gear = [0.0] * 6
        gear[axis] = 1.0
        act.gear = gear
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = 0.0
        act.biasprm[:3] = [0.0, 0.0, 0.0]
        act.forcelimited = True
        act.forcerange = [-ACTUATOR_FORCE_LIMIT_N, ACTUATOR_FORCE_LIMIT_N]
    return spec


class ToolEmbodiment:
    """The fast embodiment: one MuJoCo model built once, commanded once per control period.

    ``step`` runs ``control_dt / physics_dt`` substeps and returns the contact wrench and the sensor reading
    averaged over them.
    """

    name = "tool"
    # Cartesian inertia the attractor equation uses (Λ): the nominal tool mass, isotropic.
    attractor_inertia_kg = BODY_MASS_KG + TIP_MASS_KG
    # Mass per axis that critical damping uses (the rotational axes are not actuated).
    apparent_mass = (BODY_MASS_KG + TIP_MASS_KG,) * 3 + (1.0,) * 3

    def __init__(
        self,
        bowl: BowlSpec,
        domain: DomainSpec | None = None,
        control_dt: float = CONTROL_DT_S,
        physics_dt: float = PHYSICS_DT_S,
    ) -> None:
        self.bowl = bowl
        self.domain = domain or DomainSpec()
        n_sub = control_dt / physics_dt
        if abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise ValueError(f"control_dt={control_dt} must be a whole multiple of physics_dt={physics_dt}")
        self.n_substeps = int(round(n_sub))
        self.control_dt = control_dt
        self.spec = build_tool_spec(bowl, self.domain, physics_dt)
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        self.tip_mass_kg = float(self.model.body_mass[self.model.body("tip").id])
        # The controller's gravity compensation uses the nominal mass: a heavier tool (realistic domain)
        # sags onto the surface, as an unmodelled payload does on a real arm.
        self._gravity_comp_N = (BODY_MASS_KG + TIP_MASS_KG) * GRAVITY_MPS2
        self._gain = self.model.actuator_gainprm
        self._bias = self.model.actuator_biasprm
        self._sensor_acc = np.zeros(self.model.nsensordata)
        self._sensor_slices = {
            name: slice(self.model.sensor(name).adr[0], self.model.sensor(name).adr[0] + self.model.sensor(name).dim[0])
            for name in ("ft_force", "ft_torque", "touch")
        }
        self.reset(np.zeros(6))

    def reset(self, pose: np.ndarray) -> None:
        """Tool tip at ``pose`` (bowl frame; orientation channels ignored), at rest, attractor = pose."""
        pose = np.asarray(pose, dtype=np.float64)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:3] = pose[:3]
        self.data.ctrl[:3] = pose[:3]
        self.data.mocap_pos[0] = pose[:3]
        self.data.qfrc_applied[2] = self._gravity_comp_N
        mujoco.mj_forward(self.model, self.data)

    def set_stiffness(self, stiffness: np.ndarray, damping: np.ndarray | None = None,
                      axes: np.ndarray | None = None) -> None:
        """Write K and D (default ``2 sqrt(K)``) of the translational axes into the actuators: the joint
        actuators for bowl axes, or with ``axes`` (3, 3) the site actuators along those axes."""
        k = np.asarray(stiffness, dtype=np.float64)[:3]
        d = damping_from_stiffness(k) if damping is None else np.asarray(damping, np.float64)[:3]
        active, idle = (slice(0, 3), slice(3, 6)) if axes is None else (slice(3, 6), slice(0, 3))
        self._gain[active, 0] = k
        self._bias[active, 1] = -k
        self._bias[active, 2] = -d
        self._gain[idle, 0] = self._bias[idle, 1] = self._bias[idle, 2] = 0.0
        if axes is not None:
            mujoco.mju_mat2Quat(self.data.mocap_quat[0], np.ascontiguousarray(axes, dtype=np.float64).ravel())

    def step(self, attractor: np.ndarray, stiffness: np.ndarray, damping: np.ndarray | None = None,
             axes: np.ndarray | None = None) -> StepResult:
        """One control period: impedance towards ``attractor`` with ``stiffness`` and ``damping`` along bowl axes,
        or along the columns of ``axes`` (3, 3); averaged wrench."""
        model, data = self.model, self.data
        self.set_stiffness(stiffness, damping, axes)
        data.ctrl[:3] = np.asarray(attractor, dtype=np.float64)[:3]
        if axes is not None:
            data.mocap_pos[0] = data.ctrl[:3]
        velocity_start = data.qvel[:3].copy()
        acc = self._sensor_acc
        acc[:] = 0.0
        sensordata = data.sensordata
        step = mujoco.mj_step
        for _ in range(self.n_substeps):
            step(model, data)
            acc += sensordata
        acc /= self.n_substeps
        return self._result(acc, velocity_start)

    def _result(self, sensor_mean: np.ndarray, velocity_start: np.ndarray) -> StepResult:
        data = self.data
        f_sensor = sensor_mean[self._sensor_slices["ft_force"]]
        t_sensor = sensor_mean[self._sensor_slices["ft_torque"]]
        touch = sensor_mean[self._sensor_slices["touch"]]
        # The sensor reads the force the body exerts on the tip (site frame = bowl axes here). The tip's
        # balance m (a + g z) = f_sensor + F_contact gives the contact force, with the mean acceleration
        # over the period from the velocity change.
        accel_mean = (data.qvel[:3] - velocity_start) / self.control_dt
        gravity = np.array([0.0, 0.0, GRAVITY_MPS2])
        force_contact = self.tip_mass_kg * (accel_mean + gravity) - f_sensor
        # Torque balance about the sensor (the tip mass sits at the sphere centre, the contact force acts on
        # the sphere): re-expressed about the tip centre, which lies STEM_LENGTH_M below the sensor.
        # (l z) x F = l (-F_y, F_x, 0), written out: np.cross costs more than the rest of this method.
        torque_contact = -t_sensor
        torque_contact[0] -= STEM_LENGTH_M * force_contact[1]
        torque_contact[1] += STEM_LENGTH_M * force_contact[0]
        pose = np.zeros(6)
        pose[:3] = data.qpos[:3]
        velocity = np.zeros(6)
        velocity[:3] = data.qvel[:3]
        return StepResult(
            pose=pose,
            velocity=velocity,
            force_contact=np.concatenate([force_contact, torque_contact]),
            force_sensor=np.concatenate([f_sensor, t_sensor]),
            in_contact=bool(touch[0] > 0.0),
        )
