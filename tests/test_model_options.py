"""The model options a user can switch: prediction type, residual target, z-score normalisation, input scaling,
condition encoding."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dcm.models import diffusion
from dcm.models.baseline import Baseline
from dcm.models.cond_encoding import encode_conditions
from dcm.models.configuration import ModelInputError
from dcm.models.dcm import DCM
from dcm.models.normalizer import ZSCORE_SPAN, ChannelNormalizer

TINY_NET = {"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2}


def _positive_stiffness_cond(gen: torch.Generator, n: int = 6, horizon: int = 12) -> torch.Tensor:
    cond = torch.randn(n, horizon, 24, generator=gen)
    cond[..., 18:] = 100.0 + 2400.0 * torch.rand(n, horizon, 6, generator=gen)
    return cond


@pytest.mark.parametrize("kind", diffusion.PREDICTION_TYPES)
def test_training_target_is_what_the_scheduler_reads_back(kind: str) -> None:
    """An oracle output built by training_target makes diffusers' step recover x0, for every type.

    Only steps with alpha_bar >= 0.01 are checked: below, recovering x0 from the noise divides float32
    rounding by sqrt(alpha_bar), which is the weakness of epsilon-prediction, not of the target."""
    sched = diffusion.make_scheduler("ddpm", diffusion.NoiseSchedule(clip_sample_range=None), 10, kind)
    gen = torch.Generator().manual_seed(0)
    x0 = torch.rand(2, 8, 6, generator=gen) * 2 - 1
    noise = torch.randn(2, 8, 6, generator=gen)
    usable = [t for t in range(10) if float(sched.alphas_cumprod[t]) >= 0.01]
    assert len(usable) >= 3
    for t in usable:
        steps = torch.full((2,), t)
        x_t = diffusion.add_noise(sched, x0, noise, steps)
        out = diffusion.training_target(sched, x0, noise, steps)
        sched.set_timesteps(10)
        x0_hat = sched.step(out, t, x_t).pred_original_sample
        torch.testing.assert_close(x0_hat, x0, atol=2e-4, rtol=1e-4)


def test_bad_prediction_type_is_named() -> None:
    with pytest.raises(ModelInputError, match="prediction_type"):
        DCM(net=dict(TINY_NET), prediction_type="x0")
    with pytest.raises(ModelInputError, match="target"):
        Baseline(net=dict(TINY_NET), target="delta")
    with pytest.raises(ModelInputError, match="normalization"):
        Baseline(net=dict(TINY_NET), normalization="robust")
    with pytest.raises(ModelInputError, match="input_scaling"):
        DCM(net=dict(TINY_NET), input_scaling="edm")


def test_signal_input_scaling_feeds_about_zeros_at_pure_noise() -> None:
    """"signal" scales x_t by sqrt(alpha_bar_t): ~0 at t = T-1, ~x_t at t = 0; "unit" is the net itself."""
    sched = diffusion.make_scheduler("ddpm", "linear", 30, "sample")
    seen = {}

    def net(cond: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        seen["x"] = x
        return x

    assert diffusion.scale_noisy_input(net, sched, "unit") is net
    scaled = diffusion.scale_noisy_input(net, sched, "signal")
    x = torch.ones(2, 8, 6)
    scaled(torch.zeros(2, 8, 24), x, torch.tensor([29, 0]))
    assert float(seen["x"][0].abs().max()) < 0.01
    torch.testing.assert_close(seen["x"][1], x[1] * float(sched.alphas_cumprod[0].sqrt()))
    assert float(sched.alphas_cumprod[0].sqrt()) > 0.98


def test_signal_input_scaling_trains_and_samples() -> None:
    """One optimiser step and a DDIM prediction at tiny scale, with the option on."""
    gen = torch.Generator().manual_seed(2)
    cond, force = torch.randn(4, 8, 24, generator=gen), torch.randn(4, 8, 6, generator=gen)
    model = DCM(net=dict(TINY_NET), diffusion_steps=10, input_scaling="signal", sampler="ddim", sampling_steps=2)
    model.fit_normalizers(cond, force)
    loss = model.loss(model.net, model.cond_norm.normalize(cond), model.normalized_target(cond, force))
    loss.backward()
    assert torch.isfinite(loss) and any(p.grad is not None for p in model.net.parameters())
    samples = model.sample_normalized(model.cond_norm.normalize(cond), n_samples=2)
    assert samples.shape == (2, 4, 8, 6) and torch.isfinite(samples).all()


def test_zscore_maps_mean_pm_span_std_to_unit_range() -> None:
    data = torch.randn(1000, 3, dtype=torch.float64) * torch.tensor([1.0, 10.0, 0.1]) + 5.0
    norm = ChannelNormalizer(3).fit_data(data, "zscore")
    mean, std = data.mean(0), data.std(0)
    y = norm.normalize((mean + ZSCORE_SPAN * std).float())
    torch.testing.assert_close(y, torch.ones(3), atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(norm.normalize(mean.float()), torch.zeros(3), atol=1e-5, rtol=0)


@pytest.mark.parametrize("cls", [DCM, Baseline])
def test_residual_target_round_trip_and_prediction(cls: type) -> None:
    """A residual model learns F_obs - F_demo and adds F_demo back: the target round-trips, and predictions
    of a model whose net outputs the normalised zero residual equal F_demo."""
    gen = torch.Generator().manual_seed(1)
    cond = _positive_stiffness_cond(gen)
    force = cond[..., 6:12] + 0.3 * torch.randn(6, 12, 6, generator=gen)
    model = cls(net=dict(TINY_NET), target="residual", ema_decay=0.0)
    model.fit_normalizers(cond, force)
    target_n = model.normalized_target(cond, force)
    back = model.force_from_target(cond, model.target_norm.unnormalize(target_n))
    torch.testing.assert_close(back, force, atol=1e-5, rtol=1e-5)

    zero_n = model.target_norm.normalize(torch.zeros(6))
    model.sample_normalized = lambda c, k=1, g=None: zero_n.expand(k, *c.shape[:2], 6)  # type: ignore[method-assign]
    mean, _ = model.predict_forces(cond[..., :6].numpy(), cond[..., 6:12].numpy(), cond[..., 12:18].numpy(),
                                   cond[..., 18:].numpy())
    np.testing.assert_allclose(mean, cond[..., 6:12].numpy(), atol=1e-4)


def test_set_sampler_switches_steps_and_checks_them() -> None:
    model = DCM(net=dict(TINY_NET), diffusion_steps=10)
    calls = {"n": 0}
    net = model.inference_net
    original = net.forward

    def counting(*args, **kwargs):
        calls["n"] += 1
        return original(*args, **kwargs)

    net.forward = counting  # type: ignore[method-assign]
    model.fit_normalizers(torch.randn(2, 8, 24), torch.randn(2, 8, 6))
    model.set_sampler("ddim", 5)
    model.predict_normalized(torch.zeros(1, 8, 24))
    assert calls["n"] == 5
    with pytest.raises(diffusion.ScheduleError, match="divid"):
        model.set_sampler("ddim", 3)


def test_samples_share_their_leading_steps_and_sample_zero_is_the_unshared_chain() -> None:
    """With the signal input scaling, the three DDIM steps of T = 30 see noise of std 0.001, 0.07 and 0.46: the
    k samples share the first two (one net row per condition), branch at the last, and sample 0 is the
    independent chain's."""
    model = DCM(net=dict(TINY_NET), diffusion_steps=30, input_scaling="signal", prediction_type="sample")
    model.fit_normalizers(torch.randn(2, 8, 24), torch.randn(2, 8, 6))
    model.set_sampler("ddim", 3)
    rows: list[int] = []
    original = model.inference_net.forward
    model.inference_net.forward = lambda cond, *a: rows.append(len(cond)) or original(cond, *a)  # type: ignore
    cond_n = torch.randn(2, 8, 24)
    draw = lambda: model.sample_normalized(cond_n, 4, torch.Generator().manual_seed(5))  # noqa: E731
    independent = draw()
    assert rows == [8, 8, 8] and model.set_shared_steps("auto") == 2
    rows.clear()
    shared = draw()
    assert rows == [2, 2, 8]  # 12 rows instead of 24
    torch.testing.assert_close(shared[0], independent[0], rtol=1e-4, atol=1e-5)  # rounding of another batch size
    assert shared.shape == (4, 2, 8, 6) and float(shared.std(0).mean()) > 0  # the samples still differ
    assert model.set_shared_steps(1) == 1 and model.set_shared_steps(0) == 0
    with pytest.raises(ModelInputError, match=r"shared_steps = 3 must be below the sampler's 3 steps"):
        model.set_shared_steps(3)
    unit = DCM(net=dict(TINY_NET), diffusion_steps=30, input_scaling="unit")
    unit.set_sampler("ddim", 3)
    assert unit.set_shared_steps("auto") == 0  # it sees unit-variance noise at every step


def test_physical_encoding_is_the_deflection_and_log_stiffness() -> None:
    cond = _positive_stiffness_cond(torch.Generator().manual_seed(3))
    encoded = encode_conditions(cond, "physical")
    torch.testing.assert_close(encoded[..., :12], cond[..., :12])           # x_demo, F_demo unchanged
    torch.testing.assert_close(encoded[..., 12:18], cond[..., 12:18] - cond[..., :6])
    torch.testing.assert_close(encoded[..., 18:], cond[..., 18:].log())
    assert encode_conditions(cond, "raw") is cond


@pytest.mark.parametrize("cls", [DCM, Baseline])
def test_physical_encoding_option_fits_trains_and_predicts(cls: type) -> None:
    """The normaliser is fitted on the encoded conditions, so they reach the net in [-1, 1] (min-max), and
    predict_forces takes the same raw inputs as with the paper's encoding."""
    gen = torch.Generator().manual_seed(4)
    cond = _positive_stiffness_cond(gen)
    force = torch.randn(6, 12, 6, generator=gen)
    model = cls(net=dict(TINY_NET), cond_encoding="physical", ema_decay=0.0)
    model.fit_normalizers(cond, force)
    cond_n = model.normalized_cond(cond)
    assert float(cond_n[..., 18:21].min()) == pytest.approx(-1.0, abs=1e-5)
    assert float(cond_n[..., 18:21].max()) == pytest.approx(1.0, abs=1e-5)
    loss = model.loss(model.net, cond_n, model.normalized_target(cond, force))
    loss.backward()
    assert torch.isfinite(loss)
    mean, _ = model.predict_forces(*(cond[..., i:i + 6].numpy() for i in (0, 6, 12, 18)))
    assert mean.shape == (6, 12, 6) and np.isfinite(mean).all()
    no_stiffness = np.zeros((12, 6), np.float32)
    with pytest.raises(ModelInputError, match="K must be positive, got min 0"):
        model.predict_forces(*(cond[0, :, i:i + 6].numpy() for i in (0, 6, 12)), no_stiffness)
    with pytest.raises(ModelInputError, match="cond_encoding"):
        cls(net=dict(TINY_NET), cond_encoding="onehot")


def test_task_loss_over_samples_is_the_rms_of_the_samples_task_losses() -> None:
    """From the samples' mean and population std alone it equals the RMS over the samples of their L_task;
    with no spread it is L_task of the mean."""
    from dcm.control import task_loss, task_loss_over_samples

    rng = np.random.default_rng(0)
    samples, demo = rng.normal(size=(5, 3, 12, 6)), rng.normal(size=(3, 12, 6))
    per_sample = task_loss(samples, demo[None])
    over = task_loss_over_samples(samples.mean(0), samples.std(0), demo)
    np.testing.assert_allclose(over, np.sqrt((per_sample ** 2).mean(0)), rtol=1e-12)
    assert np.all(over > task_loss(samples.mean(0), demo))
    np.testing.assert_allclose(task_loss_over_samples(samples[0], np.zeros_like(demo), demo), per_sample[0])


def test_task_loss_option_counts_the_spread_of_a_dcms_samples() -> None:
    """``task_loss=over_samples`` ranks by the expected loss: a DCM whose samples spread by +-1 N around F_demo
    predicts L_task = 1 N instead of the 0 N of their mean; a bad value is named."""
    gen = torch.Generator().manual_seed(3)
    cond = _positive_stiffness_cond(gen)
    model = DCM(net=dict(TINY_NET), ema_decay=0.0, target="residual")
    model.fit_normalizers(cond, cond[..., 6:12] + torch.randn(6, 12, 6, generator=gen))
    spread = torch.tensor([1.0, -1.0]).view(2, 1, 1, 1)

    def plus_minus_one(c, k=1, g=None):  # residual samples F_demo +- 1 N, in normalised units
        return model.target_norm.normalize(spread.expand(2, *c.shape[:2], 6).clone())

    model.sample_normalized = plus_minus_one  # type: ignore[method-assign]
    inputs = [cond[..., s:s + 6].numpy() for s in (0, 6, 12, 18)]
    from dcm.models.predict import predict_task_loss

    np.testing.assert_allclose(predict_task_loss(model, *inputs, n_samples=2), 0.0, atol=1e-5)
    model.set_task_loss("over_samples")
    np.testing.assert_allclose(predict_task_loss(model, *inputs, n_samples=2), 1.0, atol=1e-4)
    # the validation metrics (and dcm.evaluate) rank with the same L_task
    from dcm.data.datamodule import TrajectoryDataset
    from dcm.models.callbacks import evaluate_model

    data = TrajectoryDataset(cond.numpy(), cond[..., 6:12].numpy(), [f"t{i}" for i in range(6)], np.zeros(6))
    metrics, arrays = evaluate_model(model, data, n_samples=2, skills=np.repeat([0, 1], 3))
    np.testing.assert_allclose(arrays["L_task_pred"], 1.0, atol=1e-4)
    from dcm.models.callbacks import metric_names

    assert sorted(metrics) == metric_names()  # what train.py checks checkpoint.monitor against
    Baseline(net=dict(TINY_NET)).set_task_loss("over_samples")  # accepted: with no spread both are the same
    with pytest.raises(ModelInputError, match="task_loss must be one of"):
        model.set_task_loss("median")
    with pytest.raises(ModelInputError, match="task_loss must be one of"):
        DCM(net=dict(TINY_NET), task_loss="median")


def test_top_step_fraction_puts_that_share_of_the_batch_at_pure_noise() -> None:
    """0 keeps the uniform draw as it was (same generator, same steps); 0.5 sets half the rows to T-1 and
    leaves the others' uniform draws as they were; the DCM's training loss sees those steps."""
    sched = diffusion.make_scheduler("ddpm", "linear", 30, "sample")
    uniform = diffusion.sample_timesteps(sched, 32, "cpu", torch.Generator().manual_seed(3))
    same = diffusion.sample_timesteps(sched, 32, "cpu", torch.Generator().manual_seed(3), top_step_fraction=0.0)
    half = diffusion.sample_timesteps(sched, 32, "cpu", torch.Generator().manual_seed(3), top_step_fraction=0.5)
    assert torch.equal(uniform, same)
    assert (uniform == 29).float().mean() < 0.5
    assert torch.equal(half[:16], torch.full((16,), 29)) and torch.equal(half[16:], uniform[16:])
    assert torch.equal(diffusion.sample_timesteps(sched, 5, "cpu", None, top_step_fraction=1.0), torch.full((5,), 29))

    seen = []
    model = DCM(net=dict(TINY_NET), top_step_fraction=0.25, ema_decay=0.0)
    gen = torch.Generator().manual_seed(0)
    cond = _positive_stiffness_cond(gen, n=8)
    model.fit_normalizers(cond, cond[..., 6:12])
    net = model.net

    def spy(c: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        seen.append(t.clone())
        return net(c, x, t)

    loss = model.loss(spy, model.normalized_cond(cond), model.normalized_target(cond, cond[..., 6:12]), gen)
    assert torch.isfinite(loss) and torch.equal(seen[0][:2], torch.tensor([29, 29]))


def test_bad_top_step_fraction_is_named() -> None:
    with pytest.raises(ModelInputError, match="top_step_fraction must be in \\[0, 1\\], got 1.5"):
        DCM(net=dict(TINY_NET), top_step_fraction=1.5)


def test_bfloat16_predictions_stay_close_to_float32_and_auto_follows_the_hardware() -> None:
    from dcm.models.force_model import native_bfloat16

    gen = torch.Generator().manual_seed(4)
    cond, force = _positive_stiffness_cond(gen), torch.randn(6, 12, 6, generator=gen)
    torch.manual_seed(0)  # the weights: the same net whichever tests ran before
    model = DCM(net=dict(TINY_NET), diffusion_steps=10, input_scaling="signal", sampler="ddim", sampling_steps=2)
    model.fit_normalizers(cond, force)
    model.eval()
    inputs = [cond[..., i:i + 6].numpy() for i in range(0, 24, 6)]
    predictions = {}
    for precision in ("float32", "bfloat16"):
        assert model.set_precision(precision) == precision
        predictions[precision] = model.predict_forces(*inputs, n_samples=2, generator=torch.Generator().manual_seed(0))
    # bfloat16 rounds the forces, so the mean's and the spread's errors both scale with the force, not the spread
    force_scale_N = np.abs(predictions["float32"][0]).max()
    for full, low in zip(predictions["float32"], predictions["bfloat16"]):
        assert low.dtype == np.float32
        np.testing.assert_allclose(low, full, atol=0.05 * force_scale_N)
    assert model.set_precision("auto") == ("bfloat16" if native_bfloat16("cpu") else "float32")
    with pytest.raises(ModelInputError, match="precision"):
        model.set_precision("float16")
