"""Typed configurations of the force models and the errors raised on incompatible inputs.

The LightningModules take these fields as plain keyword arguments (so Hydra overrides like
``model.diffusion_steps=10`` and ``save_hyperparameters`` both work) and rebuild the dataclass from them;
a checkpoint therefore reloads with nothing but its own file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from dcm.control.objectives import TASK_LOSSES, ObjectiveError, TaskObjective
from dcm.data.schema import (  # noqa: F401 - the channel layout is the data's; re-exported for model users
    COND_FIELDS,
    FORCE_LAYOUT,
    TARGET_FIELDS,
    DatasetMismatchError,
    TargetLayout,
    cond_channel_names,
    target_channel_names,
    target_layout,
)
from dcm.models.cond_encoding import COND_ENCODINGS
from dcm.models.diffusion import INPUT_SCALINGS, PREDICTION_TYPES, SAMPLERS
from dcm.models.normalizer import NORMALIZATIONS


class ModelInputError(ValueError):
    """Base class of the model package's input errors."""


class CheckpointKindError(ModelInputError):
    """A checkpoint holds another model class than the one asked to load it."""


class CheckpointIncompatibleError(ModelInputError):
    """A checkpoint's parameter names do not fit this code (written by another dcm version)."""


class CheckpointUnsafeError(ModelInputError):
    """A file that holds more than plain data: reading it would run code, so it is not read."""


class CheckpointVersionWarning(UserWarning):
    """A checkpoint was written by another dcm version: it loads, but its behaviour may differ."""


@dataclass
class DataSpec:
    """What the model was trained on; a dataset must match it to be evaluated or fine-tuned on."""

    cond_channels: list[str] = field(default_factory=cond_channel_names)
    target_channels: list[str] = field(default_factory=target_channel_names)
    control_hz: float = 20.0
    stiffness_frame: str = "world"  # the frame the stiffness channels are diagonals in (dcm.control.FRAMES)

    def check(self, cond_channels: list[str], target_channels: list[str], control_hz: float,
              source: str = "dataset", stiffness_frame: str = "world") -> None:
        """Raise :class:`DatasetMismatchError` naming the first difference.

        ``target_channels`` may be the model's force channels alone where the model also predicts the pose: a
        caller that only asks for predictions (a skill of the tuner) has no x_obs, and needs none."""
        if list(cond_channels) != list(self.cond_channels):
            raise DatasetMismatchError(
                f"{source}: condition channels {list(cond_channels)} differ from the model's {self.cond_channels}")
        force_only = list(self.target_channels[FORCE_LAYOUT.force])
        if list(target_channels) != list(self.target_channels) and list(target_channels) != force_only:
            raise DatasetMismatchError(
                f"{source}: target channels {list(target_channels)} differ from the model's {self.target_channels}")
        if abs(float(control_hz) - float(self.control_hz)) > 1e-9:
            raise DatasetMismatchError(
                f"{source}: control rate {control_hz} Hz, but the model was trained at {self.control_hz} Hz")
        if stiffness_frame != self.stiffness_frame:
            raise DatasetMismatchError(
                f"{source}: stiffness in the {stiffness_frame} frame, but the model was trained on stiffness in the "
                f"{self.stiffness_frame} frame (stiffness.frame={self.stiffness_frame})")


TARGETS = ("absolute", "residual")


@dataclass
class ForceModelConfig:
    """Fields shared by the DCM and the single-pass baseline."""

    # score net: {"name": <dcm.models.nets name>, **constructor kwargs}; conf/net/*.yaml
    net: dict[str, Any] = field(default_factory=lambda: {"name": "retnet", "d_model": 128})
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    lr_schedule: str = "cosine"  # cosine (to 0 over the run) | constant
    ema_decay: float = 0.999  # 0 disables the EMA copy
    eval_batch_size: int = 256
    target: str = "absolute"  # absolute: F_obs | residual: F_obs - F_demo (F_demo added back on prediction)
    normalization: str = "minmax"  # minmax: train [min, max] -> [-1, 1] | zscore: mean ± 3 std -> [-1, 1]
    cond_encoding: str = "raw"  # raw (the paper's) | physical: x_attr - x_demo and log K (dcm.models.cond_encoding)
    # weight of the within-skill L_task term added to the force loss (dcm.models.task_ranking; 0: off, the
    # paper's loss). It compares trials of one skill, so the batches must hold several: data.skill_group > 1
    task_weight: float = 0.0
    task_from_s: float = 0.0  # that term's L_task counts from this second on (1.0: after the approach)
    # what the net predicts: force (F_obs, the paper's) | force_and_pose (F_obs and the realised translation
    # x_obs - x_demo, which an objective that counts the path needs; dcm.data.schema.TargetLayout)
    target_fields: str = "force"
    # the L_task the model is trained (task term) and selected for: TaskObjective.to_dict(); None: the paper's
    objective: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if not (float(self.task_weight) >= 0.0 and math.isfinite(float(self.task_weight))):
            raise ModelInputError(f"task_weight must be a finite number >= 0, got {self.task_weight}")
        if not (float(self.task_from_s) >= 0.0 and math.isfinite(float(self.task_from_s))):
            raise ModelInputError(f"task_from_s must be a finite number of seconds >= 0, got {self.task_from_s}")
        if self.target not in TARGETS:
            raise ModelInputError(f"target must be one of {TARGETS}, got {self.target!r}")
        if self.normalization not in NORMALIZATIONS:
            raise ModelInputError(f"normalization must be one of {NORMALIZATIONS}, got {self.normalization!r}")
        if self.cond_encoding not in COND_ENCODINGS:
            raise ModelInputError(f"cond_encoding must be one of {COND_ENCODINGS}, got {self.cond_encoding!r}")
        if self.lr <= 0:
            raise ModelInputError(f"lr must be > 0, got {self.lr}")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ModelInputError(f"ema_decay must be in [0, 1), got {self.ema_decay}")
        if self.lr_schedule not in ("cosine", "constant"):
            raise ModelInputError(f"lr_schedule must be 'cosine' or 'constant', got {self.lr_schedule!r}")
        self.net = _net_config(self.net)
        if "name" not in self.net:
            raise ModelInputError(f"net config needs a 'name' (one of dcm.models.nets.SCORE_NETS), got {self.net}")
        if self.warmup_steps < 0:
            raise ModelInputError(f"warmup_steps must be >= 0, got {self.warmup_steps}")
        if self.target_fields not in TARGET_FIELDS:
            raise ModelInputError(f"target_fields must be one of {TARGET_FIELDS}, got {self.target_fields!r}")
        if self.objective is not None:
            self.objective = self.task_objective.to_dict()
        check_objective_fits(self.task_objective, self.target_fields)

    @property
    def task_objective(self) -> TaskObjective:
        """The configured L_task (``objective``), the paper's when none is recorded."""
        try:
            return TaskObjective.from_dict(self.objective)
        except ObjectiveError as err:
            raise ModelInputError(str(err)) from None

    @property
    def layout(self) -> TargetLayout:
        return target_layout(self.target_fields)

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any]):
        """Build from keyword arguments, naming any unknown key instead of silently ignoring it."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ModelInputError(f"unknown {cls.__name__} fields {unknown}; known: {sorted(known)}")
        return cls(**{k: (dict(v) if isinstance(v, Mapping) else v) for k, v in kwargs.items()})

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def check_objective_fits(objective: TaskObjective, target_fields: str) -> None:
    """Refuse an objective that counts the tool's path for a model that predicts only the force: it could not
    tell one schedule's path from another's."""
    if problem := target_layout(target_fields).objective_problem(objective):
        raise ModelInputError(problem)


def check_objective_name(given: TaskObjective, own: TaskObjective, source: str) -> None:
    """Refuse scoring with an objective of another kind than the one a predictor was trained or fitted for
    (``source`` names it, e.g. the checkpoint): its L_task is another quantity, in another unit."""
    if given.name != own.name:
        raise ModelInputError(f"objective {given.describe()} differs from {own.describe()} of {source}; use "
                              f"objective={own.name}, or a predictor trained for objective={given.name}")


def _net_config(net: Mapping[str, Any]) -> dict[str, Any]:
    """Plain {name, **kwargs}; a ``_target_`` naming a registered net class stands in for ``name``."""
    net = dict(net)
    target = net.pop("_target_", None)
    if "name" not in net and target:
        from dcm.models.nets import SCORE_NETS

        by_path = {v.replace(":", "."): k for k, v in SCORE_NETS.items()}
        if target in by_path:
            net["name"] = by_path[target]
    return net


MAX_DIFFUSION_STEPS = 100


@dataclass
class DCMConfig(ForceModelConfig):
    """The diffusion contact model: DDPM over the normalised force trajectory."""

    diffusion_steps: int = 30  # T, 1..100
    # what the net outputs and the loss compares: sample (x0, the default: the x0 estimate of ε-prediction
    # divides the net's error by sqrt(alpha_bar), which is small near pure noise), epsilon, v_prediction
    prediction_type: str = "sample"
    # noise schedule: dcm.models.diffusion.NoiseSchedule fields (name, beta_start, ...); conf/schedule/*.yaml
    # omitted fields take NoiseSchedule's defaults (incl. clipping the x0 estimate, which sampling needs)
    schedule: dict[str, Any] = field(default_factory=lambda: {"name": "linear"})
    # ddpm (ancestral, T steps) | ddim | ddim_even (deterministic, sampling_steps) | one_step (a student written by
    # dcm-distill, whose net maps unit noise at t = T-1 to a sample in one call; it samples only so)
    sampler: str = "ddpm"
    sampling_steps: int | None = None  # None = T
    n_samples: int = 1  # k samples averaged per prediction during evaluation
    # L_task of k samples: of_mean (of their mean force) | over_samples (RMS over the samples' L_task, i.e. the
    # expected loss, spread included: what a model of the force distribution adds over one of its mean)
    task_loss: str = "of_mean"
    # how the noisy force enters the net: unit (x_t, the paper's) | signal (x_t * sqrt(alpha_bar_t))
    input_scaling: str = "unit"
    # share of each training batch drawn at the pure-noise step T-1, the rest uniform over 0..T-1 (0: the
    # paper's uniform draw, 1/T of the batch there). With input_scaling=signal the net sees about zeros at
    # that step and regresses the force as the single-pass baseline does (studies/record.md, "The pure-noise step").
    top_step_fraction: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 <= float(self.top_step_fraction) <= 1.0:
            raise ModelInputError(f"top_step_fraction must be in [0, 1], got {self.top_step_fraction}")
        if not 1 <= int(self.diffusion_steps) <= MAX_DIFFUSION_STEPS:
            raise ModelInputError(f"diffusion_steps must be in 1..{MAX_DIFFUSION_STEPS}, got {self.diffusion_steps}")
        if isinstance(self.schedule, str):
            self.schedule = {"name": self.schedule}
        self.schedule = {k: v for k, v in dict(self.schedule).items() if k != "_target_"}
        if self.sampler not in SAMPLERS:
            raise ModelInputError(f"sampler must be one of {SAMPLERS}, got {self.sampler!r}")
        if self.sampler == "one_step":
            if self.input_scaling != "unit" or self.prediction_type != "sample" or self.sampling_steps not in (None, 1):
                raise ModelInputError("sampler one_step is a student's (dcm-distill): it needs input_scaling=unit, "
                                      "prediction_type=sample and sampling_steps 1, got "
                                      f"{self.input_scaling}, {self.prediction_type}, {self.sampling_steps}")
            self.sampling_steps = 1
        if self.sampling_steps is not None and not 1 <= int(self.sampling_steps) <= int(self.diffusion_steps):
            raise ModelInputError(
                f"sampling_steps must be in 1..diffusion_steps={self.diffusion_steps}, got {self.sampling_steps}")
        if self.prediction_type not in PREDICTION_TYPES:
            raise ModelInputError(f"prediction_type must be one of {PREDICTION_TYPES}, got {self.prediction_type!r}")
        if int(self.n_samples) < 1:
            raise ModelInputError(f"n_samples must be >= 1, got {self.n_samples}")
        if self.task_loss not in TASK_LOSSES:
            raise ModelInputError(f"task_loss must be one of {TASK_LOSSES}, got {self.task_loss!r}")
        if self.input_scaling not in INPUT_SCALINGS:
            raise ModelInputError(f"input_scaling must be one of {INPUT_SCALINGS}, got {self.input_scaling!r}")


@dataclass
class BaselineConfig(ForceModelConfig):
    """The paper's T=1 baseline: the same score net regressing the force in one pass."""
