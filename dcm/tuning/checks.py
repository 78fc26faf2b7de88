"""The checks of a tune run: every setting of ``conf/tune.yaml`` before any work, then the predictor against the
skill it is to tune, so a setting that cannot work ends in one line naming it. What a run only warns about
while it runs is in :mod:`dcm.tuning.diagnostics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from dcm.configs import check_integer, check_number
from dcm.console import one_line
from dcm.control import TASK_LOSSES, phase_boundaries
from dcm.control.objectives import ObjectiveError, TaskObjective, task_window_start
from dcm.search import SearchSpace, check_budget, make_search, space_from_settings
from dcm.tuning.settings import TuneSettings, as_settings

SAMPLERS = ("ddpm", "ddim", "ddim_even", "one_step")  # dcm.models.diffusion.SAMPLERS, without importing torch
AUTO_SAMPLER = "auto"  # robot_free.sampler: a one-step student's own step, ddim for any other DCM


class TuneConfigError(ValueError):
    """A tune.py setting that cannot work; the message names the setting, its value and what is allowed."""



def to_container(value: Any) -> Any:
    """A config node as plain lists and dicts; any other value unchanged."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def _integer(value: Any, key: str, minimum: int, note: str = "") -> int:
    return check_integer(value, key, minimum, TuneConfigError, note)


def _number(value: Any, key: str) -> float:
    return check_number(value, key, TuneConfigError)


def _check_search(cfg: TuneSettings, space: SearchSpace) -> None:
    """The strategy builds, its budget covers both searches, and each search outlasts its random start-up."""
    name, options = cfg.search.name, dict(cfg.search.options or {})
    try:
        search = make_search(name, space, 0, **options)
    except (TypeError, ValueError) as err:
        raise TuneConfigError(f"search={name} with options {options}: {one_line(err)}") from None
    startup = options.get("n_startup_trials")
    for key in ("robot_free.n_trials", "robot_based.n_trials"):
        n = cfg.robot_free.n_trials if key == "robot_free.n_trials" else cfg.robot_based_n_trials
        if n == 0:
            continue  # robot_based.n_trials = 0 skips the robot-based search
        try:
            check_budget(search, n)
        except ValueError as err:
            raise TuneConfigError(f"{key} = {n}: {one_line(err)}") from None
        if isinstance(startup, int) and n <= startup:
            raise TuneConfigError(
                f"{key} = {n} is not above search.options.n_startup_trials = {startup}: every trial would be a "
                f"random start-up trial, not {name}; raise {key} or lower search.options.n_startup_trials"
                + (" (robot_based.n_trials=0 skips the robot-based search)" if key.startswith("robot_based") else ""))


ROBOTS = ("sim", "files")


def _check_loop(cfg: TuneSettings, space: SearchSpace) -> None:
    """The robot loop's settings (conf/tune.yaml ``robot``, ``observations``, ``loop``)."""
    from dcm.tuning.correction import CORRECTIONS
    from dcm.tuning.schedule_files import check_bowl_in_base

    robot = cfg.robot
    if robot is not None and robot not in ROBOTS:
        raise TuneConfigError(f"robot = {robot!r}; expected null (validate once in the simulator), sim (the simulator "
                              "plays the robot, round after round) or files (write each round for a real robot)")
    if cfg.observations and not cfg.resume:
        raise TuneConfigError(f"observations = {cfg.observations} needs resume=<the run directory that proposed the "
                              "schedules>")
    loop = cfg.loop
    if loop is None:
        return
    _integer(loop.rounds, "loop.rounds", 1)
    _integer(loop.batch, "loop.batch", 1)
    n_trials = _integer(loop.n_trials, "loop.n_trials", 0, " (0: re-rank the robot-free search's trials only)")
    startup = (cfg.search.options or {}).get("n_startup_trials")
    if n_trials and isinstance(startup, int) and n_trials <= startup:
        raise TuneConfigError(f"loop.n_trials = {n_trials} is not above search.options.n_startup_trials = {startup}: "
                              "every trial of a round's search would be random; raise it, or 0 to skip the search")
    if _number(loop.tolerance_N, "loop.tolerance_N") < 0:
        raise TuneConfigError(f"loop.tolerance_N = {loop.tolerance_N} must be >= 0 N")
    if loop.correction not in CORRECTIONS:
        raise TuneConfigError(f"loop.correction = {loop.correction!r}; expected one of {', '.join(CORRECTIONS)}")
    for key in ("lengthscale", "noise_ratio", "ridge_alpha"):
        if _number(getattr(loop, key), f"loop.{key}") <= 0:
            raise TuneConfigError(f"loop.{key} = {getattr(loop, key)} must be > 0")
    try:
        check_bowl_in_base(loop.bowl_in_base)
    except ValueError as err:
        raise TuneConfigError(str(err)) from None


def min_compliance_loss(space: SearchSpace) -> float:
    """The lowest L_comp [kN/m] any schedule of ``space`` reaches: every translational axis at ``min_Npm``."""
    return math.sqrt(3.0) * space.min_Npm / 1000.0


def _check_reference_point(value: Any, space: SearchSpace) -> np.ndarray | None:
    value = to_container(value)
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise TuneConfigError(f"reference_point = {value!r} must be null or [L_task_N, L_comp_kNpm]")
    task, comp = (_number(v, f"reference_point[{i}]") for i, v in enumerate(value))
    if task <= 0:
        raise TuneConfigError(f"reference_point = [{task:g}, {comp:g}]: nothing can dominate it: L_task >= 0 N "
                              "for every schedule; choose an L_task above 0 (or reference_point=null)")
    lowest = min_compliance_loss(space)
    if comp <= lowest:
        raise TuneConfigError(
            f"reference_point = [{task:g}, {comp:g}]: nothing can dominate it: L_comp >= {lowest:.4g} kN/m for "
            f"every schedule with stiffness.min_Npm = {space.min_Npm:g}; choose an L_comp above it "
            "(or reference_point=null)")
    return np.array([task, comp])


@dataclass(frozen=True)
class CheckedConfig:
    """What :func:`check_config` parsed on the way."""

    spec: Any  # dcm.sim.demos.DemoSpec of the new skill
    domain: Any  # dcm.sim.domain.DomainSpec
    space: SearchSpace
    reference: np.ndarray | None  # the configured hypervolume reference point; None: the skill's own
    objective: TaskObjective  # what a trial costs (conf/objective/)


def check_config(cfg: Any) -> CheckedConfig:
    """Check every setting of ``conf/tune.yaml`` that can be checked without the model or the simulator.

    Runs before any costly work; raises :class:`TuneConfigError` (or the demo/domain spec's own ValueError)
    with one line naming the setting.
    """

    from dcm.sim.demos import DemoSpec
    from dcm.sim.domain import DomainSpec
    from dcm.sim.rollout import EMBODIMENTS

    cfg = as_settings(cfg)
    if cfg.ckpt in (None, ""):
        raise TuneConfigError("ckpt is required: python tune.py ckpt=<model.ckpt | reference.json>")
    free = cfg.robot_free
    _integer(free.n_trials, "robot_free.n_trials", 1)
    _integer(free.batch_size, "robot_free.batch_size", 1)
    _integer(free.n_samples, "robot_free.n_samples", 1)
    _integer(free.n_validate, "robot_free.n_validate", 1)
    _integer(cfg.validation_rollouts, "validation_rollouts", 1)
    _integer(cfg.robot_based_n_trials, "robot_based.n_trials", 0, " (0 skips the robot-based search)")
    sampler = free.sampler
    if sampler is not None and sampler not in (AUTO_SAMPLER, *SAMPLERS):
        raise TuneConfigError(f"robot_free.sampler = {sampler!r}; expected null (the checkpoint's), "
                              + ", ".join((AUTO_SAMPLER, *SAMPLERS)))
    if free.sampling_steps is not None:
        _integer(free.sampling_steps, "robot_free.sampling_steps", 1, " or null")
    if free.shared_steps not in (None, "auto"):
        _integer(free.shared_steps, "robot_free.shared_steps", 0, " or auto")
    if free.task_loss not in (None, *TASK_LOSSES):
        raise TuneConfigError(f"robot_free.task_loss = {free.task_loss!r}; expected null (the checkpoint's), "
                              + " or ".join(TASK_LOSSES))
    _integer(cfg.seed, "seed", 0)
    _number(cfg.control_hz, "control_hz")
    if not 1.0 <= cfg.control_hz <= 500.0:
        raise TuneConfigError(f"control_hz = {cfg.control_hz:g} is outside [1, 500] Hz")
    if cfg.embodiment not in EMBODIMENTS:
        raise TuneConfigError(f"embodiment = {cfg.embodiment!r}; known: {', '.join(sorted(EMBODIMENTS))}")
    if cfg.torch_threads is not None:
        _integer(cfg.torch_threads, "torch_threads", 1, " or null")
    if not isinstance(cfg.overwrite, bool):
        raise TuneConfigError(f"overwrite = {cfg.overwrite!r} must be true or false")
    space = space_from_settings(cfg.stiffness, TuneConfigError)
    _check_search(cfg, space)
    _check_loop(cfg, space)
    reference = _check_reference_point(cfg.reference_point, space)
    domain = DomainSpec.resolve(cfg.domain)
    if cfg.demo_file:
        spec = DemoSpec.load(cfg.demo_file)
    else:
        spec = DemoSpec.from_dict(cfg.demo, where="tune.demo")
    _number(cfg.task_from_s, "task_from_s")
    try:
        objective = TaskObjective.from_config(cfg.objective)
    except ObjectiveError as err:
        raise TuneConfigError(str(err)) from None
    if cfg.prior or cfg.prior_weight:  # imported only then: the defaults are checked without torch
        from dcm.models.prior_blend import check_prior

        try:
            check_prior(cfg.prior, cfg.prior_weight)
        except ValueError as err:
            raise TuneConfigError(str(err)) from None
    horizon = spec.horizon(cfg.control_hz)  # a path leaving the bowl is named by the spec's own error
    try:
        task_window_start(cfg.task_from_s, cfg.control_hz, horizon)
    except ValueError as err:
        raise TuneConfigError(f"{err} (this skill's demo)") from None
    probe = np.random.default_rng(0).normal(size=(horizon, 6))  # stands in for the demo force
    try:
        phase_boundaries(cfg.stiffness["phases"], cfg.stiffness["n_phases"], probe)
    except ValueError as err:
        raise TuneConfigError(f"stiffness.phases = {cfg.stiffness['phases']!r}, stiffness.n_phases = "
                              f"{cfg.stiffness['n_phases']}: {err}") from None
    return CheckedConfig(spec, domain, space, reference, objective)


def check_objective(model: Any, objective: TaskObjective, ckpt: Any) -> None:
    """Refuse a predictor trained (or fitted) for another objective than the run's, or one that cannot predict
    what the objective counts (:func:`dcm.models.predict.resolve_objective`, the check every scorer makes)."""
    from dcm.models.configuration import ModelInputError
    from dcm.models.predict import resolve_objective

    try:
        resolve_objective(model, objective)
    except ModelInputError as err:
        raise TuneConfigError(f"ckpt={ckpt}: {err}") from None


def check_predictor(model: Any, cfg: Any) -> None:
    """Refuse a predictor that cannot tune this skill: one that ranks nothing, another phase count, another
    control rate or other input/output channels than the tuner builds."""
    from dcm.data.schema import cond_channel_names, target_channel_names

    cfg = as_settings(cfg)

    if not getattr(model, "ranks_schedules", True):
        raise TuneConfigError(f"ckpt={cfg.ckpt} cannot tune: it predicts F_obs = F_demo, hence L_task = 0, for "
                              "every stiffness schedule, so it cannot rank them; use a checkpoint or a stiffness "
                              "reference JSON (python -m dcm.models.references fit)")
    check_objective(model, TaskObjective.from_config(cfg.objective), cfg.ckpt)
    if hasattr(model, "check_phases"):  # the stiffness reference reads K as per-phase values
        model.check_phases(cfg.stiffness["n_phases"], source="tune stiffness.n_phases")
        model.check_window(cfg.task_from_s, source=f"tune task_from_s for ckpt={cfg.ckpt}")
    spec = getattr(model, "data_spec", None)
    if spec is not None:
        spec.check(cond_channel_names(), target_channel_names(), cfg.control_hz,
                   source=f"the tuner's model inputs (tune.control_hz, stiffness.frame) for ckpt={cfg.ckpt}",
                   stiffness_frame=cfg.stiffness.get("frame", "world"))
