"""Stiffness schedules: split a demo into phases, hold one stiffness per phase, and the frame it acts in.

:class:`StiffnessSchedule` is the one representation of a schedule the simulator, the attractor, the search,
the datasets and the schedule files share: a diagonal (H, 6) in the axes of a frame, ``world`` (the bowl's
axes, the paper's) or ``surface`` (normal and tangents along the demo).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def equal_time_phases(horizon: int, n_phases: int) -> np.ndarray:
    """Phase boundaries (n_phases + 1,) that cut ``horizon`` steps into equal-time phases."""
    if n_phases < 1 or horizon < n_phases:
        raise ValueError(f"cannot split a horizon of {horizon} steps into n_phases={n_phases} phases")
    return np.round(np.linspace(0, horizon, n_phases + 1)).astype(int)


def changepoint_phases(signal: np.ndarray, n_phases: int, min_size: int = 5) -> np.ndarray:
    """Data-driven phase boundaries: the ``n_phases - 1`` strongest change points of a demo signal.

    ``signal`` (H, C) is typically the demo force or path; each channel is standardised first so that
    newtons and metres weigh alike. Uses ruptures' exact dynamic-programming segmentation (L2 cost).
    """
    import ruptures

    signal = np.asarray(signal, dtype=np.float64)
    if signal.ndim == 1:
        signal = signal[:, None]
    horizon = signal.shape[0]
    if n_phases < 1 or horizon < n_phases * min_size:
        raise ValueError(
            f"cannot segment a signal of {horizon} steps into n_phases={n_phases} phases of >= {min_size} steps"
        )
    if n_phases == 1:
        return np.array([0, horizon])
    std = signal.std(axis=0)
    scaled = (signal - signal.mean(axis=0)) / np.where(std > 1e-12, std, 1.0)
    ends = ruptures.Dynp(model="l2", min_size=min_size, jump=1).fit(scaled).predict(n_bkps=n_phases - 1)
    return np.array([0, *ends], dtype=int)


def schedule_from_phases(
    phase_stiffness: np.ndarray, boundaries: np.ndarray, rot_stiffness: float = 20.0
) -> np.ndarray:
    """Expand per-phase stiffness (P, 3) or (P, 6) into a schedule K_{1:H} (H, 6) held constant per phase.

    With 3 columns the rotational stiffness is ``rot_stiffness`` N·m/rad on every axis.
    """
    phase_stiffness = np.atleast_2d(np.asarray(phase_stiffness, dtype=np.float64))
    boundaries = np.asarray(boundaries, dtype=int)
    n_phases = phase_stiffness.shape[0]
    if phase_stiffness.shape[1] not in (3, 6):
        raise ValueError(f"phase stiffness must have 3 or 6 columns, got shape {phase_stiffness.shape}")
    if boundaries.shape != (n_phases + 1,) or boundaries[0] != 0 or np.any(np.diff(boundaries) <= 0):
        raise ValueError(
            f"phase boundaries {boundaries.tolist()} must start at 0 and increase, one more than {n_phases} phases"
        )
    if phase_stiffness.shape[1] == 3:
        rot = np.full((n_phases, 3), float(rot_stiffness))
        phase_stiffness = np.concatenate([phase_stiffness, rot], axis=1)
    return np.repeat(phase_stiffness, np.diff(boundaries), axis=0)


def phase_boundaries(method: str, n_phases: int, force_demo: np.ndarray) -> np.ndarray:
    """Phase boundaries of a demo by ``method``: ``equal_time``, or ``changepoint`` of the demo force (H, >=3)."""
    force_demo = np.asarray(force_demo)
    if method == "equal_time":
        return equal_time_phases(force_demo.shape[0], n_phases)
    if method == "changepoint":
        return changepoint_phases(force_demo[:, :3], n_phases)
    raise ValueError(f"phase method {method!r} is unknown; expected 'equal_time' or 'changepoint'")


# -- the stiffness representation ---------------------------------------------------------------------------------

FRAMES = ("world", "surface")


class StiffnessFrameError(ValueError):
    """A stiffness frame that is unknown or cannot be built for a demo."""


def check_frame(frame: str, key: str = "stiffness.frame") -> str:
    if frame not in FRAMES:
        raise StiffnessFrameError(f"{key} = {frame!r} is unknown; expected one of {', '.join(FRAMES)}")
    return frame


def surface_axes(x_demo: np.ndarray, force_demo: np.ndarray, name: str = "the demo") -> np.ndarray:
    """Stiffness axes (H, 3, 3) that follow the surface along a demo: columns t1, t2, n in bowl-frame coordinates.

    The normal n is the one the wipe objective uses (:func:`dcm.control.objectives.surface_normals`): from the
    demo's own pose and contact force, which a user's robot logs, so no model of the surface is needed. t1 is
    bowl x projected into the tangent plane and t2 = n × t1; with one tangential stiffness their choice does not
    matter. A demo that never presses has no normal to follow: refused, naming ``name``.
    """
    from dcm.control.objectives import NORMAL_FROM_FORCE_MIN_N, surface_normals

    force = np.asarray(force_demo, dtype=np.float64)
    if np.linalg.norm(force[..., :3], axis=-1).max(initial=0.0) < NORMAL_FROM_FORCE_MIN_N:
        raise StiffnessFrameError(
            f"stiffness.frame = 'surface' follows the surface normal, but {name} never presses more than "
            f"{NORMAL_FROM_FORCE_MIN_N:g} N, so it has none; use stiffness.frame=world")
    return axes_from_normals(surface_normals(x_demo, force))


def frame_axes(frame: str, x_demo: np.ndarray, force_demo: np.ndarray, name: str = "the demo") -> np.ndarray | None:
    """The stiffness axes (H, 3, 3) of ``frame`` along a demo: None for the world frame (bowl axes), else
    :func:`surface_axes`."""
    return None if check_frame(frame) == "world" else surface_axes(x_demo, force_demo, name)


def axes_from_normals(normal: np.ndarray) -> np.ndarray:
    """Stiffness axes (..., H, 3, 3), columns t1, t2, n, of unit normals (..., H, 3): t1 is bowl x projected
    into the tangent plane, t2 = n × t1."""
    t1 = np.zeros_like(normal)
    t1[..., 0] = 1.0
    t1 = t1 - normal[..., :1] * normal
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return np.stack([t1, np.cross(normal, t1), normal], axis=-1)


def frame_diagonal(phase_values: np.ndarray, frame: str) -> np.ndarray:
    """The per-phase diagonal (..., P, 3) in the frame's axes of a search's per-phase values: world (Kx, Ky, Kz)
    as they are, surface (K_tangent, K_normal) as (K_t, K_t, K_n)."""
    values = np.asarray(phase_values, dtype=np.float64)
    if check_frame(frame) == "world":
        return values
    return values[..., [0, 0, 1]]


def frame_values(diagonal: np.ndarray, frame: str) -> np.ndarray:
    """The inverse of :func:`frame_diagonal`: (..., P, 3) -> the search's values. A surface diagonal whose two
    tangents differ is none of that frame's schedules: ValueError."""
    diagonal = np.asarray(diagonal, dtype=np.float64)
    if check_frame(frame) == "world":
        return diagonal
    if not np.allclose(diagonal[..., 0], diagonal[..., 1], rtol=1e-6):
        raise ValueError("its two tangential stiffnesses differ, and the surface frame has one")
    return diagonal[..., [0, 2]]


def in_axes(axes: np.ndarray, diagonal: np.ndarray) -> np.ndarray:
    """``R diag(k) Rᵀ`` (..., 3, 3) of axes R (..., 3, 3) (columns) and translational diagonals k (..., 3)."""
    return np.einsum("...ij,...j,...kj->...ik", axes, diagonal, axes)


def eigen_axes(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(eigenvalues (..., 3), axes (..., 3, 3)) of symmetric matrices, the axes a rotation (det +1)."""
    values, vectors = np.linalg.eigh(matrix)
    vectors[..., 2] *= np.sign(np.linalg.det(vectors))[..., None]
    return values, vectors


@dataclass(frozen=True)
class StiffnessSchedule:
    """A stiffness schedule: its diagonal (H, 6) in the axes of its frame, and those axes.

    ``diagonal`` holds the translational stiffness along the frame's three axes [N/m] and the rotational
    stiffness about bowl axes [N·m/rad]. ``axes`` (H, 3, 3) holds the frame's axes as columns in bowl-frame
    coordinates; ``None`` is the world frame (the bowl's axes, the paper's convention), whose every path stays
    the diagonal arithmetic it always was. The translational stiffness the controller applies is
    ``R diag(k) Rᵀ`` (:meth:`translational_matrix`), which a franka_ros controller stores as it is and
    libfranka takes as a stiffness frame R with the diagonal k.
    """

    diagonal: np.ndarray
    axes: np.ndarray | None = None

    def __post_init__(self) -> None:
        diagonal = np.asarray(self.diagonal, dtype=np.float64)
        if diagonal.ndim != 2 or diagonal.shape[1] != 6:
            raise ValueError(f"a stiffness schedule's diagonal must have shape (H, 6), got {diagonal.shape}")
        object.__setattr__(self, "diagonal", diagonal)
        if self.axes is not None:
            axes = np.asarray(self.axes, dtype=np.float64)
            if axes.shape != (diagonal.shape[0], 3, 3):
                raise ValueError(f"stiffness axes must have shape ({diagonal.shape[0]}, 3, 3), got {axes.shape}")
            object.__setattr__(self, "axes", axes)

    @classmethod
    def for_demo(cls, diagonal: np.ndarray, frame: str, x_demo: np.ndarray, force_demo: np.ndarray,
                 name: str = "the demo") -> StiffnessSchedule:
        """The schedule of ``diagonal`` (H, 6) in ``frame`` along a demo (``world`` keeps no axes)."""
        return cls(diagonal, frame_axes(frame, x_demo, force_demo, name))

    @classmethod
    def from_matrix(cls, translational: np.ndarray, rotational: np.ndarray, limits: Any = None,
                    where: str = "stiffness") -> StiffnessSchedule:
        """The schedule of full translational matrices (H, 3, 3) [N/m] and rotational diagonals (H, 3), as a
        franka_ros controller's 6×6 stiffness holds them. Refuses, naming ``where`` and the step, a matrix that
        is not symmetric or whose eigenvalues leave ``limits`` (:class:`dcm.control.StiffnessLimits`)."""
        from dcm.control.impedance import StiffnessLimits, StiffnessOutOfRange

        matrix = np.asarray(translational, dtype=np.float64)
        rotational = np.asarray(rotational, dtype=np.float64)
        if matrix.ndim != 3 or matrix.shape[1:] != (3, 3) or rotational.shape != (matrix.shape[0], 3):
            raise ValueError(f"{where}: need translational (H, 3, 3) and rotational (H, 3), got {matrix.shape} "
                             f"and {rotational.shape}")
        transposed = np.swapaxes(matrix, -1, -2)
        asymmetric = ~np.isclose(matrix, transposed, rtol=1e-6, atol=1e-6).all(axis=(-1, -2))
        if asymmetric.any():
            raise StiffnessOutOfRange(f"{where}[t={int(np.argmax(asymmetric))}]: the translational stiffness matrix "
                                      "is not symmetric")
        values, axes = eigen_axes(0.5 * (matrix + transposed))
        schedule = cls(np.concatenate([values, rotational], axis=-1), axes)
        (limits or StiffnessLimits()).check(schedule.diagonal, where=f"{where} eigenvalues")
        return schedule

    def translational_matrix(self) -> np.ndarray:
        """(H, 3, 3) ``R diag(k) Rᵀ`` in bowl-frame coordinates [N/m]."""
        k = self.diagonal[:, :3]
        return k[:, :, None] * np.eye(3) if self.axes is None else in_axes(self.axes, k)


def axis_mass(mass: np.ndarray, axes: np.ndarray | None) -> np.ndarray:
    """The per-axis mass along stiffness ``axes`` (..., H, 3, 3) of a per-bowl-axis mass (6,): rᵢᵀ M rᵢ for the
    translational axes, so that critical damping ``2 sqrt(m k)`` stays critical along every axis of the frame
    (with an isotropic mass, as both embodiments have, D = 2 sqrt(m K) is the matrix square root exactly)."""
    mass = np.asarray(mass, dtype=np.float64)
    if axes is None:
        return mass
    translational = np.einsum("...ji,j->...i", axes ** 2, mass[:3])
    return np.concatenate([translational, np.broadcast_to(mass[3:], (*translational.shape[:-1], 3))], axis=-1)


def filter_in_frame(diagonal: np.ndarray, axes: np.ndarray | None, dt: float, tau_s: float = 0.2,
                    max_rate: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The applied (diagonal, axes) of a commanded schedule (..., H, 6) in ``axes`` (H, 3, 3), or None (world).

    A real controller filters the stiffness it is sent, and for a frame that turns along the path that is the
    matrix ``R diag(k) Rᵀ``: it is low-pass filtered entry by entry (a mix of positive definite matrices stays
    one) and split back into eigenvalues and axes. The world frame filters its diagonal, as it always did.
    """
    from dcm.control.impedance import filter_schedule

    diagonal = np.asarray(diagonal, dtype=np.float64)
    if axes is None:
        return filter_schedule(diagonal, dt, tau_s=tau_s, max_rate=max_rate), None
    matrix = in_axes(axes, diagonal[..., :3])
    flat = np.concatenate([matrix.reshape(*matrix.shape[:-2], 9), diagonal[..., 3:]], axis=-1)
    applied = filter_schedule(flat, dt, tau_s=tau_s, max_rate=max_rate)
    values, applied_axes = eigen_axes(applied[..., :9].reshape(matrix.shape))
    return np.concatenate([values, applied[..., 9:]], axis=-1), applied_axes
