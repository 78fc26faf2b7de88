"""Pieces every score net shares: tokenizer, diffusion-step embedding, output head.

The score function eps_theta(F^(i), cond, i) sees, at every control step t, the concatenation of the
conditions (x_demo | F_demo | x_attr | K) and the noisy force F^(i)_t. One linear layer turns that vector
into a d_model token; the diffusion step i enters as a Gaussian-Fourier embedding added to every token.
Keeping these pieces shared means the architecture ablation changes only the sequence mixer.
"""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = [
    "NetShapeError",
    "GaussianFourierProjection",
    "StepEmbedding",
    "Tokenizer",
    "OutputHead",
    "TokenScoreNet",
    "check_inputs",
]


class NetShapeError(ValueError):
    """A score net received tensors whose shapes disagree with its configuration."""


def check_inputs(
    cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor, cond_dim: int, out_dim: int, where: str
) -> torch.Tensor:
    """Validate the score-net call and return `step` as a float (B,) tensor on the inputs' device.

    A scalar step is broadcast to the batch, so `net(cond, noisy, 0)`-style calls from the baseline work.
    """
    if cond.dim() != 3 or cond.shape[-1] != cond_dim:
        raise NetShapeError(f"{where}: cond must be (B, H, {cond_dim}), got {tuple(cond.shape)}")
    if noisy.dim() != 3 or noisy.shape[-1] != out_dim:
        raise NetShapeError(f"{where}: noisy must be (B, H, {out_dim}), got {tuple(noisy.shape)}")
    if cond.shape[:2] != noisy.shape[:2]:
        raise NetShapeError(
            f"{where}: cond {tuple(cond.shape)} and noisy {tuple(noisy.shape)} differ in batch or horizon"
        )
    step = torch.as_tensor(step, device=cond.device)
    if step.dim() == 0:
        step = step.expand(cond.shape[0])
    if step.dim() != 1 or step.shape[0] != cond.shape[0]:
        raise NetShapeError(f"{where}: step must be (B,) = ({cond.shape[0]},), got {tuple(step.shape)}")
    return step.to(cond.dtype)


class GaussianFourierProjection(nn.Module):
    """Fixed random Fourier features of a scalar (Song et al. 2021, score-based SDEs).

    Steps are divided by `step_scale` (the largest supported T) before projection, so integer steps
    0..T-1 land in [0, 1) where frequencies drawn with std `scale` separate neighbouring steps well.
    The weights are a buffer, not a parameter: they are random features, and saving them in the
    state dict makes a checkpoint reproduce the same embedding.
    """

    def __init__(self, embed_dim: int, scale: float = 16.0, step_scale: float = 100.0) -> None:
        super().__init__()
        if embed_dim % 2:
            raise ValueError(f"GaussianFourierProjection: embed_dim must be even, got {embed_dim}")
        gen = torch.Generator().manual_seed(0)  # same features for every net built with this size
        self.register_buffer("W", torch.randn(embed_dim // 2, generator=gen) * scale)
        self.step_scale = float(step_scale)

    def forward(self, step: torch.Tensor) -> torch.Tensor:
        """(B,) -> (B, embed_dim)."""
        proj = (step.to(self.W.dtype) / self.step_scale)[:, None] * self.W[None, :] * (2.0 * math.pi)
        return torch.cat([torch.sin(proj), torch.cos(proj)], dim=-1)


class StepEmbedding(nn.Module):
    """Gaussian-Fourier features of the diffusion step followed by a small MLP -> (B, d_model)."""

    def __init__(self, d_model: int, fourier_dim: int | None = None, scale: float = 16.0, step_scale: float = 100.0):
        super().__init__()
        fourier_dim = fourier_dim or d_model
        self.fourier = GaussianFourierProjection(fourier_dim, scale=scale, step_scale=step_scale)
        self.mlp = nn.Sequential(nn.Linear(fourier_dim, d_model), nn.SiLU(), nn.Linear(d_model, d_model))

    def forward(self, step: torch.Tensor) -> torch.Tensor:
        return self.mlp(self.fourier(step))


class Tokenizer(nn.Module):
    """One fully connected layer over the per-step concatenation [cond_t, noisy_t] -> token e_t."""

    def __init__(self, cond_dim: int, out_dim: int, d_model: int) -> None:
        super().__init__()
        self.proj = nn.Linear(cond_dim + out_dim, d_model)

    def forward(self, cond: torch.Tensor, noisy: torch.Tensor) -> torch.Tensor:
        """(B,H,cond_dim), (B,H,out_dim) -> (B,H,d_model)."""
        return self.proj(torch.cat([cond, noisy], dim=-1))


class OutputHead(nn.Module):
    """LayerNorm + linear map from d_model tokens to the predicted noise (or force) channels."""

    def __init__(self, d_model: int, out_dim: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(d_model)
        self.proj = nn.Linear(d_model, out_dim)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.proj(self.norm(h))


class TokenScoreNet(nn.Module):
    """Template for token-based score nets: tokenizer + step embedding -> `mix` -> head.

    Subclasses implement `mix(tokens: (B,H,d)) -> (B,H,d)`, the sequence model being ablated.
    """

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        fourier_scale: float = 16.0,
        step_scale: float = 100.0,
    ) -> None:
        super().__init__()
        if cond_dim <= 0 or out_dim <= 0 or d_model <= 0:
            raise ValueError(f"{type(self).__name__}: dims must be positive, got {cond_dim=}, {out_dim=}, {d_model=}")
        self.cond_dim, self.out_dim, self.d_model = int(cond_dim), int(out_dim), int(d_model)
        self.tokenizer = Tokenizer(cond_dim, out_dim, d_model)
        self.step_embed = StepEmbedding(d_model, scale=fourier_scale, step_scale=step_scale)
        self.head = OutputHead(d_model, out_dim)

    def embed(self, cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """Tokens with the step embedding added: (B,H,d_model)."""
        step = check_inputs(cond, noisy, step, self.cond_dim, self.out_dim, type(self).__name__)
        return self.tokenizer(cond, noisy) + self.step_embed(step)[:, None, :]

    def mix(self, tokens: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """eps_theta: (B,H,cond_dim), (B,H,out_dim), (B,) -> (B,H,out_dim)."""
        return self.head(self.mix(self.embed(cond, noisy, step)))
