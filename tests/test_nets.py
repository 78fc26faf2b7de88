"""Every score net honours the shared interface: (B,H,24) + (B,H,6) + (B,) -> (B,H,6), any H."""

from __future__ import annotations

import pytest
import torch

from dcm.models.nets import SCORE_NETS, NetShapeError, UnknownNetError, build_score_net

COND, OUT = 24, 6
SMALL = dict(d_model=32)  # width only; depth stays at each net's default


def _inputs(B: int, H: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, H, COND, generator=g), torch.randn(B, H, OUT, generator=g), torch.randint(0, 30, (B,), generator=g)


@pytest.mark.parametrize("name", sorted(SCORE_NETS))
@pytest.mark.parametrize("H", [160, 37])
def test_shape_and_gradients(name: str, H: int) -> None:
    torch.manual_seed(0)
    net = build_score_net(name, COND, OUT, **SMALL)
    cond, noisy, step = _inputs(3, H)
    cond.requires_grad_(True)
    out = net(cond, noisy, step)
    assert out.shape == (3, H, OUT) and out.dtype == torch.float32
    assert torch.isfinite(out).all()
    out.square().mean().backward()
    for pname, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), f"{name}: no/bad grad for {pname}"
    assert net.tokenizer.proj.weight.grad.abs().sum() > 0
    assert net.step_embed.mlp[0].weight.grad.abs().sum() > 0
    assert cond.grad.abs().sum() > 0


def test_default_nets_handle_paper_horizon() -> None:
    cond, noisy, step = _inputs(2, 160)
    for name in SCORE_NETS:
        assert build_score_net(name, COND, OUT)(cond, noisy, step).shape == (2, 160, OUT)


@pytest.mark.parametrize("H", [1, 2, 5, 161])
def test_unet_pads_and_crops_any_horizon(H: int) -> None:
    net = build_score_net("unet1d", COND, OUT, d_model=16, down_dims=(16, 32, 32, 32))  # factor 8
    assert net.factor == 8
    cond, noisy, step = _inputs(2, H)
    assert net(cond, noisy, step).shape == (2, H, OUT)


@pytest.mark.parametrize("name", sorted(SCORE_NETS))
def test_step_changes_output_and_scalar_step_broadcasts(name: str) -> None:
    net = build_score_net(name, COND, OUT, **SMALL).eval()
    cond, noisy, _ = _inputs(2, 12)
    with torch.no_grad():
        a = net(cond, noisy, torch.zeros(2, dtype=torch.long))
        b = net(cond, noisy, torch.full((2,), 20.0))
        c = net(cond, noisy, 0)  # the baseline's call
    assert not torch.allclose(a, b)
    assert torch.allclose(a, c)


@pytest.mark.parametrize("name", sorted(SCORE_NETS))
def test_batch_items_are_independent(name: str) -> None:
    net = build_score_net(name, COND, OUT, **SMALL).eval()
    cond, noisy, step = _inputs(4, 20)
    with torch.no_grad():
        full = net(cond, noisy, step)
        one = net(cond[1:2], noisy[1:2], step[1:2])
    assert torch.allclose(full[1:2], one, atol=1e-5)


def test_mlp_is_per_step_and_sequence_nets_are_not() -> None:
    cond, noisy, step = _inputs(1, 16)
    cond2 = cond.clone()
    cond2[:, 10] += torch.linspace(-1.0, 1.0, COND)
    for name in SCORE_NETS:
        net = build_score_net(name, COND, OUT, **SMALL).eval()
        with torch.no_grad():
            changed = ~torch.isclose(net(cond, noisy, step), net(cond2, noisy, step), atol=1e-7).all(-1)[0]
        if name == "mlp":
            assert changed.nonzero().flatten().tolist() == [10]
        else:
            assert changed.sum() > 1, name


def test_bad_inputs_raise_clear_errors() -> None:
    net = build_score_net("mlp", COND, OUT, **SMALL)
    cond, noisy, step = _inputs(2, 8)
    with pytest.raises(NetShapeError, match="cond must be"):
        net(cond[..., :20], noisy, step)
    with pytest.raises(NetShapeError, match="noisy must be"):
        net(cond, noisy[..., :3], step)
    with pytest.raises(NetShapeError, match="differ"):
        net(cond, noisy[:, :5], step)
    with pytest.raises(NetShapeError, match="step"):
        net(cond, noisy, step[:1])
    with pytest.raises(UnknownNetError, match="choose one of"):
        build_score_net("gru", COND, OUT)
    with pytest.raises(UnknownNetError, match="rejected"):
        build_score_net("mlp", COND, OUT, n_heads=4)


def test_aliases_and_float64() -> None:
    net = build_score_net("UNet", COND, OUT, **SMALL).double()
    cond, noisy, step = _inputs(1, 9)
    assert net(cond.double(), noisy.double(), step).dtype == torch.float64
