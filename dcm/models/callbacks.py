"""Task metrics of a force model: sample forces for an evaluation set and score them the way the tuner uses them.

* ``R_within`` / ``R_within_spearman``: Pearson / Spearman correlation of predicted vs true L_task (the model's
  configured objective, :class:`dcm.control.objectives.TaskObjective`: by default the force RMSE to F_demo in N)
  computed within each skill (demo) and averaged over skills, with ``R_within_n_skills`` the skills used — the
  tuner ranks one skill's schedules, so this is what checkpoints are selected on (``checkpoint.monitor`` in
  conf/train.yaml). See :mod:`dcm.models.metrics`.
* ``R_pooled`` (also logged as ``R``): Pearson correlation over all trajectories.
* ``L_task_mae_N``: mean absolute error of predicted L_task.
* ``top3_regret``: what a tuner keeping each skill's 3 best-ranked schedules loses (0: the truly best,
  1: a random pick; :func:`dcm.models.metrics.within_skill_regret`).
* ``L_MSE``: mean squared error of the predicted (k-sample mean) and true wrench, normalised units [-1, 1].
* ``rmse_<axis>``: per-axis RMSE of the wrench [N for forces, N·m for torques]; ``force_rmse_N`` over the
  three force axes, next to ``force_rmse_copy_N`` (predicting F_obs := F_demo) and their ratio
  ``force_rmse_ratio_copy`` (< 1: the model beats copying the demo).
* for a model that predicts the pose: ``path_rmse_m`` (tangent-plane RMSE of the predicted tool translation),
  ``path_rmse_copy_m`` (predicting x_obs := x_demo), ``path_rmse_ratio_copy`` and ``mean_std_m``.

:class:`ForceMetricsCallback` logs them after validation/test epochs, plus TensorBoard figures of predicted vs
true force curves; :func:`evaluate_model` is the same computation for ``python -m dcm.evaluate``.
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import numpy as np
import torch
import torchmetrics
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.utilities import rank_zero_warn

from dcm.control.objectives import task_window_start
from dcm.data.datamodule import TrajectoryDataset
from dcm.data.schema import FORCE_LAYOUT, cond_slice, target_layout
from dcm.models.metrics import MIN_TRIALS, WRENCH_AXES, force_prediction_metrics

AXES: tuple[str, ...] = WRENCH_AXES  # Fx, Fy, Fz, Tx, Ty, Tz


@torch.no_grad()
def evaluate_model(model: Any, dataset: TrajectoryDataset, n_samples: int | None = None, seed: int = 0,
                   skills: np.ndarray | None = None, from_step: int = 0
                   ) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Sample forces (and, for a pose model, poses) for every trajectory of ``dataset`` and compute the metrics.

    ``skills`` (N,) labels trajectories for the within-skill correlations (None leaves them NaN).
    ``from_step``: force and path errors and L_task (the model's ``objective``) count the steps from this one
    on (L_MSE counts all). Returns ``(metrics, arrays)``; arrays holds ``pred_N``, ``std_N``, ``true_N``,
    ``F_demo_N`` (N,H,6), for a pose model ``x_pred_m``, ``x_std_m``, ``x_true_m`` (N,H,3), and
    ``L_task_pred``/``L_task_true`` (N,). Sampling uses a generator seeded with ``seed``.
    """
    device = model.device
    layout = model.layout
    generator = torch.Generator(device=device).manual_seed(int(seed))
    cond = dataset.cond.to(device)
    true = dataset.target.to(device)
    if true.shape[-1] != layout.width:
        raise ValueError(f"evaluate_model: the dataset's targets have {true.shape[-1]} channels, the model's "
                         f"{layout.width} ({', '.join(layout.channel_names())}): load it with the model's layout")
    pred, std = model.predict_raw(cond, n_samples, generator)

    # L_MSE compares what the net learns (F_obs, or its residual from F_demo; the pose) in normalised units
    mse = torchmetrics.MeanSquaredError().to(device)
    mse.update(model.normalized_target(cond, pred).reshape(-1), model.normalized_target(cond, true).reshape(-1))
    F_demo, x_demo = cond[..., cond_slice("F_demo")], cond[..., cond_slice("x_demo")]
    force = layout.force
    arrays = {"pred_N": pred[..., force].cpu().numpy(), "std_N": std[..., force].cpu().numpy(),
              "true_N": true[..., force].cpu().numpy(), "F_demo_N": F_demo.cpu().numpy()}
    poses: dict[str, Any] = {}
    if model.predicts_pose:
        x_pred, x_true = model.pose_from_target(cond, pred), model.pose_from_target(cond, true)
        x_std = std[..., layout.pose]
        arrays.update(x_pred_m=x_pred.cpu().numpy(), x_std_m=x_std.cpu().numpy(), x_true_m=x_true.cpu().numpy())
        poses = {"x_mean": x_pred.double(), "x_std": x_std.double(), "x_demo": x_demo.double()}
    L_pred = model.predicted_task_loss(pred[..., force].double(), std[..., force].double(), F_demo.double(),
                                       from_step=int(from_step), **poses).cpu().numpy()
    scores, L_pred, L_true = force_prediction_metrics(
        arrays["pred_N"], arrays["true_N"], arrays["F_demo_N"], skills, L_pred=L_pred, objective=model.objective,
        x_pred=arrays.get("x_pred_m"), x_obs=arrays.get("x_true_m"),
        x_demo=x_demo.cpu().numpy() if model.predicts_pose else None, from_step=int(from_step))
    spread_m = float(arrays["x_std_m"].mean()) if model.predicts_pose else None
    metrics = _with_model_metrics(scores, float(mse.compute()), float(std[..., force][..., :3].mean()), spread_m)
    arrays.update(L_task_pred=L_pred, L_task_true=L_true)
    return metrics, arrays


def _with_model_metrics(scores: dict[str, float], l_mse: float, mean_std_N: float,
                        mean_std_m: float | None = None) -> dict[str, float]:
    """The prediction scores plus what only a model has: its normalised MSE and its samples' spread."""
    spread = {"mean_std_N": mean_std_N} if mean_std_m is None else {"mean_std_N": mean_std_N, "mean_std_m": mean_std_m}
    return {"L_MSE": l_mse, "R": scores["R_pooled"], **scores, **spread}


def metric_names(target_fields: str = "force") -> list[str]:
    """The metric names :class:`ForceMetricsCallback` logs (as ``val/<name>`` and ``test/<name>``) for a model of
    ``target_fields``, from the metric code itself on a made-up split, so a ``checkpoint.monitor`` can be
    checked before training instead of failing at the first validation."""
    rng = np.random.default_rng(0)
    forces = rng.normal(size=(4, 2, FORCE_LAYOUT.width))
    poses = {}
    spread_m = None
    if target_layout(target_fields).predicts_pose:
        x = rng.normal(size=(4, 2, 6))
        poses = {"x_pred": x[..., :3] + 0.01, "x_obs": x[..., :3], "x_demo": x}
        spread_m = 0.0
    scores, _, _ = force_prediction_metrics(forces, forces + 1.0, forces, np.array([0, 0, 1, 1]), **poses)
    return sorted(_with_model_metrics(scores, 0.0, 0.0, spread_m))


def force_figure(arrays: dict[str, np.ndarray], names: list[str], n_plot: int = 3, dt: float | None = None):
    """Predicted (±std) vs true Fx/Fy/Fz curves for the first ``n_plot`` trajectories, with F_demo dashed."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    n = min(n_plot, arrays["pred_N"].shape[0])
    fig, axes = plt.subplots(n, 3, figsize=(11, 2.3 * n), squeeze=False, sharex=True)
    H = arrays["pred_N"].shape[1]
    t = np.arange(H) * (dt or 1.0)
    for i in range(n):
        for j, axis in enumerate(AXES[:3]):
            ax = axes[i][j]
            mean, std = arrays["pred_N"][i, :, j], arrays["std_N"][i, :, j]
            ax.plot(t, arrays["true_N"][i, :, j], color="k", lw=1.2, label="F_obs (true)")
            ax.plot(t, mean, color="tab:red", lw=1.2, label="predicted")
            ax.fill_between(t, mean - std, mean + std, color="tab:red", alpha=0.25, lw=0)
            ax.plot(t, arrays["F_demo_N"][i, :, j], color="tab:blue", lw=0.8, ls="--", label="F_demo")
            if i == 0:
                ax.set_title(f"{axis} [N]")
            if j == 0:
                ax.set_ylabel(names[i] if i < len(names) else f"#{i}", fontsize=7)
    axes[0][0].legend(fontsize=7, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]" if dt else "step")
    fig.tight_layout()
    return fig


class ForceMetricsCallback(Callback):
    """After validation (and test) epochs: sample forces for the evaluation set, log metrics and figures.

    The ranking metrics score the model's configured L_task (its ``objective``), so checkpoint selection on
    ``val/R_within`` or ``val/top3_regret`` picks the model that ranks schedules by what the tuner minimises.

    How often is the trainer's ``check_val_every_n_epoch`` (the metrics must be logged at every validation,
    since ModelCheckpoint monitors one of them); how many trajectories is the DataModule's ``n_eval``
    (null = the whole split, the default, so checkpoint selection sees every validation skill); how many
    samples per trajectory is ``n_samples`` (None = the model's own default). Skills are the trajectories'
    ``demo_id``, which the DataModule's splits carry. ``task_from_s``: the force metrics and L_task count from
    this second on (1.0 leaves out the demos' approach), and so does checkpoint selection on them.

    Under DDP every rank scores the WHOLE split (``eval_set``, not its dataloader's shard), with the same
    weights and the same seeded generator, so each rank computes the metrics of a one-process evaluation:
    a within-skill Pearson/Spearman needs all of a skill's trials, and a mean of per-rank correlations over
    halves would be another, wrong number; nor does the DistributedSampler's padding (it repeats trials to
    even out the shards) reach them. Sharding the sampling and gathering the forces would make validation
    scale with the devices, but the draws, and so the figures, would then depend on the number of ranks.
    The values are logged with ``sync_dist``: a mean of identical values, which keeps every rank's
    ModelCheckpoint on the same monitor.
    """

    def __init__(self, n_samples: int | None = None, n_plot: int = 3, plot_every_n_evals: int = 1,
                 seed: int = 0, task_from_s: float = 0.0) -> None:
        super().__init__()
        self.n_samples = n_samples
        self.task_from_s = float(task_from_s)
        self.n_plot = int(n_plot)
        self.plot_every_n_evals = max(1, int(plot_every_n_evals))
        self.seed = int(seed)
        self._evals = 0
        self._warned: set[str] = set()

    def _run(self, trainer: L.Trainer, pl_module: Any, split: str, prefix: str) -> dict[str, float] | None:
        datamodule = trainer.datamodule
        if datamodule is None or not hasattr(datamodule, "eval_set"):
            return None
        dataset = datamodule.eval_set(split)
        skills = dataset.skills.numpy()  # each trial's demo_id, as the DataModule read it
        from_step = task_window_start(self.task_from_s, datamodule.control_hz, dataset.cond.shape[1])
        metrics, arrays = evaluate_model(pl_module, dataset, self.n_samples, self.seed, skills, from_step)
        for key, value in metrics.items():
            # identical on every rank (same data, weights and seed): the sync's mean is the value itself
            pl_module.log(f"{prefix}/{key}", value if math.isfinite(value) else float("nan"),
                          prog_bar=key in ("R_within", "L_MSE"), sync_dist=trainer.world_size > 1)
        if not math.isfinite(metrics["R_within"]) and split not in self._warned:
            self._warned.add(split)
            rank_zero_warn(f"{prefix}/R_within is undefined: no skill of the {split} split ({len(dataset)} "
                           f"trajectories) has >= {MIN_TRIALS} trials with varying L_task; checkpoint selection on "
                           "it keeps the first checkpoints only — use checkpoint.monitor=val/R_pooled for this data")
        self._evals += 1
        logger = trainer.logger
        if (self.n_plot > 0 and trainer.is_global_zero and logger is not None
                and hasattr(logger, "experiment") and hasattr(logger.experiment, "add_figure")
                and (prefix == "test" or self._evals % self.plot_every_n_evals == 0)):
            dt = 1.0 / float(datamodule.control_hz)
            fig = force_figure(arrays, dataset.names, self.n_plot, dt)
            logger.experiment.add_figure(f"{prefix}/forces", fig, global_step=trainer.global_step)
        return metrics

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        if trainer.sanity_checking:
            return
        self._run(trainer, pl_module, "valid", "val")

    def on_test_epoch_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        self._run(trainer, pl_module, "test", "test")

    def state_dict(self) -> dict[str, Any]:
        return {"evals": self._evals}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._evals = int(state_dict.get("evals", 0))


class RunETACallback(Callback):
    """Shows the whole run's remaining time (``eta_min``) in the progress bar and logs it.

    Lightning's bar times the current epoch only; a run ends at ``max_epochs`` or ``max_time``, whichever
    comes first, and this estimates which from the mean epoch duration so far (validation included).
    """

    def __init__(self) -> None:
        super().__init__()
        self._start: float | None = None
        self._start_epoch = 0

    def on_train_start(self, trainer: L.Trainer, pl_module: Any) -> None:
        import time

        self._start = time.monotonic()
        self._start_epoch = trainer.current_epoch

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        import time

        if self._start is None:
            return
        done = trainer.current_epoch + 1 - self._start_epoch
        elapsed = time.monotonic() - self._start
        per_epoch = elapsed / max(done, 1)
        remaining = math.inf
        if trainer.max_epochs is not None and trainer.max_epochs > 0:
            remaining = (trainer.max_epochs - trainer.current_epoch - 1) * per_epoch
        for cb in trainer.callbacks:  # max_time lives in the Timer callback
            time_left = getattr(cb, "time_remaining", None)
            if callable(time_left) and time_left() is not None:
                remaining = min(remaining, float(time_left()))
        if math.isfinite(remaining):  # each rank times itself; DDP keeps them in step, so their mean is the run's
            pl_module.log("eta_min", remaining / 60.0, prog_bar=True, on_epoch=True, on_step=False, sync_dist=True)


class RandomStateCallback(Callback):
    """Saves torch's global random state in every checkpoint and restores it when a killed run resumes.

    The DCM draws its training noise and timesteps from the global generator, so without this the epochs
    after a resume would see other noise than the uninterrupted run and end elsewhere. The state is applied
    at the first training epoch after the resume, after the sanity check has drawn what it draws.
    """

    def __init__(self) -> None:
        self._restored: dict[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        state: dict[str, Any] = {"torch": torch.get_rng_state()}
        if torch.cuda.is_available():
            state["cuda"] = torch.cuda.get_rng_state_all()
        return state

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._restored = state_dict

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._restored is None:
            return
        torch.set_rng_state(self._restored["torch"])
        if len(self._restored.get("cuda", [])) == torch.cuda.device_count() > 0:  # same GPUs as when saved
            torch.cuda.set_rng_state_all(self._restored["cuda"])
        self._restored = None
