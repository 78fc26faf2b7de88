"""Per-step MLP score net: every control step is denoised independently (the ablation's floor).

It sees no neighbouring steps, so whatever it gets right comes from the per-step conditions alone;
the gap to the sequence models measures how much temporal context matters.
"""

from __future__ import annotations

import torch
from torch import nn

from dcm.models.nets.embedding import TokenScoreNet

__all__ = ["MLPScoreNet"]


class _ResidualMLPBlock(nn.Module):
    def __init__(self, d_model: int, hidden: int, dropout: float) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(d_model)
        self.ff = nn.Sequential(
            nn.Linear(d_model, hidden), nn.SiLU(), nn.Dropout(dropout), nn.Linear(hidden, d_model)
        )

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return h + self.ff(self.norm(h))


class MLPScoreNet(TokenScoreNet):
    """Tokenizer + step embedding -> `n_layers` pre-LN residual MLP blocks applied per step -> head."""

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        n_layers: int = 3,
        ffn_mult: int = 2,
        dropout: float = 0.0,
        **embed_kwargs: float,
    ) -> None:
        super().__init__(cond_dim, out_dim, d_model, **embed_kwargs)
        self.blocks = nn.ModuleList(_ResidualMLPBlock(d_model, ffn_mult * d_model, dropout) for _ in range(n_layers))

    def mix(self, tokens: torch.Tensor) -> torch.Tensor:
        for block in self.blocks:
            tokens = block(tokens)
        return tokens
