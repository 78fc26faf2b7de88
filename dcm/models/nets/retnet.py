"""Retentive network (Sun et al. 2023, "Retentive Network: A Successor to Transformer"), the paper's score net.

Multi-scale retention (MSR), per head h with decay gamma_h = 1 - 2^(-5-h):
    Retention(X)_n = sum_{m<=n} (q_n . k_m) gamma^(n-m) v_m / sqrt(c_n),   c_n = sum_{m<=n} gamma^(n-m)
with q, k rotated by their absolute positions (rotary / xPos-style), so q_n . k_m depends on n - m only.
Rows are then divided by max(|sum_m (q_n . k_m) D_nm|, 1) (the paper's normalisation), each head is
group-normed, gated by swish(X W_G) and projected back.

The parallel form (an (H x H) decay mask) trains fast; the recurrent form keeps a per-head state
S_n = gamma S_{n-1} + k_n^T v_n and gives identical outputs one step at a time. Both normalisers above
are linear in k (the signed sum q_n . z_n with z_n = gamma z_{n-1} + k_n), which is what makes the
recurrent form exact rather than approximate. The chunkwise form (the paper's third) mixes the two: the
parallel form inside chunks of ``CHUNK_STEPS`` tokens, the recurrent state across them. It gives the same
outputs with far less work on the (H x H) scores, so predictions (no gradient) use it; training keeps the
parallel form. The existing libraries (torchscale, yet-another-retnet)
pin old dependencies or are unmaintained, hence this self-contained version.

Bidirectional option: a forward causal MSR plus a second causal MSR run on the time-reversed sequence,
summed. Each direction keeps its recurrent form; the denoiser sees the whole trajectory anyway.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from dcm.models.nets.embedding import TokenScoreNet

__all__ = ["MultiScaleRetention", "BidirectionalRetention", "RetNetBlock", "RetNet", "RetNetScoreNet"]

RetState = tuple[torch.Tensor, torch.Tensor, torch.Tensor]  # S (B,h,dk,dv), z (B,h,dk), c (h,)


def _rotate(x: torch.Tensor, pos: torch.Tensor, inv_freq: torch.Tensor) -> torch.Tensor:
    """Rotary position: rotate channel pairs (i, i + d/2) of x (..., L, d) by angle pos * inv_freq."""
    angle = pos.to(x.dtype)[:, None] * inv_freq.to(x.dtype)[None, :]  # (L, d/2)
    cos, sin = angle.cos(), angle.sin()
    x1, x2 = x.chunk(2, dim=-1)
    return torch.cat([x1 * cos - x2 * sin, x1 * sin + x2 * cos], dim=-1)


class MultiScaleRetention(nn.Module):
    """Causal multi-scale retention with parallel (`forward`), chunkwise and recurrent (`step`) forms."""

    # Tokens per chunk of the chunkwise form: small enough that the per-chunk scores stay in cache, large enough
    # that the products between chunks and states are few.
    CHUNK_STEPS = 48

    def __init__(self, d_model: int, n_heads: int = 4, value_factor: int = 1, gn_eps: float = 1e-5) -> None:
        super().__init__()
        if d_model % n_heads or (d_model // n_heads) % 2:
            raise ValueError(f"MultiScaleRetention: d_model={d_model} must split into {n_heads} heads of even size")
        self.d_model, self.n_heads = d_model, n_heads
        self.key_dim = d_model // n_heads
        self.v_dim = d_model * value_factor
        self.head_v = self.v_dim // n_heads
        # q, k, v and the gate in one matmul (fewer passes over the tokens than four Linear layers)
        self.in_proj = nn.Linear(d_model, 2 * d_model + 2 * self.v_dim, bias=False)
        self.out_proj = nn.Linear(self.v_dim, d_model, bias=False)
        self.group_norm = nn.GroupNorm(n_heads, self.v_dim, eps=gn_eps)
        heads = torch.arange(n_heads, dtype=torch.float64)
        self.register_buffer("log_gamma", torch.log1p(-(2.0 ** (-5.0 - heads))).float())
        self.register_buffer(
            "inv_freq", 1.0 / 10000 ** (torch.arange(self.key_dim // 2, dtype=torch.float32) / (self.key_dim // 2))
        )
        # Small init of each projection, as in the reference RetNet, keeps early residual updates gentle.
        with torch.no_grad():
            for block in self.in_proj.weight.split([d_model, d_model, self.v_dim, self.v_dim]):
                nn.init.xavier_uniform_(block, gain=2**-2.5)
        nn.init.xavier_uniform_(self.out_proj.weight, gain=2**-1)

    def _qkvg(self, x: torch.Tensor, pos: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """x (B,L,d) -> q, k (B,h,L,dk) rotated, k scaled by dk^-1/2; v (B,h,L,dv); gate (B,L,v_dim)."""
        B, L, _ = x.shape
        qk, v, g = self.in_proj(x).split([2 * self.d_model, self.v_dim, self.v_dim], dim=-1)
        qk = _rotate(qk.view(B, L, 2 * self.n_heads, self.key_dim).transpose(1, 2), pos, self.inv_freq)
        q, k = qk.split(self.n_heads, dim=1)
        v = v.reshape(B, L, self.n_heads, self.head_v).transpose(1, 2)
        return q, k * self.key_dim**-0.5, v, g

    def _output(self, g: torch.Tensor, ret: torch.Tensor) -> torch.Tensor:
        """ret (B,h,L,dv) -> group norm per head, swish gate, output projection -> (B,L,d)."""
        B, _, L, _ = ret.shape
        # GroupNorm with one group per head is a layer norm over each head's channels plus the per-channel
        # affine; torch's layer norm kernel is several times faster on a CPU than its group norm for these shapes
        gn = self.group_norm
        ret = F.layer_norm(ret.transpose(1, 2), (self.head_v,), eps=gn.eps).reshape(B, L, self.v_dim)
        return self.out_proj(F.silu(g) * torch.addcmul(gn.bias, ret, gn.weight))

    def decay_mask(self, L: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
        """D (h,L,L): gamma^(n-m) for m <= n else 0, each row divided by sqrt of its sum."""
        n = torch.arange(L, device=device, dtype=dtype)
        diff = n[:, None] - n[None, :]
        log_g = self.log_gamma.to(device=device, dtype=dtype)[:, None, None]
        D = torch.where(diff >= 0, torch.exp(diff.clamp(min=0) * log_g), torch.zeros((), device=device, dtype=dtype))
        return D / D.sum(dim=-1, keepdim=True).sqrt()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Parallel form: (B,L,d) -> (B,L,d); the chunkwise form when no gradient is recorded (predictions)."""
        L = x.shape[1]
        if L > self.CHUNK_STEPS and not torch.is_grad_enabled():
            return self.forward_chunkwise(x, self.CHUNK_STEPS)
        q, k, v, g = self._qkvg(x, torch.arange(L, device=x.device))
        qk = (q @ k.transpose(-1, -2)).mul_(self.decay_mask(L, x.device, x.dtype))  # matmul keeps no output for backward
        # Dividing the (L x dv) result instead of the (L x L) scores: same numbers, one pass less over L^2.
        denom = qk.detach().sum(dim=-1, keepdim=True).abs().clamp(min=1.0)
        return self._output(g, (qk @ v) / denom)

    def forward_chunkwise(self, x: torch.Tensor, chunk: int) -> torch.Tensor:
        """Chunkwise form: (B,L,d) -> (B,L,d), the parallel form's outputs.

        Per head, with n = i*C + a in chunk i and the state of all tokens before chunk i,
        S_i = sum_{m < iC} gamma^(iC-1-m) k_m^T v_m and z_i = sum_{m < iC} gamma^(iC-1-m) k_m:
        numerator_n = sum_{m in chunk i, m <= n} (q_n . k_m) gamma^(n-m) v_m + gamma^(a+1) q_n S_i, and the
        normaliser's sum likewise with z_i; both are then divided by sqrt(c_n) as in the parallel form.
        """
        B, L, _ = x.shape
        q, k, v, g = self._qkvg(x, torch.arange(L, device=x.device))
        n_chunks = -(-L // chunk)
        if n_chunks * chunk > L:  # zero tokens at the end change nothing before them
            q, k, v = (F.pad(t, (0, 0, 0, n_chunks * chunk - L)) for t in (q, k, v))
        q, k, v = (t.reshape(B, self.n_heads, n_chunks, chunk, -1) for t in (q, k, v))
        log_g = self.log_gamma.to(device=x.device, dtype=torch.float64)[:, None]  # (h, 1)
        a = torch.arange(chunk, device=x.device, dtype=torch.float64)
        diff = a[:, None] - a[None, :]
        zero = torch.zeros((), dtype=diff.dtype, device=x.device)
        inner = torch.where(diff >= 0, torch.exp(diff.clamp(min=0) * log_g[..., None]), zero)  # (h,C,C)
        qk = q @ k.transpose(-1, -2)  # (B,h,N,C,C)
        qk = qk * inner[:, None].to(qk.dtype)
        numerator, normaliser = qk @ v, qk.sum(dim=-1, keepdim=True)
        # Each chunk's own contribution to the state, then the states before every chunk, chunk by chunk.
        k_in = k * torch.exp((chunk - 1 - a) * log_g)[:, None, :, None].to(k.dtype)
        own_S, own_z = k_in.transpose(-1, -2) @ v, k_in.sum(dim=-2)  # (B,h,N,dk,dv), (B,h,N,dk)
        carry = torch.exp(chunk * log_g).to(own_S.dtype)  # (h, 1): gamma^C
        S, z = torch.zeros_like(own_S[:, :, 0]), torch.zeros_like(own_z[:, :, 0])
        states_S, states_z = [], []
        for i in range(n_chunks):
            states_S.append(S)
            states_z.append(z)
            S = carry[..., None] * S + own_S[:, :, i]
            z = carry * z + own_z[:, :, i]
        q_out = q * torch.exp((a + 1) * log_g)[:, None, :, None].to(q.dtype)  # gamma^(a+1) q_n
        numerator = numerator + q_out @ torch.stack(states_S, dim=2)
        normaliser = normaliser + (q_out * torch.stack(states_z, dim=2)[:, :, :, None, :]).sum(dim=-1, keepdim=True)
        # c_n = sum_{m <= n} gamma^(n-m) = (1 - gamma^(n+1)) / (1 - gamma)
        steps = torch.arange(n_chunks * chunk, device=x.device, dtype=torch.float64)
        root_c = ((1 - torch.exp((steps + 1) * log_g)) / -torch.expm1(log_g)).sqrt()
        root_c = root_c.reshape(1, self.n_heads, n_chunks, chunk, 1).to(numerator.dtype)
        ret = (numerator / root_c) / (normaliser / root_c).abs().clamp(min=1.0)
        return self._output(g, ret.reshape(B, self.n_heads, n_chunks * chunk, -1)[:, :, :L])

    def init_state(self, batch: int, device: torch.device, dtype: torch.dtype) -> RetState:
        h = self.n_heads
        return (
            torch.zeros(batch, h, self.key_dim, self.head_v, device=device, dtype=dtype),
            torch.zeros(batch, h, self.key_dim, device=device, dtype=dtype),
            torch.zeros(h, device=device, dtype=dtype),
        )

    def step(self, x_t: torch.Tensor, state: RetState, n: int) -> tuple[torch.Tensor, RetState]:
        """Recurrent form for position n: x_t (B,d) -> y_t (B,d), new state. O(1) in the sequence length."""
        S, z, c = state
        q, k, v, g = self._qkvg(x_t[:, None, :], torch.tensor([n], device=x_t.device))
        q, k, v = q[:, :, 0], k[:, :, 0], v[:, :, 0]  # (B,h,dk), (B,h,dk), (B,h,dv)
        gamma = self.log_gamma.to(x_t.dtype).exp()
        S = gamma[None, :, None, None] * S + k[..., :, None] * v[..., None, :]
        z = gamma[None, :, None] * z + k
        c = gamma * c + 1.0
        root_c = c.sqrt()[None, :, None]
        num = torch.einsum("bhk,bhkv->bhv", q, S) / root_c
        den = ((q * z).sum(-1, keepdim=True) / root_c).abs().clamp(min=1.0)
        y = self._output(g, (num / den)[:, :, None, :])[:, 0]
        return y, (S, z, c)

    def forward_recurrent(self, x: torch.Tensor) -> torch.Tensor:
        """The recurrent form over a whole sequence (slow; for checking and streaming)."""
        state = self.init_state(x.shape[0], x.device, x.dtype)
        ys = []
        for n in range(x.shape[1]):
            y, state = self.step(x[:, n], state, n)
            ys.append(y)
        return torch.stack(ys, dim=1)


class BidirectionalRetention(nn.Module):
    """Forward causal MSR + a causal MSR over the reversed sequence, summed (each with its own weights)."""

    def __init__(self, d_model: int, n_heads: int = 4, value_factor: int = 1) -> None:
        super().__init__()
        self.fwd = MultiScaleRetention(d_model, n_heads, value_factor)
        self.bwd = MultiScaleRetention(d_model, n_heads, value_factor)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fwd(x) + self.bwd(x.flip(1)).flip(1)

    def forward_recurrent(self, x: torch.Tensor) -> torch.Tensor:
        return self.fwd.forward_recurrent(x) + self.bwd.forward_recurrent(x.flip(1)).flip(1)


class RetNetBlock(nn.Module):
    """Pre-LN residual block: x + MSR(LN(x)), then x + FFN(LN(x))."""

    def __init__(
        self,
        d_model: int,
        n_heads: int = 4,
        ffn_mult: int = 2,
        value_factor: int = 1,
        dropout: float = 0.0,
        bidirectional: bool = False,
    ) -> None:
        super().__init__()
        self.bidirectional = bidirectional
        self.norm1 = nn.LayerNorm(d_model)
        self.norm2 = nn.LayerNorm(d_model)
        retention_cls = BidirectionalRetention if bidirectional else MultiScaleRetention
        self.retention = retention_cls(d_model, n_heads, value_factor)
        self.ffn = nn.Sequential(
            nn.Linear(d_model, ffn_mult * d_model), nn.GELU(), nn.Dropout(dropout), nn.Linear(ffn_mult * d_model, d_model)
        )
        self.dropout = nn.Dropout(dropout)

    def _ffn(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.dropout(self.ffn(self.norm2(x)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._ffn(x + self.dropout(self.retention(self.norm1(x))))

    def forward_recurrent(self, x: torch.Tensor) -> torch.Tensor:
        return self._ffn(x + self.dropout(self.retention.forward_recurrent(self.norm1(x))))

    def step(self, x_t: torch.Tensor, state: RetState, n: int) -> tuple[torch.Tensor, RetState]:
        if self.bidirectional:
            raise RuntimeError("RetNetBlock.step: a bidirectional block cannot stream token by token")
        y, state = self.retention.step(self.norm1(x_t), state, n)
        return self._ffn(x_t + self.dropout(y)), state


class RetNet(nn.Module):
    """A stack of RetNet blocks over (B,L,d) tokens."""

    def __init__(
        self,
        d_model: int = 128,
        n_layers: int = 3,
        n_heads: int = 4,
        ffn_mult: int = 2,
        value_factor: int = 1,
        dropout: float = 0.0,
        bidirectional: bool = False,
    ) -> None:
        super().__init__()
        self.bidirectional = bidirectional
        self.blocks = nn.ModuleList(
            RetNetBlock(d_model, n_heads, ffn_mult, value_factor, dropout, bidirectional) for _ in range(n_layers)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Parallel form (training)."""
        for block in self.blocks:
            x = block(x)
        return x

    def forward_recurrent(self, x: torch.Tensor) -> torch.Tensor:
        """Recurrent form, layer by layer; equals `forward` (causal and bidirectional)."""
        for block in self.blocks:
            x = block.forward_recurrent(x)
        return x

    def init_state(self, batch: int, device: torch.device, dtype: torch.dtype) -> list[RetState]:
        if self.bidirectional:
            raise RuntimeError("RetNet.init_state: streaming needs a causal RetNet (bidirectional=False)")
        return [blk.retention.init_state(batch, device, dtype) for blk in self.blocks]

    def step(self, x_t: torch.Tensor, states: list[RetState], n: int) -> tuple[torch.Tensor, list[RetState]]:
        """Stream one token (B,d) at position n through all layers (causal only)."""
        new_states = []
        for block, state in zip(self.blocks, states):
            x_t, state = block.step(x_t, state, n)
            new_states.append(state)
        return x_t, new_states


class RetNetScoreNet(TokenScoreNet):
    """The paper's score function: tokenizer + Gaussian-Fourier step embedding -> RetNet -> head."""

    def __init__(
        self,
        cond_dim: int,
        out_dim: int,
        d_model: int = 128,
        n_layers: int = 3,
        n_heads: int = 4,
        ffn_mult: int = 2,
        value_factor: int = 1,
        dropout: float = 0.0,
        bidirectional: bool = False,
        **embed_kwargs: float,
    ) -> None:
        super().__init__(cond_dim, out_dim, d_model, **embed_kwargs)
        self.retnet = RetNet(d_model, n_layers, n_heads, ffn_mult, value_factor, dropout, bidirectional)

    def mix(self, tokens: torch.Tensor) -> torch.Tensor:
        return self.retnet(tokens)

    def forward_recurrent(self, cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """Same output as `forward`, computed with the recurrent form of every retention layer."""
        return self.head(self.retnet.forward_recurrent(self.embed(cond, noisy, step)))

    def forward_streaming(self, cond: torch.Tensor, noisy: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """Causal nets only: process the trajectory token by token with O(1) state per layer."""
        tokens = self.embed(cond, noisy, step)
        states = self.retnet.init_state(tokens.shape[0], tokens.device, tokens.dtype)
        outs = []
        for n in range(tokens.shape[1]):
            y, states = self.retnet.step(tokens[:, n], states, n)
            outs.append(y)
        return self.head(torch.stack(outs, dim=1))

