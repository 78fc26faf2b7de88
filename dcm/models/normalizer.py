"""Per-channel affine normalisation, kept as module buffers so it travels inside checkpoints.

Two ways to fit it: ``minmax`` maps the train split's [min, max] to [-1, 1] (the paper's); ``zscore`` maps
mean ± 3 std to [-1, 1], so that a few force spikes do not squeeze every other value towards 0.

The model, not the data pipeline, owns the normaliser: a fine-tuned model keeps the statistics it was
pre-trained with, and ``predict_forces`` accepts raw inputs in physical units.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

# A channel whose train-split range is below this is treated as constant (e.g. the tool's orientation,
# the fixed rotational stiffness): it maps to 0 and deviations pass through unscaled instead of exploding.
MIN_RANGE = 1e-6
NORMALIZATIONS = ("minmax", "zscore")
ZSCORE_SPAN = 3.0  # zscore maps mean ± ZSCORE_SPAN std to [-1, 1]


class ChannelNormalizer(nn.Module):
    """Maps each channel of (..., C) tensors by ``(x - center) * scale``; the inverse maps back."""

    center: torch.Tensor
    scale: torch.Tensor

    def __init__(self, n_channels: int) -> None:
        super().__init__()
        self.n_channels = int(n_channels)
        self.register_buffer("center", torch.zeros(n_channels))
        self.register_buffer("scale", torch.ones(n_channels))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))

    @torch.no_grad()
    def fit(self, minimum: np.ndarray | torch.Tensor, maximum: np.ndarray | torch.Tensor) -> ChannelNormalizer:
        """Set the statistics from per-channel minima and maxima (C,)."""
        lo = torch.as_tensor(np.asarray(minimum, dtype=np.float64)).reshape(-1)
        hi = torch.as_tensor(np.asarray(maximum, dtype=np.float64)).reshape(-1)
        if lo.numel() != self.n_channels or hi.numel() != self.n_channels:
            raise ValueError(f"normaliser expects {self.n_channels} channels, got min {tuple(lo.shape)} "
                             f"and max {tuple(hi.shape)}")
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all()):
            raise ValueError("normaliser statistics contain NaN or inf")
        if (hi < lo).any():
            raise ValueError(f"normaliser max < min in channels {torch.nonzero(hi < lo).flatten().tolist()}")
        span = hi - lo
        scale = torch.where(span > MIN_RANGE, 2.0 / span.clamp_min(MIN_RANGE), torch.ones_like(span))
        self.center.copy_(((hi + lo) / 2).float())
        self.scale.copy_(scale.float())
        self.fitted.fill_(True)
        return self

    @torch.no_grad()
    def fit_data(self, data: np.ndarray | torch.Tensor, mode: str = "minmax") -> ChannelNormalizer:
        """Set the statistics from stacked samples (..., C): ``minmax`` or ``zscore`` (see the module)."""
        flat = torch.as_tensor(np.asarray(data, dtype=np.float64)).reshape(-1, self.n_channels)
        if mode == "minmax":
            return self.fit(flat.min(0).values, flat.max(0).values)
        if mode != "zscore":
            raise ValueError(f"normalization = {mode!r}; expected one of {NORMALIZATIONS}")
        mean, std = flat.mean(0), flat.std(0)
        return self.fit(mean - ZSCORE_SPAN * std, mean + ZSCORE_SPAN * std)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.center) * self.scale

    def unnormalize(self, y: torch.Tensor) -> torch.Tensor:
        return y / self.scale + self.center

    def unnormalize_std(self, std: torch.Tensor) -> torch.Tensor:
        """A spread in normalised units, in physical units (no offset)."""
        return std / self.scale

    def value_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel (low, high) in input units that map to [-1, 1]: the train split's range the statistics
        were fitted on (``zscore``: mean ± ZSCORE_SPAN std), so a caller can tell how far an input lies outside."""
        center = self.center.detach().cpu().double().numpy()
        half = 1.0 / self.scale.detach().cpu().double().numpy()
        return center - half, center + half

    def extra_repr(self) -> str:
        return f"channels={self.n_channels}, fitted={bool(self.fitted)}"
