"""A round of proposed stiffness schedules as files a Cartesian impedance controller consumes.

    <run>/proposals/round_<r>/
        round.yaml      round, control_hz, demo (its spec), embodiment, frame: bowl, phase boundaries, the damping
                        rule, the stiffness filter, and per proposal its id, file, per-phase stiffness and the
                        tuner's predicted (L_task, L_comp)
        <id>.csv        one row per control step: t_s, the attractor pose (x_m ... rz_rad), the per-axis stiffness
                        (Kx_Npm ... Krz_Nmprad) and damping (Dx_Nspm ... Drz_Nmsprad), bowl frame
        <id>_base.csv   with a bowl_in_base pose: t_s, the attractor in the robot base frame as position and
                        quaternion (the PoseStamped of an equilibrium_pose topic), the stiffness and damping on the
                        base frame's axes
        demo.csv        the skill's demo (t, x_demo, F_demo; bowl frame), as the log importer reads it per episode

With ``stiffness.frame=surface`` each <id>.csv holds the stiffness two ways a Franka controller takes it: the
frame and its diagonal (libfranka's stiffness frame: the frame's orientation in the bowl frame as a quaternion
``Fqx..Fqw``, then ``Kt1_Npm, Kt2_Npm, Kn_Npm`` along its axes), and the full translational matrices
``R diag Rᵀ`` in bowl axes (``Kxx_Npm .. Kzz_Npm``, ``Dxx_Nspm .. Dzz_Nspm``, row-major: the translational block
of franka_ros' 6×6 ``cartesian_stiffness_``); <id>_base.csv then holds the matrices on the base frame's axes.

Frames and conventions are the dataset's (docs/conventions.md). The attractor is the one the simulator's
controller uses for that schedule: the paper's equation with the low-pass filtered stiffness a Franka
controller applies, so a controller that filters its stiffness the same way (franka_ros: about 0.2 s at the
default filter) reproduces the demo's force where the schedule holds. Damping follows the run's rule
``D = 2 sqrt(m K)`` per axis (``stiffness.damping``: unit mass, franka_ros' rule, or the arm's apparent mass).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dcm.control import StiffnessSchedule, damping_from_stiffness
from dcm.control.schedule import axis_mass
from dcm.data.schema import POSE_CHANNELS, STIFFNESS_CHANNELS

DAMPING_CHANNELS = ["Dx_Nspm", "Dy_Nspm", "Dz_Nspm", "Drx_Nmsprad", "Dry_Nmsprad", "Drz_Nmsprad"]
SCHEDULE_COLUMNS = ["t_s", *POSE_CHANNELS, *STIFFNESS_CHANNELS, *DAMPING_CHANNELS]
BASE_COLUMNS = ["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw", *STIFFNESS_CHANNELS, *DAMPING_CHANNELS]
DEMO_COLUMNS = ["t", "x", "y", "z", "rx", "ry", "rz", "Fx", "Fy", "Fz", "Tx", "Ty", "Tz"]
NOMINAL_DOWN = np.diag([1.0, -1.0, -1.0])  # the "tool pointing down" flange in a Franka base frame (the importer's)
# The surface frame's columns: along its axes, the frame itself, and the matrices R diag Rᵀ in bowl axes.
FRAME_STIFFNESS = ["Kt1_Npm", "Kt2_Npm", "Kn_Npm", "Krx_Nmprad", "Kry_Nmprad", "Krz_Nmprad"]
FRAME_DAMPING = ["Dt1_Nspm", "Dt2_Nspm", "Dn_Nspm", "Drx_Nmsprad", "Dry_Nmsprad", "Drz_Nmsprad"]
FRAME_QUATERNION = ["Fqx", "Fqy", "Fqz", "Fqw"]
MATRIX_STIFFNESS = [f"K{a}{b}_Npm" for a in "xyz" for b in "xyz"]
MATRIX_DAMPING = [f"D{a}{b}_Nspm" for a in "xyz" for b in "xyz"]
SURFACE_COLUMNS = ["t_s", *POSE_CHANNELS, *FRAME_STIFFNESS, *FRAME_DAMPING, *FRAME_QUATERNION, *MATRIX_STIFFNESS,
                   *MATRIX_DAMPING]
SURFACE_BASE_COLUMNS = ["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw", *MATRIX_STIFFNESS, *STIFFNESS_CHANNELS[3:],
                        *MATRIX_DAMPING, *DAMPING_CHANNELS[3:]]


def round_dir(run_dir: Path, round_index: int) -> Path:
    return Path(run_dir) / "proposals" / f"round_{round_index}"


def proposal_id(index: int) -> str:
    return f"p{index + 1:02d}"


def check_bowl_in_base(value: Any, key: str = "loop.bowl_in_base") -> np.ndarray | None:
    """A 4x4 row-major pose of the bowl frame in the base frame, or None; raises ValueError naming ``key``.

    Its rotation must permute axes (with signs): a diagonal stiffness stays diagonal only then, as the log
    importer requires of the same pose (the surface frame's matrices would take any rotation; one rule keeps
    the importer and both frames alike)."""
    if value is None:
        return None
    try:
        pose = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise ValueError(f"{key} = {value!r} must be null or a 4x4 row-major pose (16 numbers)") from None
    rotation = pose[:3, :3]
    if (not np.all(np.isfinite(pose)) or not np.allclose(pose[3], [0, 0, 0, 1])
            or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0):
        raise ValueError(f"{key}: not a rigid pose (rotation orthonormal with det +1, last row [0, 0, 0, 1])")
    if not np.allclose(np.abs(rotation), np.abs(rotation).round(), atol=1e-6):
        raise ValueError(f"{key}: its rotation is not an axis permutation, so a diagonal stiffness has no diagonal "
                         "base-frame equivalent")
    return pose


def base_frame_rows(attractor: np.ndarray, stiffness: np.ndarray, damping: np.ndarray,
                    bowl_in_base: np.ndarray) -> np.ndarray:
    """(H, 19) attractor position and quaternion (x, y, z, w) in the base frame, stiffness and damping on its axes:
    the inverse of the log importer's base-to-bowl conversion (the attractor is the tool tip)."""
    permutation = np.abs(bowl_in_base[:3, :3])
    on_base = lambda v: np.column_stack([v[:, :3] @ permutation.T, v[:, 3:] @ permutation.T])  # noqa: E731
    return np.column_stack([_base_pose(attractor, bowl_in_base), on_base(stiffness), on_base(damping)])


def surface_base_rows(attractor: np.ndarray, schedule: StiffnessSchedule, damping: np.ndarray,
                      bowl_in_base: np.ndarray) -> np.ndarray:
    """(H, 31) rows of :data:`SURFACE_BASE_COLUMNS` after ``t_s``: the attractor in the base frame, and the
    translational stiffness and damping matrices on the base frame's axes (rotational diagonals permuted)."""
    rotation = bowl_in_base[:3, :3]
    permutation = np.abs(rotation)
    on_base = lambda d: np.einsum("ij,hjk,lk->hil", rotation,  # noqa: E731
                                  StiffnessSchedule(d, schedule.axes).translational_matrix(), rotation).reshape(-1, 9)
    return np.column_stack([_base_pose(attractor, bowl_in_base), on_base(schedule.diagonal),
                            schedule.diagonal[:, 3:] @ permutation.T, on_base(damping), damping[:, 3:] @ permutation.T])


def _base_pose(attractor: np.ndarray, bowl_in_base: np.ndarray) -> np.ndarray:
    """(H, 7) the attractor's position and quaternion (x, y, z, w) in the base frame."""
    from scipy.spatial.transform import Rotation

    rotation, origin = bowl_in_base[:3, :3], bowl_in_base[:3, 3]
    position = attractor[:, :3] @ rotation.T + origin
    relative = Rotation.from_rotvec(attractor[:, 3:]).as_matrix()  # from "pointing down", bowl-frame axes
    orientation = rotation @ relative @ rotation.T @ NOMINAL_DOWN
    return np.column_stack([position, Rotation.from_matrix(orientation).as_quat()])


def surface_rows(attractor: np.ndarray, schedule: StiffnessSchedule, damping: np.ndarray) -> np.ndarray:
    """(H, 43) rows of :data:`SURFACE_COLUMNS` after ``t_s``: the attractor, the diagonal and damping along the
    frame, the frame's quaternion (x, y, z, w) in the bowl frame, and the translational matrices in bowl axes."""
    from scipy.spatial.transform import Rotation

    damping_matrix = StiffnessSchedule(damping, schedule.axes).translational_matrix()
    return np.column_stack([attractor, schedule.diagonal, damping, Rotation.from_matrix(schedule.axes).as_quat(),
                            schedule.translational_matrix().reshape(-1, 9), damping_matrix.reshape(-1, 9)])


def read_surface_schedule(path: Path) -> StiffnessSchedule:
    """The schedule a surface-frame <id>.csv commands, read from its full matrices as franka_ros takes them
    (refused, naming the file and step, where a matrix is not symmetric positive definite within the limits)."""
    path = Path(path)
    columns = path.read_text().split("\n", 1)[0].strip().split(",")
    missing = [c for c in (*MATRIX_STIFFNESS, *STIFFNESS_CHANNELS[3:]) if c not in columns]
    if missing:
        raise ValueError(f"{path}: no column {missing[0]}; a surface-frame schedule file has {', '.join(MATRIX_STIFFNESS)}")
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    pick = lambda names: table[:, [columns.index(c) for c in names]]  # noqa: E731
    return StiffnessSchedule.from_matrix(pick(MATRIX_STIFFNESS).reshape(-1, 3, 3), pick(STIFFNESS_CHANNELS[3:]),
                                         where=str(path))


def _write_csv(path: Path, columns: Sequence[str], rows: np.ndarray) -> None:
    np.savetxt(path, rows, delimiter=",", header=",".join(columns), comments="", fmt="%.9g")


def write_round(folder: Path, round_index: int, proposals: np.ndarray, schedules: np.ndarray,
                attractors: np.ndarray, damping_mass: np.ndarray, demo: Any, info: dict[str, Any],
                predicted: np.ndarray, bowl_in_base: np.ndarray | None = None,
                axes: np.ndarray | None = None) -> dict[str, Any]:
    """Write the round folder (see the module doc) into ``folder`` (created; the caller makes it atomic).

    ``proposals`` (B, P, axes) N/m, ``schedules`` and ``attractors`` (B, H, 6), ``predicted`` (B, 2) the tuner's
    (L_task, L_comp); ``info``: run-level keys of round.yaml (control_hz, demo, embodiment, phase boundaries,
    damping, next command ...); ``axes`` (H, 3, 3) the surface frame's axes (None: the world frame). Returns
    round.yaml's content."""
    folder.mkdir(parents=True, exist_ok=True)
    horizon = schedules.shape[1]
    t_s = np.arange(horizon) / float(info["control_hz"])
    entries = []
    for index, (phases, stiffness, attractor, pred) in enumerate(zip(proposals, schedules, attractors, predicted)):
        name = proposal_id(index)
        damping = damping_from_stiffness(stiffness, axis_mass(damping_mass, axes))
        if axes is None:
            _write_csv(folder / f"{name}.csv", SCHEDULE_COLUMNS, np.column_stack([t_s, attractor, stiffness, damping]))
        else:
            rows = surface_rows(attractor, StiffnessSchedule(stiffness, axes), damping)
            _write_csv(folder / f"{name}.csv", SURFACE_COLUMNS, np.column_stack([t_s, rows]))
        entry = {"id": name, "file": f"{name}.csv", "phase_stiffness_Npm": np.asarray(phases).tolist(),
                 "predicted": {"L_task_N": float(pred[0]), "L_comp_kNpm": float(pred[1])}}
        if bowl_in_base is not None:
            if axes is None:
                rows = base_frame_rows(attractor, stiffness, damping, bowl_in_base)
                _write_csv(folder / f"{name}_base.csv", BASE_COLUMNS, np.column_stack([t_s, rows]))
            else:
                rows = surface_base_rows(attractor, StiffnessSchedule(stiffness, axes), damping, bowl_in_base)
                _write_csv(folder / f"{name}_base.csv", SURFACE_BASE_COLUMNS, np.column_stack([t_s, rows]))
            entry["file_base_frame"] = f"{name}_base.csv"
        entries.append(entry)
    _write_csv(folder / "demo.csv", DEMO_COLUMNS, np.column_stack([t_s, demo.x_demo, demo.force_demo]))
    content = {"round": int(round_index), **info, "frame": "bowl", "stiffness_frame": "world" if axes is None else "surface",
               "demo_file": "demo.csv", "proposals": entries}
    if bowl_in_base is not None:
        content["bowl_in_base"] = bowl_in_base.tolist()
    (folder / "round.yaml").write_text(yaml.safe_dump(content, sort_keys=False, width=120))
    return content


__all__ = ["BASE_COLUMNS", "DAMPING_CHANNELS", "SCHEDULE_COLUMNS", "SURFACE_BASE_COLUMNS", "SURFACE_COLUMNS",
           "base_frame_rows", "check_bowl_in_base", "proposal_id", "read_surface_schedule", "round_dir",
           "surface_base_rows", "surface_rows", "write_round"]
