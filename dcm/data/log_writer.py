"""Write a trial as a Franka would log it: a CSV episode folder or a ROS 1 / ROS 2 bag the importer reads.

A trial comes in the dataset's conventions (:class:`TrialSignals`: bowl frame, tool-tip pose, contact wrench
with the torque about the tip); :func:`robot_streams` turns it into robot-side streams (robot base frame,
libfranka ``O_T_EE`` flattened column-major, ``O_F_ext_hat_K`` with the torque about the end effector, a
sensor bias and noise, a state stream at its own rate with timestamp jitter), so an import exercises every
conversion the importer makes. Times are whole nanoseconds on one clock starting at 0, so a CSV folder and a
bag of the same trial import to the same numbers.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.log_episode import NOMINAL_DOWN

BAG_EPOCH_NS = 1_700_000_000 * 1_000_000_000  # the bags' ROS time of log time 0
YAW_90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _bowl_in_base() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = YAW_90, [0.5, 0.1, 0.2]
    return pose


@dataclass
class RobotConventions:
    """How the robot logs: where the bowl stands in its base frame, the tool, the state rate, the F/T errors.

    The defaults put the bowl 0.5 m in front of a Franka base, 0.2 m up, turned 90° about z (so base-frame
    stiffness axes differ from the bowl's), a 0.1 m tool, a 200 Hz state stream with ±0.2 ms jitter and a
    wrench bias and noise of the size a Franka's estimate shows.
    """

    bowl_in_base: np.ndarray = field(default_factory=_bowl_in_base)
    base_frame: str = "panda_link0"
    tip_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.1)
    nominal_rotation: np.ndarray = field(default_factory=lambda: NOMINAL_DOWN.copy())
    state_hz: float = 200.0
    jitter_s: float = 2e-4
    bias: tuple[float, ...] = (1.0, -0.7, 2.5, 0.10, -0.05, 0.02)  # base frame, N and N·m
    noise_std: tuple[float, ...] = (0.3, 0.3, 0.3, 0.01, 0.01, 0.01)

    @classmethod
    def clean(cls, **changes: Any) -> RobotConventions:
        """No bias, noise or jitter: an import then returns the trial itself (round-trip checks)."""
        return cls(jitter_s=0.0, bias=(0.0,) * 6, noise_std=(0.0,) * 6, **changes)


@dataclass
class TrialSignals:
    """One trial in the dataset's conventions, as keyframes the writer interpolates linearly.

    ``obs_t_s`` / ``pose`` (N, 6) / ``wrench`` (N, 6): the observed tool-tip pose and contact wrench, covering
    the whole log (free motion before the trial included); ``command_t_s`` / ``stiffness`` (M, 6) bowl axes /
    ``attractor`` (M, 6) or None; ``demo_t_s`` / ``demo`` (H, 12); ``meta``: the episode's meta.json keys
    besides the frames (demo_id, trial, split, skill, demo, free_motion_s, start_s, ...).
    """

    obs_t_s: np.ndarray
    pose: np.ndarray
    wrench: np.ndarray
    command_t_s: np.ndarray
    stiffness: np.ndarray
    attractor: np.ndarray | None
    demo_t_s: np.ndarray
    demo: np.ndarray
    meta: dict[str, Any]


def _ns(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s, np.float64) * 1e9).astype(np.int64)


def _interp(t: np.ndarray, keys_t: np.ndarray, keys: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t, keys_t, keys[:, c]) for c in range(keys.shape[1])])


def _base_poses(pose_bowl: np.ndarray, conv: RobotConventions) -> np.ndarray:
    """Tool-tip poses (N, 6) in the bowl frame -> end-effector transforms (N, 4, 4) in the base frame."""
    from scipy.spatial.transform import Rotation

    bowl_R, bowl_o = conv.bowl_in_base[:3, :3], conv.bowl_in_base[:3, 3]
    rot_base = bowl_R @ Rotation.from_rotvec(pose_bowl[:, 3:]).as_matrix() @ bowl_R.T @ conv.nominal_rotation
    tip_base = pose_bowl[:, :3] @ bowl_R.T + bowl_o
    transforms = np.tile(np.eye(4), (len(pose_bowl), 1, 1))
    transforms[:, :3, :3] = rot_base
    transforms[:, :3, 3] = tip_base - rot_base @ np.asarray(conv.tip_offset_m)
    return transforms


def robot_streams(signals: TrialSignals, conv: RobotConventions, rng: np.random.Generator
                  ) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, Any]]:
    """Robot-side streams {name: (t_ns (N,), values (N, C))} and the episode's meta.json."""
    end_s = float(signals.obs_t_s[-1])
    n_state = int(np.floor(end_s * conv.state_hz + 1e-9)) + 1
    jitter = rng.uniform(-conv.jitter_s, conv.jitter_s, n_state) if conv.jitter_s else np.zeros(n_state)
    jitter[0] = 0.0  # the log's first message opens the clock at 0
    state_ns = np.unique(_ns(np.arange(n_state) / conv.state_hz + jitter))
    state_t = state_ns / 1e9
    transforms = _base_poses(_interp(state_t, signals.obs_t_s, signals.pose), conv)
    wrench_bowl = _interp(state_t, signals.obs_t_s, signals.wrench)
    bowl_R = conv.bowl_in_base[:3, :3]
    force_base, torque_tip_base = wrench_bowl[:, :3] @ bowl_R.T, wrench_bowl[:, 3:] @ bowl_R.T
    lever = np.einsum("nij,j->ni", transforms[:, :3, :3], np.asarray(conv.tip_offset_m))
    torque_ee_base = torque_tip_base + np.cross(lever, force_base)
    noise = rng.normal(size=(len(state_t), 6)) * np.asarray(conv.noise_std)
    wrench_logged = np.column_stack([force_base, torque_ee_base]) + np.asarray(conv.bias) + noise
    permutation = np.abs(bowl_R)  # bowl axes -> base axes of a diagonal stiffness (an axis permutation)
    command_ns = _ns(signals.command_t_s)
    streams = {
        "pose": (state_ns, transforms.reshape(-1, 16, order="F")),
        "wrench": (state_ns, wrench_logged),
        "stiffness": (command_ns, np.column_stack([signals.stiffness[:, :3] @ permutation.T,
                                                   signals.stiffness[:, 3:] @ permutation.T])),
        "demo": (_ns(signals.demo_t_s), signals.demo),
    }
    if signals.attractor is not None:
        streams["equilibrium"] = (command_ns, _base_poses(signals.attractor, conv).reshape(-1, 16, order="F"))
    meta = dict(signals.meta, base_frame=conv.base_frame, bowl_in_base=conv.bowl_in_base.tolist(),
                tip_offset_m=list(conv.tip_offset_m), nominal_rotation=conv.nominal_rotation.tolist())
    return streams, meta


# ----------------------------------------------------------------------------------------------- CSV
HEADERS = {
    "pose": ["t"] + [f"T{i}" for i in range(16)],
    "equilibrium": ["t"] + [f"T{i}" for i in range(16)],
    "wrench": ["t", "Fx", "Fy", "Fz", "Tx", "Ty", "Tz"],
    "stiffness": ["t", "Kx", "Ky", "Kz", "Krx", "Kry", "Krz"],
    "demo": ["t", "x", "y", "z", "rx", "ry", "rz", "Fx", "Fy", "Fz", "Tx", "Ty", "Tz"],
}


def write_csv(path: Path, header: list[str], t_s: np.ndarray, values: np.ndarray) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(np.column_stack([t_s, values]).tolist())


def write_meta(episode: Path, streams: dict[str, tuple[np.ndarray, np.ndarray]], meta: dict[str, Any]) -> None:
    """meta.json and demo.csv: what a bag episode keeps beside its bag, and a CSV episode beside its streams."""
    episode.mkdir(parents=True, exist_ok=True)
    (episode / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    write_csv(episode / "demo.csv", HEADERS["demo"], streams["demo"][0] / 1e9, streams["demo"][1])


def write_csv_episode(episode: Path, streams: dict[str, tuple[np.ndarray, np.ndarray]], meta: dict[str, Any]) -> None:
    write_meta(episode, streams, meta)
    for name, (t_ns, values) in streams.items():
        if name != "demo":
            write_csv(episode / f"{name}.csv", HEADERS[name], t_ns / 1e9, values)


# ----------------------------------------------------------------------------------------------- bags
def _default(store: Any, typename: str) -> Any:
    """A message of ``typename`` with every field zero / empty (rosbags messages have no defaults)."""
    from rosbags.typesys.base import Nodetype

    def value(node: tuple[Any, Any]) -> Any:
        kind, detail = node
        if kind == Nodetype.BASE:
            name = detail[0]
            return "" if name == "string" else False if name == "bool" else 0.0 if name.startswith("float") else 0
        if kind == Nodetype.NAME:
            return _default(store, detail)
        inner, length = detail
        if inner[0] == Nodetype.BASE and inner[1][0] not in ("string", "bool"):
            return np.zeros(length if kind == Nodetype.ARRAY else 0, dtype=np.dtype(inner[1][0]))
        return [value(inner) for _ in range(length if kind == Nodetype.ARRAY else 0)]

    _, fields = store.fielddefs[typename]
    return store.types[typename](**{name: value(node) for name, node in fields})


def _header(store: Any, stamp_ns: int, frame_id: str) -> Any:
    """A header stamped ``stamp_ns`` after the bags' epoch."""
    stamp_ns = BAG_EPOCH_NS + stamp_ns
    header = _default(store, "std_msgs/msg/Header")
    header.stamp = store.types["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000),
                                                              nanosec=int(stamp_ns % 1_000_000_000))
    header.frame_id = frame_id
    return header


def _pose_stamped(store: Any, stamp_ns: int, frame_id: str, column_major: np.ndarray) -> Any:
    from scipy.spatial.transform import Rotation

    transform = column_major.reshape(4, 4, order="F")
    x, y, z, w = Rotation.from_matrix(transform[:3, :3]).as_quat()
    msg = _default(store, "geometry_msgs/msg/PoseStamped")
    msg.header = _header(store, stamp_ns, frame_id)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, transform[:3, 3])
    msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w = x, y, z, w
    return msg


def bag_messages(store: Any, streams: dict[str, tuple[np.ndarray, np.ndarray]], topics: dict[str, str | None],
                 frame_id: str, ros2: bool) -> list[tuple[int, str, str, Any]]:
    """(time ns, topic, type, message) for the state, stiffness and equilibrium streams, in time order."""
    from dcm.data.franka_msgs import STATE_TYPE

    pose_name, wrench_name = ("o_t_ee", "o_f_ext_hat_k") if ros2 else ("O_T_EE", "O_F_ext_hat_K")
    messages = []
    state_ns, pose = streams["pose"]
    wrench = streams["wrench"][1]
    for k, stamp in enumerate(state_ns):
        msg = _default(store, STATE_TYPE)
        msg.header = _header(store, int(stamp), frame_id)
        setattr(msg, pose_name, np.ascontiguousarray(pose[k]))
        setattr(msg, wrench_name, np.ascontiguousarray(wrench[k]))
        msg.time = stamp / 1e9
        messages.append((int(stamp), topics["state"], STATE_TYPE, msg))
    for stamp, k_base in zip(*streams["stiffness"]):
        msg = _default(store, "geometry_msgs/msg/WrenchStamped")
        msg.header = _header(store, int(stamp), frame_id)
        f, t = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, t.x, t.y, t.z = map(float, k_base)
        messages.append((int(stamp), topics["stiffness"], "geometry_msgs/msg/WrenchStamped", msg))
    if "equilibrium" in streams and topics.get("equilibrium"):
        for stamp, column_major in zip(*streams["equilibrium"]):
            messages.append((int(stamp), topics["equilibrium"], "geometry_msgs/msg/PoseStamped",
                             _pose_stamped(store, int(stamp), frame_id, column_major)))
    messages.sort(key=lambda m: m[0])
    return messages


def write_bag(path: Path, streams: dict[str, tuple[np.ndarray, np.ndarray]], frame_id: str, ros2: bool,
              storage: str = "sqlite3", topics: dict[str, str | None] | None = None) -> None:
    """One trial as a ROS 1 ``.bag`` or a ROS 2 bag directory (``sqlite3`` -> .db3, ``mcap``), franka_ros topics."""
    from dcm.data.franka_msgs import franka_typestore
    from dcm.data.rosbag_logs import DEFAULT_TOPICS

    store = franka_typestore(ros2)
    messages = bag_messages(store, streams, dict(DEFAULT_TOPICS, **(topics or {})), frame_id, ros2)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    with writer:
        connections: dict[str, Any] = {}
        for stamp, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], BAG_EPOCH_NS + stamp, serialize(msg, msgtype))
