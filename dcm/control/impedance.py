"""Cartesian impedance law pieces: damping, attractor, stiffness limits and filtering."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = ("x", "y", "z", "rx", "ry", "rz")


DAMPING_MODES = ("unit", "critical")


def damping_from_stiffness(stiffness: np.ndarray, mass: float | np.ndarray = 1.0) -> np.ndarray:
    """Critical damping ``D = 2 sqrt(m K)`` for a mass ``m`` per axis (elementwise on the diagonal).

    ``mass = 1`` is the paper's (and franka_ros') ``D = 2 sqrt(K)``, critical only for unit inertia; a Panda
    tip feels several kilograms, so that damping leaves the arm under-damped and it rings after every change.
    Passing the embodiment's apparent Cartesian mass makes the damping critical for the arm itself.
    """
    return 2.0 * np.sqrt(np.asarray(mass, dtype=np.float64) * np.asarray(stiffness, dtype=np.float64))


def damping_mass(mode: str, apparent_mass: np.ndarray) -> np.ndarray:
    """The per-axis mass ``damping_from_stiffness`` uses: 1 for ``"unit"``, the embodiment's for ``"critical"``."""
    if mode == "unit":
        return np.ones(6)
    if mode == "critical":
        return np.asarray(apparent_mass, dtype=np.float64)
    raise ValueError(f"damping = {mode!r}; expected one of {DAMPING_MODES}")


def attractor_from_demo(
    x_demo: np.ndarray,
    force_demo: np.ndarray,
    stiffness: np.ndarray,
    dt: float,
    inertia: float | np.ndarray = 0.0,
    mass: float | np.ndarray = 1.0,
    axes: np.ndarray | None = None,
) -> np.ndarray:
    """Attractor that makes the impedance law reproduce the demo: x + K^-1 (D xdot + Λ xddot - F).

    With the controller ``F_cmd = K (x_attr - x) - D xdot`` and the demo pose and force, this is the pose the
    spring must pull towards so that the commanded force balances the demonstrated contact force.
    ``stiffness`` must be what the controller applies (after filtering), and ``mass`` the damping's mass
    (``damping_from_stiffness``); otherwise the attractor jumps while the gains lag and every stiffness
    change produces a force spike. Velocities and accelerations come from central finite differences.
    ``stiffness`` may be a batch (B, H, 6) of schedules for the one demo: the demo's derivatives are then
    computed once, and each schedule's attractor is the one a call of its own returns.

    With stiffness ``axes`` (..., H, 3, 3) (:class:`dcm.control.StiffnessSchedule`), ``stiffness`` holds the
    diagonal along them and ``mass`` the damping's mass along them (:func:`dcm.control.schedule.axis_mass`):
    the translational K and D are then ``R diag Rᵀ`` and K^-1 is ``R diag(1/k) Rᵀ``.
    """
    x_demo = np.asarray(x_demo, dtype=np.float64)
    force_demo = np.asarray(force_demo, dtype=np.float64)
    stiffness = np.asarray(stiffness, dtype=np.float64)
    if (not (x_demo.shape == force_demo.shape == stiffness.shape[-2:]) or x_demo.ndim != 2 or x_demo.shape[1] != 6
            or stiffness.ndim not in (2, 3)):
        raise ValueError(
            f"attractor_from_demo needs x_demo and force_demo of shape (H, 6) and stiffness (H, 6) or (B, H, 6); "
            f"got {x_demo.shape}, {force_demo.shape}, {stiffness.shape}"
        )
    if np.any(stiffness <= 0):
        where = tuple(np.argwhere(stiffness <= 0)[0])
        raise StiffnessOutOfRange(f"stiffness must be positive; K[{where[-2]}, {AXES[where[-1]]}] = {stiffness[where]}")
    velocity = np.gradient(x_demo, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    damping = damping_from_stiffness(stiffness, mass)
    if axes is None:
        return x_demo + (damping * velocity + np.asarray(inertia) * acceleration - force_demo) / stiffness
    axes = np.asarray(axes, dtype=np.float64)
    inertial = np.broadcast_to(np.asarray(inertia, dtype=np.float64), (6,)) * acceleration - force_demo
    # In the frame's axes each direction is a diagonal law again: k u = d (Rᵀ xdot) + Rᵀ (Λ xddot - F).
    along = lambda v: np.einsum("...hji,...hj->...hi", axes, v)  # noqa: E731  Rᵀ v
    u = (damping[..., :3] * along(velocity[:, :3]) + along(inertial[:, :3])) / stiffness[..., :3]
    offset = np.concatenate([np.einsum("...hij,...hj->...hi", axes, u),
                             (damping[..., 3:] * velocity[:, 3:] + inertial[:, 3:]) / stiffness[..., 3:]], axis=-1)
    return x_demo + offset


class StiffnessOutOfRange(ValueError):
    """A stiffness value outside the controller's limits."""


@dataclass(frozen=True)
class StiffnessLimits:
    """Range a Franka-style controller accepts; beyond it the wrist torques saturate and the arm goes unstable."""

    trans_min_Npm: float = 10.0
    trans_max_Npm: float = 3000.0
    rot_min_Nmprad: float = 1.0
    rot_max_Nmprad: float = 300.0

    def check(self, stiffness: np.ndarray, where: str = "stiffness") -> None:
        """Raise ``StiffnessOutOfRange`` naming the first value (time index, axis) outside the limits."""
        stiffness = np.atleast_2d(np.asarray(stiffness, dtype=np.float64))
        if stiffness.shape[-1] != 6:
            raise ValueError(f"{where}: expected 6 stiffness channels, got shape {stiffness.shape}")
        low = np.array([self.trans_min_Npm] * 3 + [self.rot_min_Nmprad] * 3)
        high = np.array([self.trans_max_Npm] * 3 + [self.rot_max_Nmprad] * 3)
        bad = ~np.isfinite(stiffness) | (stiffness < low) | (stiffness > high)
        if bad.any():
            t, axis = np.argwhere(bad)[0]
            unit = "N/m" if axis < 3 else "N·m/rad"
            raise StiffnessOutOfRange(
                f"{where}[t={t}, {AXES[axis]}] = {stiffness[t, axis]:g} {unit} is outside "
                f"[{low[axis]:g}, {high[axis]:g}] {unit}"
            )


class StiffnessFilter:
    """First-order low-pass on stiffness changes, optionally rate limited, as franka_ros controllers do.

    Abrupt stiffness drops make a pressing tool lift off and bounce; filtering them with a time constant of a
    few control periods keeps the contact smooth.
    """

    def __init__(self, tau_s: float = 0.2, dt: float = 0.05, max_rate: float | None = None):
        if tau_s < 0 or dt <= 0:
            raise ValueError(f"StiffnessFilter needs tau_s >= 0 and dt > 0, got tau_s={tau_s}, dt={dt}")
        self.alpha = 1.0 if tau_s == 0 else 1.0 - float(np.exp(-dt / tau_s))
        self.max_step = None if max_rate is None else max_rate * dt
        self.state: np.ndarray | None = None

    def reset(self, stiffness: np.ndarray) -> None:
        self.state = np.array(stiffness, dtype=np.float64)

    def step(self, stiffness_cmd: np.ndarray) -> np.ndarray:
        """Advance one control period towards the commanded stiffness; returns the stiffness to apply."""
        if self.state is None:
            self.reset(stiffness_cmd)
            return self.state.copy()
        change = self.alpha * (np.asarray(stiffness_cmd, dtype=np.float64) - self.state)
        if self.max_step is not None:
            change = np.clip(change, -self.max_step, self.max_step)
        self.state = self.state + change
        return self.state.copy()


def filter_schedule(
    stiffness: np.ndarray, dt: float, tau_s: float = 0.2, max_rate: float | None = None
) -> np.ndarray:
    """The stiffness the controller actually applies at each step of a commanded schedule (H, 6), or of each
    schedule of a batch (B, H, 6) at once."""
    flt = StiffnessFilter(tau_s=tau_s, dt=dt, max_rate=max_rate)
    return np.stack([flt.step(k) for k in np.moveaxis(np.asarray(stiffness, dtype=np.float64), -2, 0)], axis=-2)
