"""The Diffusion Contact Model: a DDPM over the contact wrench, on the shared :class:`ForceModel` machinery::

    from dcm.models.dcm import DCM
    model = DCM.load_from_checkpoint("runs/.../checkpoints/last.ckpt")
    mean_N, std_N = model.predict_forces(x_demo, F_demo, x_attr, K, n_samples=8)   # (B,H,6) each, raw units
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from dcm.models import diffusion
from dcm.models.configuration import DCMConfig, ModelInputError
from dcm.models.force_model import ForceModel


class DCM(ForceModel):
    """DDPM over the normalised target trajectory (F_obs or its residual from F_demo, and for a pose model
    the translation x_obs - x_demo), conditioned per step.

    Training draws a uniform step t and regresses x0, the injected noise or v (``prediction_type``);
    prediction runs ancestral DDPM over all T steps (or DDIM over ``sampling_steps``) from pure noise,
    ``n_samples`` times, and averages.
    """

    model_kind = "dcm"
    config_cls = DCMConfig
    cfg: DCMConfig

    def __init__(self, data_spec: dict[str, Any] | None = None, **config: Any) -> None:
        super().__init__(data_spec=data_spec, **config)
        self.noise_schedule = diffusion.NoiseSchedule(**self.cfg.schedule)
        self.train_scheduler = diffusion.make_scheduler("ddpm", self.noise_schedule, self.cfg.diffusion_steps,
                                                        self.cfg.prediction_type)
        self.set_sampler(self.cfg.sampler, self.cfg.sampling_steps)  # checks DDIM's divisor rule now
        self.shared_steps: int | str = 0  # of predictions only (set_shared_steps); 0: independent samples

    @property
    def is_one_step_student(self) -> bool:
        """Written by dcm-distill: its net maps unit noise at t = T-1 to a sample, and it samples only so."""
        return self.cfg.sampler == "one_step"  # set_sampler never switches a model into or out of it

    @property
    def default_samples(self) -> int:
        return int(self.cfg.n_samples)

    def set_sampler(self, sampler: str | None = None, sampling_steps: int | None = None) -> None:
        """Switch how predictions are sampled (ddpm | ddim, and DDIM's step count) without retraining: the
        net is the same for every sampler, so evaluation and tuning can trade steps for speed. A one-step student's
        net is valid at t = T-1 only, so it keeps its sampler."""
        sampler = sampler or self.cfg.sampler
        student = self.is_one_step_student
        if student and (sampler != "one_step" or sampling_steps not in (None, 1)):
            raise ModelInputError(f"sampler {sampler} with {sampling_steps} steps: this DCM is a one-step student "
                                  "(dcm-distill) and samples only with its own single step (sampler one_step)")
        if sampler == "one_step" and not student:
            raise ModelInputError("sampler one_step needs a one-step student of this DCM (dcm-distill); a DCM "
                                  "trained by train.py samples with ddpm, ddim or ddim_even")
        sampling_steps = 1 if student else sampling_steps
        scheduler = diffusion.make_scheduler(sampler, self.noise_schedule, self.cfg.diffusion_steps,
                                             self.cfg.prediction_type)
        diffusion.check_inference_steps(scheduler, sampling_steps)
        self.cfg.sampler, self.cfg.sampling_steps = sampler, sampling_steps
        self.sample_scheduler = scheduler

    def set_shared_steps(self, shared_steps: int | str = "auto") -> int:
        """Let the n_samples of one prediction share their first ``shared_steps`` denoising steps (one net call
        per condition, :func:`diffusion.sample_many`), in this process only. ``auto``: the leading steps at
        which the net sees noise of std <= :data:`diffusion.SHARED_NOISE_STD` (:func:`diffusion.shareable_steps`),
        re-resolved whenever the sampler changes; 0: fully independent samples. Why: with the ``signal`` input
        scaling the net sees the start noise scaled by about 1e-3, so every sample's first estimates are the
        same and computing them k times is waste. Returns the steps shared under the current sampler."""
        if shared_steps != "auto":
            if isinstance(shared_steps, bool) or not isinstance(shared_steps, int) or shared_steps < 0:
                raise ModelInputError(f"shared_steps must be 'auto' or an integer >= 0, got {shared_steps!r}")
            n = diffusion.check_inference_steps(self.sample_scheduler, self.cfg.sampling_steps)
            if shared_steps >= n:
                raise ModelInputError(f"shared_steps = {shared_steps} must be below the sampler's {n} steps "
                                 "(the samples branch before the last)")
        self.shared_steps = shared_steps
        return self.resolved_shared_steps

    @property
    def resolved_shared_steps(self) -> int:
        """The steps the samples of one prediction share under the current sampler (``set_shared_steps``)."""
        if self.shared_steps == "auto":
            return diffusion.shareable_steps(self.sample_scheduler, self.cfg.sampling_steps, self.cfg.input_scaling)
        n = diffusion.check_inference_steps(self.sample_scheduler, self.cfg.sampling_steps)
        return min(int(self.shared_steps), n - 1)

    def on_fit_start(self) -> None:
        if self.is_one_step_student:
            raise ModelInputError("this DCM is a one-step student (dcm-distill): the diffusion loss would retrain "
                                  "its net for every step; distil again from a retrained teacher instead")
        super().on_fit_start()

    def denoising_outputs(self, net: nn.Module, cond_n: torch.Tensor, target_n: torch.Tensor,
                          generator: torch.Generator | None = None, groups: torch.Tensor | None = None
                          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        net_in = diffusion.scale_noisy_input(net, self.train_scheduler, self.cfg.input_scaling)
        return diffusion.denoising_outputs(net_in, cond_n, target_n, self.train_scheduler, generator,
                                           self.cfg.top_step_fraction, groups)

    def sample_normalized(self, cond_n: torch.Tensor, n_samples: int = 1,
                          generator: torch.Generator | None = None) -> torch.Tensor:
        scaled = diffusion.scale_noisy_input(self.inference_net, self.sample_scheduler, self.cfg.input_scaling)

        def net_in(cond: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            return scaled(cond, x, t).float()  # under a bfloat16 autocast, the sampler's steps stay in float32

        return diffusion.sample_many(net_in, cond_n, self.out_dim, self.sample_scheduler, n_samples,
                                     num_inference_steps=self.cfg.sampling_steps, generator=generator,
                                     shared_steps=self.resolved_shared_steps)


__all__ = ["DCM"]
