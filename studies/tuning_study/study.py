"""Multi-seed tuning study of one skill: every tuner and control, I_H against one fixed reference point.

    python -m studies.tuning_study.study ckpt=<dcm.ckpt> [baseline_ckpt=<ckpt>] [reference_json=<json>] [seeds=16]
        [k=v ...]

Why: one tuning run per method is a single draw, too few to tell two tuners apart. The study repeats every
method over S seeds on the same skill and asks whether the DCM's hypervolume differs from each control's,
paired by seed (Wilcoxon signed-rank). Per seed s it runs, each in its own folder
``runs/<tuner>/seed_<s>`` of the study folder:

* ``dcm`` (and ``baseline``, ``reference`` when given): robot-free tuning with :func:`dcm.tuning.run.tune`,
  ``robot_free.n_validate`` simulator validations; the DCM's run also holds the robot-based search of
  ``max(robot_based.n_trials)`` trials, reported as ``robot_based_<N>`` for each N by truncation;
* ``prior``: the model-free control of :mod:`studies.tuning_study.study_controls`;
* ``robot_based_<N>``, only with ``validation_rollouts`` > 1: the front of the first N robot-based trials,
  re-run like a robot-free tuner's solutions (:func:`studies.tuning_study.study_controls.run_robot_based_picks`);
  for N = all trials these are the DCM run's own ``robot_based.solutions``, taken rather than rolled out again.

A finished run (``results.json`` present) is never redone; an unfinished one resumes from its trial logs; the
folder remembers its settings and, once a run has finished, refuses other settings. Then it writes
``study.json`` (reference point, I_H per tuner and seed, medians, IQRs, tests, times), ``study.md``,
``study.png`` and ``cost.md``. The settings are ``studies/conf/study.yaml``; each run's tune settings are
composed from the product's ``conf/tune.yaml``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dcm.tuning.pareto import hypervolume
from dcm.tuning.setup import ROBOT_LOG
from studies.tuning_study.study_config import (
    Tuner,
    check_resume,
    check_study,
    plain,
    robot_trial_counts,
    seeds,
    tune_config,
    tuners,
)
from studies.tuning_study.study_controls import (
    demo_reference_point,
    run_prior,
    run_robot_based_picks,
    setup_skill,
    write_json,
)
from studies.tuning_study.study_report import box_plot, cost_table, label, study_table
from studies.tuning_study.study_stats import aggregate, landscape

RESULTS = "results.json"
TIMING = "timing.json"  # wall time of the invocation that finished a run (for the study's time estimate)


def run_dir(out_dir: Path, tuner: str, seed: int) -> Path:
    return out_dir / "runs" / tuner / f"seed_{seed:03d}"


def _validated(results: dict[str, Any]) -> np.ndarray:
    """(n, 2) validated (L_task, L_comp) of a tune or prior results.json; NaN rows for failed rollouts."""
    solutions = results["robot_free"]["solutions"] if "robot_free" in results else results["solutions"]
    rows = [[s["validated"]["L_task_N"], s["validated"]["L_comp_kNpm"]] for s in solutions]
    return np.asarray(rows, dtype=np.float64).reshape(-1, 2)


def _hv(points: np.ndarray, reference: np.ndarray) -> float:
    return hypervolume(points[np.isfinite(points).all(axis=1)], reference)


def study_reference(cfg: Any, dcm: Tuner, out_dir: Path) -> dict[str, Any]:
    """The study's one reference point: given, or from the demo-stiffness rollout; cached in the folder."""
    path = out_dir / "reference_point.json"
    if path.is_file():
        return json.loads(path.read_text())
    value = plain(cfg.reference_point.value)
    if value is not None:
        if not isinstance(value, list) or len(value) != 2 or not all(isinstance(v, (int, float)) for v in value):
            raise ValueError(f"reference_point.value = {value!r} must be null or [L_task_N, L_comp_kNpm]")
        reference = {"L_task_N": float(value[0]), "L_comp_kNpm": float(value[1]), "source": "reference_point.value"}
    else:
        ref = cfg.reference_point
        setup = setup_skill(tune_config(cfg, dcm, int(ref.seed), None, out_dir))
        reference = {**demo_reference_point(setup, float(ref.task_factor), float(ref.comp_factor),
                                            int(cfg.validation_rollouts)),
                     "seed": int(ref.seed)}
    write_json(path, reference)
    return reference


def _run_tuner(cfg: Any, tuner: Tuner, seed: int, reference: list[float], folder: Path) -> None:
    from dcm.tuning.run import tune

    start = time.perf_counter()
    tune(tune_config(cfg, tuner, seed, reference, folder), folder)
    write_json(folder / TIMING, {"wall_seconds": time.perf_counter() - start})


def _run_prior(cfg: Any, dcm: Tuner, seed: int, folder: Path) -> None:
    start = time.perf_counter()
    run_prior(setup_skill(tune_config(cfg, dcm, seed, None, folder)), int(cfg.prior.n_levels), folder,
              int(cfg.validation_rollouts))
    write_json(folder / TIMING, {"wall_seconds": time.perf_counter() - start})


def _run_robot_based_picks(cfg: Any, dcm: Tuner, seed: int, counts: list[int], out_dir: Path) -> None:
    """Judge the seed's robot-based search, truncated to each N, by the expected loss of its front's picks."""
    from dcm.tuning.optimize import TrialLog

    folders = {n: run_dir(out_dir, f"robot_based_{n}", seed) for n in counts}
    if all((folder / RESULTS).is_file() for folder in folders.values()):
        return
    dcm_dir = run_dir(out_dir, dcm.name, seed)
    params, objectives = TrialLog.load(dcm_dir / ROBOT_LOG).arrays()
    tuned = json.loads((dcm_dir / RESULTS).read_text())["robot_based"]  # its own validation of all its trials
    setup = setup_skill(tune_config(cfg, dcm, seed, None, folders[counts[0]]))
    for n, folder in folders.items():
        if not (folder / RESULTS).is_file():
            run_robot_based_picks(setup, params[:n], objectives[:n], int(cfg.robot_free.n_validate),
                                  int(cfg.validation_rollouts), folder, tuned)


def _check_runs(cfg: Any, tuner_list: list[Tuner], seed: int, reference: list[float] | None, out_dir: Path) -> None:
    """Every tuner's tune settings, checked before the first hour of work rather than at its run."""
    from dcm.tuning.checks import check_config

    for tuner in tuner_list:
        try:
            check_config(tune_config(cfg, tuner, seed, reference, run_dir(out_dir, tuner.name, seed)))
        except ValueError as err:
            raise type(err)(f"tuner {tuner.name}: {' '.join(str(err).split())}") from None


def run_study(cfg: Any, out_dir: Path) -> dict[str, Any]:
    """Run (or resume) the study of ``studies/conf/study.yaml`` in ``out_dir``; returns what ``study.json`` holds.

    ``threads`` sets torch's intra-op threads for the duration (restored afterwards): the study's small batches
    gain little from more threads and lose much when they compete for shared cores.
    """
    import torch

    check_study(cfg)
    threads = torch.get_num_threads()
    if cfg.get("threads"):
        torch.set_num_threads(int(cfg.threads))
    try:
        return _run_study(cfg, out_dir)
    finally:
        torch.set_num_threads(threads)


def _run_study(cfg: Any, out_dir: Path) -> dict[str, Any]:
    tuner_list, seed_list, counts = tuners(cfg), seeds(cfg), robot_trial_counts(cfg)
    dcm = tuner_list[0]
    _check_runs(cfg, tuner_list, seed_list[0], None, out_dir)
    check_resume(cfg, out_dir)
    reference_info = study_reference(cfg, dcm, out_dir)
    reference = np.array([reference_info["L_task_N"], reference_info["L_comp_kNpm"]])

    for i, seed in enumerate(seed_list, start=1):
        for name in [t.name for t in tuner_list] + ["prior"]:
            folder = run_dir(out_dir, name, seed)
            if (folder / RESULTS).is_file():
                continue
            print(f"study: seed {seed} ({i}/{len(seed_list)}), {label(name)} -> {folder}", file=sys.stderr, flush=True)
            if name == "prior":
                _run_prior(cfg, dcm, seed, folder)
            else:
                _run_tuner(cfg, next(t for t in tuner_list if t.name == name), seed, reference.tolist(), folder)
        if int(cfg.validation_rollouts) > 1:
            _run_robot_based_picks(cfg, dcm, seed, counts, out_dir)

    report = collect(cfg, out_dir, tuner_list, seed_list, counts, reference)
    report["reference_point"] = reference_info
    write_outputs(cfg, out_dir, report, len(seed_list))
    return report


def collect(cfg: Any, out_dir: Path, tuner_list: list[Tuner], seed_list: list[int], counts: list[int],
            reference: np.ndarray) -> dict[str, Any]:
    """I_H of every tuner and seed against ``reference``, the statistics, and the measured times."""
    from dcm.tuning.optimize import TrialLog

    names = [t.name for t in tuner_list] + ["prior"] + [f"robot_based_{n}" for n in counts]
    values: dict[str, list[float]] = {name: [] for name in names}
    times: dict[str, list[dict[str, float]]] = {name: [] for name in names}
    seed_seconds = []
    robot_stiffness, robot_objectives = [], []
    for seed in seed_list:
        wall = 0.0
        for name in [t.name for t in tuner_list] + ["prior"]:
            folder = run_dir(out_dir, name, seed)
            results = json.loads((folder / RESULTS).read_text())
            values[name].append(_hv(_validated(results), reference))
            if (folder / TIMING).is_file():
                wall += json.loads((folder / TIMING).read_text())["wall_seconds"]
            if name == "prior":
                times[name].append({"opt_seconds": 0.0, "validation_seconds": results["validation_seconds"]})
            else:
                free = results["robot_free"]
                times[name].append({"opt_seconds": free["seconds"], "model_seconds": free["seconds_model"],
                                    "validation_seconds": free["validation_seconds"]})
        robot_folder = run_dir(out_dir, tuner_list[0].name, seed)
        trial_stiffness, trial_objectives = TrialLog.load(robot_folder / ROBOT_LOG).arrays()
        robot_stiffness.append(trial_stiffness)
        robot_objectives.append(trial_objectives)
        robot_seconds = json.loads((robot_folder / RESULTS).read_text())["robot_based"]["seconds"]
        for n in counts:
            if int(cfg.validation_rollouts) > 1:
                picks = json.loads((run_dir(out_dir, f"robot_based_{n}", seed) / RESULTS).read_text())
                values[f"robot_based_{n}"].append(_hv(_validated(picks), reference))
            else:
                values[f"robot_based_{n}"].append(_hv(trial_objectives[:n], reference))
            times[f"robot_based_{n}"].append({"opt_seconds": robot_seconds * n / len(trial_objectives),
                                              "validation_seconds": 0.0})
        seed_seconds.append(wall)

    stats = aggregate(values, subject=tuner_list[0].name, alpha=float(cfg.alpha))
    n_validate, n_trials = int(cfg.robot_free.n_validate), int(cfg.robot_free.n_trials)
    costs = {}
    for name in names:
        medians = {key: float(np.median([t[key] for t in times[name]]))
                   for key in ("opt_seconds", "model_seconds", "validation_seconds") if key in times[name][0]}
        if name.startswith("robot_based_"):
            shape = {"opt_trials": int(name.rsplit("_", 1)[1]), "opt_virtual": False, "validation_trials": 0}
        elif name == "prior":
            shape = {"opt_trials": 0, "opt_virtual": False, "validation_trials": int(cfg.prior.n_levels)}
        else:
            shape = {"opt_trials": n_trials, "opt_virtual": True, "validation_trials": n_validate}
        costs[name] = {**shape, **medians}
    measured = [s for s in seed_seconds if s > 0]
    per_seed = float(np.median(measured)) if measured else None
    return {
        "seeds": seed_list,
        "tuners": names,
        "robot_trials": {name: c["validation_trials"] + (0 if c["opt_virtual"] else c["opt_trials"])
                         for name, c in costs.items()},
        "hypervolume": values,
        "statistics": stats,
        # over every robot-based trial of every seed: does stiffness move this skill's L_task at all?
        "landscape": landscape(np.concatenate(robot_stiffness), np.concatenate(robot_objectives)[:, 0]),
        "costs": costs,
        "wall_seconds_per_seed": per_seed,  # all tuners of one seed, median over the seeds run here
        "estimated_seconds": None if per_seed is None else {str(s): per_seed * s for s in (len(seed_list), 16)},
    }


def write_outputs(cfg: Any, out_dir: Path, report: dict[str, Any], n_seeds: int) -> None:
    stats, reference = report["statistics"], report["reference_point"]
    write_json(out_dir / "study.json", report)
    table = study_table(stats, report["robot_trials"], reference, n_seeds, report["landscape"],
                        int(cfg.validation_rollouts))
    (out_dir / "study.md").write_text(table)
    (out_dir / "cost.md").write_text(cost_table(report["costs"], float(cfg.robot_minutes_per_trial)))
    skill = Path(cfg.demo_file).stem if cfg.demo_file else cfg.demo.get("name", "skill")
    box_plot(out_dir / "study.png", report["hypervolume"], stats,
             f"{skill} ({cfg.embodiment}), {n_seeds} seeds\n"
             f"{label(stats['subject'])} vs each control: Wilcoxon signed-rank, * p<0.05, ** p<0.01, *** p<0.001")


def _hydra_main() -> None:
    import hydra

    from studies.tuning_study.study_config import STUDY_CONF_DIR, with_product_conf

    sys.argv[1:] = with_product_conf(sys.argv[1:])

    @hydra.main(config_path=str(STUDY_CONF_DIR), config_name="study")
    def main(cfg: Any) -> None:
        try:
            report = run_study(cfg, Path(cfg.out_dir))
        except (ValueError, OSError, RuntimeError) as err:
            raise SystemExit(f"error: {' '.join(str(err).split())}") from None
        print((Path(cfg.out_dir) / "study.md").read_text())
        print((Path(cfg.out_dir) / "cost.md").read_text())
        if report["wall_seconds_per_seed"] is not None:
            print(f"wall time per seed (all tuners): {report['wall_seconds_per_seed']:.0f} s; 16 seeds: about "
                  f"{report['estimated_seconds']['16'] / 60:.0f} min")
        print(f"study: {cfg.out_dir}")

    main()


if __name__ == "__main__":
    _hydra_main()
