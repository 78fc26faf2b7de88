"""The checks of a tune run: every setting of ``conf/tune.yaml`` before any work, then the predictor against the
skill it is to tune, so a setting that cannot work ends in one line naming it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.cli import check_integer, check_number, one_line
from dcm.control import TASK_LOSSES, phase_boundaries
from dcm.control.objectives import task_window_start
from dcm.search import SearchSpace, check_budget, make_search, space_from_settings

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


def _check_search(cfg: Any, space: SearchSpace) -> None:
    """The strategy builds, its budget covers both searches, and each search outlasts its random start-up."""
    name, options = cfg.search.name, to_container(cfg.search.options) or {}
    try:
        search = make_search(name, space, 0, **options)
    except (TypeError, ValueError) as err:
        raise TuneConfigError(f"search={name} with options {options}: {one_line(err)}") from None
    startup = options.get("n_startup_trials")
    for key in ("robot_free.n_trials", "robot_based.n_trials"):
        n = cfg.robot_free.n_trials if key == "robot_free.n_trials" else cfg.robot_based.n_trials
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


def _check_loop(cfg: Any, space: SearchSpace) -> None:
    """The robot loop's settings (conf/tune.yaml ``robot``, ``observations``, ``loop``)."""
    from dcm.tuning.correction import CORRECTIONS
    from dcm.tuning.schedule_files import check_bowl_in_base

    robot = cfg.get("robot")
    if robot is not None and robot not in ROBOTS:
        raise TuneConfigError(f"robot = {robot!r}; expected null (validate once in the simulator), sim (the simulator "
                              "plays the robot, round after round) or files (write each round for a real robot)")
    if cfg.get("observations") and not cfg.get("resume"):
        raise TuneConfigError(f"observations = {cfg.observations} needs resume=<the run directory that proposed the "
                              "schedules>")
    loop = cfg.get("loop")
    if loop is None:
        return
    _integer(loop.rounds, "loop.rounds", 1)
    _integer(loop.batch, "loop.batch", 1)
    n_trials = _integer(loop.n_trials, "loop.n_trials", 0, " (0: re-rank the robot-free search's trials only)")
    startup = (to_container(cfg.search.options) or {}).get("n_startup_trials")
    if n_trials and isinstance(startup, int) and n_trials <= startup:
        raise TuneConfigError(f"loop.n_trials = {n_trials} is not above search.options.n_startup_trials = {startup}: "
                              "every trial of a round's search would be random; raise it, or 0 to skip the search")
    if _number(loop.tolerance_N, "loop.tolerance_N") < 0:
        raise TuneConfigError(f"loop.tolerance_N = {loop.tolerance_N} must be >= 0 N")
    if loop.correction not in CORRECTIONS:
        raise TuneConfigError(f"loop.correction = {loop.correction!r}; expected one of {', '.join(CORRECTIONS)}")
    for key in ("lengthscale", "noise_ratio", "ridge_alpha"):
        if _number(loop[key], f"loop.{key}") <= 0:
            raise TuneConfigError(f"loop.{key} = {loop[key]} must be > 0")
    try:
        check_bowl_in_base(to_container(loop.get("bowl_in_base")))
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


def check_config(cfg: Any) -> CheckedConfig:
    """Check every setting of ``conf/tune.yaml`` that can be checked without the model or the simulator.

    Runs before any costly work; raises :class:`TuneConfigError` (or the demo/domain spec's own ValueError)
    with one line naming the setting.
    """
    from omegaconf import OmegaConf

    from dcm.sim.demos import DemoSpec
    from dcm.sim.domain import DomainSpec
    from dcm.sim.rollout import EMBODIMENTS

    if OmegaConf.is_missing(cfg, "ckpt") or cfg.ckpt in (None, ""):
        raise TuneConfigError("ckpt is required: python tune.py ckpt=<model.ckpt | reference.json>")
    free, robot = cfg.robot_free, cfg.robot_based
    _integer(free.n_trials, "robot_free.n_trials", 1)
    _integer(free.batch_size, "robot_free.batch_size", 1)
    _integer(free.n_samples, "robot_free.n_samples", 1)
    _integer(free.n_validate, "robot_free.n_validate", 1)
    _integer(cfg.validation_rollouts, "validation_rollouts", 1)
    _integer(robot.n_trials, "robot_based.n_trials", 0, " (0 skips the robot-based search)")
    sampler = free.get("sampler")
    if sampler is not None and sampler not in (AUTO_SAMPLER, *SAMPLERS):
        raise TuneConfigError(f"robot_free.sampler = {sampler!r}; expected null (the checkpoint's), "
                              + ", ".join((AUTO_SAMPLER, *SAMPLERS)))
    if free.get("sampling_steps") is not None:
        _integer(free.sampling_steps, "robot_free.sampling_steps", 1, " or null")
    if free.get("shared_steps") not in (None, "auto"):
        _integer(free.shared_steps, "robot_free.shared_steps", 0, " or auto")
    if free.get("task_loss") not in (None, *TASK_LOSSES):
        raise TuneConfigError(f"robot_free.task_loss = {free.task_loss!r}; expected null (the checkpoint's), "
                              + " or ".join(TASK_LOSSES))
    _integer(cfg.seed, "seed", 0)
    _number(cfg.control_hz, "control_hz")
    if not 1.0 <= cfg.control_hz <= 500.0:
        raise TuneConfigError(f"control_hz = {cfg.control_hz:g} is outside [1, 500] Hz")
    if cfg.embodiment not in EMBODIMENTS:
        raise TuneConfigError(f"embodiment = {cfg.embodiment!r}; known: {', '.join(sorted(EMBODIMENTS))}")
    if cfg.get("torch_threads") is not None:
        _integer(cfg.torch_threads, "torch_threads", 1, " or null")
    if not isinstance(cfg.get("overwrite", False), bool):
        raise TuneConfigError(f"overwrite = {cfg.overwrite!r} must be true or false")
    space = space_from_settings(cfg.stiffness, TuneConfigError)
    _check_search(cfg, space)
    _check_loop(cfg, space)
    reference = _check_reference_point(cfg.get("reference_point"), space)
    domain = DomainSpec.resolve(to_container(cfg.domain))
    if cfg.demo_file:
        spec = DemoSpec.load(cfg.demo_file)
    else:
        spec = DemoSpec.from_dict(to_container(cfg.demo), where="tune.demo")
    _number(cfg.get("task_from_s", 0.0), "task_from_s")
    if cfg.get("prior") or cfg.get("prior_weight"):  # imported only then: the defaults are checked without torch
        from dcm.models.prior_blend import check_prior

        try:
            check_prior(cfg.get("prior"), cfg.get("prior_weight", 0.0))
        except ValueError as err:
            raise TuneConfigError(str(err)) from None
    horizon = spec.horizon(cfg.control_hz)  # a path leaving the bowl is named by the spec's own error
    try:
        task_window_start(cfg.get("task_from_s", 0.0), cfg.control_hz, horizon)
    except ValueError as err:
        raise TuneConfigError(f"{err} (this skill's demo)") from None
    probe = np.random.default_rng(0).normal(size=(horizon, 6))  # stands in for the demo force
    try:
        phase_boundaries(cfg.stiffness.phases, cfg.stiffness.n_phases, probe)
    except ValueError as err:
        raise TuneConfigError(f"stiffness.phases = {cfg.stiffness.phases!r}, stiffness.n_phases = "
                              f"{cfg.stiffness.n_phases}: {err}") from None
    return CheckedConfig(spec, domain, space, reference)


def check_predictor(model: Any, cfg: Any) -> None:
    """Refuse a predictor that cannot tune this skill: one that ranks nothing, another phase count, another
    control rate or other input/output channels than the tuner builds."""
    from dcm.data.schema import cond_channel_names, target_channel_names

    if not getattr(model, "ranks_schedules", True):
        raise TuneConfigError(f"ckpt={cfg.ckpt} cannot tune: it predicts F_obs = F_demo, hence L_task = 0, for "
                              "every stiffness schedule, so it cannot rank them; use a checkpoint or a stiffness "
                              "reference JSON (python -m dcm.models.references fit)")
    if hasattr(model, "check_phases"):  # the stiffness reference reads K as per-phase values
        model.check_phases(cfg.stiffness.n_phases, source="tune stiffness.n_phases")
        model.check_window(cfg.get("task_from_s", 0.0), source=f"tune task_from_s for ckpt={cfg.ckpt}")
    spec = getattr(model, "data_spec", None)
    if spec is not None:
        spec.check(cond_channel_names(), target_channel_names(), cfg.control_hz,
                   source=f"tune.control_hz and the tuner's model inputs for ckpt={cfg.ckpt}")


class DemoRecordingWarning(UserWarning):
    """The new skill's demo is recorded otherwise than the predictor's training demos."""


def recording_mismatch(ckpt: Any, spec: Any, control_hz: float = 20.0) -> str | None:
    """Why the skill's demo (a DemoSpec) is not recorded as the predictor's training demos were; None if it
    is, or if the predictor does not say how its demos were recorded. F_demo and x_demo are model inputs, so another
    duration or demonstrator is an input the model never saw, and its ranking can drop. A waypoint file sets
    its own duration: it matches when it gives the training demos' step count at ``control_hz``."""
    from dcm.data.recording import Recording
    from dcm.models.predict import trained_on, trained_recording
    from dcm.sim.demos import waypoint_span_s

    trained = trained_recording(ckpt)
    if trained is None:
        return None
    fixes = []
    if spec.family == "waypoints":
        trained_horizon = round(trained.duration_s * control_hz)
        if spec.horizon(control_hz) != trained_horizon:
            fixes.append(f"retime {spec.waypoints} to span {waypoint_span_s(trained_horizon, control_hz):g} s "
                         f"({trained_horizon} steps at {control_hz:g} Hz, the last row at step {trained_horizon - 1})")
    elif float(spec.duration_s) != trained.duration_s:
        fixes.append(f"demo.duration_s={trained.duration_s:g}")
    if bool(spec.lead) != trained.lead:
        fixes.append(f"++demo.lead={str(trained.lead).lower()}")
    grid = int(spec.bowl.hfield_res)
    if trained.bowl_grid is not None and grid != trained.bowl_grid:
        name = {"name": f"{spec.bowl.name}_{trained.bowl_grid}"} if spec.bowl.name else {}
        fixes.append(bowl_override(spec.bowl, hfield_res=trained.bowl_grid, **name))
    if trained.hover_m is not None and float(spec.hover_m) != trained.hover_m:
        fixes.append(f"++demo.hover_m={trained.hover_m:g}")
    if not fixes:
        return None
    here = Recording(float(spec.duration_s), bool(spec.lead), None if trained.bowl_grid is None else grid,
                     None if trained.hover_m is None else float(spec.hover_m))
    return (f"ckpt={ckpt} learned from {trained.describe()} (dataset {trained_on(ckpt)}); this skill's demo: "
            f"{here.describe()}. To record it as the model's training demos were: {' '.join(fixes)} "
            "(or those fields of demo_file)")


def bowl_override(bowl: Any, **changes: Any) -> str:
    """The command-line override that gives the skill ``bowl`` (a BowlSpec) with ``changes``: the fields that
    differ from BowlSpec's defaults, as one inline mapping (a bowl preset name cannot take a field override)."""
    from dcm.sim.geometry import BowlSpec

    default = BowlSpec().to_dict()
    fields = {k: v for k, v in {**bowl.to_dict(), **changes}.items() if v != default[k] or k in changes}
    plain = lambda v: "[" + ",".join(f"{x:g}" for x in v) + "]" if isinstance(v, list) else (  # noqa: E731
        f"{v:g}" if isinstance(v, float) else str(v))
    return "'demo.bowl={" + ",".join(f"{k}:{plain(v)}" for k, v in fields.items()) + "}'"



class SampleSpreadWarning(UserWarning):
    """The samples of one prediction branch only where the net sees an almost clean force, so they barely differ
    and a loss over them ranks by about the mean alone."""


def spread_warning(sampler: str | None, n_samples: int, task_loss: str | None) -> str | None:
    """Why ``task_loss=over_samples`` will see little spread under ``sampler``; None where it will not.
    ddim_even's last step is at t = 0, where the samples of a proposal converge; ddim's last step, at t = T/n - 1,
    keeps their spread."""
    if sampler != "ddim_even" or n_samples <= 1 or task_loss != "over_samples":
        return None
    return ("robot_free.sampler=ddim_even ends its chain at t = 0, where the robot_free.n_samples barely differ; "
            "robot_free.sampler=ddim robot_free.sampling_steps=3 keeps the spread task_loss=over_samples ranks by")


# ----------------------------------------------------------------------------------------------- guessing
class ConditioningRangeWarning(UserWarning):
    """A model input of this skill lies far outside the range the model was trained on: its predictions there
    are extrapolations."""


class PredictionErrorWarning(UserWarning):
    """The model's L_task on the validated solutions is much further from the simulator's than on its valid
    split: its ranking of this skill's schedules is likely off."""


# Inputs are judged in the model's normalised units, where the normaliser's training range is [-1, 1]: warn
# beyond this many half-widths from its centre (past the range by half its width; zscore: 6 std from the mean).
CONDITIONING_LIMIT = 2.0
# The validated solutions' mean |predicted - realised| L_task may reach this multiple of the model's valid
# error (its card's evaluation on the valid split) ...
PREDICTION_ERROR_FACTOR = 3.0
# ... or, without one (a training checkpoint, a stiffness reference, a blend with a prior), this many newtons.
PREDICTION_TOLERANCE_N = 0.3
_UNITS = {"m": "m", "rad": "rad", "N": "N", "Nm": "N·m", "Npm": "N/m", "Nmprad": "N·m/rad"}


def _force_model(model: Any) -> Any:
    """The force model behind a predictor (a blend's model), or None for one without input normalisers."""
    inner = getattr(model, "model", model)  # PriorBlend keeps the force model as .model
    return inner if hasattr(inner, "cond_norm") and hasattr(inner, "cfg") else None


def conditioning_check(model: Any, inputs: tuple[np.ndarray, ...], stiffness_Npm: list[float]) -> dict[str, Any]:
    """Where this skill's model inputs leave the model's training range, channel by channel.

    ``inputs``: the raw (x_demo, F_demo, x_attr, K), each (B, H, 6), of the B constant schedules at
    ``stiffness_Npm`` (the search space's softest and stiffest), so the attractor is judged over the space's
    stiffness range. Returns what ``results.json`` records; the range is the one the model's input normaliser
    stores (``minmax``: the train split's min..max; ``zscore``: its mean ± 3 std).
    """
    import torch

    from dcm.data.schema import cond_channel_names, cond_slice
    from dcm.models.cond_encoding import encode_conditions

    force_model = _force_model(model)
    if force_model is None:
        return {"checked": False, "why": "the predictor has no input normaliser (a stiffness reference)"}
    encoding = force_model.cfg.cond_encoding
    cond = torch.as_tensor(np.concatenate(inputs, axis=-1))
    encoded = encode_conditions(cond, encoding).double().numpy()  # (B, H, 24)
    low, high = force_model.cond_norm.value_range()
    center, half = (low + high) / 2, (high - low) / 2
    normalised = (encoded - center) / half
    x_attr, k = cond_slice("x_attr"), cond_slice("K")
    outside = []
    for c, name in enumerate(cond_channel_names()):
        b, t = np.unravel_index(np.argmax(np.abs(normalised[..., c])), normalised.shape[:2])
        z = float(normalised[b, t, c])
        if abs(z) <= CONDITIONING_LIMIT:
            continue
        value, lo, hi, shown = float(encoded[b, t, c]), float(low[c]), float(high[c]), name
        if encoding == "physical" and k.start <= c < k.stop:  # the net reads log K: show it in N/m
            value, lo, hi = (float(np.exp(v)) for v in (value, lo, hi))
        elif encoding == "physical" and x_attr.start <= c < x_attr.stop:  # the net reads x_attr - x_demo
            shown = f"{name} - x_demo.{name.split('.', 1)[1]}"
        depends = x_attr.start <= c < x_attr.stop or k.start <= c < k.stop
        outside.append({"channel": shown, "value": value, "unit": _UNITS[name.rsplit("_", 1)[1]],
                        "training_low": lo, "training_high": hi, "normalised": z,
                        "stiffness_Npm": float(stiffness_Npm[b]) if depends else None})
    return {"checked": True, "normalization": force_model.cfg.normalization, "cond_encoding": encoding,
            "limit": CONDITIONING_LIMIT, "in_range": not outside, "outside": outside}


def conditioning_warnings(conditioning: dict[str, Any]) -> list[str]:
    """One line per channel :func:`conditioning_check` found outside, naming it and how far out it lies."""
    lines = []
    for c in conditioning.get("outside", []):
        unit, at = c["unit"], "" if c["stiffness_Npm"] is None else f" at stiffness {c['stiffness_Npm']:g} N/m"
        lines.append(f"{c['channel']}: {c['value']:.3g} {unit}{at} lies outside the training range "
                     f"[{c['training_low']:.3g}, {c['training_high']:.3g}] {unit}, {abs(c['normalised']):.3g}x the "
                     f"range's half-width from its centre (warned above {conditioning['limit']:g}x); the model's "
                     "predictions there are extrapolations")
    return lines


def prediction_limit(ckpt: Any, prior: Any) -> dict[str, Any]:
    """How far the validated solutions' predicted L_task may be from the realised one before the run warns:
    ``PREDICTION_ERROR_FACTOR`` x the valid-split L_task error the checkpoint's card records for its own
    dataset, else ``PREDICTION_TOLERANCE_N`` (and always with a prior: the blend is not what the card scored)."""
    from dcm.models.checkpoint import checkpoint_card

    card: dict[str, Any] = {}
    if not prior and str(ckpt).lower().endswith(".ckpt"):
        try:
            card = checkpoint_card(ckpt) or {}
        except ValueError:
            card = {}
    trained_on = Path(str((card.get("dataset") or {}).get("path") or "")).name
    for key, evaluation in (card.get("evaluations") or {}).items():
        if not isinstance(evaluation, dict) or evaluation.get("split") != "valid" or not trained_on:
            continue
        error = evaluation.get("L_task_mae_N")
        if Path(str(evaluation.get("dataset", ""))).name == trained_on and isinstance(error, (int, float)) and \
                math.isfinite(error) and error > 0:
            return {"limit_N": PREDICTION_ERROR_FACTOR * float(error), "valid_L_task_mae_N": float(error),
                    "factor": PREDICTION_ERROR_FACTOR, "limit_source": f"{PREDICTION_ERROR_FACTOR:g} x the valid "
                    f"L_task error in the checkpoint's card ({key})"}
    return {"limit_N": PREDICTION_TOLERANCE_N, "valid_L_task_mae_N": None, "factor": None,
            "limit_source": "absolute tolerance"}


def prediction_check(predicted: np.ndarray, realised: np.ndarray, limit: dict[str, Any]) -> dict[str, Any]:
    """Predicted against realised L_task [N] of the validated solutions (failed rollouts left out), for
    ``results.json``: their mean absolute difference and whether it exceeds ``limit``."""
    keep = np.isfinite(predicted) & np.isfinite(realised)
    error = float(np.mean(np.abs(predicted[keep] - realised[keep]))) if keep.any() else None
    return {"predicted_L_task_N": predicted[keep].tolist(), "realised_L_task_N": realised[keep].tolist(),
            "L_task_mae_N": error, "n_solutions": int(keep.sum()), **limit,
            "exceeded": error is not None and error > limit["limit_N"]}
