"""Robot-free stiffness tuning of one new skill, validated in the simulator and compared with robot-based search.

Steps (each resumable from the run directory):
0. check every setting (:func:`dcm.tuning.checks.check_config`), load the predictor and check it against the
   skill, and check that the run directory's trial logs were written by these settings (their *fingerprint*);
1. record the new skill's demo in the simulator (0 and 1: :func:`dcm.tuning.setup.prepare`, once);
2. robot-free search: ``robot_free.n_trials`` virtual trials, L_task predicted by the checkpoint (or by a
   stiffness reference JSON, ``python -m dcm.models.references fit``; ``copy_demo`` is refused: it ranks nothing);
3. validate up to ``robot_free.n_validate`` solutions spread along the predicted Pareto front in the simulator,
   each over ``validation_rollouts`` rollouts (their mean L_task: the expected loss under a per-rollout spread);
4. robot-based search: ``robot_based.n_trials`` simulated trials with the same strategy; with
   ``validation_rollouts`` > 1 its front is judged the same way, since its own one-rollout values are the lucky
   draws the search kept;
5. hypervolume I_H of both, against one reference point, written to ``results.json`` with figures.

With ``robot`` set, :func:`run_robot_loop` follows step 2 with the robot loop (:mod:`dcm.tuning.loop`) instead
of steps 3 to 5; :func:`run_once` and it are siblings on one :class:`dcm.tuning.setup.TuneSetup`.

A diffusion model's samples are seeded per batch from ``(seed, first trial of the batch)``, so the same
settings give the same numbers, and a killed run resumed from its logs gives the numbers of an uninterrupted one.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.search import make_search
from dcm.tuning.diagnostics import PredictionErrorWarning, prediction_check, prediction_limit
from dcm.tuning.objectives import PLOT_BATCH, ModelObjective, SimulatorObjective
from dcm.tuning.optimize import LoopTimes, TrialLog, TrialLogMismatch, optimize
from dcm.tuning.pareto import hypervolume, pick_spread, solution_record
from dcm.tuning.predictor import inference_precision
from dcm.tuning.report import plot_overview, plot_pareto, plot_solution_forces
from dcm.tuning.setup import TuneSetup, free_search_options, prepare


@dataclass(frozen=True)
class OneShotResult:
    """A one-shot run's outcome: what ``results.json`` holds, and the run directory with its figures."""

    results: dict[str, Any]
    out_dir: Path


@dataclass(frozen=True)
class LoopResult:
    """A robot loop's outcome after this invocation: what ``loop.json`` holds, and the run directory."""

    loop: dict[str, Any]
    out_dir: Path


def validate_front(objective: SimulatorObjective, params: np.ndarray, objectives: np.ndarray,
                   count: int) -> tuple[np.ndarray, np.ndarray]:
    """Re-run up to ``count`` picks spread along the front of observed ``objectives`` with ``objective`` (the
    validation's rollouts): the indices picked and their validated (L_task, L_comp)."""
    picks = pick_spread(objectives, count)
    return picks, objective(params[picks]) if len(picks) else np.zeros((0, 2))


def _search(setup: TuneSetup, evaluate: Any, n_trials: int, batch_size: int, path: Path, fingerprint: dict,
            desc: str, times: LoopTimes, notes: dict | None = None, options: dict | None = None) -> TrialLog:
    """One search of ``n_trials`` trials logged at ``path``, resumed from it; with ``overwrite`` a log of the same
    settings that the optimiser no longer replays is started over, as asked."""
    settings = setup.settings

    def run() -> TrialLog:
        search = make_search(settings.search.name, setup.checked.space, settings.seed,
                             **(options if options is not None else dict(settings.search.options or {})))
        return optimize(search, evaluate, n_trials, batch_size, path, desc=desc, fingerprint=fingerprint,
                        overwrite=settings.overwrite, notes=notes, times=times)

    try:
        return run()
    except TrialLogMismatch:
        if not settings.overwrite or not path.exists():
            raise
        path.unlink()
        return run()


def robot_free_search(setup: TuneSetup) -> tuple[TrialLog, LoopTimes]:
    """Step 2: the virtual trials of the predictor, resumed from the run directory's log."""
    times = LoopTimes()
    free = setup.settings.robot_free
    log = _search(setup, setup.model_objective, free.n_trials, free.batch_size, setup.free_log,
                  setup.prints["robot_free"], "robot-free (model)", times, setup.notes,
                  free_search_options(setup.settings))
    return log, times


def run_robot_loop(setup: TuneSetup, observations: Path | None = None) -> LoopResult:
    """The robot-free search, then the robot loop: the robot validates and corrects, round after round;
    ``observations``: the trials of its pending round."""
    from dcm.tuning.loop import LoopRun, run_loop

    free_log, _ = robot_free_search(setup)
    free_params, free_predicted = free_log.arrays()
    run = LoopRun(setup.settings, setup.out_dir, setup.prints["robot_free"], setup.simulator, setup.demo, setup.skill,
                  setup.checked.space, setup.model_objective, free_params, free_predicted, setup.reference_info,
                  free_search_options(setup.settings))
    return LoopResult(run_loop(run, observations), setup.out_dir)


def run_once(setup: TuneSetup) -> OneShotResult:
    """The robot-free search, its validation in the simulator, the robot-based search and both hypervolumes;
    writes results.json and the figures."""
    settings, simulator, demo, skill = setup.settings, setup.simulator, setup.demo, setup.skill
    free_log, free_times = robot_free_search(setup)
    free_params, free_predicted = free_log.arrays()
    n_validate, rollouts = settings.robot_free.n_validate, settings.validation_rollouts
    chosen = pick_spread(free_predicted, n_validate)
    validation = SimulatorObjective(simulator, demo, skill, rollouts)
    start = time.perf_counter()
    validated = validation(free_params[chosen])
    validation_seconds = time.perf_counter() - start
    prediction = prediction_check(free_predicted[chosen, 0], validated[:, 0],
                                  prediction_limit(settings.ckpt, settings.prior))
    if prediction["exceeded"]:
        warnings.warn(f"the model's L_task error on the validated solutions, {prediction['L_task_mae_N']:.3g} N "
                      f"(mean |predicted - realised| over {prediction['n_solutions']}), exceeds "
                      f"{prediction['limit_N']:.3g} N ({prediction['limit_source']}): its ranking of this skill's "
                      "schedules is likely off", PredictionErrorWarning, stacklevel=2)
    free = {"log": free_log, "times": free_times, "chosen": chosen, "validated": validated,
            "validation_seconds": validation_seconds, "prediction": prediction}
    robot = robot_based_search(setup)
    results = _results(setup, free, robot)
    out_dir = setup.out_dir
    (out_dir / "results.json").write_text(json.dumps(results, indent=2, default=float))
    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    pareto = (free_predicted[np.isfinite(free_predicted).all(axis=1)], finite(validated), finite(robot["objectives"]),
              setup.reference, type(setup.model).__name__)
    plot_pareto(out_dir / "pareto.png", *pareto)
    _plot_best(out_dir, setup.model_objective, free_params[chosen], validated, validation.trials[::rollouts], demo,
               pareto)
    return OneShotResult(results, out_dir)


def robot_based_search(setup: TuneSetup) -> dict[str, Any]:
    """Step 4: the simulated trials of the same strategy, and with ``validation_rollouts`` > 1 its front's picks
    judged as the robot-free solutions are."""
    settings, simulator, demo, skill = setup.settings, setup.simulator, setup.demo, setup.skill
    out: dict[str, Any] = {"objectives": np.zeros((0, 2)), "times": LoopTimes(), "expected": None,
                           "validation_seconds": 0.0}
    if settings.robot_based_n_trials <= 0:
        return out
    log = _search(setup, SimulatorObjective(simulator, demo, skill), settings.robot_based_n_trials, 1,
                  setup.robot_log, setup.prints["robot_based"], "robot-based (simulator)", out["times"])
    out["params"], out["objectives"] = log.arrays()
    if settings.validation_rollouts > 1:
        start = time.perf_counter()
        out["expected"] = validate_front(SimulatorObjective(simulator, demo, skill, settings.validation_rollouts),
                                         out["params"], out["objectives"], settings.robot_free.n_validate)
        out["validation_seconds"] = time.perf_counter() - start
    return out


def _results(setup: TuneSetup, free: dict[str, Any], robot: dict[str, Any]) -> dict[str, Any]:
    """What ``results.json`` holds."""
    from dcm.models.predict import describe

    settings, model, reference = setup.settings, setup.model, setup.reference
    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    free_params, free_predicted = free["log"].arrays()
    free_times, chosen, validated = free["times"], free["chosen"], free["validated"]
    robot_times, robot_based = robot["times"], robot["objectives"]
    results = {
        "checkpoint": str(settings.ckpt),
        "model": type(model).__name__,
        "predictor": {**describe(model, settings.robot_free.n_samples),
                      "sha256": setup.prints["robot_free"]["predictor_sha256"]},
        "demo": setup.checked.spec.to_dict(),
        "embodiment": settings.embodiment,
        "seed": int(settings.seed),
        "torch_threads": _torch_threads(),
        "skill": setup.prints["skill"],
        "objective": setup.checked.objective.to_dict(),  # L_task's meaning, and its unit: N (paper) or 1 (wipe)
        "reference_point": setup.reference_info,
        "conditioning": setup.conditioning,
        "robot_free": {
            "n_virtual_trials": len(free["log"]),
            "precision": inference_precision(model),
            # this invocation only: the seconds are those of replaying n_replayed trials from the run's log (no
            # model time) and computing n_computed
            "n_replayed": free_times.replayed,
            "n_computed": free_times.computed,
            "seconds": free_times.total,
            "seconds_model": setup.model_objective.seconds_model,
            "seconds_inputs": setup.model_objective.seconds_inputs,
            "seconds_optimiser": free_times.optimiser,
            "n_validated": len(chosen),
            "validation_rollouts": settings.validation_rollouts,
            "validation_seconds": free["validation_seconds"],
            "prediction": free["prediction"],
            "hypervolume": hypervolume(finite(validated), reference),
            "solutions": [solution_record(free_params[i], validated[j], predicted=free_predicted[i])
                          for j, i in enumerate(chosen)],
        },
        "robot_based": {
            "n_trials": len(robot_based),
            "n_replayed": robot_times.replayed,
            "n_computed": robot_times.computed,
            "seconds": robot_times.total,
            "hypervolume": hypervolume(finite(robot_based), reference) if len(robot_based) else None,
        },
    }
    if robot["expected"] is not None:  # its front's picks, judged as the robot-free solutions are
        picks, expected = robot["expected"]
        results["robot_based"].update(
            hypervolume_validated=hypervolume(finite(expected), reference),
            validation_rollouts=settings.validation_rollouts, validation_seconds=robot["validation_seconds"],
            solutions=[solution_record(robot["params"][i], expected[j], observed=robot_based[i])
                       for j, i in enumerate(picks)])
    return results


def tune(cfg: Any, out_dir: Path, observations: Path | None = None) -> dict[str, Any]:
    """For scripts: :func:`prepare`, then the run its settings ask for; returns the content of the file it wrote,
    results.json's (one-shot), or ``{"loop": <loop.json's>}`` (``robot`` set)."""
    setup = prepare(cfg, out_dir)
    if setup.settings.robot:
        return {"loop": run_robot_loop(setup, observations).loop}
    return run_once(setup).results


def _torch_threads() -> int:
    import torch

    return int(torch.get_num_threads())


def _plot_best(out_dir: Path, objective: ModelObjective, params: np.ndarray, validated: np.ndarray,
               trials: list[Any], demo: Any, pareto: tuple) -> None:
    """solution_forces.png and overview.png of the validated solution with the lowest genuine L_task."""
    if not len(params) or np.isnan(validated[:, 0]).all():
        return
    best = int(np.nanargmin(validated[:, 0]))
    stiffness, predicted, _ = objective.predict(params[best : best + 1], first_trial=PLOT_BATCH)
    forces = (demo.dt, demo.force_demo, None if predicted is None else predicted[0], trials[best].force_obs,
              stiffness[0])
    title = f"validated solution {best}: L_task={validated[best, 0]:.2f} N, L_comp={validated[best, 1]:.2f} kN/m"
    plot_solution_forces(out_dir / "solution_forces.png", *forces, title)
    plot_overview(out_dir / "overview.png", pareto, *forces, f"{demo.spec.name}: {title}")


__all__ = ["LoopResult", "OneShotResult", "pick_spread", "robot_based_search", "robot_free_search", "run_once",
           "run_robot_loop", "solution_record", "tune", "validate_front"]
