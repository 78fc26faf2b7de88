"""Import real Franka logs into the dataset format, so robot data and simulated data train the same model.

    python -m dcm.data.import_logs logs/ --out data/real.h5 [--control-hz 20] [--lowpass-hz 5] [--overwrite]
        [--topics topics.yaml] [--state-topic T] [--stiffness-topic T] [--equilibrium-topic T]

Input format: one directory per episode (one stiffness trial) under ``<log_dir>``, processed in name order.
Its streams come from CSV/npz files or from one ROS bag in the directory (``*.bag``; a ROS 2 bag directory,
``*.db3`` or ``*.mcap``; see :mod:`dcm.data.rosbag_logs` for topics and message types); ``meta.json`` and
``demo.csv`` are always files. Either way the streams take one processing path
(:func:`dcm.data.log_episode.process_episode`)::

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
        equilibrium.csv t, T0..T15        (optional) the controller's equilibrium (attractor) pose, base frame,
                                          end effector, column-major as O_T_EE
        attractor.csv   t, x, y, z, rx, ry, rz   (optional) the attractor already in the bowl frame; with neither
                                          file it is recomputed from the demo and K (paper's equation)

    Instead of ``<name>.csv`` a ``<name>.npz`` with arrays ``t`` (N,) and ``values`` (N, C) is accepted.
    Each stream carries its own timestamps [s] (any common clock, jitter and different rates are fine).

    meta.json (a value of another type, shape or choice is refused, naming the file, key and value):
        demo_id (int), trial (int, optional, default 0), split ("train" | "valid" | "test", required),
        skill (str, optional), demo (DemoSpec dict, optional), base_frame (str, the same for every episode),
        bowl_in_base: 4x4 row-major pose of the bowl frame in the base frame (bowl frame = world axes, origin
                      at the lowest point of the bowl),
        free_motion_s: [t0, t1] a window (stream clock) without contact, whose mean wrench is the bias,
        start_s (optional): time of control step 0 (default: the first demo.csv time),
        tip_offset_m (optional, default [0,0,0]): tool-tip position in the EE frame, if O_T_EE is not the tip;
                      the stiffness frame K is assumed to coincide with the EE frame,
        nominal_rotation (optional): 3x3 row-major base-frame rotation of the "tool pointing straight down"
                      pose (default diag(1, -1, -1), Franka's usual downward flange),
        wrench_frame (optional): "base" (default) for O_F_ext_hat_K, "K" for K_F_ext_hat_K,
        proposal, round (optional): copied to the trajectory, so observations find the proposals they ran,
        sim_failure (optional): why a dcm-sim-logs trial diverged; the trial is imported as failed.

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
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.console import print_error, quiet_libraries
from dcm.data.log_episode import (
    NOMINAL_DOWN,
    EpisodeStreams,
    LogFormatError,
    Stream,
    clean_stream,
    load_meta,
    process_episode,
)
from dcm.data.rosbag_logs import add_topic_arguments, topics_from_arguments
from dcm.data.schema import DatasetError, write_dataset

__all__ = ["NOMINAL_DOWN", "LogFormatError", "import_logs", "main"]
STREAM_COLUMNS = {"pose": 16, "wrench": 6, "stiffness": 6, "demo": 12, "attractor": 6, "equilibrium": 16}


# ----------------------------------------------------------------------------------------------- reading
def read_stream(episode: Path, name: str, required: bool = True) -> Stream | None:
    """One ``<name>.csv`` / ``<name>.npz`` stream, sorted by time, repeated timestamps dropped."""
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
    return clean_stream(t, values, str(where), n_columns)


def read_folder_episode(episode: Path, meta: dict[str, Any], meta_where: str) -> EpisodeStreams:
    """The streams of a CSV/npz episode folder."""
    return EpisodeStreams(
        name=episode.name, meta=meta, meta_where=meta_where,
        pose=read_stream(episode, "pose"), wrench=read_stream(episode, "wrench"),
        stiffness=read_stream(episode, "stiffness"), demo=read_stream(episode, "demo"),
        equilibrium=read_stream(episode, "equilibrium", required=False),
        attractor=read_stream(episode, "attractor", required=False))


def read_episode(episode: Path, topics: dict[str, str | None] | None = None) -> EpisodeStreams:
    """An episode directory's streams, from its ROS bag when it holds one, else from its CSV/npz files."""
    from dcm.data.rosbag_logs import find_bag, read_bag_episode

    meta, meta_where = load_meta(episode)
    bag = find_bag(episode)
    if bag is None:
        return read_folder_episode(episode, meta, meta_where)
    if (episode / "pose.csv").exists() or (episode / "pose.npz").exists():
        raise LogFormatError(f"{episode}: holds both a pose stream file and the bag {bag.name}; keep one source")
    demo = read_stream(episode, "demo")
    return read_bag_episode(bag, episode.name, meta, meta_where, demo, topics)


def import_episode(episode: Path, control_hz: float, horizon: int | None, lowpass_hz: float, lowpass_order: int,
                   contact_threshold_N: float, topics: dict[str, str | None] | None = None) -> dict[str, Any]:
    """One episode directory -> one trajectory dict for ``write_dataset``."""
    return process_episode(read_episode(episode, topics), control_hz, horizon, lowpass_hz, lowpass_order,
                           contact_threshold_N)


def import_logs(log_dir: str | Path, out: str | Path, control_hz: float = 20.0, horizon: int | None = None,
                lowpass_hz: float = 5.0, lowpass_order: int = 2, contact_threshold_N: float = 1.0,
                overwrite: bool = False, topics: dict[str, str | None] | None = None) -> int:
    """Import every episode directory of ``log_dir`` into one dataset file; returns the trajectory count.

    ``topics`` overrides the bag topics (keys of :data:`dcm.data.rosbag_logs.DEFAULT_TOPICS`); CSV episodes
    ignore it.

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
        traj = import_episode(episode, control_hz, horizon, lowpass_hz, lowpass_order, contact_threshold_N, topics)
        horizon = traj.pop("horizon")  # the first episode fixes H for the file
        trajectories.append(traj)
    frames = {t["base_frame"] for t in trajectories}
    if len(frames) != 1:
        raise LogFormatError(f"{log_dir}: episodes use different base frames {sorted(frames)}")
    masks: dict[str, list[str]] = {"train": [], "valid": [], "test": []}
    for index, traj in enumerate(trajectories):
        traj["name"] = f"traj_{index:06d}"
        masks[traj["split"]].append(traj["name"])  # load_meta admits only these splits
    attrs = {
        "control_hz": float(control_hz), "embodiment": "franka_real", "domain": {"name": "real"},
        "dataset": "real", "source": str(log_dir.resolve()),
        "import_lowpass": "butterworth, zero-phase (sosfiltfilt) on the wrench at its own rate, before resampling",
        "import_lowpass_hz": float(lowpass_hz), "import_lowpass_order": int(lowpass_order),
        "import_bias": "mean wrench over each episode's free_motion_s window, subtracted",
        "import_resampling": "linear interpolation onto t_k = start_s + k / control_hz; stiffness zero-order hold",
        "import_contact_threshold_N": float(contact_threshold_N),
        "config": {"log_dir": str(log_dir), "control_hz": control_hz, "horizon": horizon, "topics": topics,
                   "lowpass_hz": lowpass_hz, "lowpass_order": lowpass_order,
                   "contact_threshold_N": contact_threshold_N},
    }
    write_dataset(out, trajectories, masks, attrs)
    return len(trajectories)


def _option_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the numeric options, or None: argparse takes any int or float, nan and inf too, and a
    horizon or rate <= 0 would fail deep in processing with a traceback instead of naming the option."""
    if args.horizon is not None and args.horizon < 1:
        return f"--horizon {args.horizon}: must be at least 1 (or left out: the first episode's length)"
    if args.lowpass_order < 1:
        return f"--lowpass-order {args.lowpass_order}: must be at least 1"
    if not (math.isfinite(args.control_hz) and args.control_hz > 0):
        return f"--control-hz {args.control_hz}: must be a finite number > 0"
    for option, value in (("--lowpass-hz", args.lowpass_hz), ("--contact-threshold-N", args.contact_threshold_N)):
        if not (math.isfinite(value) and value >= 0):
            return f"{option} {value}: must be a finite number >= 0"
    return None


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
    add_topic_arguments(parser)
    args = parser.parse_args(argv)
    quiet_libraries()
    problem = _option_problem(args)
    if problem:
        return print_error(problem)
    if args.out.exists() and not args.overwrite:
        return print_error(f"{args.out} exists; pass --overwrite to replace it, or choose another --out")
    try:
        topics = topics_from_arguments(args)
        n = import_logs(args.log_dir, args.out, args.control_hz, args.horizon, args.lowpass_hz, args.lowpass_order,
                        args.contact_threshold_N, overwrite=args.overwrite, topics=topics)
    except (LogFormatError, DatasetError) as err:
        return print_error(err)
    print(f"wrote {args.out}: {n} trajectories")
    return 0


if __name__ == "__main__":
    sys.exit(main())
