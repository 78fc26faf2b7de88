"""Play the robot: run stiffness schedules in the simulator and write the trials as robot logs.

    python -m dcm.data.sim_logs --demo wavelike --trials 5 --format csv --out logs/ [--seed 0]
    python -m dcm.data.sim_logs --schedules <run_dir>/proposals/round_1 --format ros1 --out logs/round_1
    (console script: dcm-sim-logs)

The logs are what ``dcm-import-logs`` reads (docs/robot_logs.md): one folder per trial holding ``meta.json``,
``demo.csv`` and either the CSV streams (``--format csv``) or one bag (``ros1``: ``trial.bag``; ``ros2``: a
``trial/`` bag directory, ``--storage sqlite3|mcap``), with a Franka's conventions (robot base frame with the
bowl 0.5 m ahead and turned 90°, column-major ``O_T_EE``, ``O_F_ext_hat_K`` about the end effector, a 1 s
free-motion window, F/T bias and noise, state timestamps with jitter), so the import exercises every
conversion. ``--clean`` drops bias, noise and jitter: the import then returns the simulated trial itself.

Schedules: ``--trials N`` draws N random three-phase schedules (seeded); ``--schedules DIR`` runs exactly the
proposals of a tuner's round (``round.yaml`` + one CSV per proposal, per-step K columns) on the round's demo,
embodiment and control rate, one trial per proposal, named by its id.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import os
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.console import print_error
from dcm.data.log_writer import RobotConventions, TrialSignals, robot_streams, write_bag, write_csv_episode, write_meta
from dcm.shipped import SHIPPED_ROOT, shipped_path

DEMOS = SHIPPED_ROOT / "data" / "demos"  # the demos --demo names
FREE_MOTION_S = 1.0  # the robot stands still before the trial: the importer's bias window
AFTER_S = 0.3  # logging goes on briefly after the last control step
PROPOSAL_K = ["Kx_Npm", "Ky_Npm", "Kz_Npm", "Krx_Nmprad", "Kry_Nmprad", "Krz_Nmprad"]
FORMATS = ("csv", "ros1", "ros2")
STORAGES = ("sqlite3", "mcap")  # a ROS 2 bag's; a ROS 1 bag has one format
EVAL_FRACTION = 0.2  # of random trials, the share each of valid and test gets (at least one each)
# Trials of one skill a split needs for every ranking metric (dcm.models.metrics.REGRET_TRIALS; kept here so
# that this command loads without torch)
RANKING_TRIALS = 4


class SimLogsError(ValueError):
    """Bad input to the sim-logs command: names the file, field or value."""


# ----------------------------------------------------------------------------------------------- trials
def trial_signals(demo: Any, trial: Any, control_hz: float, meta: dict[str, Any]) -> TrialSignals:
    """A simulated ``Trial`` of ``demo`` as log keyframes: still at the start pose for ``FREE_MOTION_S``, then
    control step k's state at ``FREE_MOTION_S + k / control_hz``, held for ``AFTER_S`` at the end."""
    dt = 1.0 / control_hz
    horizon = demo.horizon
    steps_t = FREE_MOTION_S + np.arange(horizon) * dt
    start_pose = np.asarray(demo.start_pose if demo.start_pose is not None else demo.spec.start_pose(control_hz))
    obs_t = np.concatenate([[0.0, FREE_MOTION_S - dt], steps_t, [steps_t[-1] + AFTER_S]])
    pose = np.vstack([start_pose, start_pose, trial.x_obs, trial.x_obs[-1]])
    wrench = np.vstack([np.zeros((2, 6)), trial.force_obs, trial.force_obs[-1]])
    demo_rows = np.column_stack([demo.x_demo, demo.force_demo])
    meta = dict(meta, free_motion_s=[0.0, FREE_MOTION_S - 0.1], start_s=FREE_MOTION_S,
                demo=demo.spec.to_dict(), skill=demo.spec.name or demo.spec.family)
    return TrialSignals(obs_t_s=obs_t, pose=pose, wrench=wrench, command_t_s=steps_t,
                        stiffness=np.asarray(trial.stiffness, np.float64), attractor=np.asarray(trial.x_attr),
                        demo_t_s=steps_t, demo=demo_rows, meta=meta)


def random_schedules(horizon: int, n: int, rng: np.random.Generator, phases: int = 3) -> list[np.ndarray]:
    """n piecewise-constant schedules (H, 6): per phase and axis a translational stiffness in 200..1500 N/m."""
    bounds = np.linspace(0, horizon, phases + 1).round().astype(int)
    schedules = []
    for _ in range(n):
        schedule = np.full((horizon, 6), 20.0)
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            schedule[lo:hi, :3] = rng.uniform(200.0, 1500.0, size=3).round()
        schedules.append(schedule)
    return schedules


def load_demo_spec(name: str, duration_s: float | None) -> Any:
    """``--demo``: a file, or a name in data/demos (wavelike, spiral, ...)."""
    from dcm.sim.demos import DemoSpec, DemoSpecError

    path = Path(shipped_path(name)) if name.endswith((".yaml", ".yml")) else DEMOS / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in DEMOS.glob("*.yaml"))
        raise SimLogsError(f"--demo {name}: no file {path}; known demos: {', '.join(known)}")
    try:
        spec = DemoSpec.load(path)
        if duration_s is not None:
            data = spec.to_dict()
            data["duration_s"] = float(duration_s)
            data["approach_s"] = min(float(data.get("approach_s", 1.0)), float(duration_s) / 4)
            spec = DemoSpec.from_dict(data, where=f"{path} with --duration-s {duration_s}")
    except DemoSpecError as err:
        raise SimLogsError(str(err)) from None
    return spec


def read_proposals(round_dir: Path) -> tuple[dict[str, Any], list[tuple[str, np.ndarray, np.ndarray]]]:
    """A tuner's round: round.yaml and, per proposal, (id, stiffness (H, 6), attractor (H, 6) bowl frame)."""
    import yaml

    round_path = round_dir / "round.yaml"
    if not round_path.is_file():
        raise SimLogsError(f"--schedules {round_dir}: no round.yaml")
    try:
        spec = yaml.safe_load(round_path.read_text())
    except yaml.YAMLError as err:
        raise SimLogsError(f"{round_path}: invalid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(spec, dict):
        raise SimLogsError(f"{round_path}: expected a map, got {type(spec).__name__}")
    for key in ("round", "control_hz", "demo", "embodiment", "proposals"):
        if key not in spec:
            raise SimLogsError(f"{round_path}: missing key {key!r}")
    if spec.get("frame", "bowl") != "bowl":
        raise SimLogsError(f"{round_path}: frame {spec['frame']!r}; the schedules must be in the bowl frame")
    if spec.get("stiffness_frame", "world") != "world":  # a Franka log records a diagonal K, as the importer reads it
        raise SimLogsError(f"{round_path}: stiffness_frame {spec['stiffness_frame']!r}; the simulated logs record a "
                           "diagonal K on bowl axes, so only a stiffness.frame=world round can be played")
    if not isinstance(spec["proposals"], list) or not spec["proposals"]:
        raise SimLogsError(f"{round_path}: proposals must be a non-empty list")
    proposals = []
    for index, entry in enumerate(spec["proposals"]):
        if not isinstance(entry, dict) or "id" not in entry or "file" not in entry:
            raise SimLogsError(f"{round_path}: proposals[{index}] needs keys 'id' and 'file'")
        path = round_dir / str(entry["file"])
        if not path.is_file():
            raise SimLogsError(f"{round_path}: proposals[{index}] names {path}, which does not exist")
        with path.open() as handle:
            rows = list(csv.reader(handle))
        if not rows:
            raise SimLogsError(f"{path}: empty file")
        header = rows[0]
        missing = [c for c in ["t_s", "x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"] + PROPOSAL_K if c not in header]
        if missing:
            raise SimLogsError(f"{path}: missing column(s) {', '.join(missing)}")
        try:
            table = np.array([[float(v) for v in row] for row in rows[1:] if row], dtype=np.float64)
        except ValueError as err:
            raise SimLogsError(f"{path}: non-numeric value ({err})") from None
        if table.ndim != 2 or table.shape[1] != len(header) or not np.all(np.isfinite(table)):
            raise SimLogsError(f"{path}: every row needs {len(header)} finite numbers")
        column = {name: i for i, name in enumerate(header)}
        stiffness = table[:, [column[c] for c in PROPOSAL_K]]
        attractor = table[:, [column[c] for c in ["x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"]]]
        proposals.append((str(entry["id"]), stiffness, attractor))
    return spec, proposals


# ----------------------------------------------------------------------------------------------- writing
def write_episode(episode: Path, signals: TrialSignals, fmt: str, conventions: RobotConventions,
                  rng: np.random.Generator, storage: str = "sqlite3") -> None:
    """One trial as one episode folder of ``fmt`` (csv, ros1, ros2)."""
    streams, meta = robot_streams(signals, conventions, rng)
    if fmt == "csv":
        write_csv_episode(episode, streams, meta)
        return
    write_meta(episode, streams, meta)
    bag = episode / ("trial.bag" if fmt == "ros1" else "trial")
    write_bag(bag, streams, conventions.base_frame, ros2=fmt == "ros2", storage=storage)


def simulate_logs(out: Path, fmt: str, demo_name: str = "wavelike", trials: int = 5, seed: int = 0,
                  embodiment: str = "tool", duration_s: float | None = None, schedules: Path | None = None,
                  clean: bool = False, storage: str | None = None, split: str = "auto", progress: bool = True) -> int:
    """Simulate and write the trials; returns how many. ``out`` must not hold anything yet: the folder appears
    complete or not at all. ``split="auto"``: every proposal of a round is ``train``; of N >= 3 random trials
    the last fifth (at least one) is ``test`` and the fifth before ``valid`` (fine-tuning and evaluation need
    both), the rest train."""
    from dcm.sim.demos import DemoSpec, DemoSpecError
    from dcm.sim.rollout import Simulator, SimulatorError

    if fmt not in FORMATS:
        raise SimLogsError(f"--format {fmt}: use one of {', '.join(FORMATS)}")
    if storage is not None and (storage not in STORAGES or fmt != "ros2"):
        raise SimLogsError(f"--storage {storage}: the storage of a ROS 2 bag ({', '.join(STORAGES)}); --format {fmt} "
                           "has none: drop --storage or use --format ros2")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SimLogsError(f"--out {out} exists and is not empty; choose another folder")
    rng = np.random.default_rng(seed)
    round_meta: dict[str, Any] = {}
    try:
        if schedules is not None:
            spec, proposals = read_proposals(schedules)
            demo_spec = DemoSpec.from_dict(spec["demo"], where=f"{schedules / 'round.yaml'} demo")
            sim = Simulator(str(spec["embodiment"]), control_hz=float(spec["control_hz"]), seed=seed)
            round_meta = {"round": int(spec["round"])}
        else:
            demo_spec = load_demo_spec(demo_name, duration_s)
            sim = Simulator(embodiment, seed=seed)
            proposals = None
        demo = sim.record_demo(demo_spec)
    except (DemoSpecError, SimulatorError) as err:
        raise SimLogsError(str(err)) from None
    if proposals is None:
        if trials < 1:
            raise SimLogsError(f"--trials {trials}: need at least 1")
        runs = [(f"episode_{i:03d}", schedule, None)
                for i, schedule in enumerate(random_schedules(demo.horizon, trials, rng))]
    else:
        runs = []
        for proposal_id, stiffness, attractor in proposals:
            where = f"{schedules / proposal_id}"
            if stiffness.shape[0] != demo.horizon:
                raise SimLogsError(f"{where}: {stiffness.shape[0]} rows, the round's demo has {demo.horizon} "
                                   f"control steps at {sim.control_hz:g} Hz")
            expected = sim.attractor(demo, stiffness)
            gap = np.abs(expected[:, :3] - attractor[:, :3]).max(axis=1)
            if gap.max() > 1e-3:
                step = int(np.argmax(gap > 1e-3))
                raise SimLogsError(f"{where}: attractor at step {step} is {gap[step] * 1000:.1f} mm from the one the "
                                   "simulator computes for this demo and K; was the round written for another demo?")
            runs.append((proposal_id, stiffness, proposal_id))
    conventions = RobotConventions.clean() if clean else RobotConventions()
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    started = time.monotonic()
    for index, (name, stiffness, proposal_id) in enumerate(runs):
        try:
            trial = sim.rollout(demo, stiffness)
        except (SimulatorError, ValueError) as err:
            shutil.rmtree(partial, ignore_errors=True)
            raise SimLogsError(f"{name}: {err}") from None
        meta = dict(round_meta, demo_id=0, trial=index, split=_split(split, index, len(runs), proposals is None))
        if proposal_id is not None:
            meta["proposal"] = proposal_id
        if trial.failed:
            meta["sim_failure"] = trial.failure_reason
        write_episode(partial / name, trial_signals(demo, trial, sim.control_hz, meta), fmt, conventions, rng,
                      storage or STORAGES[0])
        if progress:
            elapsed = time.monotonic() - started
            eta = elapsed / (index + 1) * (len(runs) - index - 1)
            print(f"trial {index + 1}/{len(runs)} {name}: L_task {trial.L_task:.3f} N "
                  f"({elapsed:.1f} s, ETA {eta:.1f} s)", file=sys.stderr)
    if out.exists():
        out.rmdir()
    os.replace(partial, out)
    return len(runs)


def eval_trials(n: int) -> int:
    """How many of ``n`` random trials each of the valid and test splits gets under ``--split auto``."""
    return max(1, round(EVAL_FRACTION * n)) if n >= 3 else 0


def _split(split: str, index: int, n: int, random_trials: bool) -> str:
    if split != "auto":
        return split
    k = eval_trials(n) if random_trials else 0
    if index >= n - k:
        return "test"
    return "valid" if index >= n - 2 * k else "train"


def split_note(n: int) -> str | None:
    """What ``--split auto`` of ``n`` random trials leaves undefined, and the count that defines it."""
    k = eval_trials(n)
    if k >= RANKING_TRIALS:
        return None
    enough = next(m for m in itertools.count(n) if eval_trials(m) >= RANKING_TRIALS)
    return (f"note: valid and test get {k} trial(s) each; the ranking metrics (R within skill, top-3 regret) need "
            f">= {RANKING_TRIALS} trials of a skill per split: --trials {enough} gives {RANKING_TRIALS} each")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dcm.data.sim_logs",
                                     description="Run schedules in the simulator and write the trials as robot logs.")
    parser.add_argument("--out", type=Path, required=True, help="a new (or empty) folder")
    parser.add_argument("--format", choices=FORMATS, default="csv")
    parser.add_argument("--storage", choices=STORAGES, default=None, help="ROS 2 bag storage (default sqlite3)")
    parser.add_argument("--demo", default="wavelike", help="a name in data/demos or a DemoSpec YAML file")
    parser.add_argument("--duration-s", type=float, default=None, help="shorten (or lengthen) the demo")
    parser.add_argument("--trials", type=int, default=5, help="random three-phase schedules to run")
    parser.add_argument("--schedules", type=Path, default=None,
                        help="a tuner's proposals/round_<r> folder: run exactly its proposals instead")
    parser.add_argument("--embodiment", choices=("tool", "panda"), default="tool")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--split", choices=("auto", "train", "valid", "test"), default="auto",
                        help="auto: of N >= 3 random trials the last fifth is test and the fifth before valid; "
                             "proposals train")
    parser.add_argument("--clean", action="store_true", help="no F/T bias, noise or timestamp jitter")
    args = parser.parse_args(argv)
    given = [flag for flag, value, default in (("--demo", args.demo, "wavelike"), ("--trials", args.trials, 5),
                                               ("--duration-s", args.duration_s, None),
                                               ("--embodiment", args.embodiment, "tool")) if value != default]
    if args.seed < 0:
        return print_error(f"--seed {args.seed}: must be an integer >= 0")
    if args.schedules is not None and given:
        return print_error("--schedules takes the demo, embodiment and schedules from round.yaml; "
                           f"drop {', '.join(given)}")
    try:
        n = simulate_logs(args.out, args.format, args.demo, args.trials, args.seed, args.embodiment,
                          args.duration_s, args.schedules, args.clean, args.storage, args.split)
    except SimLogsError as err:
        return print_error(err)
    print(f"wrote {n} {args.format} episode(s) to {args.out}; import with: dcm-import-logs {args.out} --out <file>.h5")
    if args.schedules is None and args.split == "auto" and (note := split_note(n)):
        print(note, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
