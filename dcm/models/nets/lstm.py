"""LSTM score net for the architecture ablation (bidirectional by default, like the Bi-GRU of Gao et al.)."""

from __future__ import annotations

import torch
from torch import nn

from dcm.models.nets.embedding import TokenScoreNet

__all__ = ["LSTMScoreNet"]


class LSTMScoreNet(TokenScoreNet):
    """Tokenizer + step embedding -> stacked LSTM -> linear back to d_model -> head.

    When bidirectional, each direction gets d_model // 2 hidden units so the width (and roughly the
    cost) matches the unidirectional net.
    """

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        n_layers: int = 2,
        bidirectional: bool = True,
        dropout: float = 0.0,
        **embed_kwargs: float,
    ) -> None:
        super().__init__(cond_dim, out_dim, d_model, **embed_kwargs)
        if bidirectional and d_model % 2:
            raise ValueError(f"LSTMScoreNet: bidirectional needs an even d_model, got {d_model}")
        hidden = d_model // 2 if bidirectional else d_model
        self.lstm = nn.LSTM(
            d_model,
            hidden,
            num_layers=n_layers,
            batch_first=True,
            bidirectional=bidirectional,
            dropout=dropout if n_layers > 1 else 0.0,
        )
        self.proj = nn.Linear(hidden * (2 if bidirectional else 1), d_model)

    def mix(self, tokens: torch.Tensor) -> torch.Tensor:
        out, _ = self.lstm(tokens)
        return tokens + self.proj(out)  # residual keeps the per-step conditions close to the head
