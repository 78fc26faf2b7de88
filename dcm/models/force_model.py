"""The base class the DCM and the baseline share, as a LightningModule.

Both models own their normalisers (buffers, saved in every checkpoint), an EMA copy of the score net used
for validation and prediction, and the one prediction call users need::

    from dcm.models.dcm import DCM
    model = DCM.load_from_checkpoint("runs/.../checkpoints/last.ckpt")
    mean_N, std_N = model.predict_forces(x_demo, F_demo, x_attr, K, n_samples=8)   # (B,H,6) each, raw units
    contact = model.predict_contact(x_demo, F_demo, x_attr, K, n_samples=8)  # + x_mean (B,H,3) for a pose model
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, ClassVar

import lightning as L
import numpy as np
import torch
from torch import nn

from dcm import __version__
from dcm.control.objectives import TASK_LOSSES, TaskObjective, task_window_start
from dcm.data.schema import POSE_DELTA_WIDTH, TargetLayout, cond_slice
from dcm.models.checkpoint import KIND_KEY, VERSION_KEY, _incompatible, check_code_version, read_checkpoint
from dcm.models.cond_encoding import encode_conditions
from dcm.models.configuration import (
    CheckpointKindError,
    DataSpec,
    ForceModelConfig,
    ModelInputError,
    check_objective_fits,
    check_objective_name,
)
from dcm.models.contact import ContactPrediction
from dcm.models.nets import build_score_net
from dcm.models.normalizer import ChannelNormalizer
from dcm.models.task_ranking import within_skill_task_error

COND_DIM = 24
_F_DEMO = cond_slice("F_demo")
_X_DEMO = cond_slice("x_demo")
PRECISIONS = ("float32", "bfloat16", "auto")


def native_bfloat16(device: torch.device | str) -> bool:
    """Whether ``device`` multiplies bfloat16 matrices in hardware (CPUs with AVX512-BF16 or AMX, CUDA GPUs that
    support it). Elsewhere bfloat16 is emulated and slower than float32."""
    device = torch.device(device)
    try:
        if device.type == "cuda":
            return bool(torch.cuda.is_bf16_supported())
        if device.type == "cpu":
            return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
    except (AttributeError, RuntimeError):  # an older torch or a device it cannot query: stay in float32
        return False
    return False


def _weight(cond: torch.Tensor) -> Any:
    """A batch's weight in an epoch mean that ``self.log(..., sync_dist=True)`` syncs across DDP ranks, as a
    float. Lightning sums each rank's weights as given; an integer sum is then averaged over the ranks in integer
    arithmetic on gloo ((2 + 1) / 2 = 1), so ranks of unequal shards (valid/test: no padding) would log a wrong
    mean. A float keeps it exact."""
    return float(cond.shape[0])


class ForceModel(L.LightningModule):
    """Shared machinery: score net + EMA copy, normalisers, data spec, optimiser, ``predict_contact`` and
    ``predict_forces``. The target's width and slices come from ``layout`` (``cfg.target_fields``)."""

    model_kind: ClassVar[str] = "force_model"
    config_cls: ClassVar[type[ForceModelConfig]] = ForceModelConfig

    def __init__(self, data_spec: dict[str, Any] | None = None, **config: Any) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.cfg = self.config_cls.from_kwargs(config)
        self.layout: TargetLayout = self.cfg.layout
        self.data_spec = DataSpec(**{"target_channels": self.layout.channel_names(), **(data_spec or {})})
        if list(self.data_spec.target_channels) != self.layout.channel_names():
            raise ModelInputError(f"data_spec.target_channels {self.data_spec.target_channels} are not those of "
                                  f"target_fields={self.cfg.target_fields}: {self.layout.channel_names()}")
        net_kwargs = {k: v for k, v in self.cfg.net.items() if k != "name"}
        self.net = build_score_net(self.cfg.net["name"], cond_dim=COND_DIM, out_dim=self.out_dim, **net_kwargs)
        self.ema_net: nn.Module | None = None
        if self.cfg.ema_decay > 0:
            self.ema_net = copy.deepcopy(self.net).requires_grad_(False)
        self.cond_norm = ChannelNormalizer(COND_DIM)
        self.target_norm = ChannelNormalizer(self.out_dim)
        self.inference_precision = "float32"  # of predictions only (set_precision); training is unaffected

    @property
    def out_dim(self) -> int:
        """The target's channels: what the net outputs and the sampler draws."""
        return self.layout.width

    @property
    def predicts_pose(self) -> bool:
        """Whether predictions give the tool's pose as well as its wrench (``target_fields=force_and_pose``)."""
        return self.layout.predicts_pose

    @property
    def objective(self) -> TaskObjective:
        """The L_task this model is trained and selected for, and that ``predicted_task_loss`` computes."""
        return self.cfg.task_objective

    def set_objective(self, objective: TaskObjective | None, source: str = "objective") -> TaskObjective:
        """Score with ``objective`` (None: keep the model's) in this process, e.g. other tolerances of the same
        kind. One of another kind than the model's, or one counting the path for a force-only model, is
        refused in one line naming both. Returns the objective in use."""
        if objective is not None:
            check_objective_name(objective, self.objective, source)
            check_objective_fits(objective, self.cfg.target_fields)
            self.cfg.objective = objective.to_dict()
        return self.objective

    # ------------------------------------------------------------------ checkpoint identity
    @classmethod
    def load_from_checkpoint(cls, checkpoint_path: str | Path, map_location: Any = None, **kwargs: Any):  # type: ignore[override]
        """Load a checkpoint written by this class, as plain data only (:func:`read_checkpoint`). Another model's
        checkpoint, one whose parameter names no longer fit the code, or a file that would run code raises a
        ModelInputError; one from another dcm version warns, naming both."""
        ckpt = read_checkpoint(checkpoint_path)
        kind, written_by = ckpt.get(KIND_KEY), ckpt.get(VERSION_KEY)
        if kind != cls.model_kind:
            raise CheckpointKindError(
                f"checkpoint {checkpoint_path} holds a {kind!r} model, not {cls.model_kind!r}; "
                "load it with its own class or with dcm.models.predict.load_model, which picks the class")
        check_code_version(checkpoint_path, written_by)
        try:
            return super().load_from_checkpoint(checkpoint_path, map_location=map_location or "cpu",
                                                **{**kwargs, "weights_only": True})
        except RuntimeError as err:
            if "state_dict" not in str(err):
                raise
            raise _incompatible(checkpoint_path, written_by, err) from None

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint[KIND_KEY] = self.model_kind
        checkpoint[VERSION_KEY] = __version__

    # ------------------------------------------------------------------ normalisation
    def fit_normalizers(self, cond: Any, target: Any) -> None:
        """Fit both normalisers on the training split's raw conditions (N,H,24) and targets (N,H,C) (F_obs, and
        x_obs - x_demo's translation for a pose model: ``layout``), the way ``cfg.normalization`` says, on the
        residual when ``cfg.target == "residual"``; every channel on its own, so the pose's metres do not share
        a scale with the force's newtons. They are saved with the weights, so a fine-tuned model keeps its
        pre-training statistics."""
        cond = torch.as_tensor(np.asarray(cond, dtype=np.float32))
        target = torch.as_tensor(np.asarray(target, dtype=np.float32))
        if target.shape[-1] != self.out_dim:
            raise ModelInputError(f"fit_normalizers: targets have {target.shape[-1]} channels, but this model "
                                  f"predicts {self.out_dim} ({', '.join(self.layout.channel_names())})")
        self.cond_norm.fit_data(encode_conditions(cond, self.cfg.cond_encoding), self.cfg.normalization)
        self.target_norm.fit_data(self.model_target(cond, target), self.cfg.normalization)

    def model_target(self, cond: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """What the net learns, in physical units: the target (``layout``), with F_demo taken from its force for
        a residual model. The pose part is a deviation from the demo already, and stays as it is."""
        if self.cfg.target != "residual":
            return target
        if not self.predicts_pose:
            return target - cond[..., _F_DEMO]
        return torch.cat([target[..., self.layout.force] - cond[..., _F_DEMO], target[..., self.layout.pose]], -1)

    def target_from_model(self, cond: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
        """The inverse of ``model_target``: the target (F_obs [N, N·m], and x_obs - x_demo [m] for a pose model)
        from the net's (un-normalised) output."""
        if self.cfg.target != "residual":
            return value
        if not self.predicts_pose:
            return value + cond[..., _F_DEMO]
        return torch.cat([value[..., self.layout.force] + cond[..., _F_DEMO], value[..., self.layout.pose]], -1)

    def force_from_target(self, cond: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
        """The wrench F_obs [N, N·m] from the net's (un-normalised) output."""
        return self.target_from_model(cond, value)[..., self.layout.force]

    def pose_from_target(self, cond: torch.Tensor, target: torch.Tensor) -> torch.Tensor | None:
        """The tool's translation x_obs (..., 3) [m] from raw conditions and a target (``target_from_model``'s
        output, or a batch's): x_demo plus the deviation; None for a force-only model."""
        if not self.predicts_pose:
            return None
        return cond[..., _X_DEMO][..., :POSE_DELTA_WIDTH] + target[..., self.layout.pose]

    def _require_fitted(self) -> None:
        if not (bool(self.cond_norm.fitted) and bool(self.target_norm.fitted)):
            raise ModelInputError(f"{type(self).__name__}: normalisers are not fitted; call fit_normalizers "
                                  "with the training split's data (train.py does) before use")

    @property
    def inference_net(self) -> nn.Module:
        """The EMA weights when kept, else the trained ones."""
        return self.ema_net if self.ema_net is not None else self.net

    # ------------------------------------------------------------------ the model-specific parts
    def denoising_outputs(self, net: nn.Module, cond_n: torch.Tensor, target_n: torch.Tensor,
                          generator: torch.Generator | None = None, groups: torch.Tensor | None = None
                          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The net's training output, its target and the force estimate (normalised units) it implies; rows
        sharing a label in ``groups`` share their random draws (:func:`diffusion.denoising_outputs`)."""
        raise NotImplementedError

    def loss(self, net: nn.Module, cond_n: torch.Tensor, target_n: torch.Tensor,
             generator: torch.Generator | None = None, cond: torch.Tensor | None = None,
             groups: torch.Tensor | None = None) -> torch.Tensor:
        """The force loss: MSE of the net's output against its target. With ``task_weight`` > 0, and the
        batch's raw conditions ``cond`` and skill labels ``groups`` given, plus ``task_weight`` times the
        within-skill L_task error of the implied force (:meth:`task_term`)."""
        return self._weighted(self.loss_terms(net, cond_n, target_n, generator, cond, groups))

    def _weighted(self, terms: dict[str, torch.Tensor]) -> torch.Tensor:
        return terms["force"] + self.cfg.task_weight * terms["task"] if "task" in terms else terms["force"]

    def loss_terms(self, net: nn.Module, cond_n: torch.Tensor, target_n: torch.Tensor,
                   generator: torch.Generator | None = None, cond: torch.Tensor | None = None,
                   groups: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The unweighted parts of :meth:`loss`: ``force``, and ``task`` when the task term applies."""
        with_task = self.cfg.task_weight > 0 and cond is not None and groups is not None
        output, target, estimate_n = self.denoising_outputs(net, cond_n, target_n, generator,
                                                            groups if with_task else None)
        terms = {"force": torch.nn.functional.mse_loss(output, target)}
        if with_task:
            terms["task"] = self.task_term(cond, estimate_n, target_n, groups)
        return terms

    def task_term(self, cond: torch.Tensor, estimate_n: torch.Tensor, target_n: torch.Tensor,
                  groups: torch.Tensor) -> torch.Tensor:
        """Within-skill error of the configured L_task (``objective``, from ``cfg.task_from_s``) of the estimated
        against the true target, in the normaliser's force units (a wipe's L_task times its force tolerance,
        which is in newtons) so that ``task_weight`` does not depend on the data's scale."""
        F_demo, x_demo = cond[..., _F_DEMO], cond[..., _X_DEMO]
        start = task_window_start(self.cfg.task_from_s, self.data_spec.control_hz, cond.shape[-2])
        objective = self.objective
        force_scale = self.target_norm.scale[self.layout.force][:3].mean() * objective.force_tolerance_N

        def L_task(value: torch.Tensor) -> torch.Tensor:
            target = self.target_from_model(cond, self.target_norm.unnormalize(value))
            return objective.task_loss(target[..., self.layout.force], F_demo, self.pose_from_target(cond, target),
                                       x_demo, start)

        L_pred, L_true = (L_task(value) for value in (estimate_n, target_n))
        return within_skill_task_error(L_pred * force_scale, L_true * force_scale, groups)

    def sample_normalized(self, cond_n: torch.Tensor, n_samples: int = 1,
                          generator: torch.Generator | None = None) -> torch.Tensor:
        """(n_samples, B, H, C) target samples in normalised units for normalised conditions (B, H, 24)."""
        raise NotImplementedError

    @property
    def default_samples(self) -> int:
        return 1

    # ------------------------------------------------------------------ Lightning hooks
    def on_fit_start(self) -> None:
        self._require_fitted()

    def normalized_cond(self, cond: torch.Tensor) -> torch.Tensor:
        """The net's condition input for raw conditions: encoded (``cfg.cond_encoding``), then normalised."""
        return self.cond_norm.normalize(encode_conditions(cond, self.cfg.cond_encoding))

    def input_range(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw conditions (..., 24) as the net's encoder reads them (``cfg.cond_encoding``), with each encoded
        channel's training range (low, high) that the input normaliser maps to [-1, 1]: a caller judges how far
        its inputs lie outside the training data without reaching into the normaliser."""
        encoded = encode_conditions(torch.as_tensor(np.asarray(cond)), self.cfg.cond_encoding).double().numpy()
        low, high = self.cond_norm.value_range()
        return encoded, low, high

    def normalized_target(self, cond: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The training target in normalised units for raw conditions and a raw target (``layout``)."""
        return self.target_norm.normalize(self.model_target(cond, target))

    def _batch_loss(self, net: nn.Module, batch: dict[str, torch.Tensor], generator: torch.Generator | None = None,
                    prefix: str | None = None) -> torch.Tensor:
        """The loss of a batch; with ``prefix``, its parts are logged as ``<prefix>/loss_force`` and
        ``<prefix>/loss_task`` when the task term applies."""
        cond = batch["cond"]
        terms = self.loss_terms(net, self.normalized_cond(cond), self.normalized_target(cond, batch["target"]),
                                generator, cond=cond, groups=batch.get("skill"))
        if prefix and "task" in terms:
            for name, value in terms.items():
                self.log(f"{prefix}/loss_{name}", value, on_step=False, on_epoch=True,
                         batch_size=_weight(cond), sync_dist=True)
        return self._weighted(terms)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        """One optimiser step. Every loss is logged with ``sync_dist=True``: under DDP each rank holds the mean
        of its own shard, and Lightning's batch-size-weighted sync makes the logged value the mean over all
        ranks' trajectories (one all-reduce of a scalar per step, small beside the gradients')."""
        loss = self._batch_loss(self.net, batch, prefix="train")
        self.log("train/loss", loss, prog_bar=True, on_step=True, on_epoch=True, batch_size=_weight(batch["cond"]),
                 sync_dist=True)
        return loss

    def _eval_loss(self, batch: dict[str, torch.Tensor], batch_idx: int, prefix: str) -> torch.Tensor:
        # A fixed generator per batch makes the (noisy) diffusion loss comparable across epochs.
        gen = torch.Generator(device=self.device).manual_seed(10_000 + batch_idx)
        loss = self._batch_loss(self.inference_net, batch, gen, prefix)
        self.log(f"{prefix}/loss", loss, prog_bar=False, on_epoch=True, batch_size=_weight(batch["cond"]),
                 sync_dist=True)
        return loss

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._eval_loss(batch, batch_idx, "val")

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._eval_loss(batch, batch_idx, "test")

    @torch.no_grad()
    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        """EMA update after every optimiser step, with the usual warm-up so early averages are not stale."""
        if self.ema_net is None:
            return
        step = max(int(self.global_step), 1)
        decay = min(self.cfg.ema_decay, (1 + step) / (10 + step))
        ema_params = list(self.ema_net.parameters())
        params = [p.detach() for p in self.net.parameters()]
        torch._foreach_lerp_(ema_params, params, 1.0 - decay)
        for b_ema, b in zip(self.ema_net.buffers(), self.net.buffers()):
            b_ema.copy_(b)

    def configure_optimizers(self) -> Any:
        optimizer = torch.optim.AdamW(self.net.parameters(), lr=self.cfg.lr, weight_decay=self.cfg.weight_decay)
        warmup = int(self.cfg.warmup_steps)
        total = 0
        if self.cfg.lr_schedule == "cosine" and self._trainer is not None:
            total = int(self.trainer.estimated_stepping_batches)
            if not math.isfinite(total) or total <= 0:
                total = 0  # max_epochs=-1 / only max_time: cosine has no end, fall back to constant

        def factor(step: int) -> float:
            if warmup and step < warmup:
                return (step + 1) / warmup
            if total > warmup:
                progress = min(1.0, (step - warmup) / max(1, total - warmup))
                return 0.5 * (1.0 + math.cos(math.pi * progress))
            return 1.0

        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    # ------------------------------------------------------------------ prediction API
    def set_precision(self, precision: str = "float32") -> str:
        """Run the score net's matrix products of predictions in ``precision``: ``float32``, ``bfloat16``
        (autocast; normalisations and the sampler's arithmetic stay in float32), or ``auto``: bfloat16 where the
        model's device multiplies it in hardware (:func:`native_bfloat16`), else float32. A robot-free search
        trades the last digits of each prediction for a net several times faster on such hardware. Returns
        the precision in use."""
        if precision not in PRECISIONS:
            raise ModelInputError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if precision == "auto":
            precision = "bfloat16" if native_bfloat16(self.device) else "float32"
        self.inference_precision = precision
        return precision

    @torch.no_grad()
    def predict_normalized(self, cond_n: torch.Tensor, n_samples: int | None = None,
                           generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and spread over ``n_samples`` samples, normalised units, for (B,H,24) normalised conditions."""
        k = self.default_samples if n_samples is None else int(n_samples)
        if k < 1:
            raise ModelInputError(f"n_samples must be >= 1, got {n_samples}")
        was_training = self.training
        self.eval()
        low = getattr(self, "inference_precision", "float32") == "bfloat16"
        try:
            means, stds = [], []
            for chunk in cond_n.split(max(1, self.cfg.eval_batch_size // k)):
                with torch.autocast(cond_n.device.type, dtype=torch.bfloat16, enabled=low):
                    samples = self.sample_normalized(chunk, k, generator)
                samples = samples.float()
                means.append(samples.mean(0))
                stds.append(samples.std(0, unbiased=False) if k > 1 else torch.zeros_like(samples[0]))
        finally:
            self.train(was_training)
        return torch.cat(means), torch.cat(stds)

    @torch.no_grad()
    def predict_raw(self, cond: torch.Tensor, n_samples: int | None = None,
                    generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and spread of the target (B,H,C) for raw conditions (B,H,24) on the model's device: the wrench
        [N, N·m] and, for a pose model, the translation x_obs - x_demo [m] (``layout``)."""
        mean_n, std_n = self.predict_normalized(self.normalized_cond(cond), n_samples, generator)
        mean = self.target_from_model(cond, self.target_norm.unnormalize(mean_n))
        return mean, self.target_norm.unnormalize_std(std_n)

    def set_task_loss(self, task_loss: str) -> None:
        """Switch how k samples give L_task (``of_mean`` | ``over_samples``) without retraining. A DCM option:
        the baseline's spread is 0, so both give the same L_task there."""
        if task_loss not in TASK_LOSSES:
            raise ModelInputError(f"task_loss must be one of {TASK_LOSSES}, got {task_loss!r}")
        if hasattr(self.cfg, "task_loss"):
            self.cfg.task_loss = task_loss

    def predicted_task_loss(self, mean: Any, std: Any, F_demo: Any, x_mean: Any = None, x_std: Any = None,
                            x_demo: Any = None, from_step: int = 0, objective: TaskObjective | None = None) -> Any:
        """L_task (B,) of the model's objective (or ``objective``) that a prediction implies, from ``from_step``
        on: of the mean force (and, when the objective counts the path, the mean pose ``x_mean``), or with
        ``task_loss=over_samples`` (a DCM option) the RMS over the samples, whose spreads then count (the
        baseline's are 0). ``x_demo`` is the demo's pose, whose surface normals the path error needs."""
        objective = self.objective if objective is None else objective
        if getattr(self.cfg, "task_loss", "of_mean") == "over_samples":
            return objective.task_loss_over_samples(mean, std, F_demo, x_mean, x_std, x_demo, from_step)
        return objective.task_loss(mean, F_demo, x_mean, x_demo, from_step)

    def _raw_conditions(self, caller: str, x_demo: Any, F_demo: Any, x_attr: Any, K: Any
                        ) -> tuple[torch.Tensor, bool, torch.device]:
        """Checked raw inputs as (B,H,24) on the model's device, whether they came as one (H,6) trajectory,
        and the inputs' device."""
        self._require_fitted()
        parts = []
        for name, value in (("x_demo", x_demo), ("F_demo", F_demo), ("x_attr", x_attr), ("K", K)):
            t = torch.as_tensor(np.asarray(value) if not torch.is_tensor(value) else value, dtype=torch.float32)
            if t.shape[-1:] != (6,) or t.dim() not in (2, 3):
                raise ModelInputError(f"{caller}: {name} must be (B,H,6) or (H,6), got {tuple(t.shape)}")
            parts.append(t)
        if not bool((parts[-1] > 0).all()):
            raise ModelInputError(f"{caller}: K must be positive, got min {float(parts[-1].min()):.4g} N/m")
        shapes = {tuple(p.shape) for p in parts}
        if len(shapes) != 1:
            raise ModelInputError(f"{caller}: inputs differ in shape: {sorted(shapes)}")
        single = parts[0].dim() == 2
        out_device = parts[0].device
        cond = torch.cat(parts, dim=-1).to(self.device)
        if single:
            cond = cond[None]
        if not torch.isfinite(cond).all():
            raise ModelInputError(f"{caller}: inputs contain NaN or inf")
        return cond, single, out_device

    @torch.no_grad()
    def predict_contact(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                        generator: torch.Generator | None = None, caller: str = "predict_contact"
                        ) -> ContactPrediction:
        """Predict the contact wrench F_obs and, for a pose model, the tool's translation x_obs for raw inputs.

        Args:
            x_demo, F_demo, x_attr, K: (B,H,6) or (H,6) numpy arrays or tensors in the dataset's units
                (m/rad, N/N·m, m/rad, N/m/N·m/rad, bowl frame), at the model's control rate.
            n_samples: samples averaged per trajectory (DCM; default ``n_samples`` of the config). The
                baseline is deterministic and ignores it (its spread is 0).
            generator: a torch.Generator (on the model's device) for reproducible samples.

        Returns:
            a :class:`ContactPrediction`: ``force_mean`` / ``force_std`` (B,H,6) [N, N·m] and, when
            ``predicts_pose``, ``x_mean`` / ``x_std`` (B,H,3) [m] (x_demo plus the predicted deviation); numpy
            when ``x_demo`` is numpy, else tensors on the inputs' device.
        """
        as_numpy = isinstance(x_demo, np.ndarray)
        cond, single, out_device = self._raw_conditions(caller, x_demo, F_demo, x_attr, K)
        mean, std = self.predict_raw(cond, n_samples, generator)
        values = [mean[..., self.layout.force], std[..., self.layout.force]]
        if self.predicts_pose:
            values += [self.pose_from_target(cond, mean), std[..., self.layout.pose]]
        if single:
            values = [v[0] for v in values]
        values = [v.cpu().numpy() if as_numpy else v.to(out_device) for v in values]
        return ContactPrediction(*values)

    @torch.no_grad()
    def predict_forces(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                       generator: torch.Generator | None = None) -> tuple[Any, Any]:
        """The wrench part of :meth:`predict_contact`: ``(mean_N, std_N)``, (B,H,6) [N, N·m] each, numpy when
        ``x_demo`` is numpy, else tensors on the inputs' device."""
        contact = self.predict_contact(x_demo, F_demo, x_attr, K, n_samples, generator, caller="predict_forces")
        return contact.force_mean, contact.force_std


__all__ = ["COND_DIM", "ForceModel"]
