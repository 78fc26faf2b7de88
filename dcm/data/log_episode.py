"""One logged robot episode as time-stamped streams, and the one processing path every log source goes through.

The CSV/npz folders (:mod:`dcm.data.import_logs`) and the ROS bags (:mod:`dcm.data.rosbag_logs`) only read
their streams into :class:`EpisodeStreams`; :func:`process_episode` does the rest, so both sources give the
same dataset for the same signals. The conventions (libfranka ``O_T_EE`` column-major, ``O_F_ext_hat_K``,
the bowl frame, bias from a free-motion window, low-pass, resampling) are described in docs/robot_logs.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from dcm.configs import JSONFileError, check_integer, check_number, load_json

NOMINAL_DOWN = np.diag([1.0, -1.0, -1.0])
META_REQUIRED = ("demo_id", "split", "bowl_in_base", "free_motion_s", "base_frame")
SPLITS = ("train", "valid", "test")
# "base": O_F_ext_hat_K (base-frame axes), "K": K_F_ext_hat_K (stiffness-frame axes).
WRENCH_FRAMES = ("base", "K")
# Numeric meta.json values and their shapes, checked once on reading so processing can trust them.
META_ARRAYS = {"bowl_in_base": (4, 4), "free_motion_s": (2,), "tip_offset_m": (3,), "nominal_rotation": (3, 3)}
# Passed from meta.json to the trajectory's attributes when present (a tuner matches observations to proposals).
META_PASSED = ("proposal", "round")


class LogFormatError(ValueError):
    """A log episode that breaks the input format: names the episode, the file and what is wrong."""


class Stream(NamedTuple):
    """Samples of one signal: t (N,) [s] increasing, values (N, C), and where they came from (for messages)."""

    t: np.ndarray
    values: np.ndarray
    where: str


@dataclass
class EpisodeStreams:
    """What every log source hands to :func:`process_episode` (robot-side conventions, one clock per episode).

    ``pose`` and ``equilibrium`` are libfranka-style 4x4 base-frame poses flattened column-major (N, 16);
    ``wrench`` is ``O_F_ext_hat_K`` (or ``K_F_ext_hat_K`` with ``meta["wrench_frame"] == "K"``); ``stiffness``
    is the commanded diagonal stiffness in base axes; ``demo`` the reference in the dataset's conventions;
    ``attractor`` an attractor already in the bowl frame (the CSV format's ``attractor.csv``); ``meta`` as
    :func:`load_meta` returns it (checked, so processing trusts its values).
    """

    name: str
    meta: dict[str, Any]
    meta_where: str
    pose: Stream
    wrench: Stream
    stiffness: Stream
    demo: Stream
    equilibrium: Stream | None = None
    attractor: Stream | None = None


def clean_stream(t: np.ndarray, values: np.ndarray, where: str, n_columns: int) -> Stream:
    """Check shape and finiteness, sort by time and drop exact duplicate times."""
    t, values = np.asarray(t, np.float64), np.asarray(values, np.float64)
    if values.ndim != 2 or values.shape[1] != n_columns or len(t) != len(values):
        raise LogFormatError(f"{where}: expected a time column and {n_columns} value columns, got {values.shape}")
    if len(t) < 2:
        raise LogFormatError(f"{where}: needs at least 2 samples, has {len(t)}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(values))):
        row = int(np.argwhere(~np.isfinite(np.column_stack([t, values])))[0, 0])
        raise LogFormatError(f"{where}: NaN or inf in data row {row + 1}")
    order = np.argsort(t, kind="stable")
    t, values = t[order], values[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return Stream(t[keep], values[keep], where)


def load_meta(episode: Path) -> tuple[dict[str, Any], str]:
    """An episode's meta.json, checked for the keys every source needs."""
    meta_path = episode / "meta.json"
    if not meta_path.exists():
        raise LogFormatError(f"{episode}: missing meta.json")
    try:
        meta = load_json(meta_path)
    except JSONFileError as err:
        raise LogFormatError(str(err)) from None
    if not isinstance(meta, dict):
        raise LogFormatError(f"{meta_path}: expected a JSON object {{...}}, got {type(meta).__name__}")
    for key in META_REQUIRED:
        if key not in meta:
            raise LogFormatError(f"{meta_path}: missing key {key!r}")
    check_meta(meta, str(meta_path))
    return meta, str(meta_path)


def check_meta(meta: dict[str, Any], where: str) -> None:
    """Refuse a meta.json value of the wrong type, shape or choice, naming the field: a misspelt choice (a
    ``wrench_frame`` of "k") would otherwise read as the default and give wrong forces without an error."""
    check_integer(meta["demo_id"], f"{where}: demo_id", 0, LogFormatError)
    if "trial" in meta:
        check_integer(meta["trial"], f"{where}: trial", 0, LogFormatError)
    for key, choices in (("split", SPLITS), ("wrench_frame", WRENCH_FRAMES)):
        if key in meta and meta[key] not in choices:
            raise LogFormatError(f"{where}: {key} = {meta[key]!r} must be one of {', '.join(map(repr, choices))}")
    for key in ("base_frame", "sim_failure"):
        if key in meta and not (isinstance(meta[key], str) and meta[key]):
            raise LogFormatError(f"{where}: {key} = {meta[key]!r} must be a non-empty string")
    if meta.get("demo") is not None and not isinstance(meta["demo"], dict):
        raise LogFormatError(f"{where}: demo = {meta['demo']!r} must be a DemoSpec object {{...}}")
    if "start_s" in meta:
        check_number(meta["start_s"], f"{where}: start_s", LogFormatError)
    for key, shape in META_ARRAYS.items():
        if key in meta:
            _check_numbers(meta[key], shape, f"{where}: {key}")


def _check_numbers(value: Any, shape: tuple[int, ...], where: str) -> None:
    """``value`` must be finite numbers of ``shape`` (matrices as row-major nested lists)."""
    what = f"{shape[0]} numbers" if len(shape) == 1 else f"a {shape[0]}x{shape[1]} matrix (row-major nested lists)"
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != shape or not np.all(np.isfinite(array)):
        raise LogFormatError(f"{where} = {value!r} must be {what}, all finite")


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


class _Frames:
    """The bowl frame seen from the robot base, and the tool: converts base-frame EE poses to bowl-frame tip poses."""

    def __init__(self, meta: dict[str, Any], meta_where: str) -> None:
        bowl_in_base = np.asarray(meta["bowl_in_base"], dtype=np.float64)
        check_transforms(bowl_in_base[None], f"{meta_where} bowl_in_base")
        self.nominal = np.asarray(meta.get("nominal_rotation", NOMINAL_DOWN), dtype=np.float64)
        self.tip_offset = np.asarray(meta.get("tip_offset_m", [0.0, 0.0, 0.0]), dtype=np.float64)
        self.base_to_bowl_R = bowl_in_base[:3, :3].T
        self.bowl_origin = bowl_in_base[:3, 3]

    def transforms(self, stream: Stream) -> np.ndarray:
        """(N, 4, 4) from column-major rows (reshaped in Fortran order, as libfranka stores O_T_EE)."""
        transforms = stream.values.reshape(-1, 4, 4, order="F")
        check_transforms(transforms, f"{stream.where} (O_T_EE)")
        return transforms

    def pose_bowl(self, transforms: np.ndarray) -> np.ndarray:
        """Tool-tip pose in the bowl frame: position + rotation vector from "tool pointing down"."""
        rot_base = transforms[:, :3, :3]
        tip_base = transforms[:, :3, 3] + rot_base @ self.tip_offset
        position_bowl = (tip_base - self.bowl_origin) @ self.base_to_bowl_R.T
        rot_bowl = self.base_to_bowl_R @ rot_base
        rotvec_bowl = rotation_to_rotvec(rot_bowl @ (self.base_to_bowl_R @ self.nominal).T)
        return np.column_stack([position_bowl, rotvec_bowl])


# ----------------------------------------------------------------------------------------------- episode
def process_episode(streams: EpisodeStreams, control_hz: float, horizon: int | None, lowpass_hz: float,
                    lowpass_order: int, contact_threshold_N: float) -> dict[str, Any]:
    """One episode's streams -> one trajectory dict for ``write_dataset`` (plus ``horizon``)."""
    from dcm.control.impedance import attractor_from_demo
    from dcm.control.objectives import compliance_loss, task_loss

    meta, meta_where = streams.meta, streams.meta_where
    frames = _Frames(meta, meta_where)
    base_to_bowl_R = frames.base_to_bowl_R
    pose_t = streams.pose.t
    transforms = frames.transforms(streams.pose)
    rot_base = transforms[:, :3, :3]
    pose_bowl = frames.pose_bowl(transforms)

    # Wrench: into base axes (if logged in K), bias from free motion, then bowl axes and torque about the tip.
    wrench_t, wrench = streams.wrench.t, streams.wrench.values.copy()
    if meta.get("wrench_frame", "base") == "K":
        rot_at_wrench = rot_base[np.clip(np.searchsorted(pose_t, wrench_t), 0, len(pose_t) - 1)]
        wrench[:, :3] = np.einsum("nij,nj->ni", rot_at_wrench, wrench[:, :3])
        wrench[:, 3:] = np.einsum("nij,nj->ni", rot_at_wrench, wrench[:, 3:])
    t0, t1 = map(float, meta["free_motion_s"])
    window = (wrench_t >= t0) & (wrench_t <= t1)
    if window.sum() < 10:
        raise LogFormatError(f"{meta_where}: free_motion_s {meta['free_motion_s']} holds {int(window.sum())} wrench "
                             "samples; need >= 10 to estimate the bias")
    bias = wrench[window].mean(axis=0)
    wrench = wrench - bias
    filt_t, wrench_filt = lowpass(wrench_t, wrench, lowpass_hz, lowpass_order)

    demo_t = streams.demo.t
    start = float(meta.get("start_s", demo_t[0]))
    if horizon is None:
        end = min(pose_t[-1], wrench_t[-1], demo_t[-1])
        horizon = int(np.floor((end - start) * control_hz + 1e-9)) + 1
    grid = start + np.arange(horizon) / control_hz
    x_obs = _resample(pose_t, pose_bowl, grid, streams.pose.where)
    # rotate the filtered wrench into bowl axes, then move the torque from the stiffness frame to the tool tip
    wrench_grid_base = _resample(filt_t, wrench_filt, grid, streams.wrench.where)
    rot_grid = rot_base[np.clip(np.searchsorted(pose_t, grid), 0, len(pose_t) - 1)]
    force_base = wrench_grid_base[:, :3]
    torque_tip_base = wrench_grid_base[:, 3:] - np.cross(np.einsum("nij,j->ni", rot_grid, frames.tip_offset), force_base)
    F_obs = np.column_stack([force_base @ base_to_bowl_R.T, torque_tip_base @ base_to_bowl_R.T])
    K_base = _zero_order_hold(streams.stiffness.t, streams.stiffness.values, grid, streams.stiffness.where)
    # a diagonal stiffness stays diagonal under the base->bowl rotation only if that is an axis permutation
    if not np.allclose(np.abs(base_to_bowl_R), np.abs(base_to_bowl_R).round(), atol=1e-6):
        raise LogFormatError(f"{meta_where}: bowl_in_base rotation is not an axis permutation; a diagonal base-frame "
                             "stiffness has no diagonal bowl-frame equivalent")
    permutation = np.abs(base_to_bowl_R)
    K = np.column_stack([K_base[:, :3] @ permutation.T, K_base[:, 3:] @ permutation.T])
    if np.any(K <= 0):
        raise LogFormatError(f"{streams.stiffness.where}: non-positive stiffness {K[K <= 0][0]}")
    demo_grid = _resample(demo_t, streams.demo.values, grid, streams.demo.where)
    x_demo, F_demo = demo_grid[:, :6], demo_grid[:, 6:]
    if streams.equilibrium is not None:
        equilibrium_bowl = frames.pose_bowl(frames.transforms(streams.equilibrium))
        x_attr = _resample(streams.equilibrium.t, equilibrium_bowl, grid, streams.equilibrium.where)
    elif streams.attractor is not None:
        x_attr = _resample(*streams.attractor[:2], grid, streams.attractor.where)
    else:
        x_attr = attractor_from_demo(x_demo, F_demo, K, 1.0 / control_hz)
    contact = np.abs(F_obs[:, 2]) > contact_threshold_N
    # A trial dcm-sim-logs saw diverge is failed as a generated one is: kept, out of the splits, L_task = inf.
    failure = meta.get("sim_failure", "")
    traj = {
        "name": None,
        "x_demo": x_demo, "F_demo": F_demo, "x_attr": x_attr, "K": K, "x_obs": x_obs, "F_obs": F_obs,
        "contact": contact,
        "L_task": float("inf") if failure else float(task_loss(F_obs, F_demo)), "L_comp": float(compliance_loss(K)),
        "failed": bool(failure), "failure_reason": failure,
        "demo_id": int(meta["demo_id"]), "trial": int(meta.get("trial", 0)), "skill": str(meta.get("skill", "")),
        "split": meta["split"], "demo": meta.get("demo", {}),
        "bowl": (meta.get("demo") or {}).get("bowl", {}), "embodiment": "franka_real", "domain": {"name": "real"},
        "seed": -1, "episode": streams.name, "base_frame": str(meta["base_frame"]), "bias_removed": bias.tolist(),
        "horizon": horizon,
    }
    traj.update({key: meta[key] for key in META_PASSED if key in meta})
    return traj
