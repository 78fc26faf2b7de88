"""Compare tuning runs by hypervolume against ONE shared reference point.

    python -m studies.tuning_study.compare outputs/tune/<run_a> outputs/tune/<run_b> [--robot-trials 5 20 50]
        [--reference-point L_TASK_N L_COMP_KNPM] [--out cmp.json]

Runs of one skill store the same reference point (set by the skill, not by the run), and this command
scores on it; runs that stored different points (e.g. written before the point was the skill's, or given
their own ``reference_point``) are scored on one point taken over the pool of every run's validated
robot-free solutions and robot-based trials, or on the one given. It reports I_H for each run's robot-free
solutions and for the first N robot-based trials of the first run
(a seeded search's first N trials are exactly what an N-trial run would have done). Runs must have tuned
the same skill (demo, simulator, stiffness space, seed: ``results.json``'s ``skill``); others are refused.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dcm.tuning.optimize import TrialLog
from dcm.tuning.pareto import hypervolume, reference_point


def _validated(run: Path) -> np.ndarray:
    results = json.loads((run / "results.json").read_text())
    rows = [[s["validated"]["L_task_N"], s["validated"]["L_comp_kNpm"]] for s in results["robot_free"]["solutions"]]
    return np.asarray(rows, dtype=np.float64).reshape(-1, 2)


def _finite(points: np.ndarray) -> np.ndarray:
    return points[np.isfinite(points).all(axis=1)]


def _stored_reference(run: Path) -> tuple[float, float] | None:
    """The reference point a run stored, if it stored one."""
    point = json.loads((run / "results.json").read_text()).get("reference_point")
    return (float(point["L_task_N"]), float(point["L_comp_kNpm"])) if isinstance(point, dict) else None


def _check_same_skill(runs: Sequence[Path]) -> None:
    """Refuse runs of different skills: their hypervolumes measure different problems."""
    from dcm.tuning.optimize import fingerprint_differences

    skills = {run: json.loads((run / "results.json").read_text()).get("skill") for run in runs}
    unknown = [str(run) for run, skill in skills.items() if skill is None]
    if unknown:
        print(f"warning: {', '.join(unknown)}: results.json records no skill; "
              "cannot check that the runs tuned the same skill", file=sys.stderr)
    known = [(run, skill) for run, skill in skills.items() if skill is not None]
    for run, skill in known[1:]:
        if skill != known[0][1]:
            diffs = "; ".join(fingerprint_differences(known[0][1], skill))
            raise ValueError(f"{run} tuned another skill than {known[0][0]} ({diffs}); compare runs of one skill")


def compare(runs: Sequence[Path], robot_trials: Sequence[int], reference: Sequence[float] | None = None) -> dict:
    """Hypervolumes of every run's validated solutions and of robot-based prefixes, one reference point
    (``reference`` = (L_task_N, L_comp_kNpm), or None: the point the runs stored if they agree, else one taken
    over all the runs' points)."""
    for run in runs:
        if not (run / "results.json").is_file():
            raise FileNotFoundError(f"{run}: no results.json (is it a finished tune.py run directory?)")
    _check_same_skill(runs)
    robot_log = runs[0] / "robot_based_trials.npz"
    robot = TrialLog.load(robot_log).arrays()[1] if robot_log.is_file() else np.zeros((0, 2))
    validated = {str(run): _finite(_validated(run)) for run in runs}
    if reference is not None:
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (2,) or not np.isfinite(reference).all():
            raise ValueError(f"--reference-point needs two finite numbers (L_task_N L_comp_kNpm), got {reference}")
    elif len(stored := {_stored_reference(run) for run in runs}) == 1 and None not in stored:
        reference = np.asarray(stored.pop(), dtype=np.float64)
    else:
        reference = reference_point(*validated.values(), _finite(robot))
    report = {
        "reference_point": {"L_task_N": reference[0], "L_comp_kNpm": reference[1]},
        "robot_free": {name: hypervolume(points, reference) for name, points in validated.items()},
        "robot_based": {},
    }
    rollouts = json.loads((runs[0] / "results.json").read_text())["robot_free"].get("validation_rollouts", 1)
    if robot_trials and rollouts > 1:
        raise ValueError(f"{runs[0]} judged its solutions over {rollouts} rollouts each, but its robot-based trials "
                         "are one draw each, so their prefixes would be judged on other terms; pass --robot-trials "
                         "without values, or run python -m studies.tuning_study.study validation_rollouts=R, which "
                         "re-runs each prefix's front")
    for n in robot_trials:
        if n > len(robot):
            raise ValueError(f"{robot_log} holds {len(robot)} robot-based trials; cannot report the first {n}")
        report["robot_based"][f"N={n}"] = hypervolume(_finite(robot[:n]), reference)
    return report


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.tuning_study.compare", description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="tune.py run directories")
    parser.add_argument("--robot-trials", nargs="*", type=int, default=[5, 20, 50])
    parser.add_argument("--reference-point", nargs=2, type=float, default=None, metavar=("L_TASK_N", "L_COMP_KNPM"),
                        help="the reference point of every hypervolume (default: taken over all the runs' points)")
    parser.add_argument("--out", type=Path, default=None, help="also write the report as JSON")
    args = parser.parse_args(argv)
    try:
        report = compare(args.runs, args.robot_trials, args.reference_point)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    ref = report["reference_point"]
    print(f"reference point: L_task {ref['L_task_N']:.3f} N, L_comp {ref['L_comp_kNpm']:.3f} kN/m")
    for name, value in report["robot_free"].items():
        print(f"robot-free  {name}: I_H = {value:.4f}")
    for name, value in report["robot_based"].items():
        print(f"robot-based {name}: I_H = {value:.4f}")
    if args.out is not None:
        args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
