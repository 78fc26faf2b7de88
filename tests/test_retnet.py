"""Multi-scale retention: the recurrent form must reproduce the parallel form exactly (float64)."""

from __future__ import annotations

import pytest
import torch

from dcm.models.nets.retnet import MultiScaleRetention, RetNet, RetNetScoreNet

TOL = 1e-10


def _boost_qk(module: torch.nn.Module, factor: float = 30.0) -> None:
    """Large q/k weights so the max(|sum|, 1) row normaliser is actually active, not clamped to 1."""
    with torch.no_grad():
        for m in module.modules():
            if isinstance(m, MultiScaleRetention):
                m.in_proj.weight[: 2 * m.d_model].mul_(factor)  # the q and k rows


def test_decays_follow_sun_et_al() -> None:
    msr = MultiScaleRetention(64, n_heads=4)
    expected = 1 - 2.0 ** (-5 - torch.arange(4, dtype=torch.float64))
    assert torch.allclose(msr.log_gamma.double().exp(), expected, atol=1e-7)


def test_msr_parallel_equals_recurrent_and_normaliser_active() -> None:
    torch.manual_seed(0)
    msr = MultiScaleRetention(32, n_heads=4).double()
    _boost_qk(msr)
    x = torch.randn(3, 41, 32, dtype=torch.float64)
    # the normaliser must bite somewhere, otherwise this test would not cover it
    q, k, _, _ = msr._qkvg(x, torch.arange(41))
    row_sums = ((q @ k.transpose(-1, -2)) * msr.decay_mask(41, x.device, x.dtype)).sum(-1).abs()
    assert (row_sums > 1).any() and (row_sums < 1).any()
    assert torch.allclose(msr(x), msr.forward_recurrent(x), atol=TOL, rtol=0)


@pytest.mark.parametrize("bidirectional", [False, True])
def test_retnet_stack_parallel_equals_recurrent(bidirectional: bool) -> None:
    torch.manual_seed(1)
    net = RetNet(d_model=32, n_layers=2, n_heads=4, bidirectional=bidirectional).double()
    _boost_qk(net)
    x = torch.randn(2, 33, 32, dtype=torch.float64)
    assert torch.allclose(net(x), net.forward_recurrent(x), atol=TOL, rtol=0)


def test_score_net_streaming_equals_parallel() -> None:
    torch.manual_seed(2)
    net = RetNetScoreNet(24, 6, d_model=32, n_layers=2, n_heads=4).double().eval()
    _boost_qk(net, 10.0)
    cond = torch.randn(2, 29, 24, dtype=torch.float64)
    noisy = torch.randn(2, 29, 6, dtype=torch.float64)
    step = torch.tensor([0, 17])
    ref = net(cond, noisy, step)
    assert torch.allclose(ref, net.forward_recurrent(cond, noisy, step), atol=TOL, rtol=0)
    assert torch.allclose(ref, net.forward_streaming(cond, noisy, step), atol=TOL, rtol=0)


def test_causal_ignores_future_bidirectional_does_not() -> None:
    torch.manual_seed(3)
    x = torch.randn(1, 20, 32, dtype=torch.float64)
    x2 = x.clone()
    x2[:, 12:] += torch.randn(1, 8, 32, dtype=torch.float64)  # not a constant: LayerNorm would remove that
    causal = RetNet(32, 2, 4, bidirectional=False).double()
    assert torch.allclose(causal(x)[:, :12], causal(x2)[:, :12], atol=TOL, rtol=0)
    bi = RetNet(32, 2, 4, bidirectional=True).double()
    assert not torch.allclose(bi(x)[:, :12], bi(x2)[:, :12], atol=1e-6)


def test_streaming_refuses_bidirectional() -> None:
    net = RetNet(32, 1, 4, bidirectional=True)
    with pytest.raises(RuntimeError, match="causal"):
        net.init_state(1, torch.device("cpu"), torch.float32)


@pytest.mark.parametrize("chunk", [1, 8, 41, 64])
def test_msr_chunkwise_equals_parallel(chunk: int) -> None:
    """Chunks that divide the sequence or not, one token per chunk, one chunk for all: the parallel outputs."""
    torch.manual_seed(1)
    msr = MultiScaleRetention(32, n_heads=4).double()
    _boost_qk(msr)
    x = torch.randn(3, 41, 32, dtype=torch.float64)
    assert torch.allclose(msr.forward_chunkwise(x, chunk), msr(x), atol=TOL, rtol=0)


@pytest.mark.parametrize("bidirectional", [False, True])
def test_predictions_use_the_chunkwise_form_and_match_training_outputs(bidirectional: bool) -> None:
    torch.manual_seed(2)
    net = RetNetScoreNet(cond_dim=5, out_dim=3, d_model=32, n_layers=2, n_heads=4, bidirectional=bidirectional)
    net = net.double()
    _boost_qk(net)
    cond, noisy, step = torch.randn(2, 130, 5, dtype=torch.float64), torch.randn(2, 130, 3, dtype=torch.float64), 3
    trained = net(cond, noisy, torch.full((2,), step))
    calls = []
    original = MultiScaleRetention.forward_chunkwise
    try:
        MultiScaleRetention.forward_chunkwise = lambda self, x, c: calls.append(c) or original(self, x, c)
        with torch.inference_mode():
            predicted = net(cond, noisy, torch.full((2,), step))
    finally:
        MultiScaleRetention.forward_chunkwise = original
    assert calls and set(calls) == {MultiScaleRetention.CHUNK_STEPS}
    assert torch.allclose(predicted, trained, atol=1e-9, rtol=0)
