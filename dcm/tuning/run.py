"""Robot-free stiffness tuning of one new skill, validated in the simulator and compared with robot-based search.

Steps (each resumable from the run directory):
0. check every setting (:func:`dcm.tuning.checks.check_config`), load the predictor and check it against the
   skill, and check that the run directory's trial logs were written by these settings (their *fingerprint*);
1. record the new skill's demo in the simulator;
2. robot-free search: ``robot_free.n_trials`` virtual trials, L_task predicted by the checkpoint (or by a
   stiffness reference JSON, ``python -m dcm.models.references fit``; ``copy_demo`` is refused: it ranks nothing);
3. validate up to ``robot_free.n_validate`` solutions spread along the predicted Pareto front in the simulator,
   each over ``validation_rollouts`` rollouts (their mean L_task: the expected loss under a per-rollout spread);
4. robot-based search: ``robot_based.n_trials`` simulated trials with the same strategy; with
   ``validation_rollouts`` > 1 its front is judged the same way, since its own one-rollout values are the lucky
   draws the search kept;
5. hypervolume I_H of both, against one reference point, written to ``results.json`` with figures.

The reference point is the skill's (:func:`skill_reference_point`), set before any search: hypervolumes
compare only on one point, so a point pooled from a run's own results would score two seeds of one skill on
different points, and their verdicts could flip.

A diffusion model's samples are seeded per batch from ``(seed, first trial of the batch)``, so the same
settings give the same numbers, and a killed run resumed from its logs gives the numbers of an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from dcm.cli import one_line
from dcm.control import phase_boundaries
from dcm.control.objectives import task_window_start
from dcm.search import make_search
from dcm.tuning.checks import (
    AUTO_SAMPLER,
    CheckedConfig,
    ConditioningRangeWarning,
    DemoRecordingWarning,
    PredictionErrorWarning,
    SampleSpreadWarning,
    TuneConfigError,
    check_config,
    check_predictor,
    conditioning_check,
    conditioning_warnings,
    prediction_check,
    prediction_limit,
    recording_mismatch,
    spread_warning,
    to_container,
)
from dcm.tuning.objectives import ModelObjective, SimulatorObjective, Skill
from dcm.tuning.optimize import LoopTimes, TrialLog, TrialLogMismatch, optimize, resumable_log
from dcm.tuning.pareto import hypervolume, pick_spread, solution_record
from dcm.tuning.report import plot_overview, plot_pareto, plot_solution_forces

# The skill's hypervolume reference point (docs/tune.md#what-a-run-does): L_task of a rollout at the demo's own
# stiffness times REFERENCE_TASK_FACTOR, and L_comp of the stiffest schedule of the search space times
# REFERENCE_COMP_FACTOR, in the simulator seeded REFERENCE_SEED; the multi-seed studies use the same rule.
REFERENCE_TASK_FACTOR = 1.5
REFERENCE_COMP_FACTOR = 1.0
REFERENCE_SEED = 0
FREE_LOG = "robot_free_trials.npz"
ROBOT_LOG = "robot_based_trials.npz"
PLOT_BATCH = 2**31  # the figure's prediction is seeded like a batch no run reaches


def validate_front(objective: SimulatorObjective, params: np.ndarray, objectives: np.ndarray,
                   count: int) -> tuple[np.ndarray, np.ndarray]:
    """Re-run up to ``count`` picks spread along the front of observed ``objectives`` with ``objective`` (the
    validation's rollouts): the indices picked and their validated (L_task, L_comp)."""
    picks = pick_spread(objectives, count)
    return picks, objective(params[picks]) if len(picks) else np.zeros((0, 2))


# ----------------------------------------------------------------------------------------------- predictor
def use_sampler(model: Any, sampler: str | None = None, sampling_steps: int | None = None) -> bool:
    """Make a loaded DCM sample with ``sampler`` over ``sampling_steps`` denoising steps, in this process only
    (:meth:`dcm.models.dcm.DCM.set_sampler`; the checkpoint file is untouched): a run trades the full chain's
    accuracy for speed without a new checkpoint.

    ``sampler``: ``"ddpm"`` (ancestral), ``"ddim"`` or ``"ddim_even"`` (deterministic given the start noise;
    the latter's steps end at t = 0); None keeps the checkpoint's; ``"auto"`` keeps a one-step student's single
    step (:mod:`dcm.training.distill`) and runs any other DCM with ``"ddim"``. ``sampling_steps``: steps of the chain
    (ddim: must divide T); None keeps the checkpoint's
    when the sampler is unchanged, else T. Predictors that do not diffuse (baseline, stiffness reference) are
    left alone. Returns whether ``model`` was changed; raises :class:`TuneConfigError` naming
    ``robot_free.sampling_steps`` for a step count the sampler cannot run.
    """
    from dcm.models.dcm import DCM

    if not isinstance(model, DCM) or (sampler is None and sampling_steps is None):
        return False
    student = model.is_one_step_student
    if sampler == AUTO_SAMPLER:
        if student:
            return False
        sampler = "ddim"
    kind = model.cfg.sampler if sampler is None else sampler
    steps = sampling_steps
    if steps is None and kind == model.cfg.sampler:
        steps = model.cfg.sampling_steps
    try:
        model.set_sampler(kind, steps)
    except ValueError as err:
        hint = "robot_free.sampler=auto" if student else "robot_free.sampling_steps=null runs all T steps"
        raise TuneConfigError(f"robot_free.sampling_steps = {steps} with robot_free.sampler = {kind}: "
                              f"{one_line(err)} ({hint})") from None
    return True


def load_predictor(cfg: Any, spec: Any, device: Any) -> Any:
    """The predictor of ``cfg.ckpt`` as the robot-free search uses it: checked against the skill (warning when
    its demo is recorded otherwise than the predictor's training demos), with ``robot_free``'s sampler, sampling
    steps, precision and task loss, and blended with the stiffness ridge ``prior`` at ``prior_weight`` when one is
    given (:mod:`dcm.models.prior_blend`)."""
    from dcm.models.dcm import DCM
    from dcm.models.predict import load_model, with_prior

    model = load_model(cfg.ckpt, map_location=device)
    check_predictor(model, cfg)
    if (mismatch := recording_mismatch(cfg.ckpt, spec, cfg.control_hz)) is not None:
        warnings.warn(mismatch, DemoRecordingWarning, stacklevel=3)
    use_sampler(model, cfg.robot_free.get("sampler"), cfg.robot_free.get("sampling_steps"))
    if cfg.robot_free.get("precision") is not None and hasattr(model, "set_precision"):  # force models
        try:
            model.set_precision(cfg.robot_free.precision)
        except ValueError as err:
            raise TuneConfigError(f"robot_free.precision: {err}") from None
    if cfg.robot_free.get("shared_steps") is not None and hasattr(model, "set_shared_steps"):  # DCM only
        try:
            model.set_shared_steps(cfg.robot_free.shared_steps)
        except ValueError as err:
            raise TuneConfigError(f"robot_free.shared_steps: {err}") from None
    if cfg.robot_free.get("task_loss") is not None and hasattr(model, "set_task_loss"):  # not the ridge
        model.set_task_loss(cfg.robot_free.task_loss)
    if isinstance(model, DCM) and (why := spread_warning(
            model.cfg.sampler, int(cfg.robot_free.n_samples), model.cfg.task_loss)) is not None:
        warnings.warn(why, SampleSpreadWarning, stacklevel=3)
    if cfg.get("prior"):
        try:
            model = with_prior(model, cfg.prior, cfg.get("prior_weight", 0.0), source=f"tune prior={cfg.prior}")
        except ValueError as err:
            raise TuneConfigError(str(err)) from None
        check_predictor(model, cfg)  # the prior's phases and L_task window
    return model


# ----------------------------------------------------------------------------------------------- fingerprints
def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fingerprints(cfg: Any, spec: Any, domain: Any, model: Any, device: Any) -> dict[str, dict[str, Any]]:
    """What determines each trial log's values (the ``skill`` part is also what compared runs must share).

    ``skill``: demo spec, embodiment, domain, damping, control rate, stiffness space, seed.
    ``robot_based``: skill + search settings. ``robot_free``: that + the predictor's content hash and how it
    samples (sampler, steps, samples per prediction), the batch size and the device type.
    """
    from dcm.models.predict import describe

    stiffness = to_container(cfg.stiffness)
    skill = {
        "demo": spec.to_dict(),
        "embodiment": cfg.embodiment,
        "domain": domain.to_dict(),
        "damping": stiffness["damping"],
        "control_hz": float(cfg.control_hz),
        "stiffness": {k: stiffness[k] for k in ("n_phases", "phases", "min_Npm", "max_Npm", "log", "rot_Nmprad")},
        "seed": int(cfg.seed),
    }
    if cfg.get("task_from_s", 0.0):  # only when set: the trial logs of whole-demo runs keep their fingerprint
        skill["task_from_s"] = float(cfg.task_from_s)
    robot = {**skill, "search": {"name": cfg.search.name, "options": to_container(cfg.search.options) or {}}}
    sampling = {k: v for k, v in describe(model, cfg.robot_free.n_samples).items() if k != "ckpt"}
    if cfg.get("prior"):  # only when set: the trial logs of runs without a prior keep their fingerprint
        sampling["prior_sha256"] = file_sha256(cfg.prior)
        sampling.pop("prior", None)  # its content counts, not where it lies
    free = {**robot, "search": {**robot["search"], "options": free_search_options(cfg)},
            "predictor_sha256": file_sha256(cfg.ckpt), "predictor": sampling,
            "n_samples": int(cfg.robot_free.n_samples), "batch_size": int(cfg.robot_free.batch_size),
            "device": getattr(device, "type", str(device))}
    plain = lambda d: json.loads(json.dumps(d, default=_jsonable))  # noqa: E731 - what a log stores and reloads
    return {"skill": plain(skill), "robot_based": plain(robot), "robot_free": plain(free)}


def free_search_options(cfg: Any) -> dict[str, Any]:
    """The robot-free search's options: ``search.options``, and with ``robot_free.batched_search`` (MOTPE only)
    one optimiser fit per batch of ``robot_free.batch_size`` proposals, so that 1,000 virtual trials do not
    cost more in the optimiser than in the model (:mod:`dcm.search.motpe`)."""
    options = to_container(cfg.search.options) or {}
    if cfg.search.name == "motpe" and cfg.robot_free.get("batched_search", False):
        options["batched"] = True
    return options


def _jsonable(value: Any) -> Any:
    return value.tolist() if hasattr(value, "tolist") else str(value)


# ----------------------------------------------------------------------------------------------- the run
def record_skill(cfg: Any, checked: CheckedConfig, seed: int | None = None) -> tuple[Any, Any, Skill]:
    """The new skill's simulator, its recorded demo and the ``Skill`` (phases, schedules) the tuners search;
    the simulator seeded ``seed`` instead of ``cfg.seed`` when given."""
    from dcm.sim.rollout import Simulator

    simulator = Simulator(embodiment=cfg.embodiment, bowl=checked.spec.bowl, domain=checked.domain,
                          control_hz=cfg.control_hz, seed=cfg.seed if seed is None else seed,
                          damping=cfg.stiffness.damping)
    demo = simulator.record_demo(checked.spec)
    boundaries = phase_boundaries(cfg.stiffness.phases, cfg.stiffness.n_phases, demo.force_demo)
    start = task_window_start(cfg.get("task_from_s", 0.0), cfg.control_hz, demo.horizon)  # checked by check_config
    return simulator, demo, Skill(demo.x_demo, demo.force_demo, boundaries, cfg.stiffness.rot_Nmprad, start)


def skill_reference_point(cfg: Any, checked: CheckedConfig, recorded: tuple[Any, Any, Skill]) -> dict[str, Any]:
    """The hypervolume reference point of this skill: ``reference_point`` when given, else
    ``(REFERENCE_TASK_FACTOR x L_task at the demo's own stiffness, REFERENCE_COMP_FACTOR x L_comp of the
    stiffest schedule)``.

    Why these: the demonstrator's stiffness is the schedule a user has without tuning, so a solution counts
    when it tracks the demo force nearly as well as that; the stiffest schedule bounds L_comp for every
    schedule of the search space. The rollout runs in a simulator seeded ``REFERENCE_SEED`` (on a demo
    recorded there), with ``validation_rollouts`` rollouts as a validated solution is judged, so the point
    depends on the skill, the domain and the search space, not on the run's seed or results. ``recorded``:
    this run's (simulator, demo, skill), reused when its seed is ``REFERENCE_SEED``.
    """
    from dcm.control import compliance_loss

    if checked.reference is not None:
        return {"L_task_N": float(checked.reference[0]), "L_comp_kNpm": float(checked.reference[1]),
                "source": "reference_point"}
    simulator, demo, skill = recorded if int(cfg.seed) == REFERENCE_SEED else record_skill(cfg, checked,
                                                                                           REFERENCE_SEED)
    space = checked.space
    demo_stiffness = np.tile(np.asarray(checked.spec.stiffness_Npm, dtype=np.float64), (1, space.n_phases, 1))
    task = float(SimulatorObjective(simulator, demo, skill, int(cfg.validation_rollouts))(demo_stiffness)[0, 0])
    if not np.isfinite(task):
        raise TuneConfigError(
            f"the rollout at the demo's own stiffness {list(checked.spec.stiffness_Npm)} N/m failed, so it cannot "
            "set the hypervolume reference point; give reference_point=[L_task_N,L_comp_kNpm]")
    stiffest = float(compliance_loss(skill.schedules(np.full((1, space.n_phases, 3), space.max_Npm)))[0])
    return {"L_task_N": REFERENCE_TASK_FACTOR * task, "L_comp_kNpm": REFERENCE_COMP_FACTOR * stiffest,
            "source": "skill",
            "rule": {"demo_stiffness_Npm": [float(v) for v in checked.spec.stiffness_Npm],
                     "demo_stiffness_L_task_N": task, "task_factor": REFERENCE_TASK_FACTOR,
                     "stiffest_Npm": float(space.max_Npm), "stiffest_L_comp_kNpm": stiffest,
                     "comp_factor": REFERENCE_COMP_FACTOR, "simulator_seed": REFERENCE_SEED,
                     "rollouts": int(cfg.validation_rollouts)}}


def check_conditioning(model: Any, objective: ModelObjective, space: Any) -> dict[str, Any]:
    """Judge the skill's model inputs against the model's training range before the search (the demo, and the
    attractor and stiffness of the space's softest and stiffest constant schedules); warn once per channel
    outside it (:class:`ConditioningRangeWarning`). Returns what ``results.json`` records."""
    levels = [float(space.min_Npm), float(space.max_Npm)]
    proposals = np.stack([np.full((space.n_phases, 3), level) for level in levels])
    conditioning = conditioning_check(model, objective.inputs(proposals), levels)
    for line in conditioning_warnings(conditioning):
        warnings.warn(line, ConditioningRangeWarning, stacklevel=3)
    return conditioning


def tune(cfg: Any, out_dir: Path, observations: Path | None = None) -> dict[str, Any]:
    """Run the whole comparison for the config of ``conf/tune.yaml``; returns what ``results.json`` holds.

    With ``robot`` set (``sim`` or ``files``) the robot-free search is followed by the robot loop instead of the
    one-shot validation (:mod:`dcm.tuning.loop`), ``observations`` being the trials of its pending round; returns
    ``{"loop": <what loop.json holds>}``."""
    from dcm.cli import resolve_device
    from dcm.models.predict import describe

    checked = check_config(cfg)
    spec, domain, space = checked.spec, checked.domain, checked.space
    overwrite = bool(cfg.get("overwrite", False))
    device = resolve_device(cfg.device, "device")
    if cfg.get("torch_threads") is not None:
        import torch

        torch.set_num_threads(int(cfg.torch_threads))
    model = load_predictor(cfg, spec, device)

    prints = fingerprints(cfg, spec, domain, model, device)
    notes = {"predictor": str(cfg.ckpt), "model": type(model).__name__}
    out_dir.mkdir(parents=True, exist_ok=True)
    free_path, robot_path = out_dir / FREE_LOG, out_dir / ROBOT_LOG
    # Refuse another run's logs now, not after recording the demo and running the trials.
    resumable_log(free_path, prints["robot_free"], overwrite, notes)
    looping = bool(cfg.get("robot"))
    if cfg.robot_based.n_trials > 0 and not looping:
        resumable_log(robot_path, prints["robot_based"], overwrite)

    simulator, demo, skill = record_skill(cfg, checked)
    reference_info = skill_reference_point(cfg, checked, (simulator, demo, skill))
    reference = np.array([reference_info["L_task_N"], reference_info["L_comp_kNpm"]])

    def search_loop(evaluate: Any, n_trials: int, batch_size: int, path: Path, fingerprint: dict, desc: str,
                    times: LoopTimes, log_notes: dict | None = None, options: dict | None = None) -> TrialLog:
        def run() -> TrialLog:
            search = make_search(cfg.search.name, space, cfg.seed,
                                 **(options if options is not None else to_container(cfg.search.options) or {}))
            return optimize(search, evaluate, n_trials, batch_size, path, desc=desc, fingerprint=fingerprint,
                            overwrite=overwrite, notes=log_notes, times=times)

        try:
            return run()
        except TrialLogMismatch:
            if not overwrite or not path.exists():
                raise
            path.unlink()  # same settings, but the optimiser no longer replays it: start over, as asked
            return run()

    model_objective = ModelObjective(model, skill, lambda k: simulator.attractor(demo, k), cfg.robot_free.n_samples,
                                     seed=cfg.seed)
    conditioning = check_conditioning(model, model_objective, space)
    free_times = LoopTimes()
    free_log = search_loop(model_objective, cfg.robot_free.n_trials, cfg.robot_free.batch_size, free_path,
                           prints["robot_free"], "robot-free (model)", free_times, notes, free_search_options(cfg))
    free_params, free_predicted = free_log.arrays()
    if looping:  # the robot validates and corrects, round after round
        from dcm.tuning.loop import LoopRun, run_loop

        run = LoopRun(cfg, out_dir, prints["robot_free"], simulator, demo, skill, space, model_objective,
                      free_params, free_predicted, reference_info, free_search_options(cfg))
        return {"loop": run_loop(run, observations)}

    n_validate, rollouts = cfg.robot_free.n_validate, cfg.validation_rollouts
    chosen = pick_spread(free_predicted, n_validate)
    validation = SimulatorObjective(simulator, demo, skill, rollouts)
    start = time.perf_counter()
    validated = validation(free_params[chosen])
    validation_seconds = time.perf_counter() - start
    prediction = prediction_check(free_predicted[chosen, 0], validated[:, 0],
                                  prediction_limit(cfg.ckpt, cfg.get("prior")))
    if prediction["exceeded"]:
        warnings.warn(f"the model's L_task error on the validated solutions, {prediction['L_task_mae_N']:.3g} N "
                      f"(mean |predicted - realised| over {prediction['n_solutions']}), exceeds "
                      f"{prediction['limit_N']:.3g} N ({prediction['limit_source']}): its ranking of this skill's "
                      "schedules is likely off", PredictionErrorWarning, stacklevel=2)

    robot_based = np.zeros((0, 2))
    robot_times = LoopTimes()
    robot_expected, robot_validation_seconds = None, 0.0
    if cfg.robot_based.n_trials > 0:
        robot_log = search_loop(SimulatorObjective(simulator, demo, skill), cfg.robot_based.n_trials, 1, robot_path,
                                prints["robot_based"], "robot-based (simulator)", robot_times)
        robot_params, robot_based = robot_log.arrays()
        if rollouts > 1:
            start = time.perf_counter()
            robot_expected = validate_front(SimulatorObjective(simulator, demo, skill, rollouts), robot_params,
                                            robot_based, n_validate)
            robot_validation_seconds = time.perf_counter() - start

    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    results = {
        "checkpoint": str(cfg.ckpt),
        "model": type(model).__name__,
        "predictor": {**describe(model, cfg.robot_free.n_samples), "sha256": prints["robot_free"]["predictor_sha256"]},
        "demo": spec.to_dict(),
        "embodiment": cfg.embodiment,
        "seed": int(cfg.seed),
        "torch_threads": _torch_threads(),
        "skill": prints["skill"],
        "reference_point": reference_info,
        "conditioning": conditioning,
        "robot_free": {
            "n_virtual_trials": len(free_log),
            "seconds": free_times.total,  # this invocation only: replayed trials cost no model time
            "seconds_model": model_objective.seconds_model,
            "seconds_inputs": model_objective.seconds_inputs,
            "seconds_optimiser": free_times.optimiser,
            "n_validated": len(chosen),
            "validation_rollouts": rollouts,
            "validation_seconds": validation_seconds,
            "prediction": prediction,
            "hypervolume": hypervolume(finite(validated), reference),
            "solutions": [solution_record(free_params[i], validated[j], predicted=free_predicted[i])
                          for j, i in enumerate(chosen)],
        },
        "robot_based": {
            "n_trials": len(robot_based),
            "seconds": robot_times.total,
            "hypervolume": hypervolume(finite(robot_based), reference) if len(robot_based) else None,
        },
    }
    if robot_expected is not None:  # its front's picks, judged as the robot-free solutions are
        picks, expected = robot_expected
        results["robot_based"].update(
            hypervolume_validated=hypervolume(finite(expected), reference), validation_rollouts=rollouts,
            validation_seconds=robot_validation_seconds,
            solutions=[solution_record(robot_params[i], expected[j], observed=robot_based[i])
                       for j, i in enumerate(picks)])
    (out_dir / "results.json").write_text(json.dumps(results, indent=2, default=float))
    pareto = (free_predicted[np.isfinite(free_predicted).all(axis=1)], finite(validated), finite(robot_based),
              reference, type(model).__name__)
    plot_pareto(out_dir / "pareto.png", *pareto)
    _plot_best(out_dir, model_objective, free_params[chosen], validated, validation.trials[::rollouts], demo, pareto)
    return results


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


__all__ = ["FREE_LOG", "REFERENCE_COMP_FACTOR", "REFERENCE_SEED", "REFERENCE_TASK_FACTOR", "ROBOT_LOG", "fingerprints",
           "load_predictor", "pick_spread", "record_skill", "skill_reference_point", "solution_record", "tune",
           "use_sampler", "validate_front"]
