"""The ``Simulator``: demos and stiffness-schedule rollouts on one embodiment, reusing its MuJoCo model.

What lives here (shared by both embodiments): demo recording, the attractor (``dcm.control``), stiffness
limits and low-pass filtering, command latency, F/T bias/noise/low-pass from the ``DomainSpec``,
divergence detection and the objectives ``L_task`` [N] and ``L_comp`` [kN/m].

Timing: step ``k`` applies command ``k`` for one control period (several physics substeps) and records the
state at its end; a demo of ``duration_s`` has ``H = duration_s * control_hz`` steps.

Determinism: sensor noise and bias and the bowl's placement and friction (``DomainSpec.bowl_offset_std_m``,
``bowl_shift_xy_std_m``, ``bowl_tilt_std_deg``, ``bowl_friction_std``, ``ft_bias_std``) are drawn from a
generator seeded by the simulator seed and a hash of the inputs (the demo's spec and the stiffness schedule),
so the same inputs give identical arrays, whatever ran before; another simulator seed gives another draw. The
hash leaves out the simulated demo arrays: their last bits differ between CPUs, and the draws must not.
"""

from __future__ import annotations

import importlib
import json
import math
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from threadpoolctl import threadpool_limits

from dcm.control import (
    StiffnessLimits,
    StiffnessSchedule,
    attractor_from_demo,
    compliance_loss,
    damping_from_stiffness,
    damping_mass,
    filter_in_frame,
    task_loss,
)
from dcm.control.schedule import axis_mass
from dcm.sim.demos import Demo, DemoSpec
from dcm.sim.domain import DomainSpec
from dcm.sim.embodiment import PHYSICS_DT_S, Embodiment
from dcm.sim.geometry import BowlSpec
from dcm.sim.scene import BOWL_GEOM

EMBODIMENTS: dict[str, str] = {
    "tool": "dcm.sim.tool:ToolEmbodiment",
    "panda": "dcm.sim.panda:PandaEmbodiment",
}
_BAD_STATE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_CONTACTFULL,
    mujoco.mjtWarning.mjWARN_CNSTRFULL,
)


class SimulatorError(ValueError):
    """Bad input to the simulator (unknown embodiment, wrong shapes, NaN commands)."""


def embodiment_class(name: str) -> type:
    """Import an embodiment lazily, so a missing robosuite only breaks ``"panda"``."""
    if name not in EMBODIMENTS:
        raise SimulatorError(f"unknown embodiment {name!r}; known: {sorted(EMBODIMENTS)}")
    module_name, cls_name = EMBODIMENTS[name].split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise SimulatorError(
            f"embodiment {name!r} is unavailable: importing {module_name} failed ({err}); "
            "use embodiment='tool' or install the missing dependency"
        ) from err
    return getattr(module, cls_name)


@dataclass
class Trial:
    """One rollout of a stiffness schedule on a demo (all arrays (H, ...), bowl frame).

    ``force_obs`` is the contact wrench as observed (domain sensing applied), ``force_sensor`` the wrist
    F/T reading in the sensor frame. A diverged trial has ``failed=True``, a reason, ``L_task = inf`` and
    its arrays hold the last valid values from the failure step on (never NaN).
    """

    x_attr: np.ndarray
    stiffness: np.ndarray  # commanded schedule (H, 6)
    x_obs: np.ndarray
    v_obs: np.ndarray
    force_obs: np.ndarray
    force_sensor: np.ndarray
    contact: np.ndarray  # (H,) bool
    L_task: float
    L_comp: float
    failed: bool = False
    failure_reason: str = ""
    stiffness_applied: np.ndarray | None = None  # after low-pass filtering, what the controller used
    stiffness_axes: np.ndarray | None = None  # (H, 3, 3) the commanded schedule's frame (None: bowl axes)
    stiffness_applied_axes: np.ndarray | None = None  # (H, 3, 3) the applied stiffness' eigenvectors (None: bowl)
    failed_step: int = -1
    bowl_offset_m: float = 0.0  # how far the bowl stood above where the demo had it (domain.bowl_offset_std_m)
    bowl_friction_factor: float = 1.0  # the bowl's friction in this rollout ÷ the nominal (domain.bowl_friction_std)
    bowl_shift_xy_m: tuple[float, float] = (0.0, 0.0)  # the bowl's horizontal re-placement (domain.bowl_shift_xy_std_m)
    bowl_tilt_deg: tuple[float, float] = (0.0, 0.0)  # its tilt about bowl x, y (domain.bowl_tilt_std_deg)
    ft_bias_draw: tuple[float, ...] = (0.0,) * 6  # this rollout's sensor bias beyond ft_bias (domain.ft_bias_std)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


@dataclass
class _Execution:
    x_obs: np.ndarray
    v_obs: np.ndarray
    force_obs: np.ndarray
    force_sensor: np.ndarray
    contact: np.ndarray
    failed: bool = False
    reason: str = ""
    failed_step: int = -1


@dataclass
class DivergenceBounds:
    """Limits past which a trial counts as diverged."""

    max_force_N: float = 300.0  # contact force norm, far above what a stable wiping contact reaches
    max_above_surface_m: float = 0.15  # the tool flew off
    max_below_surface_m: float = 0.04  # the tool tunnelled into the bowl


@dataclass(frozen=True)
class BowlPlacement:
    """Where one rollout finds the bowl relative to where the demo had it, and its friction.

    ``offset_m`` raises it, ``shift_xy_m`` moves it horizontally, ``tilt_deg`` rotates it about the bowl frame's
    x then y axis through its lowest point; ``friction_factor`` scales its sliding friction."""

    offset_m: float = 0.0
    friction_factor: float = 1.0
    shift_xy_m: tuple[float, float] = (0.0, 0.0)
    tilt_deg: tuple[float, float] = (0.0, 0.0)

    @property
    def is_nominal(self) -> bool:
        return (not self.offset_m and self.friction_factor == 1.0 and not any(self.shift_xy_m)
                and not any(self.tilt_deg))


@contextmanager
def _bowl_replaced(emb: Embodiment, placement: BowlPlacement) -> Iterator[None]:
    """Move the bowl geom by ``placement`` and scale its sliding friction for one rollout. Poses and
    divergence checks stay in the nominal bowl frame, as the controller believes it to be; the bowl's contact
    priority makes its friction the contact's."""
    if placement.is_nominal:
        yield
        return
    model = emb.model
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, BOWL_GEOM)
    nominal_pos, nominal_quat = model.geom_pos[geom].copy(), model.geom_quat[geom].copy()
    sameframe = int(model.geom_sameframe[geom])
    nominal_friction = float(model.geom_friction[geom, 0])
    model.geom_sameframe[geom] = 0  # a geom compiled at its body's frame ignores geom_pos otherwise
    model.geom_pos[geom] = nominal_pos + np.array([*placement.shift_xy_m, placement.offset_m])
    if any(placement.tilt_deg):
        quat_x, quat_y, tilt = np.zeros(4), np.zeros(4), np.zeros(4)
        mujoco.mju_axisAngle2Quat(quat_x, np.array([1.0, 0.0, 0.0]), math.radians(placement.tilt_deg[0]))
        mujoco.mju_axisAngle2Quat(quat_y, np.array([0.0, 1.0, 0.0]), math.radians(placement.tilt_deg[1]))
        mujoco.mju_mulQuat(tilt, quat_y, quat_x)
        mujoco.mju_mulQuat(model.geom_quat[geom], tilt, nominal_quat)
    model.geom_friction[geom, 0] = nominal_friction * placement.friction_factor
    try:
        yield
    finally:
        model.geom_pos[geom] = nominal_pos
        model.geom_quat[geom] = nominal_quat
        model.geom_sameframe[geom] = sameframe
        model.geom_friction[geom, 0] = nominal_friction


class Simulator:
    """Records demos and rolls out stiffness schedules on one embodiment.

    Embodiments are built once per bowl and reused for every rollout (``reset`` between them). ``bowl``
    is the default; a demo naming another bowl gets (and caches) its own model.

    The controller is consistent: the attractor is computed from the stiffness the controller applies
    (after the low-pass filter) and from the same damping, so a stiffness change moves gains and attractor
    together and leaves the contact force where the demo had it. ``damping="critical"`` (default) damps
    critically for the embodiment's apparent Cartesian mass; ``"unit"`` is the paper's ``D = 2 sqrt(K)``.
    """

    def __init__(
        self,
        embodiment: str = "panda",
        bowl: BowlSpec | None = None,
        domain: DomainSpec | None = None,
        control_hz: float = 20.0,
        seed: int = 0,
        stiffness_tau_s: float = 0.2,
        limits: StiffnessLimits | None = None,
        bounds: DivergenceBounds | None = None,
        physics_dt: float = PHYSICS_DT_S,
        damping: str = "critical",
    ) -> None:
        if not (1.0 <= control_hz <= 500.0):
            raise SimulatorError(f"control_hz = {control_hz} is outside [1, 500]")
        self.embodiment_name = embodiment
        self._cls = embodiment_class(embodiment)
        try:
            self.apparent_mass = np.asarray(getattr(self._cls, "apparent_mass", np.ones(6)), dtype=np.float64)
            self.damping_mass = damping_mass(damping, self.apparent_mass)
        except ValueError as err:
            raise SimulatorError(str(err)) from err
        self.damping = damping
        self.bowl = bowl or BowlSpec()
        self.domain = domain or DomainSpec()
        self.control_hz = float(control_hz)
        self.dt = 1.0 / self.control_hz
        self.physics_dt = physics_dt
        self.seed = int(seed)
        self.stiffness_tau_s = stiffness_tau_s
        self.limits = limits or StiffnessLimits()
        self.bounds = bounds or DivergenceBounds()
        self._embodiments: dict[str, Embodiment] = {}
        self.embodiment_for(self.bowl)

    # -- embodiments -----------------------------------------------------------------------------
    def embodiment_for(self, bowl: BowlSpec) -> Embodiment:
        """The (cached) embodiment whose model contains ``bowl``."""
        key = json.dumps(bowl.to_dict(), sort_keys=True)
        if key not in self._embodiments:
            self._embodiments[key] = self._cls(bowl, self.domain, control_dt=self.dt, physics_dt=self.physics_dt)
        return self._embodiments[key]

    @property
    def embodiment(self) -> Embodiment:
        return self.embodiment_for(self.bowl)

    # -- public API ------------------------------------------------------------------------------
    def record_demo(self, spec: DemoSpec) -> Demo:
        """Execute ``spec`` with the demonstration controller and record (x_demo, force_demo).

        With ``spec.lead`` the demonstrator's attractor runs ahead of the path by ``K⁻¹(D ẋ + m ẍ)``, with
        the controller's damping and the embodiment's apparent mass ``m``, so the tool follows the path
        instead of trailing it (on a fast path a trailing tool lags by centimetres and skims off the bowl wall).
        Rollouts keep the paper's attractor, whose inertia term this embodiment does not know
        (``attractor_inertia_kg``).
        """
        attractor = spec.attractor_path(self.control_hz)
        stiffness = np.tile(np.r_[spec.stiffness_Npm, 20.0, 20.0, 20.0], (len(attractor), 1))
        if spec.lead:
            attractor = attractor_from_demo(attractor, np.zeros_like(attractor), stiffness, self.dt,
                                            inertia=self.apparent_mass, mass=self.damping_mass)
        start = spec.start_pose(self.control_hz)
        emb = self.embodiment_for(spec.bowl)
        rng = self._rng("demo", spec.to_json())
        # The demonstration's sensor had a bias of its own (the demo bowl stands where the demo says it does).
        run = self._execute(emb, spec.bowl, start, attractor, stiffness, rng, self._bias_draw(rng))
        if run.failed:
            raise SimulatorError(f"recording demo {spec.name or spec.family!r} diverged: {run.reason}")
        return Demo(spec=spec, dt=self.dt, x_demo=run.x_obs, force_demo=run.force_obs, start_pose=start,
                    contact=run.contact)

    def rollout(self, demo: Demo, stiffness: np.ndarray | StiffnessSchedule, repeat: int = 0,
                common_draws: bool = False) -> Trial:
        """Run the impedance controller with schedule ``stiffness`` on the attractor of ``demo``: a
        :class:`~dcm.control.StiffnessSchedule`, or its diagonal (H, 6) in bowl axes (the world frame).

        A rollout's random draws (sensor noise, per-rollout bowl spread) are seeded by the simulator's seed and
        its inputs, so the same schedule gives the same trial; ``repeat`` > 0 draws another, independent one
        (the same physics with other noise), as re-running a schedule on a real robot would. With
        ``common_draws`` the draws leave the schedule out of their key: every schedule's ``repeat``-th rollout of a
        demo meets the same bowl placement, friction and sensor draws (common random numbers), so an oracle that
        compares schedules over a few rollouts compares them on the same disturbances.

        Raises ``StiffnessOutOfRange`` for values outside ``self.limits`` and ``SimulatorError`` for
        mismatched shapes or non-finite demo data; divergence gives a failed ``Trial`` instead.
        """
        axes = stiffness.axes if isinstance(stiffness, StiffnessSchedule) else None
        stiffness = np.asarray(stiffness.diagonal if isinstance(stiffness, StiffnessSchedule) else stiffness,
                               dtype=np.float64)
        x_demo = np.asarray(demo.x_demo, dtype=np.float64)
        force_demo = np.asarray(demo.force_demo, dtype=np.float64)
        horizon = x_demo.shape[0]
        if stiffness.shape != (horizon, 6) or force_demo.shape != (horizon, 6) or x_demo.shape != (horizon, 6):
            raise SimulatorError(
                f"rollout needs x_demo, force_demo and stiffness of shape (H, 6) with the same H; got "
                f"{x_demo.shape}, {force_demo.shape}, {stiffness.shape}"
            )
        for name, arr in (("x_demo", x_demo), ("force_demo", force_demo)):
            if not np.all(np.isfinite(arr)):
                t, c = np.argwhere(~np.isfinite(arr))[0]
                raise SimulatorError(f"demo {name}[t={t}, channel {c}] = {arr[t, c]} is not finite")
        if abs(demo.dt - self.dt) > 1e-9:
            raise SimulatorError(f"demo dt = {demo.dt} s does not match the simulator's control dt = {self.dt} s")
        self.limits.check(stiffness, where="stiffness")
        applied, applied_axes = filter_in_frame(stiffness, axes, self.dt, tau_s=self.stiffness_tau_s)
        x_attr = self._attractor(demo, applied, applied_axes)
        start = demo.start_pose if demo.start_pose is not None else demo.spec.start_pose(self.control_hz)
        emb = self.embodiment_for(demo.spec.bowl)
        # Keyed on what the caller chose (the demo's spec, the schedule), not on simulated floats: those differ in
        # their last bits between CPUs, and any hash of them would give every rollout another draw there.
        key = b"common" if common_draws else stiffness.tobytes() + (b"" if axes is None else b"surface")
        rng = self._rng("rollout", demo.spec.to_json(), key, *([repeat] if repeat else []))
        placement = self._bowl_draw(rng)
        bias = self._bias_draw(rng)
        with _bowl_replaced(emb, placement):
            run = self._execute(emb, demo.spec.bowl, np.asarray(start, float), x_attr, applied, rng, bias,
                                applied_axes)
        if run.failed:
            l_task = float("inf")
        else:
            l_task = float(task_loss(run.force_obs, force_demo))
        return Trial(
            x_attr=x_attr,
            stiffness=stiffness,
            x_obs=run.x_obs,
            v_obs=run.v_obs,
            force_obs=run.force_obs,
            force_sensor=run.force_sensor,
            contact=run.contact,
            L_task=l_task,
            L_comp=float(compliance_loss(stiffness)),
            failed=run.failed,
            failure_reason=run.reason,
            stiffness_applied=applied,
            stiffness_axes=axes,
            stiffness_applied_axes=applied_axes,
            failed_step=run.failed_step,
            bowl_offset_m=placement.offset_m,
            bowl_friction_factor=placement.friction_factor,
            bowl_shift_xy_m=placement.shift_xy_m,
            bowl_tilt_deg=placement.tilt_deg,
            ft_bias_draw=tuple(float(v) for v in bias) if bias is not None else (0.0,) * 6,
        )

    def _bowl_draw(self, rng: np.random.Generator) -> BowlPlacement:
        """This rollout's bowl placement and friction factor. Each is drawn only when its spread is set, and the
        newer spreads after the older ones, so a domain without them draws what it drew before they existed."""
        domain = self.domain
        offset_std, friction_std = domain.bowl_offset_std_m, domain.bowl_friction_std
        offset = float(rng.normal(0.0, offset_std)) if offset_std else 0.0
        factor = float(np.exp(rng.normal(0.0, friction_std) - friction_std**2 / 2)) if friction_std else 1.0
        shift_std, tilt_std = domain.bowl_shift_xy_std_m, domain.bowl_tilt_std_deg
        shift = tuple(float(v) for v in rng.normal(0.0, shift_std, 2)) if shift_std else (0.0, 0.0)
        tilt = tuple(float(v) for v in rng.normal(0.0, tilt_std, 2)) if tilt_std else (0.0, 0.0)
        return BowlPlacement(offset, factor, shift, tilt)  # type: ignore[arg-type]

    def _bias_draw(self, rng: np.random.Generator) -> np.ndarray | None:
        """This rollout's sensor bias beyond ``ft_bias`` (drawn only when ``ft_bias_std`` is set)."""
        std = np.asarray(self.domain.ft_bias_std)
        return rng.standard_normal(6) * std if std.any() else None

    def attractor(self, demo: Demo, stiffness: np.ndarray, axes: np.ndarray | None = None) -> np.ndarray:
        """The attractor (H, 6) a rollout of the commanded ``stiffness`` (H, 6) uses: the paper's equation with
        the applied (filtered) K, the controller's damping and the embodiment's nominal Cartesian inertia.
        ``stiffness`` is the diagonal along the stiffness ``axes`` (H, 3, 3), or along bowl axes (None).
        Robot-free tuning calls this to build model inputs, for a batch of schedules (B, H, 6) at once."""
        stiffness = np.asarray(stiffness, dtype=np.float64)
        if axes is not None:
            axes = np.broadcast_to(axes, (*stiffness.shape[:-1], 3, 3))
        return self._attractor(demo, *filter_in_frame(stiffness, axes, self.dt, tau_s=self.stiffness_tau_s))

    def _attractor(self, demo: Demo, applied: np.ndarray, axes: np.ndarray | None = None) -> np.ndarray:
        inertia = float(getattr(self._cls, "attractor_inertia_kg", 0.0))
        return attractor_from_demo(
            np.asarray(demo.x_demo, dtype=np.float64),
            np.asarray(demo.force_demo, dtype=np.float64),
            np.asarray(applied, dtype=np.float64),
            self.dt,
            inertia=inertia,
            mass=axis_mass(self.damping_mass, axes),
            axes=axes,
        )

    def constant_stiffness(self, demo: Demo, translational_Npm: Any, rotational: float = 20.0) -> np.ndarray:
        """Convenience: a constant (H, 6) schedule for ``demo``."""
        k = np.r_[np.broadcast_to(np.asarray(translational_Npm, float), (3,)), [rotational] * 3]
        return np.tile(k, (demo.horizon, 1))

    # -- internals -------------------------------------------------------------------------------
    def _rng(self, *parts: Any) -> np.random.Generator:
        crc = 0
        for part in parts:
            crc = zlib.crc32(part if isinstance(part, bytes) else str(part).encode(), crc)
        return np.random.default_rng([self.seed, crc])

    # The controllers' small matrix products run on one BLAS thread: OpenBLAS otherwise splits them by the thread
    # count (OMP_NUM_THREADS), and a rollout's bytes would depend on the shell it ran in.
    @threadpool_limits.wrap(limits=1, user_api="blas")
    def _execute(
        self,
        emb: Embodiment,
        bowl: BowlSpec,
        start_pose: np.ndarray,
        attractor: np.ndarray,
        stiffness: np.ndarray,
        rng: np.random.Generator,
        bias: np.ndarray | None = None,
        axes: np.ndarray | None = None,
    ) -> _Execution:
        """Reset at ``start_pose`` and run the commands (``stiffness`` along ``axes`` (H, 3, 3), or bowl axes);
        applies latency and sensing; detects divergence."""
        horizon = len(attractor)
        if not np.all(np.isfinite(attractor)):
            t, c = np.argwhere(~np.isfinite(attractor))[0]
            raise SimulatorError(f"attractor[t={t}, channel {c}] is not finite")
        emb.reset(start_pose)
        x_obs = np.zeros((horizon, 6))
        v_obs = np.zeros((horizon, 6))
        f_contact = np.zeros((horizon, 6))
        f_sensor = np.zeros((horizon, 6))
        contact = np.zeros(horizon, dtype=bool)
        latency = int(self.domain.latency_steps)
        bounds = self.bounds
        # Live views of MuJoCo's warning counters (a bad state makes MuJoCo reset the data and count).
        warnings = [(emb.data.warning[w], mujoco.mjtWarning(w).name) for w in _BAD_STATE_WARNINGS]
        half_extent = bowl.half_extent_m
        failed, reason, failed_step = False, "", -1
        damping = damping_from_stiffness(stiffness, axis_mass(self.damping_mass, axes))
        for k in range(horizon):
            j = k - latency
            frame = None if axes is None else axes[max(j, 0)]
            if j >= 0:
                result = emb.step(attractor[j], stiffness[j], damping[j], frame)
            else:  # the first command has not arrived yet: keep holding the start pose
                result = emb.step(start_pose, stiffness[0], damping[0], frame)
            x_obs[k], v_obs[k] = result.pose, result.velocity
            f_contact[k], f_sensor[k] = result.force_contact, result.force_sensor
            contact[k] = result.in_contact
            reason = self._divergence(result, warnings, bowl, half_extent, bounds)
            if reason:
                failed, failed_step = True, k
                reason = f"step {k} (t = {k * self.dt:.2f} s): {reason}"
                last = max(k - 1, 0)
                for arr in (x_obs, v_obs, f_contact, f_sensor):
                    arr[k:] = arr[last] if k > 0 else 0.0
                    if not np.all(np.isfinite(arr)):
                        arr[~np.isfinite(arr)] = 0.0
                contact[k:] = False
                break
        force_obs = self.domain.sense(f_contact, self.dt, rng, bias)
        force_sensor = self.domain.sense(f_sensor, self.dt, rng, bias)
        return _Execution(x_obs, v_obs, force_obs, force_sensor, contact, failed, reason, failed_step)

    @staticmethod
    def _divergence(
        result: Any, warnings: list[tuple[Any, str]], bowl: BowlSpec, half_extent: tuple[float, float],
        bounds: DivergenceBounds,
    ) -> str:
        for stat, name in warnings:
            if stat.number > 0:
                return f"MuJoCo warning {name}"
        # One finite check over everything (a NaN/inf anywhere makes the sum non-finite).
        total = float(result.pose.sum() + result.velocity.sum() + result.force_contact.sum())
        if not math.isfinite(total):
            return "non-finite pose, velocity or force"
        fx, fy, fz = result.force_contact[:3]
        force = math.sqrt(fx * fx + fy * fy + fz * fz)
        if force > bounds.max_force_N:
            return f"contact force {force:.1f} N exceeds {bounds.max_force_N:g} N"
        x, y, z = result.pose[:3]
        hx, hy = half_extent
        if abs(x) > hx or abs(y) > hy:
            return f"tool at (x, y) = ({x:.3f}, {y:.3f}) m left the bowl's heightfield"
        gap = z - bowl.height_scalar(x, y)
        if gap > bounds.max_above_surface_m:
            return f"tool {gap:.3f} m above the surface (limit {bounds.max_above_surface_m:g} m)"
        if gap < -bounds.max_below_surface_m:
            return f"tool {-gap:.3f} m below the surface (limit {bounds.max_below_surface_m:g} m)"
        return ""

