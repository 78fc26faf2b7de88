"""``panda``: a Franka Panda wiping the bowl under a Franka-style Cartesian impedance controller.

The arm, its meshes and inertias come from robosuite's assets (``panda_assets``), simulated in plain MuJoCo.
The controller is the one franka_ros' ``cartesian_impedance_example_controller`` runs:

    tau = J^T (K (x_attr - x) - D xdot) + gravity + Coriolis + (I - J^T J^T+) (k_ns (q_ns - q) - d_ns qdot)

with ``K`` the diagonal Cartesian stiffness (N/m, N·m/rad) and ``D`` the damping the ``Simulator`` passes
(``dcm.control.damping_from_stiffness``; ``2 sqrt(K)`` if none). How it is executed, and why:

* The spring-damper ``J^T (K e - D xdot)`` is six MuJoCo position actuators with *site transmission* on the
  tool centre point, referenced to two mocap "attractor" sites (one world-aligned for the translations, one
  carrying the attractor orientation for the rotations). MuJoCo evaluates it at every physics step, with
  the damping integrated implicitly (``implicitfast``), so the law is exact per physics step while Python only
  rewrites six gains and the two mocap poses once per control period. Each joint's summed actuator torque is
  clamped to Franka's joint torque limits.
* Gravity is compensated by MuJoCo's body ``gravcomp`` (exact, every step). The tool is compensated with its
  *configured* (nominal) mass, so a heavier tool in the shifted domain sags onto the surface as an unmodelled
  payload does on a real arm.
* Coriolis/centrifugal and the nullspace posture torque vary slowly at wiping speeds: they are computed once
  per control period and held (``qfrc_applied``).
* The arm's own joint friction (``domain.joint_friction``, off by default) is a physical torque, not part of
  the controller: it is computed from the joint velocities at every physics step and added to ``qfrc_applied``
  between MuJoCo's two step halves, and neither gravity compensation nor the attractor knows it.

Two reference variants exist only to validate that choice (``controller="python"`` evaluates the whole law in
Python at every physics step, as franka_ros does; ``slow_terms="substep"`` refreshes Coriolis and nullspace
every physics step); ``python bench/sim_throughput.py --variants`` compares their forces and speed with the
default's.

Dynamics worth knowing: with robosuite's link inertias the tip's apparent mass is several kilograms, so
unit-mass damping D = 2 sqrt(K) leaves the arm under-damped: it rings after every stiffness change. The
``Simulator`` therefore damps critically for ``apparent_mass`` by default
(``damping="critical"``); ``damping="unit"`` gives the paper's D = 2 sqrt(K). Rotational gains act
about the tool's axes, which differ from the bowl's only by sign flips near the nominal pose, so a diagonal
rotational stiffness means the same thing in both. The bowl sits ``BOWL_ORIGIN_WORLD`` from the arm's base.

Frames: the pose is the TCP (the far end of the sphere tip) in the bowl frame; its rotation vector is relative
to "tool pointing straight down" in bowl axes. ``force_contact`` is the wrench on the tool from the bowl,
estimated from the wrist sensor as a real setup does (tool weight and inertia removed), force in bowl axes and
torque about the tip sphere's centre. ``force_sensor`` is the raw reading in the sensor-site (tool) frame:
z along the tool, away from the flange.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from dcm.control import damping_from_stiffness
from dcm.sim import panda_assets as pa
from dcm.sim.domain import DomainSpec
from dcm.sim.embodiment import CONTROL_DT_S, PHYSICS_DT_S, StepResult
from dcm.sim.geometry import BowlSpec
from dcm.sim.scene import add_bowl

GRAVITY_MPS2 = 9.81
# Bowl centre (lowest surface point) in the robot's base frame: in front of the base, low enough that the
# hand points down comfortably over the whole bowl.
BOWL_ORIGIN_WORLD = (0.5, 0.0, 0.1)
# Nullspace posture spring (franka_ros uses a few N·m/rad, critically damped in joint space).
NULLSPACE_STIFFNESS_NMPRAD = 2.0
# Stiffness the actuators hold right after reset, before the first command arrives.
RESET_STIFFNESS = np.array([500.0, 500.0, 500.0, 20.0, 20.0, 20.0])


# Joint friction of a Panda as identified by Gaz, Cognetti, Oliva, Robuffo Giordano and De Luca, "Dynamic
# identification of the Franka Emika Panda robot with retrieval of feasible parameters using penalty-based
# optimization", IEEE RA-L 2019; the values of marcocognetti/FrankaEmikaPandaDynModel,
# matlab/dyn_model_panda/get_FrictionTorque.m (the same in cpp/.../franka_model.h), joints 1-7:
#   tau_f,i(qdot) = phi1 / (1 + exp(-phi2 (qdot_i + phi3))) - phi1 / (1 + exp(-phi2 phi3))
# tau_f is the friction torque the motor must supply on top of the rigid-body dynamics, so the torque friction
# exerts on the joint is -tau_f. It is 0 at rest and increases with qdot: it always opposes the motion.
GAZ2019_PHI1_NM = np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489])
GAZ2019_PHI2_SPRAD = np.array([5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336])
GAZ2019_PHI3_RADPS = np.array([0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526])


def gaz2019_friction_torque(qvel_radps: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """The identified friction torque tau_f [N·m] of the seven joints at joint velocities ``qvel_radps``, times
    ``scale``: what the motors must supply; the joint feels its negative.

    Written with tanh (1 / (1 + exp(-z)) = (1 + tanh(z / 2)) / 2), which cannot overflow at any speed.
    """
    qvel = np.asarray(qvel_radps, dtype=np.float64)
    half_slope = 0.5 * GAZ2019_PHI2_SPRAD
    return (0.5 * scale * GAZ2019_PHI1_NM) * (
        np.tanh(half_slope * (qvel + GAZ2019_PHI3_RADPS)) - np.tanh(half_slope * GAZ2019_PHI3_RADPS))


_GRAVITY_VEC = np.array([0.0, 0.0, GRAVITY_MPS2])
_NOMINAL_MAT = np.zeros(9)
mujoco.mju_quat2Mat(_NOMINAL_MAT, pa.NOMINAL_TOOL_QUAT)
_NOMINAL_MAT = _NOMINAL_MAT.reshape(3, 3)


class PandaError(ValueError):
    """Bad input to the panda embodiment (names the value), or an unreachable pose."""


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation vector [rad]."""
    quat = np.zeros(4)
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    mujoco.mju_axisAngle2Quat(quat, np.asarray(rotvec, dtype=np.float64) / angle, angle)
    return quat


def tool_quat(rotvec: np.ndarray) -> np.ndarray:
    """World orientation of the tool frame for a pose rotation vector (relative to pointing straight down)."""
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, rotvec_to_quat(rotvec), pa.NOMINAL_TOOL_QUAT)
    return out


def mat_to_rotvec(mat: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a 3x3 rotation matrix (flattened or not)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(mat, dtype=np.float64).reshape(9))
    out = np.zeros(3)
    mujoco.mju_quat2Vel(out, quat, 1.0)
    return out


class PandaEmbodiment:
    """The paper's setup: a Panda with a sphere-tipped wiping tool and a wrist F/T sensor.

    One MuJoCo model is built at construction and reused; ``reset`` solves inverse kinematics once per distinct
    start pose (cached) and ``step`` runs one control period of ``control_dt / physics_dt`` physics substeps.
    """

    name = "panda"
    # Diagonal of the apparent Cartesian mass Λ = (J M⁻¹ Jᵀ)⁻¹ at the TCP over the bowl's centre [kg, kg·m²]:
    # what critical damping uses. Λ varies over the bowl; tests/test_sim_panda.py checks these values against
    # the model.
    apparent_mass = (10.0, 10.0, 10.0, 2.0, 0.9, 0.2)
    # No ``attractor_inertia_kg``: the rollout attractor leaves out Λ ẍ_demo, as a controller that does not
    # know the arm's inertia. With it the arm tracks the demo at any stiffness, and no trade-off is left to tune
    # (studies/record.md).

    def __init__(
        self,
        bowl: BowlSpec,
        domain: DomainSpec | None = None,
        control_dt: float = CONTROL_DT_S,
        physics_dt: float = PHYSICS_DT_S,
        *,
        tool: pa.ToolSpec | None = None,
        bowl_origin_world: Sequence[float] = BOWL_ORIGIN_WORLD,
        nullspace_stiffness: float = NULLSPACE_STIFFNESS_NMPRAD,
        coriolis: bool = True,
        visual: bool = True,
        controller: str = "actuator",
        slow_terms: str = "period",
    ) -> None:
        n_sub = control_dt / physics_dt
        if physics_dt <= 0 or abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise PandaError(f"control_dt={control_dt} must be a whole multiple of physics_dt={physics_dt}")
        self.bowl = bowl
        self.domain = domain or DomainSpec()
        self.control_dt = float(control_dt)
        self.n_substeps = int(round(n_sub))
        self.tool = tool or pa.ToolSpec()
        self.origin = np.asarray(bowl_origin_world, dtype=np.float64)
        if self.origin.shape != (3,) or not np.all(np.isfinite(self.origin)):
            raise PandaError(f"bowl_origin_world must be 3 finite numbers, got {bowl_origin_world!r}")
        self.nullspace_stiffness = float(nullspace_stiffness)
        self.nullspace_damping = 2.0 * np.sqrt(self.nullspace_stiffness)
        self.coriolis = coriolis
        if controller not in ("actuator", "python"):
            raise PandaError(f"controller = {controller!r}; expected 'actuator' or 'python'")
        if slow_terms not in ("period", "substep"):
            raise PandaError(f"slow_terms = {slow_terms!r}; expected 'period' or 'substep'")
        self.controller = controller
        self.slow_terms = slow_terms
        self._held_slow = np.zeros(7)
        # The arm's own joint friction, unknown to the controller: None when off (the default physics, untouched).
        self._friction_scale = self.domain.joint_friction_scale if self.domain.has_joint_friction else None

        # The controller's model of the tool has the nominal mass; the simulated tool may be heavier.
        self.tool_mass_kg = self.tool.mass_kg * self.domain.tool_mass_scale
        self.spec = pa.build_panda_spec(
            pa.ToolSpec(self.tool.length_m, self.tool.tip_radius_m, self.tool_mass_kg, self.tool.shaft_radius_m),
            tool_gravcomp=1.0 / self.domain.tool_mass_scale,
            joint_damping=self.domain.joint_damping,
            joint_frictionloss=self.domain.joint_frictionloss,
            timestep=physics_dt,
            visual=visual,
        )
        self.spec.modelname = "dcm_panda"
        self.spec.visual.global_.offwidth = 640
        self.spec.visual.global_.offheight = 480
        self.spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
        self.spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
        light = self.spec.worldbody.add_light()
        light.pos = [0.5, 0.0, 1.5]
        light.dir = [0.0, 0.0, -1.0]
        add_bowl(self.spec, bowl, self.domain, origin_world=tuple(self.origin))
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)

        m = self.model
        self._tcp = m.site(pa.TIP_SITE).id
        self._ft = m.site(pa.FT_SITE).id
        self._tool_body = m.body(pa.TOOL_BODY).id
        self._mocap_pos = m.body(pa.ATTR_POS_BODY).mocapid[0]
        self._mocap_rot = m.body(pa.ATTR_ROT_BODY).mocapid[0]
        self._act = np.array([m.actuator(n).id for n in pa.IMPEDANCE_ACTUATORS])
        self._dofs = np.array([m.joint(n).dofadr[0] for n in pa.JOINT_NAMES])
        self._qadr = np.array([m.joint(n).qposadr[0] for n in pa.JOINT_NAMES])
        if not (np.array_equal(self._act, np.arange(6)) and np.array_equal(self._dofs, np.arange(7))):
            raise PandaError("unexpected model layout: impedance actuators and arm dofs must come first")
        self._jnt_range = m.jnt_range[[m.joint(n).id for n in pa.JOINT_NAMES]].copy()
        f_adr, t_adr = m.sensor(pa.FT_FORCE_SENSOR).adr[0], m.sensor(pa.FT_TORQUE_SENSOR).adr[0]
        if t_adr != f_adr + 3:
            raise PandaError("F/T force and torque sensors must be adjacent")
        self._ft_slice = slice(f_adr, f_adr + 6)
        self._tool_gravcomp = float(m.body_gravcomp[self._tool_body])
        # Lever arms in the tool frame: sensor site (origin) and tool COM relative to the tip sphere's centre.
        centre = np.array([0.0, 0.0, self.tool.length_m])
        self._sensor_from_centre = -centre
        self._com_from_centre = m.body_ipos[self._tool_body] - centre

        self._gain = m.actuator_gainprm[:6]
        self._bias = m.actuator_biasprm[:6]
        self._ik_cache: dict[tuple[float, ...], np.ndarray] = {}
        self._q_nullspace = pa.HOME_QPOS.copy()
        self._sensor_acc = np.zeros(6)
        self._rot_acc = np.zeros(9)
        self._jac = np.zeros((6, m.nv))
        self._jac_com = np.zeros((3, m.nv))
        self.set_stiffness(RESET_STIFFNESS)
        self.reset(np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0]))

    # -- frames ------------------------------------------------------------------------------------
    def tcp_pose(self) -> np.ndarray:
        """Current TCP pose (6,) in the bowl frame (from the last kinematics pass)."""
        pose = np.empty(6)
        pose[:3] = self.data.site_xpos[self._tcp] - self.origin
        rot = self.data.site_xmat[self._tcp].reshape(3, 3) @ _NOMINAL_MAT.T
        pose[3:] = mat_to_rotvec(rot)
        return pose

    def tcp_velocity(self) -> np.ndarray:
        """Current TCP twist (6,): linear [m/s] then angular [rad/s], bowl axes."""
        res = np.zeros(6)
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self._tcp, res, 0)
        return np.concatenate([res[3:], res[:3]])

    def _check_pose(self, pose: np.ndarray, what: str) -> np.ndarray:
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (6,) or not math.isfinite(pose.sum()):
            raise PandaError(f"{what} must be 6 finite numbers (bowl frame), got {pose!r}")
        return pose

    # -- inverse kinematics --------------------------------------------------------------------------
    def solve_ik(self, pose: np.ndarray, iters: int = 400, tol: float = 1e-5) -> np.ndarray:
        """Joint angles putting the TCP at ``pose`` (bowl frame), by damped least squares from the home posture.

        Always starts from ``HOME_QPOS`` (not the current state) so the answer depends only on the pose; a
        nullspace pull keeps the elbow near home. Results are cached per pose.
        """
        pose = self._check_pose(pose, "reset pose")
        key = tuple(np.round(pose, 9))
        if key in self._ik_cache:
            return self._ik_cache[key].copy()
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[self._qadr] = pa.HOME_QPOS
        target_pos = pose[:3] + self.origin
        target_quat = tool_quat(pose[3:])
        jac = np.zeros((6, m.nv))
        err = np.zeros(6)
        site_quat, neg, dq_quat = np.zeros(4), np.zeros(4), np.zeros(4)
        damping = 1e-4
        for it in range(iters):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            err[:3] = target_pos - d.site_xpos[self._tcp]
            mujoco.mju_mat2Quat(site_quat, d.site_xmat[self._tcp])
            mujoco.mju_negQuat(neg, site_quat)
            mujoco.mju_mulQuat(dq_quat, target_quat, neg)
            mujoco.mju_quat2Vel(err[3:], dq_quat, 1.0)
            if err[:3] @ err[:3] < tol**2 and err[3:] @ err[3:] < (10 * tol) ** 2 and it > 0:
                break
            mujoco.mj_jacSite(m, d, jac[:3], jac[3:], self._tcp)
            j = jac[:, self._dofs]
            jjt = j @ j.T + damping * np.eye(6)
            j_pinv = j.T @ np.linalg.inv(jjt)
            step = j_pinv @ err
            q = d.qpos[self._qadr]
            if it < iters // 2:  # posture pull first, then converge on the task alone
                step += (np.eye(7) - j_pinv @ j) @ (0.1 * (pa.HOME_QPOS - q))
            norm = np.linalg.norm(step)
            if norm > 0.2:
                step *= 0.2 / norm
            d.qpos[self._qadr] = np.clip(q + step, self._jnt_range[:, 0], self._jnt_range[:, 1])
        else:
            raise PandaError(
                f"inverse kinematics did not converge for pose {np.round(pose, 4).tolist()} (bowl frame): "
                f"residual {np.linalg.norm(err[:3]) * 1000:.2f} mm, {np.degrees(np.linalg.norm(err[3:])):.2f} deg; "
                "is it outside the Panda's workspace?"
            )
        q = d.qpos[self._qadr].copy()
        self._ik_cache[key] = q
        return q.copy()

    # -- control -------------------------------------------------------------------------------------
    def set_stiffness(self, stiffness: np.ndarray, damping: np.ndarray | None = None) -> None:
        """Write K and D (default ``2 sqrt(K)``) into the six impedance actuators (bowl-axis translation, rotation)."""
        k = np.asarray(stiffness, dtype=np.float64)
        if k.shape != (6,) or not math.isfinite(k.sum()) or k.min() < 0:
            raise PandaError(f"stiffness must be 6 finite non-negative numbers, got {k!r}")
        dmp = damping_from_stiffness(k) if damping is None else np.asarray(damping, dtype=np.float64)
        if self.controller == "python":  # the reference controller computes the law itself
            k = dmp = np.zeros(6)
        self._gain[:, 0] = k
        self._bias[:, 1] = -k
        self._bias[:, 2] = -dmp

    def set_attractor(self, attractor: np.ndarray, axes: np.ndarray | None = None) -> None:
        """Move the two mocap attractor sites to ``attractor`` (bowl frame). The translational actuators act along
        the position site's axes: bowl axes, or the columns of the stiffness ``axes`` (3, 3)."""
        attractor = self._check_pose(attractor, "attractor")
        pos = attractor[:3] + self.origin
        self.data.mocap_pos[self._mocap_pos] = pos
        self.data.mocap_pos[self._mocap_rot] = pos
        if axes is None:
            self.data.mocap_quat[self._mocap_pos] = (1.0, 0.0, 0.0, 0.0)
        else:
            mujoco.mju_mat2Quat(self.data.mocap_quat[self._mocap_pos],
                                np.ascontiguousarray(axes, dtype=np.float64).ravel())
        self.data.mocap_quat[self._mocap_rot] = tool_quat(attractor[3:])

    def _slow_torques(self) -> None:
        """Coriolis and nullspace posture torque, held over the control period (slowly varying terms)."""
        m, d = self.model, self.data
        tau = np.zeros(7)
        if self.coriolis:
            # qfrc_bias = Coriolis + full gravity; gravcomp removed the compensated gravity already. What is left
            # of the tool's weight beyond its configured mass must stay uncompensated.
            tau += d.qfrc_bias[:7]
            tau -= d.qfrc_gravcomp[:7]
            if self._tool_gravcomp != 1.0:
                mujoco.mj_jacBodyCom(m, d, self._jac_com, None, self._tool_body)
                tool_weight = m.body_mass[self._tool_body] * GRAVITY_MPS2
                tau -= (1.0 - self._tool_gravcomp) * tool_weight * self._jac_com[2, :7]
        if self.nullspace_stiffness > 0:
            # Franka's projector I - J^T (J^T)^+, with a damped pseudo-inverse (J J^T + eps I)^-1 J.
            mujoco.mj_jacSite(m, d, self._jac[:3], self._jac[3:], self._tcp)
            j = self._jac[:, :7]
            jjt = j @ j.T
            jjt[np.diag_indices(6)] += 1e-6
            posture = self.nullspace_stiffness * (self._q_nullspace - d.qpos[self._qadr])
            posture -= self.nullspace_damping * d.qvel[:7]
            tau += posture - j.T @ np.linalg.solve(jjt, j @ posture)
        self._held_slow = tau
        d.qfrc_applied[:7] = tau

    def _python_impedance(self, stiffness: np.ndarray, damping: np.ndarray, axes: np.ndarray | None = None) -> None:
        """Reference controller: tau = J^T (K e - D J qdot) evaluated in Python, clamped to the joint limits.

        Adds to ``qfrc_applied`` on top of the slow terms; used only to validate the in-engine actuators.
        """
        m, d = self.model, self.data
        jac = self._jac
        mujoco.mj_jacSite(m, d, jac[:3], jac[3:], self._tcp)
        j = jac[:, :7]
        err = np.empty(6)
        err[:3] = d.mocap_pos[self._mocap_pos] - d.site_xpos[self._tcp]
        site_quat, neg, diff = np.zeros(4), np.zeros(4), np.zeros(4)
        mujoco.mju_mat2Quat(site_quat, d.site_xmat[self._tcp])
        mujoco.mju_negQuat(neg, site_quat)
        mujoco.mju_mulQuat(diff, d.mocap_quat[self._mocap_rot], neg)
        mujoco.mju_quat2Vel(err[3:], diff, 1.0)
        velocity = j @ d.qvel[:7]
        if axes is None:
            wrench = stiffness * err - damping * velocity
        else:  # R (k ∘ Rᵀ e - d ∘ Rᵀ v) for the translation
            wrench = np.empty(6)
            wrench[:3] = axes @ (stiffness[:3] * (axes.T @ err[:3]) - damping[:3] * (axes.T @ velocity[:3]))
            wrench[3:] = stiffness[3:] * err[3:] - damping[3:] * velocity[3:]
        tau = np.clip(j.T @ wrench, -pa.TORQUE_LIMITS_NM, pa.TORQUE_LIMITS_NM)
        d.qfrc_applied[:7] = tau + self._held_slow

    def reset(self, pose: np.ndarray) -> None:
        """Arm at rest with the TCP at ``pose`` (bowl frame) and the attractor there; nullspace target = this q."""
        q = self.solve_ik(pose)
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self._qadr] = q
        self._q_nullspace = q.copy()
        self.set_attractor(pose)
        mujoco.mj_forward(m, d)
        self._slow_torques()

    def step(self, attractor: np.ndarray, stiffness: np.ndarray, damping: np.ndarray | None = None,
             axes: np.ndarray | None = None) -> StepResult:
        """One control period towards ``attractor`` with stiffness ``K`` and damping ``D`` (default ``2 sqrt(K)``)
        along bowl axes, or along the columns of ``axes`` (3, 3); wrench averaged over the substeps.

        If MuJoCo reports a numerical instability during the period, pose/velocity/wrench come back as NaN so
        the caller's divergence check marks the trial failed.
        """
        m, d = self.model, self.data
        self.set_attractor(attractor, axes)
        self.set_stiffness(stiffness, damping)
        self._slow_torques()
        warnings_before = int(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)
        v_start = self.tcp_velocity()[:3]
        acc, racc = self._sensor_acc, self._rot_acc
        acc[:] = 0.0
        racc[:] = 0.0
        sensor = d.sensordata[self._ft_slice]
        xmat = d.site_xmat[self._ft]
        contact = False
        if self.controller == "actuator" and self.slow_terms == "period" and self._friction_scale is None:
            step = mujoco.mj_step
            for _ in range(self.n_substeps):
                step(m, d)
                acc += sensor
                racc += xmat
                if d.ncon:
                    contact = True
        else:  # joint friction or a reference variant: Python work at every physics step, between MuJoCo's halves
            stiffness = np.asarray(stiffness, dtype=np.float64)
            damping = damping_from_stiffness(stiffness) if damping is None else np.asarray(damping, dtype=np.float64)
            scale = self._friction_scale
            for _ in range(self.n_substeps):
                mujoco.mj_step1(m, d)
                if self.slow_terms == "substep":
                    self._slow_torques()
                if self.controller == "python":
                    self._python_impedance(stiffness, damping, axes)
                elif scale is not None:
                    d.qfrc_applied[:7] = self._held_slow
                if scale is not None:  # at the velocity this step starts from
                    d.qfrc_applied[:7] -= gaz2019_friction_torque(d.qvel[:7], scale)
                mujoco.mj_step2(m, d)
                acc += sensor
                racc += xmat
                if d.ncon:
                    contact = True
        mujoco.mj_forward(m, d)
        if int(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number) != warnings_before:
            nan = np.full(6, np.nan)
            return StepResult(nan, nan.copy(), nan.copy(), nan.copy(), contact)
        sensor_mean = acc / self.n_substeps
        rot = (racc / self.n_substeps).reshape(3, 3)
        velocity = self.tcp_velocity()
        accel = (velocity[:3] - v_start) / self.control_dt
        return StepResult(
            pose=self.tcp_pose(),
            velocity=velocity,
            force_contact=self.contact_wrench(sensor_mean, rot, accel),
            force_sensor=sensor_mean.copy(),
            in_contact=contact,
        )

    def contact_wrench(self, sensor: np.ndarray, rot: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """Wrench of the bowl on the tool from an F/T reading, as a real setup estimates it.

        ``sensor`` is the force/torque the flange exerts on the tool, in the sensor (tool) frame; ``rot`` the
        tool frame's orientation; ``accel`` the tool's linear acceleration [m/s²]. Newton for the tool gives
        F_contact = m (a + g z) - f_sensor; the torque balance about the tip sphere's centre moves the sensor
        torque there and removes the moment of the tool's weight (and inertia) about it.
        """
        f_s, t_s = sensor[:3], sensor[3:]
        inertial_tool = self.tool_mass_kg * (rot.T @ (accel + _GRAVITY_VEC))
        f_c = inertial_tool - f_s
        # Both lever arms lie on the tool axis (tool z): (0, 0, a) x f = (-a f_y, a f_x, 0).
        a_s, a_c = self._sensor_from_centre[2], self._com_from_centre[2]
        t_c = -t_s
        t_c[0] += a_s * f_s[1] - a_c * inertial_tool[1]
        t_c[1] += -a_s * f_s[0] + a_c * inertial_tool[0]
        out = np.empty(6)
        out[:3] = rot @ f_c
        out[3:] = rot @ t_c
        return out
