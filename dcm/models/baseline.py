"""The single-pass baseline (the paper's T=1): the same score net regressing F_obs directly.

It calls the net with a zero "noisy force" and step 0, and trains on the MSE to the normalised target,
so any gap to the DCM comes from iterative denoising rather than from the architecture.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from dcm.models.configuration import BaselineConfig
from dcm.models.force_model import ForceModel


class Baseline(ForceModel):
    """Deterministic regression F = net(cond, 0, 0); ``predict_forces`` reports a zero spread."""

    model_kind = "baseline"
    config_cls = BaselineConfig
    cfg: BaselineConfig

    def __init__(self, data_spec: dict[str, Any] | None = None, **config: Any) -> None:
        super().__init__(data_spec=data_spec, **config)

    def _forward(self, net: nn.Module, cond_n: torch.Tensor) -> torch.Tensor:
        zeros = cond_n.new_zeros(*cond_n.shape[:2], self.out_dim)
        step = torch.zeros(cond_n.shape[0], dtype=torch.long, device=cond_n.device)
        return net(cond_n, zeros, step)

    def denoising_outputs(self, net: nn.Module, cond_n: torch.Tensor, target_n: torch.Tensor,
                          generator: torch.Generator | None = None, groups: torch.Tensor | None = None
                          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        pred = self._forward(net, cond_n)  # one pass: the output is the force estimate
        return pred, target_n, pred

    def sample_normalized(self, cond_n: torch.Tensor, n_samples: int = 1,
                          generator: torch.Generator | None = None) -> torch.Tensor:
        # one pass; repeated so callers averaging over samples see the same shape as from the DCM
        pred = self._forward(self.inference_net, cond_n)
        return pred.unsqueeze(0).expand(max(1, int(n_samples)), *pred.shape)
