"""Transformer-encoder score net for the architecture ablation (non-causal self-attention)."""

from __future__ import annotations

import math

import torch
from torch import nn

from dcm.models.nets.embedding import TokenScoreNet

__all__ = ["TransformerScoreNet", "sinusoidal_positions"]


def sinusoidal_positions(length: int, d_model: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """Fixed sin/cos absolute positions (L, d): computed on the fly so any horizon H works."""
    pos = torch.arange(length, device=device, dtype=torch.float32)[:, None]
    freq = torch.exp(torch.arange(0, d_model, 2, device=device, dtype=torch.float32) * (-math.log(10000.0) / d_model))
    pe = torch.zeros(length, d_model, device=device, dtype=torch.float32)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: d_model // 2])
    return pe.to(dtype)


class TransformerScoreNet(TokenScoreNet):
    """Tokenizer + step embedding + sinusoidal positions -> pre-LN TransformerEncoder -> head."""

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        n_layers: int = 3,
        n_heads: int = 4,
        ffn_mult: int = 2,
        dropout: float = 0.0,
        causal: bool = False,
        **embed_kwargs: float,
    ) -> None:
        super().__init__(cond_dim, out_dim, d_model, **embed_kwargs)
        if d_model % n_heads:
            raise ValueError(f"TransformerScoreNet: d_model={d_model} not divisible by n_heads={n_heads}")
        layer = nn.TransformerEncoderLayer(
            d_model,
            n_heads,
            dim_feedforward=ffn_mult * d_model,
            dropout=dropout,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        # enable_nested_tensor only matters with padding masks, which we never use.
        self.encoder = nn.TransformerEncoder(layer, n_layers, enable_nested_tensor=False)
        self.causal = causal

    def mix(self, tokens: torch.Tensor) -> torch.Tensor:
        L = tokens.shape[1]
        h = tokens + sinusoidal_positions(L, self.d_model, tokens.device, tokens.dtype)[None]
        mask = (nn.Transformer.generate_square_subsequent_mask(L, device=tokens.device, dtype=tokens.dtype)
                if self.causal else None)
        return self.encoder(h, mask=mask, is_causal=self.causal)
