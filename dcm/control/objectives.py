"""What a trial costs: the task objective (the paper's force error, or a wipe's force and path against
tolerances) and the compliance cost. Both are minimised; both accept numpy arrays or torch tensors.

Generation, training selection, evaluation and tuning all score a trial through :class:`TaskObjective`, so the
configured objective (``conf/objective/``) means the same thing at every stage.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

# how k force samples give a predicted L_task: of their mean force, or over the samples (spread included)
TASK_LOSSES = ("of_mean", "over_samples")
OBJECTIVES = ("paper", "wipe")
# Below this tangential-free contact force [N] the demo's force says too little about the surface normal, and
# the tool's approach axis (bowl z) takes over (:func:`surface_normals`).
NORMAL_FROM_FORCE_MIN_N = 1.0
# The tool slides (and friction lies along its velocity) where it moves faster than this fraction of the demo's
# wiping speed, and its velocity's cosine with the force is below SLIDING_MAX_COSINE (friction coefficients up to
# 0.58); a slower or a pressing motion is the approach, a dwell or a lift-off.
SLIDING_SPEED_FRACTION = 0.1
SLIDING_MAX_COSINE = 0.5


class ObjectiveError(ValueError):
    """An objective setting that cannot score a trial; the message names the setting."""


def task_loss(force_obs: Any, force_demo: Any, from_step: int = 0) -> Any:
    """The paper's L_task [N]: RMSE of the observed against the demonstrated contact force over time and the
    3 force axes.

    Torques are left out because their unit differs. Leading batch dimensions are kept; time is the second
    to last axis. ``from_step``: count the steps from this one on (:func:`task_window_start`).
    """
    err = (force_obs[..., from_step:, :3] - force_demo[..., from_step:, :3]) ** 2
    return err.mean(-1).mean(-1) ** 0.5


def task_window_start(task_from_s: float, control_hz: float, horizon: int) -> int:
    """The first control step that L_task counts when scoring from ``task_from_s`` seconds on.

    Every demo starts with an approach (``DemoSpec.approach_s``): the tool descends onto the bowl and F_demo
    jumps from 0 to the press force within a step or two. A rollout that touches down a step earlier or later,
    or overshoots on impact, errs by newtons there, and those few steps can hold most of a trajectory's
    squared error. Scoring from the approach's end ranks schedules by how they track the force while wiping.
    Raises ValueError naming ``task_from_s`` unless 0 <= it < the horizon.
    """
    seconds = float(task_from_s)
    start = int(round(seconds * float(control_hz))) if math.isfinite(seconds) else -1
    if start < 0 or start >= int(horizon):
        raise ValueError(f"task_from_s = {task_from_s} s must be >= 0 and before the end of the "
                         f"{int(horizon) / float(control_hz):g} s trajectories")
    return start


def task_loss_over_samples(force_mean: Any, force_std: Any, force_demo: Any, from_step: int = 0) -> Any:
    """The root mean square over k force samples of their L_task [N], from the samples' mean and population
    std alone: ``sqrt(mean_t,axes((mean - F_demo)^2 + std^2))``.

    Unlike :func:`task_loss` of the mean force, it counts the spread: a force that is uncertain (say, by the
    stiffness times an unknown surface offset) tracks the demo worse on average than its mean does. With
    ``std = 0`` it is ``task_loss(force_mean, force_demo)``.
    """
    w = slice(from_step, None)
    err = (force_mean[..., w, :3] - force_demo[..., w, :3]) ** 2 + force_std[..., w, :3] ** 2
    return err.mean(-1).mean(-1) ** 0.5


def surface_normals(x_demo: Any, force_demo: Any) -> np.ndarray:
    """Unit surface normals (..., H, 3) along a demo, bowl frame, from the demo's own pose and contact force.

    Sliding friction opposes the tool's velocity, which lies in the surface's tangent plane; so where the tool
    slides, the contact force with its component along the velocity taken out points along the normal. A user's
    robot logs both (the pose, and the F/T or external-wrench estimate), so the normal needs no model of the
    surface. The tool slides where it moves faster than :data:`SLIDING_SPEED_FRACTION` of the demo's wiping
    speed (its 90th percentile) and not mostly along the force (the approach, a lift-off); elsewhere the force
    is taken as it is. Where that force is below :data:`NORMAL_FROM_FORCE_MIN_N` (before touch-down) the
    normal blends into bowl z, the axis the tool approaches along. Always numpy: a normal depends on the demo
    alone, never on a gradient.
    """
    x = _numpy(x_demo)[..., :3]
    force = _numpy(force_demo)[..., :3]
    velocity = np.zeros_like(x)  # per step; central differences, one-sided at the ends
    if x.shape[-2] > 1:
        velocity[..., 1:-1, :] = (x[..., 2:, :] - x[..., :-2, :]) / 2.0
        velocity[..., 0, :] = x[..., 1, :] - x[..., 0, :]
        velocity[..., -1, :] = x[..., -1, :] - x[..., -2, :]
    speed = np.linalg.norm(velocity, axis=-1, keepdims=True)
    along = np.divide(velocity, speed, out=np.zeros_like(velocity), where=speed > 0)
    magnitude = np.linalg.norm(force, axis=-1, keepdims=True)
    cosine = np.abs(np.divide((force * along).sum(-1, keepdims=True), magnitude, out=np.ones_like(magnitude),
                              where=magnitude > 0))
    wiping_speed = np.percentile(speed, 90, axis=-2, keepdims=True)
    sliding = (speed > SLIDING_SPEED_FRACTION * wiping_speed) & (cosine < SLIDING_MAX_COSINE)
    normal_force = force - sliding * (force * along).sum(-1, keepdims=True) * along
    magnitude = np.linalg.norm(normal_force, axis=-1, keepdims=True)
    sign = np.where(normal_force[..., 2:3] < 0, -1.0, 1.0)  # point up, out of the material
    weight = np.minimum(magnitude / NORMAL_FROM_FORCE_MIN_N, 1.0)
    direction = np.divide(normal_force * sign, magnitude, out=np.zeros_like(force), where=magnitude > 0)
    blended = weight * direction + (1.0 - weight) * np.array([0.0, 0.0, 1.0])
    return blended / np.linalg.norm(blended, axis=-1, keepdims=True)


def tangential(error: Any, normals: Any) -> Any:
    """``error`` (..., 3) with its component along the unit ``normals`` (..., 3) taken out."""
    return error - (error * normals).sum(-1)[..., None] * normals


def path_error(x_obs: Any, x_demo: Any, force_demo: Any, from_step: int = 0) -> Any:
    """Path RMSE [m]: RMS over time of the distance from the tool's position to the demo's in the surface's
    tangent plane (:func:`surface_normals`), so that the normal offset a re-placed bowl forces on the tool is
    not a path error. Leading batch dimensions are kept."""
    normals = _like(surface_normals(x_demo, force_demo)[..., from_step:, :], x_obs)
    error = tangential(x_obs[..., from_step:, :3] - x_demo[..., from_step:, :3], normals)
    return (error ** 2).sum(-1).mean(-1) ** 0.5


def path_error_over_samples(x_mean: Any, x_std: Any, x_demo: Any, force_demo: Any, from_step: int = 0) -> Any:
    """The RMS over k pose samples of their path error [m], from their mean and per-axis population std:
    ``E|P e|^2 = |P mean|^2 + sum_i std_i^2 (1 - n_i^2)`` for the tangent-plane projection ``P = I - n n^T``."""
    normals = _like(surface_normals(x_demo, force_demo)[..., from_step:, :], x_mean)
    error = tangential(x_mean[..., from_step:, :3] - x_demo[..., from_step:, :3], normals)
    spread = (x_std[..., from_step:, :3] ** 2 * (1.0 - normals ** 2)).sum(-1)
    return ((error ** 2).sum(-1) + spread).mean(-1) ** 0.5


@dataclass(frozen=True)
class TaskObjective:
    """The configured L_task (``conf/objective/``).

    * ``paper``: the paper's force RMSE [N] (:func:`task_loss`); the path does not count.
    * ``wipe``: ``sqrt((force RMSE / force_tolerance_N)^2 + (path RMSE / path_tolerance_m)^2)``, dimensionless:
      a wipe must press the force and cover the path, and each tolerance says how much error of its kind
      costs as much as the other's. An infinite ``path_tolerance_m`` leaves the path out.
    """

    name: str = "paper"
    force_tolerance_N: float = 1.0
    path_tolerance_m: float = math.inf

    def __post_init__(self) -> None:
        if self.name not in OBJECTIVES:
            raise ObjectiveError(f"objective = {self.name!r} is not one of {', '.join(OBJECTIVES)} "
                                 "(conf/objective/)")
        for key in ("force_tolerance_N", "path_tolerance_m"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value) or value <= 0:
                raise ObjectiveError(f"objective.{key} = {value!r} must be a number > 0")
            object.__setattr__(self, key, float(value))
        if math.isinf(self.force_tolerance_N):
            raise ObjectiveError("objective.force_tolerance_N = inf leaves the force out; a wipe must press it")
        if self.name == "paper" and (self.force_tolerance_N != 1.0 or math.isfinite(self.path_tolerance_m)):
            raise ObjectiveError("objective=paper is the force RMSE in N and takes no tolerances; "
                                 "use objective=wipe to set force_tolerance_N or path_tolerance_m")

    @classmethod
    def from_config(cls, cfg: Any) -> TaskObjective:
        """From a config node or mapping (``name`` plus the tolerances), ``"paper"``, or None (the paper's).
        YAML's ``.inf`` is the infinite path tolerance."""
        if cfg is None:
            return cls()
        if isinstance(cfg, str):
            if cfg != "paper":
                raise ObjectiveError(f"objective = {cfg!r}: give a mapping with its tolerances, as "
                                     "conf/objective/wipe.yaml does (objective=wipe on a command line)")
            return cls()
        data = dict(cfg.items()) if hasattr(cfg, "items") else None
        if not isinstance(data, Mapping):
            raise ObjectiveError(f"objective = {cfg!r} must be a preset name or a mapping of its fields")
        unknown = sorted(set(data) - {"name", "force_tolerance_N", "path_tolerance_m"})
        if unknown:
            raise ObjectiveError(f"objective.{unknown[0]} is not a field; fields: name, force_tolerance_N, "
                                 "path_tolerance_m")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        """Plain data for files (JSON has no infinity: an infinite tolerance is written as null)."""
        return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> TaskObjective:
        """The inverse of :meth:`to_dict`; None (a file that predates objectives) is the paper's."""
        if data is None:
            return cls()
        values = dict(data)
        if values.get("path_tolerance_m", 0.0) is None:
            values["path_tolerance_m"] = math.inf
        return cls.from_config(values)

    @property
    def counts_path(self) -> bool:
        """Whether L_task needs the tool's path (x_obs) as well as its force."""
        return math.isfinite(self.path_tolerance_m)

    @property
    def unit(self) -> str:
        """L_task's unit: N for the paper's force RMSE, 1 (tolerances) for a wipe."""
        return "N" if self.name == "paper" else "1"

    def describe(self) -> str:
        if self.name == "paper":
            return "paper (force RMSE, N)"
        path = f"{self.path_tolerance_m * 1e3:g} mm" if self.counts_path else "not counted"
        return f"wipe (force over {self.force_tolerance_N:g} N, path over {path})"

    def combine(self, force_rmse_N: Any, path_rmse_m: Any | None) -> Any:
        """L_task from a force RMSE [N] and, when the path counts, a path RMSE [m]."""
        if self.name == "paper":
            return force_rmse_N
        force_term = force_rmse_N / self.force_tolerance_N
        if not self.counts_path:
            return force_term
        if path_rmse_m is None:
            raise ObjectiveError(f"objective {self.describe()} needs the tool's path, and none was given")
        return (force_term ** 2 + (path_rmse_m / self.path_tolerance_m) ** 2) ** 0.5

    def task_loss(self, force_obs: Any, force_demo: Any, x_obs: Any = None, x_demo: Any = None,
                  from_step: int = 0) -> Any:
        """L_task of observed (or predicted) force and pose (..., H, 6) against the demo's, from ``from_step``."""
        path = path_error(x_obs, x_demo, force_demo, from_step) if self.counts_path and x_obs is not None else None
        return self.combine(task_loss(force_obs, force_demo, from_step), path)

    def task_loss_over_samples(self, force_mean: Any, force_std: Any, force_demo: Any, x_mean: Any = None,
                               x_std: Any = None, x_demo: Any = None, from_step: int = 0) -> Any:
        """The RMS over k samples of each error term, from the samples' mean and std (spread included)."""
        path = None
        if self.counts_path and x_mean is not None:
            path = path_error_over_samples(x_mean, x_std, x_demo, force_demo, from_step)
        return self.combine(task_loss_over_samples(force_mean, force_std, force_demo, from_step), path)

    def trial_task_loss(self, trial: Any, x_demo: Any, force_demo: Any, from_step: int = 0) -> float:
        """A simulated trial's L_task (inf where it failed)."""
        if getattr(trial, "failed", False):
            return math.inf
        return float(self.task_loss(np.asarray(trial.force_obs), np.asarray(force_demo), np.asarray(trial.x_obs),
                                    np.asarray(x_demo), from_step))


PAPER = TaskObjective()


def compliance_loss(stiffness: Any) -> Any:
    """L_comp [kN/m]: the mean over time of the Euclidean norm of the translational stiffness.

    This is the paper's sum_t |K_t| divided by the horizon, so that demos of different lengths compare.
    """
    norm = ((stiffness[..., :3] ** 2).sum(-1)) ** 0.5
    return norm.mean(-1) / 1000.0


def _numpy(a: Any) -> np.ndarray:
    if hasattr(a, "detach"):  # a torch tensor, without importing torch here
        a = a.detach().cpu().numpy()
    return np.asarray(a, dtype=np.float64)


def _like(values: np.ndarray, reference: Any) -> Any:
    """``values`` as the array type (and, for a tensor, the dtype and device) of ``reference``."""
    if hasattr(reference, "new_tensor"):
        return reference.new_tensor(values)
    return values.astype(np.asarray(reference).dtype, copy=False)
