"""Noise schedules end near pure noise for every T, and the samplers invert the forward process."""

from __future__ import annotations

import pytest
import torch
from omegaconf import OmegaConf

from dcm.models.diffusion import (
    MAX_T,
    SAMPLERS,
    SCHEDULES,
    NoiseSchedule,
    ScheduleError,
    add_noise,
    alphas_cumprod,
    diffusion_loss,
    make_betas,
    make_scheduler,
    sample,
    sample_many,
)
from dcm.models.nets import build_score_net

OUT = 6


@pytest.mark.parametrize("schedule", SCHEDULES)
def test_alpha_bar_T_small_for_every_T(schedule: str) -> None:
    for T in range(1, MAX_T + 1):
        betas = make_betas(schedule, T)
        assert betas.shape == (T,) and betas.dtype == torch.float64
        assert ((betas > 0) & (betas < 1)).all(), (schedule, T)
        ab = alphas_cumprod(betas)
        assert ab[-1] <= 0.05, f"{schedule}: alpha_bar_T = {ab[-1]:.3g} at T={T}"
        assert (ab[1:] < ab[:-1]).all()
        # the diffusers scheduler holds exactly these values (as float32)
        if T in (1, 30, 100):
            for kind in SAMPLERS:
                sch = make_scheduler(kind, schedule, T)
                assert torch.allclose(sch.alphas_cumprod.double(), ab, rtol=1e-3, atol=1e-9)  # float32 1-beta


def test_textbook_linear_endpoints_would_not_reach_noise_at_T30() -> None:
    """Why the schedules are rescaled: Ho et al.'s endpoints assume T=1000."""
    ab = alphas_cumprod(torch.linspace(1e-4, 0.02, 30, dtype=torch.float64))
    assert ab[-1] > 0.7
    assert alphas_cumprod(make_betas("linear", 30))[-1] < 1e-4


def test_scheduler_defaults_are_pinned() -> None:
    ddpm = make_scheduler("ddpm", "linear", 30)
    ddim = make_scheduler("ddim", NoiseSchedule("cosine", clip_sample_range=3.0), 30)
    unclipped = make_scheduler("ddpm", NoiseSchedule("linear", clip_sample_range=None), 30)
    assert ddpm.config.clip_sample is True and ddpm.config.clip_sample_range == 1.5
    assert ddim.config.clip_sample is True and ddim.config.clip_sample_range == 3.0
    assert unclipped.config.clip_sample is False
    for s in (ddpm, ddim):
        assert s.config.prediction_type == "epsilon" and s.config.thresholding is False
        assert s.config.timestep_spacing == "trailing" and s.config.steps_offset == 0
    assert ddpm.config.variance_type == "fixed_small" and ddim.config.set_alpha_to_one is True
    ddpm.set_timesteps(7)
    assert ddpm.timesteps[0] == 29  # a shortened chain still starts from pure noise
    ddim.set_timesteps(10)
    assert ddim.timesteps.tolist() == list(range(29, -1, -3))


def test_bad_settings_raise() -> None:
    with pytest.raises(ScheduleError, match="unknown noise schedule"):
        make_betas("quadratic", 10)
    for T in (0, 101, 2.5):
        with pytest.raises(ScheduleError, match="1..100"):
            make_betas("linear", T)
    with pytest.raises(ScheduleError, match="ddpm"):
        make_scheduler("euler", "linear", 10)
    with pytest.raises(ScheduleError, match="dividing"):
        sample(lambda c, x, t: x, torch.zeros(1, 4, 1), (1, 4, 1), make_scheduler("ddim", "linear", 30), 7)
    with pytest.raises(ScheduleError, match="num_inference_steps"):
        sample(lambda c, x, t: x, torch.zeros(1, 4, 1), (1, 4, 1), make_scheduler("ddpm", "linear", 30), 31)


def test_schedule_from_hydra_config() -> None:
    cfg = OmegaConf.load("conf/schedule/sigmoid.yaml")
    sch = make_scheduler("ddpm", cfg, 20)
    assert torch.allclose(sch.alphas_cumprod.double(), alphas_cumprod(make_betas("sigmoid", 20)), rtol=1e-5)


def _oracle(scheduler):
    """The perfect epsilon-net for data x0 stored in the first OUT condition channels."""
    ab_table = scheduler.alphas_cumprod.double()

    def net(cond: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        ab = ab_table.to(x_t.device)[t.long()].view(-1, 1, 1).to(x_t.dtype)
        return (x_t - ab.sqrt() * cond[..., :OUT]) / (1 - ab).sqrt()

    return net


def _x0(B: int = 4, H: int = 19) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return torch.rand(B, H, OUT, generator=g, dtype=torch.float64) * 2 - 1


@pytest.mark.parametrize("schedule", SCHEDULES)
@pytest.mark.parametrize("T,steps", [(1, None), (2, None), (30, None), (30, 7), (100, None)])
def test_ddpm_with_oracle_recovers_x0(schedule: str, T: int, steps: int | None) -> None:
    sch = make_scheduler("ddpm", schedule, T)
    x0 = _x0()
    out = sample(_oracle(sch), x0, x0.shape, sch, steps, torch.Generator().manual_seed(1))
    assert torch.allclose(out, x0, atol=1e-5), (out - x0).abs().max()


@pytest.mark.parametrize("schedule", SCHEDULES)
@pytest.mark.parametrize("T,steps", [(30, 10), (30, 30), (30, 1), (100, 20), (1, 1), (30, 2), (30, 3)])
@pytest.mark.parametrize("kind", ["ddim", "ddim_even"])
def test_deterministic_samplers_with_oracle_recover_x0(kind: str, schedule: str, T: int, steps: int) -> None:
    sch = make_scheduler(kind, schedule, T)
    x0 = _x0()
    out = sample(_oracle(sch), x0, x0.shape, sch, steps, torch.Generator().manual_seed(1))
    # diffusers does the step in float32: its rounding (~1e-7) is amplified by 1/sqrt(alpha_bar) of the
    # first step, which a one-step chain from t = T-1 (alpha_bar ~ 1e-6) exposes directly.
    atol = 1e-5 if steps > 1 else 1e-3
    assert torch.allclose(out, x0, atol=atol), (out - x0).abs().max()


def test_ddim_even_spreads_its_steps_to_t0_and_is_ddim_on_the_same_chain() -> None:
    """Known answer: first-order DPM-Solver++ is the DDIM update, clip included, so on DDIM's own chain both
    samplers draw the same forces; only the chain differs (any step count, the last step at t = 0)."""
    even = make_scheduler("ddim_even", "linear", 30, "sample")
    for n, chain in [(1, [29]), (2, [29, 0]), (3, [29, 14, 0]), (4, [29, 19, 10, 0]), (5, [29, 22, 14, 7, 0])]:
        even.set_timesteps(n)
        assert even.timesteps.tolist() == chain
    ddim = make_scheduler("ddim", "linear", 30, "sample")
    on_ddim_chain = make_scheduler("ddim_even", "linear", 30, "sample")
    on_ddim_chain.set_timesteps = lambda n, device=None: type(on_ddim_chain).__base__.set_timesteps(
        on_ddim_chain, timesteps=[29, 19, 9])
    cond = torch.randn(3, 8, OUT, generator=torch.Generator().manual_seed(2))

    def net(c: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return 2.5 * torch.tanh(0.7 * x + c)  # outside the clip range of 1.5: the clip is exercised

    a = sample(net, cond, cond.shape, ddim, 3, torch.Generator().manual_seed(0))
    b = sample(net, cond, cond.shape, on_ddim_chain, 3, torch.Generator().manual_seed(0))
    assert a.abs().max() == pytest.approx(1.5) and torch.allclose(a, b, atol=1e-5), (a - b).abs().max()


def test_sample_many_keeps_items_apart() -> None:
    sch = make_scheduler("ddpm", "linear", 10)
    x0 = _x0(B=3)
    draws = sample_many(_oracle(sch), x0, OUT, sch, k=5, generator=torch.Generator().manual_seed(0), max_batch=4)
    assert draws.shape == (5, 3, x0.shape[1], OUT)
    assert torch.allclose(draws, x0.expand_as(draws), atol=1e-5)


def test_sampling_is_reproducible_and_noise_is_random() -> None:
    torch.manual_seed(0)
    net = build_score_net("mlp", 24, OUT, d_model=16).eval()
    cond = torch.randn(2, 11, 24)
    sch = make_scheduler("ddpm", "linear", 10)
    a = sample(net, cond, (2, 11, OUT), sch, generator=torch.Generator().manual_seed(5))
    b = sample(net, cond, (2, 11, OUT), sch, generator=torch.Generator().manual_seed(5))
    c = sample(net, cond, (2, 11, OUT), sch, generator=torch.Generator().manual_seed(6))
    assert torch.equal(a, b) and not torch.allclose(a, c)
    assert torch.isfinite(a).all()


def test_add_noise_and_loss() -> None:
    sch = make_scheduler("ddpm", "linear", 30)
    x0 = _x0(B=2).float()
    noise = torch.randn_like(x0)
    t = torch.tensor([0, 29])
    xt = add_noise(sch, x0, noise, t)
    assert torch.allclose(xt, sch.add_noise(x0, noise, t), atol=1e-6)  # agrees with diffusers
    assert (xt[1] - noise[1]).abs().max() < 1e-2  # t = T-1 is (almost) pure noise
    net = build_score_net("mlp", 24, OUT, d_model=16)
    loss = diffusion_loss(net, torch.randn(2, x0.shape[1], 24), x0, sch, torch.Generator().manual_seed(0))
    loss.backward()
    assert loss.ndim == 0 and net.tokenizer.proj.weight.grad is not None
