"""Import real Franka logs into the dataset format, so robot data and simulated data train the same model.

    python -m dcm.data.import_logs logs/ --out data/real.h5 [--control-hz 20] [--lowpass-hz 5] [--overwrite]

Input format: one directory per episode (one stiffness trial) under ``<log_dir>``, processed in name order::

    <log_dir>/<episode>/
        meta.json       see below
        pose.csv        t, T0..T15        libfranka O_T_EE: the 4x4 end-effector pose in the robot base frame,
                                          flattened COLUMN-major as libfranka stores it (T12..T14 = position)
        wrench.csv      t, Fx, Fy, Fz, Tx, Ty, Tz
                                          libfranka O_F_ext_hat_K: the estimated external wrench the environment
                                          exerts on the robot, base-frame axes, torque about the stiffness frame
                                          (set "wrench_frame": "K" for K_F_ext_hat_K, stiffness-frame axes)
        stiffness.csv   t, Kx, Ky, Kz, Krx, Kry, Krz
                                          commanded stiffness [N/m, N·m/rad], base-frame axes; each row holds
                                          until the next (zero-order hold)
        demo.csv        t, x, y, z, rx, ry, rz, Fx, Fy, Fz, Tx, Ty, Tz
                                          the demo reference in the dataset's conventions (bowl frame, pose as
                                          position + rotation vector from "tool pointing down", contact wrench)
        attractor.csv   t, x, y, z, rx, ry, rz   (optional) the attractor the controller used, bowl frame;
                                          when absent it is recomputed from the demo and K (paper's equation)

    Instead of ``<name>.csv`` a ``<name>.npz`` with arrays ``t`` (N,) and ``values`` (N, C) is accepted.
    Each stream carries its own timestamps [s] (any common clock, jitter and different rates are fine).

    meta.json:
        demo_id (int), trial (int), split ("train" | "valid" | "test"), skill (str, optional),
        demo (DemoSpec dict, optional), base_frame (str, must be the same for every episode),
        bowl_in_base: 4x4 row-major pose of the bowl frame in the base frame (bowl frame = world axes, origin
                      at the lowest point of the bowl),
        free_motion_s: [t0, t1] a window (stream clock) without contact, whose mean wrench is the bias,
        start_s (optional): time of control step 0 (default: the first demo.csv time),
        tip_offset_m (optional, default [0,0,0]): tool-tip position in the EE frame, if O_T_EE is not the tip;
                      the stiffness frame K is assumed to coincide with the EE frame,
        nominal_rotation (optional): 3x3 row-major base-frame rotation of the "tool pointing straight down"
                      pose (default diag(1, -1, -1), Franka's usual downward flange).

Processing, in order: frame checks (rotation blocks orthonormal with det +1, last row [0,0,0,1], one base
frame for all episodes); conversion to the bowl frame and to the contract's pose/wrench conventions (force
in bowl-frame axes, torque moved to the tool tip); bias removal (mean wrench over ``free_motion_s``);
zero-phase Butterworth low-pass of the wrench (order and cut-off stored as file attributes), applied on a
uniform grid at the stream's own median rate before resampling, so it also acts as the anti-alias filter;
linear resampling of pose and wrench onto the control grid ``t_k = start_s + k / control_hz``; contact flag
= filtered |F_z| above ``--contact-threshold-N``. The pose is not filtered (it is already smooth).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from dcm.cli import JSONFileError, load_json, quiet_libraries
from dcm.data.schema import DatasetError, write_dataset

NOMINAL_DOWN = np.diag([1.0, -1.0, -1.0])
STREAM_COLUMNS = {"pose": 16, "wrench": 6, "stiffness": 6, "demo": 12, "attractor": 6}


class LogFormatError(ValueError):
    """A log episode that breaks the input format: names the episode, the file and what is wrong."""


# ----------------------------------------------------------------------------------------------- reading
def read_stream(episode: Path, name: str, required: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
    """(t (N,), values (N, C)) of one stream, sorted by time with exact duplicates dropped."""
    n_columns = STREAM_COLUMNS[name]
    csv_path, npz_path = episode / f"{name}.csv", episode / f"{name}.npz"
    if npz_path.exists():
        with np.load(npz_path) as npz:
            if "t" not in npz or "values" not in npz:
                raise LogFormatError(f"{npz_path}: needs arrays 't' and 'values'")
            t, values = np.asarray(npz["t"], np.float64), np.asarray(npz["values"], np.float64)
        where = npz_path
    elif csv_path.exists():
        with csv_path.open() as handle:
            rows = list(csv.reader(handle))
        if len(rows) < 3:
            raise LogFormatError(f"{csv_path}: needs a header and at least 2 rows, has {len(rows)} lines")
        try:
            table = np.array([[float(v) for v in row] for row in rows[1:] if row], dtype=np.float64)
        except ValueError as err:
            raise LogFormatError(f"{csv_path}: non-numeric value ({err})") from None
        if table.ndim != 2:
            raise LogFormatError(f"{csv_path}: rows have different lengths")
        t, values = table[:, 0], table[:, 1:]
        where = csv_path
    elif required:
        raise LogFormatError(f"{episode}: missing {name}.csv (or {name}.npz)")
    else:
        return None
    if values.ndim != 2 or values.shape[1] != n_columns or len(t) != len(values):
        raise LogFormatError(f"{where}: expected a time column and {n_columns} value columns, got {values.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(values))):
        row = int(np.argwhere(~np.isfinite(np.column_stack([t, values])))[0, 0])
        raise LogFormatError(f"{where}: NaN or inf in data row {row + 1}")
    order = np.argsort(t, kind="stable")
    t, values = t[order], values[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], values[keep]


def _matrix(value: Any, shape: tuple[int, int], where: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise LogFormatError(f"{where}: expected a {shape} matrix (row-major nested lists), got shape {array.shape}")
    return array


# ----------------------------------------------------------------------------------------------- geometry
def rotation_to_rotvec(rotation: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> rotation vectors (..., 3) (log map, stable near 0 and pi)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rotation.reshape(-1, 3, 3)).as_rotvec().reshape(*rotation.shape[:-2], 3)


def check_transforms(transforms: np.ndarray, where: str, tol: float = 1e-3) -> None:
    """Homogeneous transforms (N,4,4): orthonormal rotation with det +1 and last row [0,0,0,1]."""
    rotation = transforms[:, :3, :3]
    ortho_err = np.abs(np.einsum("nji,njk->nik", rotation, rotation) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rotation)
    bottom_err = np.abs(transforms[:, 3, :] - np.array([0, 0, 0, 1.0])).max(axis=1)
    bad = np.flatnonzero((ortho_err > tol) | (np.abs(det - 1) > tol) | (bottom_err > tol))
    if bad.size:
        i = int(bad[0])
        raise LogFormatError(
            f"{where}: row {i + 1} is not a rigid transform (|R^T R - I| = {ortho_err[i]:.2e}, det R = {det[i]:.4f}, "
            f"last row {transforms[i, 3].tolist()}); is O_T_EE flattened column-major?"
        )


def lowpass(t: np.ndarray, values: np.ndarray, cutoff_hz: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Zero-phase Butterworth low-pass on a uniform grid at the stream's median rate (returned with its grid)."""
    from scipy.signal import butter, sosfiltfilt

    rate_hz = 1.0 / float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 / rate_hz, 1.0 / rate_hz)
    uniform = np.column_stack([np.interp(grid, t, values[:, c]) for c in range(values.shape[1])])
    if cutoff_hz <= 0:
        return grid, uniform
    if cutoff_hz >= 0.5 * rate_hz:
        raise LogFormatError(f"low-pass cut-off {cutoff_hz} Hz is not below the stream's Nyquist rate "
                             f"{rate_hz / 2:.1f} Hz")
    sos = butter(order, cutoff_hz, fs=rate_hz, output="sos")
    return grid, sosfiltfilt(sos, uniform, axis=0)


def _resample(t: np.ndarray, values: np.ndarray, grid: np.ndarray, where: str) -> np.ndarray:
    if grid[0] < t[0] - 1e-9 or grid[-1] > t[-1] + 1e-9:
        raise LogFormatError(f"{where}: covers {t[0]:.3f}..{t[-1]:.3f} s, the control grid needs "
                             f"{grid[0]:.3f}..{grid[-1]:.3f} s")
    return np.column_stack([np.interp(grid, t, values[:, c]) for c in range(values.shape[1])])


def _zero_order_hold(t: np.ndarray, values: np.ndarray, grid: np.ndarray, where: str) -> np.ndarray:
    if grid[0] < t[0] - 1e-9:
        raise LogFormatError(f"{where}: first command at {t[0]:.3f} s, after control step 0 at {grid[0]:.3f} s")
    index = np.searchsorted(t, grid + 1e-9, side="right") - 1
    return values[index]


# ----------------------------------------------------------------------------------------------- episode
def import_episode(episode: Path, control_hz: float, horizon: int | None, lowpass_hz: float, lowpass_order: int,
                   contact_threshold_N: float) -> dict[str, Any]:
    """One episode -> one trajectory dict for ``write_dataset``."""
    from dcm.control.impedance import attractor_from_demo
    from dcm.control.objectives import compliance_loss, task_loss

    meta_path = episode / "meta.json"
    if not meta_path.exists():
        raise LogFormatError(f"{episode}: missing meta.json")
    try:
        meta = load_json(meta_path)
    except JSONFileError as err:
        raise LogFormatError(str(err)) from None
    if not isinstance(meta, dict):
        raise LogFormatError(f"{meta_path}: expected a JSON object {{...}}, got {type(meta).__name__}")
    for key in ("demo_id", "bowl_in_base", "free_motion_s", "base_frame"):
        if key not in meta:
            raise LogFormatError(f"{meta_path}: missing key {key!r}")
    bowl_in_base = _matrix(meta["bowl_in_base"], (4, 4), f"{meta_path} bowl_in_base")
    check_transforms(bowl_in_base[None], f"{meta_path} bowl_in_base")
    nominal = _matrix(meta.get("nominal_rotation", NOMINAL_DOWN), (3, 3), f"{meta_path} nominal_rotation")
    tip_offset = np.asarray(meta.get("tip_offset_m", [0.0, 0.0, 0.0]), dtype=np.float64)
    base_to_bowl_R = bowl_in_base[:3, :3].T
    bowl_origin = bowl_in_base[:3, 3]

    pose_t, pose_raw = read_stream(episode, "pose")
    wrench_t, wrench_raw = read_stream(episode, "wrench")
    stiff_t, stiff_raw = read_stream(episode, "stiffness")
    demo_t, demo_raw = read_stream(episode, "demo")
    attractor = read_stream(episode, "attractor", required=False)

    # O_T_EE is column-major: reshape in Fortran order to get the usual matrix.
    transforms = pose_raw.reshape(-1, 4, 4, order="F")
    check_transforms(transforms, f"{episode / 'pose'}.csv (O_T_EE)")
    rot_base = transforms[:, :3, :3]
    tip_base = transforms[:, :3, 3] + rot_base @ tip_offset
    position_bowl = (tip_base - bowl_origin) @ base_to_bowl_R.T
    rot_bowl = base_to_bowl_R @ rot_base
    rotvec_bowl = rotation_to_rotvec(rot_bowl @ (base_to_bowl_R @ nominal).T)
    pose_bowl = np.column_stack([position_bowl, rotvec_bowl])

    # Wrench: into base axes (if logged in K), bias from free motion, then bowl axes and torque about the tip.
    wrench = wrench_raw.copy()
    if meta.get("wrench_frame", "base") == "K":
        rot_at_wrench = rot_base[np.clip(np.searchsorted(pose_t, wrench_t), 0, len(pose_t) - 1)]
        wrench[:, :3] = np.einsum("nij,nj->ni", rot_at_wrench, wrench[:, :3])
        wrench[:, 3:] = np.einsum("nij,nj->ni", rot_at_wrench, wrench[:, 3:])
    t0, t1 = map(float, meta["free_motion_s"])
    window = (wrench_t >= t0) & (wrench_t <= t1)
    if window.sum() < 10:
        raise LogFormatError(f"{meta_path}: free_motion_s {meta['free_motion_s']} holds {int(window.sum())} wrench "
                             "samples; need >= 10 to estimate the bias")
    bias = wrench[window].mean(axis=0)
    wrench = wrench - bias
    filt_t, wrench_filt = lowpass(wrench_t, wrench, lowpass_hz, lowpass_order)

    start = float(meta.get("start_s", demo_t[0]))
    if horizon is None:
        end = min(pose_t[-1], wrench_t[-1], demo_t[-1])
        horizon = int(np.floor((end - start) * control_hz + 1e-9)) + 1
    grid = start + np.arange(horizon) / control_hz
    x_obs = _resample(pose_t, pose_bowl, grid, f"{episode / 'pose.csv'}")
    # rotate the filtered wrench into bowl axes, then move the torque from the stiffness frame to the tool tip
    wrench_grid_base = _resample(filt_t, wrench_filt, grid, f"{episode / 'wrench.csv'}")
    rot_grid = rot_base[np.clip(np.searchsorted(pose_t, grid), 0, len(pose_t) - 1)]
    force_base = wrench_grid_base[:, :3]
    torque_tip_base = wrench_grid_base[:, 3:] - np.cross(np.einsum("nij,j->ni", rot_grid, tip_offset), force_base)
    F_obs = np.column_stack([force_base @ base_to_bowl_R.T, torque_tip_base @ base_to_bowl_R.T])
    K_base = _zero_order_hold(stiff_t, stiff_raw, grid, f"{episode / 'stiffness.csv'}")
    # a diagonal stiffness stays diagonal under the base->bowl rotation only if that is an axis permutation
    if not np.allclose(np.abs(base_to_bowl_R), np.abs(base_to_bowl_R).round(), atol=1e-6):
        raise LogFormatError(f"{meta_path}: bowl_in_base rotation is not an axis permutation; a diagonal base-frame "
                             "stiffness has no diagonal bowl-frame equivalent")
    permutation = np.abs(base_to_bowl_R)
    K = np.column_stack([K_base[:, :3] @ permutation.T, K_base[:, 3:] @ permutation.T])
    if np.any(K <= 0):
        raise LogFormatError(f"{episode / 'stiffness.csv'}: non-positive stiffness {K[K <= 0][0]}")
    demo_grid = _resample(demo_t, demo_raw, grid, f"{episode / 'demo.csv'}")
    x_demo, F_demo = demo_grid[:, :6], demo_grid[:, 6:]
    if attractor is not None:
        x_attr = _resample(*attractor, grid, f"{episode / 'attractor.csv'}")
    else:
        x_attr = attractor_from_demo(x_demo, F_demo, K, 1.0 / control_hz)
    contact = np.abs(F_obs[:, 2]) > contact_threshold_N
    return {
        "name": None,
        "x_demo": x_demo, "F_demo": F_demo, "x_attr": x_attr, "K": K, "x_obs": x_obs, "F_obs": F_obs,
        "contact": contact,
        "L_task": float(task_loss(F_obs, F_demo)), "L_comp": float(compliance_loss(K)),
        "failed": False, "failure_reason": "",
        "demo_id": int(meta["demo_id"]), "trial": int(meta.get("trial", 0)), "skill": str(meta.get("skill", "")),
        "split": str(meta.get("split", "train")), "demo": meta.get("demo", {}),
        "bowl": (meta.get("demo") or {}).get("bowl", {}), "embodiment": "franka_real", "domain": {"name": "real"},
        "seed": -1, "episode": episode.name, "base_frame": str(meta["base_frame"]), "bias_removed": bias.tolist(),
        "horizon": horizon,
    }


def import_logs(log_dir: str | Path, out: str | Path, control_hz: float = 20.0, horizon: int | None = None,
                lowpass_hz: float = 5.0, lowpass_order: int = 2, contact_threshold_N: float = 1.0,
                overwrite: bool = False) -> int:
    """Import every episode directory of ``log_dir`` into one dataset file; returns the trajectory count.

    An existing ``out`` is replaced only with ``overwrite`` (then atomically, once the import succeeded), as
    :mod:`dcm.data.generate` does: an earlier import may be all that is left of logs since deleted."""
    log_dir, out = Path(log_dir), Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass overwrite=True to replace it, or choose another out")
    episodes = sorted(p for p in log_dir.iterdir() if p.is_dir()) if log_dir.is_dir() else []
    if not episodes:
        raise LogFormatError(f"{log_dir}: no episode directories")
    trajectories = []
    for episode in episodes:
        traj = import_episode(episode, control_hz, horizon, lowpass_hz, lowpass_order, contact_threshold_N)
        horizon = traj.pop("horizon")  # the first episode fixes H for the file
        trajectories.append(traj)
    frames = {t["base_frame"] for t in trajectories}
    if len(frames) != 1:
        raise LogFormatError(f"{log_dir}: episodes use different base frames {sorted(frames)}")
    masks: dict[str, list[str]] = {"train": [], "valid": [], "test": []}
    for index, traj in enumerate(trajectories):
        traj["name"] = f"traj_{index:06d}"
        if traj["split"] not in masks:
            raise LogFormatError(f"{log_dir / traj['episode']}/meta.json: split {traj['split']!r} unknown")
        masks[traj["split"]].append(traj["name"])
    attrs = {
        "control_hz": float(control_hz), "embodiment": "franka_real", "domain": {"name": "real"},
        "dataset": "real", "source": str(log_dir.resolve()),
        "import_lowpass": "butterworth, zero-phase (sosfiltfilt) on the wrench at its own rate, before resampling",
        "import_lowpass_hz": float(lowpass_hz), "import_lowpass_order": int(lowpass_order),
        "import_bias": "mean wrench over each episode's free_motion_s window, subtracted",
        "import_resampling": "linear interpolation onto t_k = start_s + k / control_hz; stiffness zero-order hold",
        "import_contact_threshold_N": float(contact_threshold_N),
        "config": {"log_dir": str(log_dir), "control_hz": control_hz, "horizon": horizon,
                   "lowpass_hz": lowpass_hz, "lowpass_order": lowpass_order,
                   "contact_threshold_N": contact_threshold_N},
    }
    write_dataset(out, trajectories, masks, attrs)
    return len(trajectories)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dcm.data.import_logs",
                                     description="Import real Franka logs (format: see the module docstring).")
    parser.add_argument("log_dir", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--control-hz", type=float, default=20.0)
    parser.add_argument("--horizon", type=int, default=None, help="steps per trajectory (default: first episode's)")
    parser.add_argument("--lowpass-hz", type=float, default=5.0, help="wrench cut-off; 0 disables the filter")
    parser.add_argument("--lowpass-order", type=int, default=2)
    parser.add_argument("--contact-threshold-N", type=float, default=1.0)
    args = parser.parse_args(argv)
    quiet_libraries()
    if args.out.exists() and not args.overwrite:
        print(f"error: {args.out} exists; pass --overwrite to replace it, or choose another --out", file=sys.stderr)
        return 1
    try:
        n = import_logs(args.log_dir, args.out, args.control_hz, args.horizon, args.lowpass_hz, args.lowpass_order,
                        args.contact_threshold_N, overwrite=args.overwrite)
    except (LogFormatError, DatasetError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {n} trajectories")
    return 0


if __name__ == "__main__":
    sys.exit(main())
