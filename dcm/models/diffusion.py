"""DDPM machinery for the contact model: noise schedules, diffusers schedulers, training noise, sampling.

Conventions
- Timesteps are 0-based, t in {0..T-1} (diffusers' indexing; the paper's step i = t + 1). The score net
  receives exactly these integers as `step`.
- Prediction types (diffusers' names): "epsilon", the net predicts the noise that `add_noise` injected;
  "sample", it predicts x0 itself; "v_prediction", v = sqrt(ab) noise - sqrt(1 - ab) x0. The loss compares
  the net's output with that target, and the scheduler turns it into the next sample.
- Every schedule is rescaled with T so the forward process ends near pure noise (alpha_bar_T <= ~1e-3)
  for every T in 1..100. The textbook linear endpoints (1e-4, 0.02) were tuned for T=1000: at T=30 they
  leave alpha_bar_T ~ 0.74, so the sampler would start from a distribution the net never saw.
- Schedulers are diffusers' DDPMScheduler / DDIMScheduler / DPMSolverMultistepScheduler (first order, which is
  DDIM, for `ddim_even`) fed with our own `trained_betas`, with every default that changes results set
  explicitly in `make_scheduler`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
import torch
from diffusers import DDIMScheduler, DDPMScheduler, DPMSolverMultistepScheduler
from diffusers.utils.torch_utils import randn_tensor

__all__ = [
    "SAMPLERS",
    "SCHEDULES",
    "PREDICTION_TYPES",
    "MAX_BETA",
    "ScheduleError",
    "NoiseSchedule",
    "make_betas",
    "alphas_cumprod",
    "make_scheduler",
    "add_noise",
    "sample_timesteps",
    "check_inference_steps",
    "diffusion_loss",
    "denoising_outputs",
    "predicted_sample",
    "training_target",
    "sample",
    "sample_many",
    "shareable_steps",
    "SHARED_NOISE_STD",
    "INPUT_SCALINGS",
    "scale_noisy_input",
]

# ddpm: ancestral; ddim: deterministic, n steps T-1, T-1-T/n, ... (ends at T/n - 1); ddim_even: deterministic, n
# steps spread evenly from T-1 to 0, so the last net call sees an almost clean force; one_step: a distilled
# student's (dcm.training.distill) single call at t = T-1 on unit-variance noise, DDIM's one step for its net
SAMPLERS = ("ddpm", "ddim", "ddim_even", "one_step")
SCHEDULES = ("linear", "cosine", "sigmoid", "scaled_linear")
PREDICTION_TYPES = ("epsilon", "sample", "v_prediction")
INPUT_SCALINGS = ("unit", "signal")
_SCHEDULE_ALIASES = {"squaredcos_cap_v2": "cosine", "squared_cosine": "cosine", "squaredcos": "cosine"}
MAX_BETA = 0.999  # the cap diffusers and Nichol & Dhariwal use; keeps 1/sqrt(alpha_t) finite
MAX_T = 100
# Noise std the net may see at a step that k samples share (shareable_steps): at the tuner's three DDIM steps of
# T = 30, the first two (0.001, 0.071) and not the last (0.46).
SHARED_NOISE_STD = 0.1

ScoreNet = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


class EvenDDIMScheduler(DPMSolverMultistepScheduler):
    """DDIM over n timesteps spread evenly from T-1 down to 0 (``np.linspace(T-1, 0, n)``, rounded).

    Why: diffusers' DDIMScheduler jumps by T // n, so a short chain's last net call is at t = T/n - 1 (t = 9 of
    30 at three steps), where the net still sees much noise; a chain ending at t = 0 gives the x0 estimate of an
    almost clean input (measured in docs/tune.md). DDIMScheduler cannot take such a chain, but first-order
    DPM-Solver++ is the DDIM update, and it takes explicit timesteps. It lacks DDIM's static clip of the x0
    estimate, which `convert_model_output` adds here.
    """

    clip_range: float | None = None

    def set_timesteps(self, num_inference_steps: int | None = None, device: str | torch.device | None = None,
                      **_: object) -> None:
        T = self.config.num_train_timesteps
        chain = np.linspace(T - 1, 0, int(num_inference_steps)).round().astype(np.int64)  # n <= T: no repeats
        super().set_timesteps(device=device, timesteps=chain.tolist())

    def convert_model_output(self, model_output: torch.Tensor, *args: object, **kwargs: object) -> torch.Tensor:
        x0 = super().convert_model_output(model_output, *args, **kwargs)
        return x0 if self.clip_range is None else x0.clamp(-self.clip_range, self.clip_range)


Scheduler = DDPMScheduler | DDIMScheduler | EvenDDIMScheduler


class ScheduleError(ValueError):
    """Bad schedule name, number of steps or sampler settings."""


def _canonical(schedule: str) -> str:
    name = _SCHEDULE_ALIASES.get(schedule.lower(), schedule.lower())
    if name not in SCHEDULES:
        raise ScheduleError(f"unknown noise schedule {schedule!r}; choose one of {SCHEDULES}")
    return name


def _check_T(T: int) -> int:
    if isinstance(T, bool) or int(T) != T or not 1 <= int(T) <= MAX_T:
        raise ScheduleError(f"number of diffusion steps T must be an integer in 1..{MAX_T}, got {T!r}")
    return int(T)


def _betas_from_alpha_bar(alpha_bar: Callable[[np.ndarray], np.ndarray], T: int) -> np.ndarray:
    """Discretise a continuous alpha_bar(s), s in [0,1], into T betas (capped at MAX_BETA)."""
    s = np.arange(T + 1, dtype=np.float64) / T
    ab = alpha_bar(s)
    betas = 1.0 - ab[1:] / ab[:-1]
    return np.clip(betas, 0.0, MAX_BETA)


def make_betas(
    schedule: str,
    T: int,
    *,
    beta_start: float = 1e-4,
    beta_end: float = 0.02,
    reference_steps: int = 1000,
) -> torch.Tensor:
    """Noise variances beta_1..beta_T (float64, shape (T,)) for `schedule` at `T` steps.

    - linear (the paper's, Ho et al. 2020): endpoints beta_start..beta_end defined for `reference_steps`
      steps and multiplied by reference_steps / T (the rescaling of Nichol & Dhariwal 2021), which keeps
      sum(beta) ~ 10 and so alpha_bar_T ~ e^-10 for any T; capped at MAX_BETA (T=1 -> beta = 0.999).
    - scaled_linear: linear in sqrt(beta) between the same endpoints, same rescaling (gentler start).
    - cosine: squared-cosine alpha_bar (Nichol & Dhariwal 2021); T-independent by construction.
    - sigmoid: alpha_bar follows a shifted sigmoid over [-3, 3] (Chen 2023, "On the importance of noise
      scheduling"); spends more steps at mid noise levels than cosine.
    """
    name, T = _canonical(schedule), _check_T(T)
    if name in ("linear", "scaled_linear"):
        if not 0.0 < beta_start < beta_end < 1.0:
            raise ScheduleError(f"need 0 < beta_start < beta_end < 1, got {beta_start=}, {beta_end=}")
        scale = reference_steps / T
        if T == 1:
            betas = np.array([beta_end * scale])
        elif name == "linear":
            betas = scale * np.linspace(beta_start, beta_end, T)
        else:
            betas = scale * np.linspace(math.sqrt(beta_start), math.sqrt(beta_end), T) ** 2
        betas = np.clip(betas, 0.0, MAX_BETA)
    elif name == "cosine":
        s_off = 0.008
        betas = _betas_from_alpha_bar(lambda s: np.cos((s + s_off) / (1 + s_off) * math.pi / 2) ** 2, T)
    else:  # sigmoid
        lo, hi, tau = -3.0, 3.0, 1.0
        sig = lambda z: 1.0 / (1.0 + np.exp(-z))  # noqa: E731
        v_lo, v_hi = sig(lo / tau), sig(hi / tau)
        betas = _betas_from_alpha_bar(lambda s: (v_hi - sig((s * (hi - lo) + lo) / tau)) / (v_hi - v_lo), T)
    return torch.as_tensor(betas, dtype=torch.float64)


def alphas_cumprod(betas: torch.Tensor) -> torch.Tensor:
    """alpha_bar_t = prod_{s<=t} (1 - beta_s); alpha_bar[-1] is how much signal survives at t = T."""
    return torch.cumprod(1.0 - betas, dim=0)


@dataclass(frozen=True)
class NoiseSchedule:
    """A named schedule plus the sampler settings that go with it; the `_target_` of conf/schedule/*.yaml.

    `clip_sample_range=r` clips the x0 estimate to [-r, r] in normalised units. Forces are normalised to
    [-1, 1], and with alpha_bar_T near 0 the first steps divide the net's error by sqrt(alpha_bar_t), so an
    unclipped chain amplifies small errors into forces far outside the data. The default 1.5 leaves room
    for forces beyond the training min/max (diffusers' own default, 1.0, would saturate them); None
    disables clipping.
    `variance_type`: "fixed_small" = posterior variance beta~_t (Ho et al.'s better-NLL choice and
    diffusers' default); "fixed_large" = beta_t, the paper's Eq. for p(F^(i-1) | F^(i)).
    """

    name: str = "linear"
    beta_start: float = 1e-4
    beta_end: float = 0.02
    reference_steps: int = 1000
    clip_sample_range: float | None = 1.5
    variance_type: Literal["fixed_small", "fixed_large"] = "fixed_small"

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _canonical(self.name))
        if self.clip_sample_range is not None and self.clip_sample_range <= 0:
            raise ScheduleError(f"clip_sample_range must be > 0 or None, got {self.clip_sample_range}")
        if self.variance_type not in ("fixed_small", "fixed_large"):
            raise ScheduleError(f"variance_type must be 'fixed_small' or 'fixed_large', got {self.variance_type!r}")

    def betas(self, T: int) -> torch.Tensor:
        return make_betas(
            self.name, T, beta_start=self.beta_start, beta_end=self.beta_end, reference_steps=self.reference_steps
        )

    def scheduler(self, kind: Literal["ddpm", "ddim", "ddim_even"], T: int) -> Scheduler:
        return make_scheduler(kind, self, T)

    def to_dict(self) -> dict:
        return asdict(self)


def _as_schedule(schedule: str | NoiseSchedule | dict) -> NoiseSchedule:
    if isinstance(schedule, NoiseSchedule):
        return schedule
    if isinstance(schedule, str):
        return NoiseSchedule(name=schedule)
    if isinstance(schedule, dict) or hasattr(schedule, "items"):  # plain dict or an OmegaConf DictConfig
        return NoiseSchedule(**{k: v for k, v in dict(schedule).items() if k != "_target_"})
    raise ScheduleError(f"schedule must be a name, NoiseSchedule or dict, got {type(schedule).__name__}")


def make_scheduler(
    kind: Literal["ddpm", "ddim", "ddim_even"], schedule: str | NoiseSchedule | dict = "linear", T: int = 30,
    prediction_type: str = "epsilon",
) -> Scheduler:
    """A diffusers scheduler over our betas, with every default that matters pinned.

    - `trained_betas` carries the T-rescaled betas (`beta_schedule` is then ignored by diffusers).
    - `prediction_type` as given, `thresholding=False`, clipping per `NoiseSchedule.clip_sample_range`.
    - `timestep_spacing="trailing"` + `steps_offset=0`: a shortened chain starts at t = T-1 (pure noise)
      and ends at t = -1; "leading" would start part-way down the chain.
    - DDIM: `set_alpha_to_one=True` so its last step returns the x0 estimate;
      `rescale_betas_zero_snr=False` (our alpha_bar_T is already ~0, and exact zero breaks epsilon-prediction).
    - one_step: DDIM, run for one step from t = T-1 (the x0 output, clipped, is the sample).
    - ddim_even (:class:`EvenDDIMScheduler`): first-order DPM-Solver++ in data prediction, whose last step
      likewise returns the x0 estimate (`final_sigmas_type="zero"`).
    """
    sched, T = _as_schedule(schedule), _check_T(T)
    if prediction_type not in PREDICTION_TYPES:
        raise ScheduleError(f"prediction_type must be one of {PREDICTION_TYPES}, got {prediction_type!r}")
    betas = sched.betas(T).numpy()
    clip = sched.clip_sample_range is not None
    common = dict(
        num_train_timesteps=T,
        trained_betas=betas,
        beta_schedule="linear",
        prediction_type=prediction_type,
        clip_sample=clip,
        clip_sample_range=float(sched.clip_sample_range) if clip else 1.0,
        thresholding=False,
        timestep_spacing="trailing",
        steps_offset=0,
    )
    kind_l = kind.lower()
    if kind_l == "ddpm":
        return DDPMScheduler(variance_type=sched.variance_type, **common)
    if kind_l in ("ddim", "one_step"):
        return DDIMScheduler(set_alpha_to_one=True, rescale_betas_zero_snr=False, **common)
    if kind_l == "ddim_even":
        even = EvenDDIMScheduler(
            num_train_timesteps=T, trained_betas=betas, prediction_type=prediction_type, thresholding=False,
            solver_order=1, algorithm_type="dpmsolver++", final_sigmas_type="zero", lower_order_final=True,
        )
        even.clip_range = common["clip_sample_range"] if clip else None
        return even
    raise ScheduleError(f"unknown sampler kind {kind!r}; choose one of {SAMPLERS}")


def _alpha_bar_at(scheduler: Scheduler, timesteps: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """alpha_bar_t per batch row, on `like`'s device and dtype, shaped to broadcast over (B, ...)."""
    ab = scheduler.alphas_cumprod.to(device=like.device, dtype=like.dtype)[timesteps.to(like.device).long()]
    return ab.reshape(-1, *([1] * (like.dim() - 1)))


def add_noise(scheduler: Scheduler, x0: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
    """Forward process q(x_t | x0) = sqrt(ab_t) x0 + sqrt(1 - ab_t) noise, for x0 of shape (B, ...)."""
    ab = _alpha_bar_at(scheduler, timesteps, x0)
    return ab.sqrt() * x0 + (1.0 - ab).sqrt() * noise


def sample_timesteps(scheduler: Scheduler, batch: int, device: torch.device | str, generator=None,
                     top_step_fraction: float = 0.0) -> torch.Tensor:
    """Training timesteps in 0..T-1, shape (batch,), long: uniform, except that the first
    round(top_step_fraction * batch) rows are set to the pure-noise step T-1 (no extra random draw, so
    0 gives the uniform draw unchanged; the loader has already shuffled the rows)."""
    T = scheduler.config.num_train_timesteps
    gen_device = device if generator is None else generator.device
    t = torch.randint(0, T, (batch,), generator=generator, device=gen_device).to(device)
    t[: round(top_step_fraction * batch)] = T - 1
    return t


def diffusion_loss(
    net: ScoreNet, cond: torch.Tensor, x0: torch.Tensor, scheduler: Scheduler, generator=None, reduction: str = "mean",
    top_step_fraction: float = 0.0,
) -> torch.Tensor:
    """MSE between the net's output and its target (noise, x0 or v, per the scheduler's prediction type)
    at a random t (``sample_timesteps``)."""
    output, target, _ = denoising_outputs(net, cond, x0, scheduler, generator, top_step_fraction)
    return torch.nn.functional.mse_loss(output, target, reduction=reduction)


def denoising_outputs(
    net: ScoreNet, cond: torch.Tensor, x0: torch.Tensor, scheduler: Scheduler, generator=None,
    top_step_fraction: float = 0.0, groups: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The net's output, its training target and the x0 estimate the output implies, at a random t.

    ``groups`` (B,) integer labels: rows with the same label share their step t and their noise, so the
    differences between their x0 estimates come from their conditions and x0 alone (a loss that compares
    trials of one skill needs that). None draws both per row, exactly as ``diffusion_loss`` does.
    """
    if groups is None:
        t = sample_timesteps(scheduler, x0.shape[0], x0.device, generator, top_step_fraction)
        noise = randn_tensor(x0.shape, generator=generator, device=x0.device, dtype=x0.dtype)
    else:
        _, member = torch.unique(groups, return_inverse=True)
        n_groups = int(member.max()) + 1
        t = sample_timesteps(scheduler, n_groups, x0.device, generator, top_step_fraction)[member]
        noise = randn_tensor((n_groups, *x0.shape[1:]), generator=generator, device=x0.device, dtype=x0.dtype)[member]
    x_t = add_noise(scheduler, x0, noise, t)
    output = net(cond, x_t, t)
    return output, training_target(scheduler, x0, noise, t), predicted_sample(scheduler, x_t, output, t)


def predicted_sample(scheduler: Scheduler, x_t: torch.Tensor, output: torch.Tensor, timesteps: torch.Tensor
                     ) -> torch.Tensor:
    """The x0 estimate a net output at step t implies, per the scheduler's prediction type (unclipped)."""
    kind = scheduler.config.prediction_type
    if kind == "sample":
        return output
    ab = _alpha_bar_at(scheduler, timesteps, x_t)
    if kind == "epsilon":
        return (x_t - (1.0 - ab).sqrt() * output) / ab.sqrt()
    return ab.sqrt() * x_t - (1.0 - ab).sqrt() * output  # v_prediction


def training_target(scheduler: Scheduler, x0: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
    """What the net must output for x_t = add_noise(x0, noise, t), per the scheduler's prediction type."""
    kind = scheduler.config.prediction_type
    if kind == "epsilon":
        return noise
    if kind == "sample":
        return x0
    ab = _alpha_bar_at(scheduler, timesteps, x0)
    return ab.sqrt() * noise - (1.0 - ab).sqrt() * x0  # v_prediction


def check_inference_steps(scheduler: Scheduler, num_inference_steps: int | None) -> int:
    """Validate a sampler step count against `scheduler` (call it at build time to fail early); returns it."""
    T = scheduler.config.num_train_timesteps
    n = T if num_inference_steps is None else int(num_inference_steps)
    if not 1 <= n <= T:
        raise ScheduleError(f"num_inference_steps must be in 1..T={T}, got {num_inference_steps}")
    if isinstance(scheduler, DDIMScheduler) and T % n:
        # diffusers' DDIM jumps by T // n between steps; with a remainder the chain's noise levels drift
        # away from the timesteps given to the net, so only exact divisors are allowed.
        divisors = [d for d in range(1, T + 1) if T % d == 0]
        raise ScheduleError(f"DDIM needs num_inference_steps dividing T={T}; got {n}, choose one of {divisors}")
    return n



@torch.no_grad()
def sample(
    net: ScoreNet,
    cond: torch.Tensor,
    shape: tuple[int, ...] | torch.Size,
    scheduler: Scheduler,
    num_inference_steps: int | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Draw x0 ~ p_theta(x0 | cond) by reverse diffusion; returns a tensor of `shape` (B, H, out_dim).

    DDPM: ancestral sampling over all T steps (default) or a trailing subset. DDIM (eta = 0,
    deterministic given the start noise): fewer steps, `num_inference_steps` must divide T; ddim_even: any
    number of steps, the last at t = 0.
    Runs on `cond`'s device and dtype; put the net in eval mode yourself. The scheduler is stateful
    (`set_timesteps`), so give each concurrent sampler its own.
    """
    n = check_inference_steps(scheduler, num_inference_steps)
    scheduler.set_timesteps(n)  # timesteps stay on the CPU: diffusers indexes its CPU tables with them
    x = randn_tensor(tuple(shape), generator=generator, device=cond.device, dtype=cond.dtype)
    batch = torch.ones(shape[0], dtype=torch.long, device=cond.device)
    for t in scheduler.timesteps:
        output = net(cond, x, batch * t)
        x = scheduler.step(output, t, x, generator=generator).prev_sample
    return x


@torch.no_grad()
def sample_many(
    net: ScoreNet,
    cond: torch.Tensor,
    out_dim: int,
    scheduler: Scheduler,
    k: int,
    num_inference_steps: int | None = None,
    generator: torch.Generator | None = None,
    max_batch: int | None = None,
    shared_steps: int = 0,
) -> torch.Tensor:
    """k independent samples per condition, batched: returns (k, B, H, out_dim).

    The k copies run as one batch of k*B (chunked by `max_batch` rows to bound memory), so averaging
    over samples costs one sampling pass. Mean over dim 0 is the prediction, std its uncertainty.

    ``shared_steps`` > 0: the first that many steps call the net once per condition, on sample 0's chain, and
    every sample takes its own scheduler step from that output. Where the net sees the noise scaled almost to
    nothing (:func:`shareable_steps`), all k outputs of those steps are about the same, so k samples then cost
    ``shared_steps + k * (steps - shared_steps)`` rows of net calls instead of ``k * steps``. Sample 0 is the
    unshared chain (up to the rounding of another batch size), a k = 1 prediction exactly so; the start noise
    is drawn as for ``max_batch=None``.
    """
    if k < 1:
        raise ScheduleError(f"k must be >= 1, got {k}")
    B, H = cond.shape[:2]
    big = cond.repeat(k, 1, 1)  # sample j of item b sits at row j*B + b
    chunk = big.shape[0] if max_batch is None else max(1, int(max_batch))
    if shared_steps <= 0 or k == 1:
        outs = [sample(net, c, (c.shape[0], H, out_dim), scheduler, num_inference_steps, generator)
                for c in big.split(chunk)]
        return torch.cat(outs).reshape(k, B, H, out_dim)
    n = check_inference_steps(scheduler, num_inference_steps)
    if shared_steps >= n:
        raise ScheduleError(f"shared_steps must be below the {n} sampling steps (the samples branch before the "
                            f"last), got {shared_steps}")
    scheduler.set_timesteps(n)
    x = randn_tensor((k * B, H, out_dim), generator=generator, device=cond.device, dtype=cond.dtype)
    ones = torch.ones(k * B, dtype=torch.long, device=cond.device)
    for i, t in enumerate(scheduler.timesteps):
        if i < shared_steps:
            output = net(cond, x[:B], ones[:B] * t).repeat(k, 1, 1)
        else:
            output = torch.cat([net(c, x_c, ones[: len(c)] * t) for c, x_c in zip(big.split(chunk), x.split(chunk))])
        x = scheduler.step(output, t, x, generator=generator).prev_sample
    return x.reshape(k, B, H, out_dim)


def shareable_steps(scheduler: Scheduler, num_inference_steps: int | None, scaling: str,
                    max_noise: float = SHARED_NOISE_STD) -> int:
    """How many leading sampling steps k samples can share (:func:`sample_many`'s ``shared_steps``): those at
    which a net with ``signal`` input scaling sees noise of std sqrt(alpha_bar_t (1 - alpha_bar_t)) <=
    ``max_noise``, and never the last step (the samples' spread enters there at the latest). A net with
    ``unit`` scaling sees unit-variance noise at every step: none."""
    n = check_inference_steps(scheduler, num_inference_steps)
    if scaling != "signal":
        return 0
    scheduler.set_timesteps(n)
    ab = scheduler.alphas_cumprod[scheduler.timesteps.long()].double()
    seen = (ab * (1.0 - ab)).sqrt()
    shared = 0
    while shared < n - 1 and float(seen[shared]) <= max_noise:
        shared += 1
    return shared


def scale_noisy_input(net: ScoreNet, scheduler: Scheduler, scaling: str = "unit") -> ScoreNet:
    """The score net as the sampler and the loss call it, with the noisy force scaled per `scaling`.

    - "unit": x_t as it is (unit variance at every t; the paper's).
    - "signal": x_t * sqrt(alpha_bar_t). Near pure noise the net then sees about zeros, the input the
      one-pass baseline sees, instead of unit-variance noise it must learn to ignore; at low noise it sees
      about x_t. The net also receives t, so no information is lost (studies/record.md, "Contact models
      against the references").
    """
    if scaling not in INPUT_SCALINGS:
        raise ScheduleError(f"input scaling must be one of {INPUT_SCALINGS}, got {scaling!r}")
    if scaling == "unit":
        return net

    def scaled(cond: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return net(cond, x * _alpha_bar_at(scheduler, t, x).sqrt(), t)

    return scaled
