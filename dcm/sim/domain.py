"""Physics and sensing domains: the nominal simulator and a shifted "realistic" stand-in.

The realistic domain is NOT real-robot data. It perturbs the same simulated task the way a physical setup
differs from its model (stickier/softer surface, joint friction and damping, a heavier tool than the
controller assumes, a biased, noisy and low-passed F/T sensor, a control latency) so that sim-to-real
transfer can be studied without a robot.

Who applies what: the embodiment applies the physical parts when it builds its MuJoCo model
(``friction_scale``, ``solref_timeconst_scale``, ``joint_frictionloss``, ``joint_damping``,
``tool_mass_scale``); the Panda applies ``joint_friction`` (the arm's identified joint friction) at every physics
step, and the tool embodiment, which has no arm joints, refuses it; the ``Simulator`` applies sensing
(``ft_bias``, ``ft_noise_std``, ``ft_lowpass_hz``) and ``latency_steps``, and draws each rollout's bowl
placement and friction (``bowl_offset_std_m``, ``bowl_shift_xy_std_m``, ``bowl_tilt_std_deg``,
``bowl_friction_std``: the bowl re-placed between trials, its surface changing) and the F/T sensor's bias of
that trial (``ft_bias_std``). All of these default to 0 (off); ``joint_friction`` to ``"none"``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from dcm.sim.spec_io import SpecIO

# Fields drawn anew for every rollout, so the same inputs give a distribution of forces.
PER_ROLLOUT_SPREADS = ("bowl_offset_std_m", "bowl_friction_std", "bowl_shift_xy_std_m", "bowl_tilt_std_deg",
                       "ft_bias_std")
# Models of the arm's own joint friction (``DomainSpec.joint_friction``); ``dcm.sim.panda`` implements them.
JOINT_FRICTION_MODELS = ("none", "gaz2019")
# Fields left out of ``to_dict`` while at these defaults, so that domains from before they existed keep their
# fingerprints.
_OPTIONAL_DEFAULTS = {"joint_friction": "none", "joint_friction_scale": 1.0}


class DomainSpecError(ValueError):
    """An invalid domain description (names the field and value)."""


def _vec6(value: Any, name: str) -> tuple[float, ...]:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (6,))
    if not np.all(np.isfinite(arr)):
        raise DomainSpecError(f"domain.{name} = {value!r} must be finite")
    return tuple(float(v) for v in arr)


@dataclass
class DomainSpec(SpecIO):
    """Perturbations relative to the nominal model.

    Units: ``joint_frictionloss`` in N (slide joints) or N·m (revolute joints); ``joint_damping`` in
    N·s/m or N·m·s/rad; ``ft_bias`` and ``ft_noise_std`` per wrench channel [N, N, N, N·m, N·m, N·m];
    ``ft_lowpass_hz`` is the cut-off of a first-order filter applied at the control rate (0 = off);
    ``latency_steps`` delays attractor and stiffness commands by whole control periods;
    ``bowl_offset_std_m`` [m] is the spread of the bowl's height from one rollout to the next (the bowl is
    re-placed between trials; the demo and the attractor know only where it stood when the demo was recorded).
    ``bowl_friction_std`` is the log-normal spread of the bowl's sliding friction from one rollout to the next
    (a surface wet in one trial and dusty in the next), mean-preserving: each rollout's friction is the
    nominal one times ``exp(s z - s^2 / 2)``. These two are the perturbations that differ between rollouts of
    the same inputs, so the force is a distribution given the model's conditions; the offset's spread grows
    with stiffness.
    ``bowl_shift_xy_std_m`` [m] spreads the re-placed bowl horizontally (x and y, independent normals) and
    ``bowl_tilt_std_deg`` [deg] tilts it about the bowl frame's x and y axes through its lowest point
    (independent normals): on a curved bowl the force either causes depends on where the path runs.
    ``ft_bias_std`` [N, N, N, N·m, N·m, N·m] is the spread of a sensor bias drawn once per rollout (an
    external-wrench estimate or a wrist sensor whose offset drifts between trials), on top of ``ft_bias``.
    ``joint_friction`` names a model of the arm's own joint friction, which the controller does not know:
    ``"none"`` (default) or ``"gaz2019"``, the sigmoid friction per joint that Gaz et al. (RA-L 2019) identified
    on a Panda, applied as a joint torque against the motion at every physics step (Panda only).
    ``joint_friction_scale`` (dimensionless, >= 0) multiplies that model's torque; 0 is the same as ``"none"``.
    Unlike ``joint_frictionloss`` (one Coulomb level for all joints, MuJoCo's constraint), it differs per joint
    and grows smoothly with the joint speed.
    """

    spec_kind: ClassVar[str] = "domain"
    spec_error: ClassVar[type[ValueError]] = DomainSpecError

    name: str = "nominal"
    friction_scale: float = 1.0
    solref_timeconst_scale: float = 1.0
    joint_frictionloss: float = 0.0
    joint_damping: float = 0.0
    tool_mass_scale: float = 1.0
    ft_bias: tuple[float, ...] = (0.0,) * 6
    ft_noise_std: tuple[float, ...] = (0.0,) * 6
    ft_lowpass_hz: float = 0.0
    latency_steps: int = 0
    bowl_offset_std_m: float = 0.0
    bowl_friction_std: float = 0.0
    bowl_shift_xy_std_m: float = 0.0
    bowl_tilt_std_deg: float = 0.0
    ft_bias_std: tuple[float, ...] | float = 0.0
    joint_friction: str = "none"
    joint_friction_scale: float = 1.0

    def __post_init__(self) -> None:
        self.ft_bias = _vec6(self.ft_bias, "ft_bias")
        self.ft_noise_std = _vec6(self.ft_noise_std, "ft_noise_std")
        self.ft_bias_std = _vec6(self.ft_bias_std, "ft_bias_std")
        self.validate()

    def validate(self) -> None:
        if not isinstance(self.joint_friction, str) or self.joint_friction not in JOINT_FRICTION_MODELS:
            raise DomainSpecError(f"domain.joint_friction = {self.joint_friction!r} is not a known model; "
                                  f"known: {list(JOINT_FRICTION_MODELS)}")
        try:
            self.joint_friction_scale = float(self.joint_friction_scale)
        except (TypeError, ValueError):
            raise DomainSpecError(f"domain.joint_friction_scale = {self.joint_friction_scale!r} must be a number "
                                  ">= 0") from None
        checks = {
            "friction_scale": (self.friction_scale, 0.0, 5.0),
            "solref_timeconst_scale": (self.solref_timeconst_scale, 0.2, 5.0),
            "joint_frictionloss": (self.joint_frictionloss, 0.0, 50.0),
            "joint_damping": (self.joint_damping, 0.0, 200.0),
            "tool_mass_scale": (self.tool_mass_scale, 0.1, 10.0),
            "ft_lowpass_hz": (self.ft_lowpass_hz, 0.0, 1e4),
            "latency_steps": (self.latency_steps, 0, 20),
            "bowl_offset_std_m": (self.bowl_offset_std_m, 0.0, 0.02),
            "bowl_friction_std": (self.bowl_friction_std, 0.0, 1.0),
            "bowl_shift_xy_std_m": (self.bowl_shift_xy_std_m, 0.0, 0.02),
            "bowl_tilt_std_deg": (self.bowl_tilt_std_deg, 0.0, 5.0),
            "joint_friction_scale": (self.joint_friction_scale, 0.0, 10.0),
        }
        for key, (value, low, high) in checks.items():
            if not np.isfinite(value) or not (low <= value <= high):
                raise DomainSpecError(f"domain.{key} = {value!r} is outside [{low}, {high}]")
        if int(self.latency_steps) != self.latency_steps:
            raise DomainSpecError(f"domain.latency_steps = {self.latency_steps!r} must be an integer")
        if min(self.ft_noise_std) < 0:
            raise DomainSpecError(f"domain.ft_noise_std = {self.ft_noise_std} must be >= 0")
        if min(self.ft_bias_std) < 0:
            raise DomainSpecError(f"domain.ft_bias_std = {self.ft_bias_std} must be >= 0")

    @property
    def has_joint_friction(self) -> bool:
        """Whether the arm meets a joint friction model (a zero scale is none: the default physics, untouched)."""
        return self.joint_friction != "none" and self.joint_friction_scale > 0

    @property
    def has_sensing_effects(self) -> bool:
        return any(self.ft_bias) or any(self.ft_noise_std) or self.ft_lowpass_hz > 0

    def sense(self, wrench: np.ndarray, dt: float, rng: np.random.Generator,
              bias_draw: np.ndarray | None = None) -> np.ndarray:
        """What the F/T sensor reads of a (H, 6) wrench sampled every ``dt`` [s]: bias (``ft_bias`` plus this
        rollout's ``bias_draw``) + white noise, then a first-order low-pass along the first axis. The wrench
        itself when the domain has no sensing effects."""
        extra = np.zeros(6) if bias_draw is None else np.asarray(bias_draw, dtype=np.float64)
        if not self.has_sensing_effects and not extra.any():
            return wrench
        out = wrench + np.asarray(self.ft_bias) + extra
        out = out + rng.standard_normal(wrench.shape) * np.asarray(self.ft_noise_std)
        if self.ft_lowpass_hz > 0:
            alpha = 1.0 - np.exp(-2.0 * np.pi * self.ft_lowpass_hz * dt)
            for k in range(1, len(out)):
                out[k] = out[k - 1] + alpha * (out[k] - out[k - 1])
        return out

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain values. The per-rollout spreads are left out while they are 0, and the joint friction
        fields while at their defaults, so a domain without them fingerprints as if they did not exist and the
        datasets and tuning logs of such domains stay valid."""
        out = asdict(self)
        for key in PER_ROLLOUT_SPREADS:
            if not np.any(out[key]):
                del out[key]
        for key, default in _OPTIONAL_DEFAULTS.items():
            if out[key] == default:
                del out[key]
        out["ft_bias"] = list(self.ft_bias)
        out["ft_noise_std"] = list(self.ft_noise_std)
        if "ft_bias_std" in out:
            out["ft_bias_std"] = list(self.ft_bias_std)
        return out

    @classmethod
    def preset(cls, name: str) -> DomainSpec:
        """``"nominal"``, ``"realistic"``, ``"replaced_bowl"`` (the benchmark task's) or ``"joint_friction"``."""
        if name not in PRESETS:
            raise DomainSpecError(f"unknown domain preset {name!r}; known: {sorted(PRESETS)}")
        return cls.from_dict(PRESETS[name])

    @classmethod
    def resolve(cls, domain: Any) -> DomainSpec:
        """A domain as configs give it: a preset name, a mapping of fields, or a ``DomainSpec``."""
        if isinstance(domain, cls):
            return domain
        if isinstance(domain, str):
            return cls.preset(domain)
        if isinstance(domain, dict):
            return cls.from_dict(domain)
        raise DomainSpecError(f"domain = {domain!r}: expected a preset name or a mapping of DomainSpec fields")


PRESETS: dict[str, dict[str, Any]] = {
    "nominal": {"name": "nominal"},
    # A stand-in for a physical setup (not real data), plausible for a Franka with a wiping sponge: more
    # friction, a softer surface, joint friction, a tool heavier than the controller's model, a biased, noisy
    # and low-passed F/T sensor, and one control period of command latency.
    "realistic": {
        "name": "realistic",
        "friction_scale": 1.3,
        "solref_timeconst_scale": 1.5,
        "joint_frictionloss": 0.5,
        "joint_damping": 2.0,
        "tool_mass_scale": 1.2,
        "ft_bias": [0.8, -0.5, 1.5, 0.02, -0.01, 0.0],
        "ft_noise_std": [0.3, 0.3, 0.4, 0.005, 0.005, 0.003],
        "ft_lowpass_hz": 5.0,
        "latency_steps": 1,
    },
    # The benchmark's task (docs/benchmark_task.md gives each size and its source): the bowl set down again
    # against a registration between trials (a millimetre or two in 3-D, half a degree of tilt), a wiping surface
    # whose friction changes, and a re-biased F/T sensor's noise and residual per-trial bias. The demo and the
    # attractor keep the nominal bowl.
    "replaced_bowl": {
        "name": "replaced_bowl",
        "bowl_offset_std_m": 0.001,
        "bowl_shift_xy_std_m": 0.002,
        "bowl_tilt_std_deg": 0.5,
        "bowl_friction_std": 0.2,
        "ft_noise_std": [0.2, 0.2, 0.2, 0.0, 0.0, 0.0],
        "ft_bias_std": [0.1, 0.1, 0.1, 0.0, 0.0, 0.0],
    },
    # The nominal simulator with the arm's own joint friction as Gaz et al. (RA-L 2019) identified it on a Panda
    # (docs/benchmark_task.md, "The arm's own friction"). Panda only: the tool embodiment has no arm joints.
    "joint_friction": {"name": "joint_friction", "joint_friction": "gaz2019"},
}


def nominal() -> DomainSpec:
    return DomainSpec.preset("nominal")


def realistic() -> DomainSpec:
    return DomainSpec.preset("realistic")
