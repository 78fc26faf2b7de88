"""1-D temporal U-Net score net for the ablation, after Janner et al. 2022 / Chi et al. 2023 (Diffusion Policy).

The per-step conditions and the noisy force enter through the shared tokenizer as input channels; the
diffusion step conditions every residual block by FiLM (per-channel scale and bias). The horizon is
padded (edge values repeated) to a multiple of the total downsampling factor and cropped back, so any H
works, including odd ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from dcm.models.nets.embedding import OutputHead, StepEmbedding, Tokenizer, check_inputs

__all__ = ["UNet1DScoreNet", "ConditionalResidualBlock1D"]


class Conv1dBlock(nn.Module):
    """Conv1d -> GroupNorm -> Mish, length-preserving."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, n_groups: int) -> None:
        super().__init__()
        self.block = nn.Sequential(
            nn.Conv1d(c_in, c_out, kernel_size, padding=kernel_size // 2), nn.GroupNorm(n_groups, c_out), nn.Mish()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.block(x)


class ConditionalResidualBlock1D(nn.Module):
    """Two conv blocks with FiLM from the step embedding in between, plus a residual path."""

    def __init__(self, c_in: int, c_out: int, emb_dim: int, kernel_size: int = 5, n_groups: int = 8) -> None:
        super().__init__()
        self.conv1 = Conv1dBlock(c_in, c_out, kernel_size, n_groups)
        self.conv2 = Conv1dBlock(c_out, c_out, kernel_size, n_groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(emb_dim, 2 * c_out))
        self.residual = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        """x (B,C_in,L), emb (B,E) -> (B,C_out,L)."""
        scale, bias = self.film(emb)[:, :, None].chunk(2, dim=1)
        h = self.conv1(x) * (1.0 + scale) + bias
        return self.conv2(h) + self.residual(x)


class UNet1DScoreNet(nn.Module):
    """Tokenizer -> U-Net over time (channels = features) with FiLM step conditioning -> head.

    `down_dims` are the channel widths per level (default three levels of d_model); every level but the
    last halves the length, so the horizon is padded to a multiple of 2**(len(down_dims)-1).
    """

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        down_dims: Sequence[int] | None = None,
        kernel_size: int = 5,
        n_groups: int = 8,
        fourier_scale: float = 16.0,
        step_scale: float = 100.0,
    ) -> None:
        super().__init__()
        dims = [d_model, *(down_dims if down_dims is not None else (d_model, d_model, d_model))]
        if len(dims) < 2 or any(c % n_groups for c in dims):
            raise ValueError(f"UNet1DScoreNet: need >= 1 level with widths divisible by n_groups={n_groups}, got {dims[1:]}")
        if kernel_size % 2 == 0:
            raise ValueError(f"UNet1DScoreNet: kernel_size must be odd to preserve length, got {kernel_size}")
        self.cond_dim, self.out_dim, self.d_model = int(cond_dim), int(out_dim), int(d_model)
        self.tokenizer = Tokenizer(cond_dim, out_dim, d_model)
        self.step_embed = StepEmbedding(d_model, scale=fourier_scale, step_scale=step_scale)
        res = lambda a, b: ConditionalResidualBlock1D(a, b, d_model, kernel_size, n_groups)  # noqa: E731

        pairs = list(zip(dims[:-1], dims[1:]))
        self.factor = 2 ** (len(pairs) - 1)
        self.down = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(pairs):
            last = i == len(pairs) - 1
            self.down.append(
                nn.ModuleList(
                    [res(c_in, c_out), res(c_out, c_out), nn.Identity() if last else nn.Conv1d(c_out, c_out, 3, 2, 1)]
                )
            )
        mid = dims[-1]
        self.mid = nn.ModuleList([res(mid, mid), res(mid, mid)])
        self.up = nn.ModuleList()
        for c_in, c_out in reversed(pairs[1:]):
            # upsample this level's features (c_out), concatenate the skip of the level above (c_in channels)
            self.up.append(nn.ModuleList([nn.ConvTranspose1d(c_out, c_out, 4, 2, 1), res(c_out + c_in, c_in), res(c_in, c_in)]))
        self.final = Conv1dBlock(dims[1], d_model, kernel_size, n_groups)
        self.head = OutputHead(d_model, out_dim)

    def forward(self, cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """(B,H,cond_dim), (B,H,out_dim), (B,) -> (B,H,out_dim)."""
        step = check_inputs(cond, noisy, step, self.cond_dim, self.out_dim, type(self).__name__)
        emb = self.step_embed(step)
        H = cond.shape[1]
        x = self.tokenizer(cond, noisy).transpose(1, 2)  # (B,d,H)
        pad = (-H) % self.factor
        if pad:
            x = F.pad(x, (0, pad), mode="replicate")
        skips = []
        for res1, res2, downsample in self.down:
            x = res2(res1(x, emb), emb)
            skips.append(x)
            x = downsample(x)
        for block in self.mid:
            x = block(x, emb)
        skips.pop()  # the deepest level feeds the middle blocks directly
        for upsample, res1, res2 in self.up:
            x = res2(res1(torch.cat([upsample(x), skips.pop()], dim=1), emb), emb)
        x = self.final(x)[:, :, :H]
        return self.head(x.transpose(1, 2))
