"""Read one robot trial from a ROS bag (ROS 1 ``.bag``, ROS 2 directory, ``.db3`` or ``.mcap``) as episode streams.

The bag replaces the CSV streams of an episode folder; the folder keeps ``meta.json`` and ``demo.csv`` (a bag
holds neither the bowl's pose nor the demo reference). Every stream then follows the CSV importer's path
(:func:`dcm.data.log_episode.process_episode`).

Topics (franka_ros names by default, each configurable):

* ``state``: ``franka_msgs/FrankaState`` (``O_T_EE``, ``O_F_ext_hat_K`` or ``K_F_ext_hat_K``; franka_ros2's
  lower-case names and ``FrankaRobotState``'s stamped poses and wrenches are read too);
* ``stiffness``: the commanded per-axis stiffness as ``geometry_msgs/WrenchStamped`` (force = translational
  [N/m], torque = rotational [N·m/rad], base axes), the message Mayr's Cartesian-Impedance-Controller takes on
  ``set_cartesian_stiffness``; or ``std_msgs/Float64MultiArray`` with 6 values (the diagonal) or 36 (a 6x6
  matrix, which must be diagonal);
* ``equilibrium``: the attractor as ``geometry_msgs/PoseStamped`` (base frame, end-effector like ``O_T_EE``);
  ``None`` / empty: not read, the attractor is recomputed from the demo and K.

Times: a message's ``header.stamp`` when it has one, else the time it was recorded; in seconds after the bag's
first recorded message, the clock of ``meta.json``'s ``free_motion_s`` / ``start_s`` and ``demo.csv``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.log_episode import EpisodeStreams, LogFormatError, Stream, clean_stream

DEFAULT_TOPICS: dict[str, str | None] = {
    "state": "/franka_state_controller/franka_states",
    "stiffness": "/cartesian_impedance_example_controller/set_cartesian_stiffness",
    "equilibrium": "/cartesian_impedance_example_controller/equilibrium_pose",
}
ROS2_SUFFIXES = (".db3", ".mcap")


# ----------------------------------------------------------------------------------------------- options
def add_topic_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("ROS bag topics (defaults: franka_ros)")
    group.add_argument("--topics", type=Path, default=None,
                       help="YAML map {state: ..., stiffness: ..., equilibrium: ...}; flags below override it")
    for key, default in DEFAULT_TOPICS.items():
        group.add_argument(f"--{key}-topic", default=None, help=f"default {default}"
                           + ("; '' to recompute the attractor" if key == "equilibrium" else ""))


def topics_from_arguments(args: argparse.Namespace) -> dict[str, str | None]:
    """The bag topics: defaults, then the ``--topics`` YAML, then the flags."""
    import yaml

    topics = dict(DEFAULT_TOPICS)
    if args.topics is not None:
        try:
            loaded = yaml.safe_load(args.topics.read_text())
        except (OSError, yaml.YAMLError) as err:
            raise LogFormatError(f"{args.topics}: cannot read the topics map ({str(err).splitlines()[0]})") from None
        if not isinstance(loaded, dict) or set(loaded) - set(DEFAULT_TOPICS):
            raise LogFormatError(f"{args.topics}: expected a map with keys among {sorted(DEFAULT_TOPICS)}, "
                                 f"got {loaded!r}")
        topics.update(loaded)
    for key in DEFAULT_TOPICS:
        flag = getattr(args, f"{key}_topic")
        if flag is not None:
            topics[key] = flag
    for key in ("state", "stiffness"):
        if not topics[key]:
            raise LogFormatError(f"the {key} topic cannot be empty")
    return {key: (value or None) for key, value in topics.items()}


# ----------------------------------------------------------------------------------------------- finding
def find_bag(episode: Path) -> Path | None:
    """The bag of an episode folder: a ``.bag``, the folder itself or a subfolder as a ROS 2 bag (with
    ``metadata.yaml``), or a lone ``.db3`` / ``.mcap``; None for a CSV/npz episode."""
    if (episode / "metadata.yaml").exists():
        return episode
    candidates = sorted(p for p in episode.iterdir()
                        if (p.is_file() and p.suffix in (".bag",) + ROS2_SUFFIXES)
                        or (p.is_dir() and (p / "metadata.yaml").exists()))
    if len(candidates) > 1:
        raise LogFormatError(f"{episode}: holds {len(candidates)} bags ({', '.join(p.name for p in candidates)}); "
                             "one bag per episode")
    return candidates[0] if candidates else None


# ----------------------------------------------------------------------------------------------- decoding
def _field(msg: Any, name: str) -> Any:
    """A message field by name, case-insensitively (franka_ros2 lower-cases libfranka's names)."""
    fields = getattr(msg, "__dataclass_fields__", {})
    for candidate in fields:
        if candidate.lower() == name.lower():
            return getattr(msg, candidate)
    return None


def _column_major(pose: Any) -> np.ndarray:
    """geometry_msgs Pose(Stamped) -> 4x4 flattened column-major, as libfranka's O_T_EE."""
    from scipy.spatial.transform import Rotation

    pose = getattr(pose, "pose", pose)
    q, p = pose.orientation, pose.position
    transform = np.eye(4)
    transform[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    transform[:3, 3] = [p.x, p.y, p.z]
    return transform.reshape(16, order="F")


def _wrench(value: Any) -> np.ndarray:
    value = getattr(value, "wrench", value)
    if hasattr(value, "force"):
        f, t = value.force, value.torque
        return np.array([f.x, f.y, f.z, t.x, t.y, t.z])
    return np.asarray(value, np.float64)


def _state_decoder(wrench_name: str) -> Callable[[Any], np.ndarray]:
    def decode(msg: Any) -> np.ndarray | None:
        pose, wrench = _field(msg, "O_T_EE"), _field(msg, wrench_name)
        if pose is None or wrench is None:
            return None
        pose = _column_major(pose) if hasattr(getattr(pose, "pose", pose), "position") else np.asarray(pose, float)
        return np.concatenate([pose, _wrench(wrench)])

    return decode


def _stiffness(msg: Any) -> np.ndarray | None:
    if hasattr(getattr(msg, "wrench", msg), "force"):
        return _wrench(msg)
    data = getattr(msg, "data", None)
    if data is None:
        return None
    data = np.asarray(data, np.float64)
    if data.size == 36:
        matrix = data.reshape(6, 6)
        if np.abs(matrix - np.diag(np.diag(matrix))).max() > 1e-9 * max(1.0, np.abs(matrix).max()):
            raise ValueError("a 6x6 stiffness matrix with off-diagonal terms; the dataset holds per-axis stiffness")
        return np.diag(matrix).copy()
    return data if data.size == 6 else None


def _equilibrium(msg: Any) -> np.ndarray | None:
    return _column_major(msg) if hasattr(getattr(msg, "pose", msg), "position") else None


def _stamp_ns(msg: Any, logged_ns: int) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        return logged_ns
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


# ----------------------------------------------------------------------------------------------- reading
def _read_topic(reader: Any, bag: Path, topic: str, what: str, decode: Callable[[Any], np.ndarray | None],
                n_columns: int) -> Stream:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        present = sorted({c.topic for c in reader.connections})
        raise LogFormatError(f"{bag}: no {what} topic {topic!r} (the bag has {', '.join(present) or 'no topics'}); "
                             f"name it with --{what}-topic or --topics")
    where = f"{bag} topic {topic}"
    times: list[int] = []
    rows: list[np.ndarray] = []
    for connection, logged_ns, raw in reader.messages(connections=connections):
        try:
            msg = reader.deserialize(raw, connection.msgtype)
            row = decode(msg)
        except ValueError as err:
            raise LogFormatError(f"{where}: {err}") from None
        except Exception as err:  # the bag library's decoding errors have no common base class
            raise LogFormatError(f"{where}: cannot decode {connection.msgtype} ({err})") from None
        if row is None or row.shape != (n_columns,):
            raise LogFormatError(f"{where}: type {connection.msgtype} is not a {what} message "
                                 f"(see docs/robot_logs.md for the accepted types)")
        times.append(_stamp_ns(msg, logged_ns) - reader.start_time)
        rows.append(row)
    if not rows:
        raise LogFormatError(f"{where}: no messages")
    t = np.asarray(times, dtype=np.int64) / 1e9
    return clean_stream(t, np.vstack(rows), where, n_columns)


def read_bag_episode(bag: Path, name: str, meta: dict[str, Any], meta_where: str, demo: Stream,
                     topics: dict[str, str | None] | None = None) -> EpisodeStreams:
    """The streams of one bag (one trial), with the episode folder's meta and demo reference."""
    from rosbags.highlevel import AnyReader

    from dcm.data.franka_msgs import franka_typestore

    topics = dict(DEFAULT_TOPICS, **(topics or {}))
    ros2 = bag.suffix != ".bag"
    wrench_name = "K_F_ext_hat_K" if meta.get("wrench_frame", "base") == "K" else "O_F_ext_hat_K"
    try:
        with AnyReader([bag], default_typestore=franka_typestore(ros2)) as reader:
            state = _read_topic(reader, bag, topics["state"], "state", _state_decoder(wrench_name), 22)
            stiffness = _read_topic(reader, bag, topics["stiffness"], "stiffness", _stiffness, 6)
            equilibrium = None
            if topics.get("equilibrium"):
                equilibrium = _read_topic(reader, bag, topics["equilibrium"], "equilibrium", _equilibrium, 16)
    except LogFormatError:
        raise
    except Exception as err:  # a bag rosbags cannot open: unreadable, truncated, unknown storage
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise LogFormatError(f"{bag}: not a readable ROS bag ({reason})") from None
    return EpisodeStreams(
        name=name, meta=meta, meta_where=meta_where,
        pose=Stream(state.t, state.values[:, :16], state.where),
        wrench=Stream(state.t, state.values[:, 16:], f"{state.where} {wrench_name}"),
        stiffness=stiffness, demo=demo, equilibrium=equilibrium)
