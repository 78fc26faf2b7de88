"""A tune run set up once from its settings: the checked settings, the predictor, the recorded skill, the
hypervolume reference point, the model objective and the trial logs' fingerprints. The one-shot run and the robot
loop (:mod:`dcm.tuning.run`) both start from a :class:`TuneSetup`.

The reference point is the skill's (:func:`skill_reference_point`), set before any search: hypervolumes
compare only on one point, so a point pooled from a run's own results would score two seeds of one skill on
different points, and their verdicts could flip.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control import StiffnessFrameError, phase_boundaries
from dcm.control.objectives import TaskObjective, task_window_start
from dcm.tuning.checks import CheckedConfig, TuneConfigError, check_config
from dcm.tuning.diagnostics import ConditioningRangeWarning, conditioning_check, conditioning_warnings
from dcm.tuning.objectives import ModelObjective, SimulatorObjective, Skill
from dcm.tuning.optimize import resumable_log
from dcm.tuning.predictor import load_predictor
from dcm.tuning.settings import TuneSettings, as_settings

# The skill's hypervolume reference point (docs/tune.md#what-a-run-does): L_task of a rollout at the demo's own
# stiffness times REFERENCE_TASK_FACTOR, and L_comp of the stiffest schedule of the search space times
# REFERENCE_COMP_FACTOR, in the simulator seeded REFERENCE_SEED; the multi-seed studies use the same rule.
REFERENCE_TASK_FACTOR = 1.5
REFERENCE_COMP_FACTOR = 1.0
REFERENCE_SEED = 0
FREE_LOG = "robot_free_trials.npz"
ROBOT_LOG = "robot_based_trials.npz"


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fingerprints(cfg: TuneSettings, spec: Any, domain: Any, model: Any, device: Any) -> dict[str, dict[str, Any]]:
    """What determines each trial log's values (the ``skill`` part is also what compared runs must share).

    ``skill``: demo spec, embodiment, domain, damping, control rate, stiffness space, seed.
    ``robot_based``: skill + search settings. ``robot_free``: that + the predictor's content hash and how it
    samples (sampler, steps, samples per prediction), the batch size and the device type.
    """
    from dcm.models.predict import describe

    stiffness = cfg.stiffness
    skill = {
        "demo": spec.to_dict(),
        "embodiment": cfg.embodiment,
        "domain": domain.to_dict(),
        "damping": stiffness["damping"],
        "control_hz": float(cfg.control_hz),
        "stiffness": {k: stiffness[k] for k in ("n_phases", "phases", "min_Npm", "max_Npm", "log", "rot_Nmprad")},
        "seed": int(cfg.seed),
    }
    if cfg.task_from_s:  # only when set: the trial logs of whole-demo runs keep their fingerprint
        skill["task_from_s"] = float(cfg.task_from_s)
    if cfg.objective and cfg.objective.get("name", "paper") != "paper":  # likewise the paper's objective
        skill["objective"] = TaskObjective.from_config(cfg.objective).to_dict()
    if stiffness.get("frame", "world") != "world":  # and the world frame
        skill["stiffness"]["frame"] = stiffness["frame"]
    robot = {**skill, "search": {"name": cfg.search.name, "options": dict(cfg.search.options or {})}}
    sampling = {k: v for k, v in describe(model, cfg.robot_free.n_samples).items() if k != "ckpt"}
    if cfg.prior:  # only when set: the trial logs of runs without a prior keep their fingerprint
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
    cfg = as_settings(cfg)
    options = dict(cfg.search.options or {})
    if cfg.search.name == "motpe" and cfg.robot_free.batched_search:
        options["batched"] = True
    return options


def _jsonable(value: Any) -> Any:
    return value.tolist() if hasattr(value, "tolist") else str(value)


def record_skill(cfg: Any, checked: CheckedConfig, seed: int | None = None) -> tuple[Any, Any, Skill]:
    """The new skill's simulator, its recorded demo and the ``Skill`` (phases, schedules) the tuners search;
    the simulator seeded ``seed`` instead of ``cfg.seed`` when given."""
    from dcm.sim.rollout import Simulator

    cfg = as_settings(cfg)

    simulator = Simulator(embodiment=cfg.embodiment, bowl=checked.spec.bowl, domain=checked.domain,
                          control_hz=cfg.control_hz, seed=cfg.seed if seed is None else seed,
                          damping=cfg.stiffness["damping"])
    demo = simulator.record_demo(checked.spec)
    boundaries = phase_boundaries(cfg.stiffness["phases"], cfg.stiffness["n_phases"], demo.force_demo)
    start = task_window_start(cfg.task_from_s, cfg.control_hz, demo.horizon)  # checked by check_config
    try:
        skill = Skill(demo.x_demo, demo.force_demo, boundaries, cfg.stiffness["rot_Nmprad"], start, checked.objective,
                      checked.space.frame)
    except StiffnessFrameError as err:
        raise TuneConfigError(str(err)) from None
    return simulator, demo, skill


def skill_reference_point(cfg: TuneSettings, checked: CheckedConfig, recorded: tuple[Any, Any, Skill]) -> dict[str, Any]:
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


@dataclass(frozen=True)
class TuneSetup:
    """What both kinds of run start from, built once by :func:`prepare`."""

    settings: TuneSettings
    out_dir: Path
    checked: CheckedConfig  # the demo spec, domain, search space and configured reference point
    device: Any
    model: Any  # the predictor, set to sample as robot_free asks
    prints: dict[str, dict[str, Any]]  # the trial logs' fingerprints (skill, robot_based, robot_free)
    notes: dict[str, Any]  # quoted beside the robot-free log's fingerprint in messages
    simulator: Any
    demo: Any
    skill: Skill
    reference_info: dict[str, Any]  # the hypervolume reference point and how it was set
    model_objective: ModelObjective
    conditioning: dict[str, Any]  # the skill's model inputs against the training range

    @property
    def reference(self) -> np.ndarray:
        return np.array([self.reference_info["L_task_N"], self.reference_info["L_comp_kNpm"]])

    @property
    def free_log(self) -> Path:
        return self.out_dir / FREE_LOG

    @property
    def robot_log(self) -> Path:
        return self.out_dir / ROBOT_LOG


def prepare(cfg: Any, out_dir: Path) -> TuneSetup:
    """Check the settings of ``cfg`` (a composed ``conf/tune.yaml``, or :class:`TuneSettings`), load the
    predictor, refuse another run's trial logs in ``out_dir``, record the skill and set its reference point:
    everything before the first trial, so a setting that cannot work stops the run before any search."""
    from dcm.devices import resolve_device

    settings = as_settings(cfg)
    checked = check_config(settings)
    device = resolve_device(settings.device, "device")
    if settings.torch_threads is not None:
        import torch

        torch.set_num_threads(int(settings.torch_threads))
    model = load_predictor(settings, checked.spec, device)
    prints = fingerprints(settings, checked.spec, checked.domain, model, device)
    notes = {"predictor": str(settings.ckpt), "model": type(model).__name__}
    out_dir.mkdir(parents=True, exist_ok=True)
    # Refuse another run's logs now, not after recording the demo and running the trials.
    resumable_log(out_dir / FREE_LOG, prints["robot_free"], settings.overwrite, notes)
    if settings.robot_based_n_trials > 0 and not settings.robot:
        resumable_log(out_dir / ROBOT_LOG, prints["robot_based"], settings.overwrite)
    simulator, demo, skill = record_skill(settings, checked)
    reference_info = skill_reference_point(settings, checked, (simulator, demo, skill))
    objective = ModelObjective(model, skill, simulator, demo, settings.robot_free.n_samples, seed=settings.seed)
    conditioning = check_conditioning(model, objective, checked.space)
    return TuneSetup(settings, out_dir, checked, device, model, prints, notes, simulator, demo, skill, reference_info,
                     objective, conditioning)


__all__ = ["FREE_LOG", "REFERENCE_COMP_FACTOR", "REFERENCE_SEED", "REFERENCE_TASK_FACTOR", "ROBOT_LOG", "TuneSetup",
           "fingerprints", "free_search_options", "prepare", "record_skill", "skill_reference_point"]
