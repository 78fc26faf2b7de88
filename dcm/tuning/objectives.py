"""The two ways to score a batch of per-phase stiffness proposals for one skill.

``ModelObjective`` is robot-free: a predictor (force model, or the stiffness-only reference) predicts L_task
through :func:`dcm.models.predict.predict_task_loss`.
``SimulatorObjective`` is robot-based: every proposal is a simulator rollout (or the mean of several). Both
return (B, 2) arrays of (L_task [N], L_comp [kN/m]), with NaN rows for failed trials, so one optimisation loop
serves both.
Both are called as ``objective(proposals, first)``, ``first`` being the index of the batch's first trial.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from dcm.control import StiffnessSchedule, compliance_loss, frame_axes, frame_diagonal, schedule_from_phases
from dcm.control.objectives import PAPER, TaskObjective


@dataclass
class Skill:
    """A recorded demo plus how proposals become stiffness schedules and attractors for it."""

    x_demo: np.ndarray  # (H, 6) bowl frame
    force_demo: np.ndarray  # (H, 6) N, N·m
    boundaries: np.ndarray  # (P + 1,) phase boundaries in control steps
    rot_Nmprad: float
    task_from_step: int = 0  # L_task counts the force from this step on (tune.task_from_s)
    objective: TaskObjective = PAPER  # what a trial of this skill costs (conf/objective/)
    frame: str = "world"  # the frame the proposals' stiffness acts in (stiffness.frame)

    def __post_init__(self) -> None:  # the frame's axes (H, 3, 3) along the demo; None: bowl axes
        self.axes: np.ndarray | None = frame_axes(self.frame, self.x_demo, self.force_demo, "this skill's demo")

    def trial_task_loss(self, trial: Any) -> float:
        """A simulated trial's L_task over the scored window (inf where it failed)."""
        return self.objective.trial_task_loss(trial, self.x_demo, self.force_demo, self.task_from_step)

    def task_loss(self, force_obs: np.ndarray, x_obs: np.ndarray) -> float:
        """L_task of one observed trial (H, 6) of this skill, as :meth:`trial_task_loss` scores a rollout."""
        return float(self.objective.task_loss(force_obs, self.force_demo, x_obs, self.x_demo, self.task_from_step))

    def schedules(self, proposals: np.ndarray) -> np.ndarray:
        """(B, P, axes) per-phase stiffness in N/m -> (B, H, 6) schedules: diagonals along the frame's axes."""
        diagonal = frame_diagonal(proposals, self.frame)
        return np.stack([schedule_from_phases(p, self.boundaries, self.rot_Nmprad) for p in diagonal])

    def in_frame(self, stiffness: np.ndarray) -> StiffnessSchedule:
        """One schedule's diagonal (H, 6) as the schedule a controller runs, in this skill's frame."""
        return StiffnessSchedule(stiffness, self.axes)


# Rows (proposals × diffusion samples) per predictor call on a CPU; see ModelObjective.calls.
CPU_ROWS_PER_CALL = 64


# batch_seed's ``first_trial`` is the index of a search's first trial of the batch, or one of these offsets for the
# model's other predictions: they share one index space and do not collide, since every search stays below
# SEARCH_TRIALS_LIMIT trials, the offsets lie above it and apart from each other, and round r's search (r >= 2)
# starts at r * ROUND_BATCH.
SEARCH_TRIALS_LIMIT = 2**31
PLOT_BATCH = 2**31  # the figure's prediction of the best validated solution
OBSERVED_BATCH = 2**39  # the robot loop's re-prediction of observed trials that were never proposed
ROUND_BATCH = 2**40  # the robot loop's round searches


def round_batch(round_index: int, first_trial: int) -> int:
    """The ``first_trial`` of :func:`batch_seed` for trial ``first_trial`` of the robot loop's round
    ``round_index`` search (round 1 is the robot-free search itself, seeded by its own trial indices)."""
    if not 0 <= first_trial < SEARCH_TRIALS_LIMIT:
        raise ValueError(f"trial {first_trial} of a round's search is outside [0, {SEARCH_TRIALS_LIMIT})")
    return int(round_index) * ROUND_BATCH + int(first_trial)


def batch_seed(seed: int, first_trial: int) -> int:
    """The torch seed of the model samples of the batch that starts at trial ``first_trial`` of a run seeded
    ``seed``: a function of the two alone, so a resumed run draws the same noise for its later batches as an
    uninterrupted one (one running generator would not: a resumed run replays the logged batches unevaluated)."""
    state = np.random.SeedSequence([int(seed), 0x7E5E, int(first_trial)]).generate_state(2, dtype=np.uint32)
    return int(state[0]) << 32 | int(state[1])


class ModelObjective:
    """L_task predicted by any predictor :func:`dcm.models.predict.load_model` returns; L_comp is exact.

    A diffusion model's samples of each batch come from a ``torch.Generator`` seeded with
    :func:`batch_seed` ``(seed, first trial of the batch)``, so the same seed gives the same predictions.
    ``seconds_inputs`` / ``seconds_model`` accumulate the time spent building inputs (schedules, attractors)
    and in the predictor.
    """

    def __init__(self, model: Any, skill: Skill, simulator: Any, demo: Any, n_samples: int = 1, seed: int = 0):
        self.model = model
        self.skill = skill
        self.simulator = simulator  # computes a batch's attractors as its rollouts would (Simulator.attractor)
        self.demo = demo
        self.n_samples = n_samples
        self.seed = int(seed)
        self.seconds_inputs = 0.0
        self.seconds_model = 0.0

    def generator(self, first_trial: int) -> Any:
        """The seeded generator for the batch starting at ``first_trial`` (None for a predictor without torch:
        only force models, and a force model blended with a prior, have a device)."""
        if not hasattr(self.model, "device"):
            return None
        import torch

        return torch.Generator(device=self.model.device).manual_seed(batch_seed(self.seed, first_trial))

    def calls(self, batch: int) -> list[slice]:
        """How a batch of ``batch`` proposals is split into predictor calls: on a CPU, into calls of at most
        :data:`CPU_ROWS_PER_CALL` rows (proposals × samples), since a score net's activations for many rows at
        once outgrow the caches and every row costs more; elsewhere one call."""
        device = getattr(self.model, "device", None)
        if device is None or getattr(device, "type", str(device)) != "cpu":
            return [slice(0, batch)]
        step = max(1, CPU_ROWS_PER_CALL // max(1, int(self.n_samples or 1)))
        return [slice(i, min(i + step, batch)) for i in range(0, batch, step)]

    def inputs(self, proposals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Raw predictor inputs (x_demo, F_demo, x_attr, K), each (B, H, 6), for (B, P, axes) proposals."""
        stiffness = self.skill.schedules(proposals)
        x_attr = np.asarray(self.simulator.attractor(self.demo, stiffness, self.skill.axes))  # the whole batch
        batch = len(proposals)
        x_demo = np.repeat(self.skill.x_demo[None], batch, axis=0)
        force_demo = np.repeat(self.skill.force_demo[None], batch, axis=0)
        return x_demo, force_demo, x_attr, stiffness

    def predict(self, proposals: np.ndarray, first_trial: int = 0
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Schedules (B, H, 6), predicted mean force (B, H, 6) [N] and its spread; None for a predictor
        without forces (the stiffness-only reference). Seeded like the batch starting at ``first_trial``."""
        x_demo, force_demo, x_attr, stiffness = self.inputs(proposals)
        if not hasattr(self.model, "predict_forces"):
            return stiffness, None, None
        with _inference_mode():
            mean, std = self.model.predict_forces(x_demo, force_demo, x_attr, stiffness, n_samples=self.n_samples,
                                                  generator=self.generator(first_trial))
        return stiffness, np.asarray(mean), np.asarray(std)

    def __call__(self, proposals: np.ndarray, first_trial: int = 0) -> np.ndarray:
        from dcm.models.predict import predict_task_loss  # torch-heavy: only when a model is used

        t0 = time.perf_counter()
        inputs = self.inputs(proposals)
        t1 = time.perf_counter()
        generator = self.generator(first_trial)  # one stream for the batch, drawn call after call
        with _inference_mode():
            L_task = np.concatenate([
                predict_task_loss(self.model, *(a[part] for a in inputs), n_samples=self.n_samples,
                                  generator=generator, from_step=self.skill.task_from_step,
                                  objective=self.skill.objective)
                for part in self.calls(len(proposals))])
        t2 = time.perf_counter()
        stiffness = inputs[3]
        self.seconds_inputs += t1 - t0
        self.seconds_model += t2 - t1
        return np.stack([L_task, compliance_loss(stiffness)], axis=1)


class _inference_mode:
    """``torch.inference_mode()`` when torch is importable (it is whenever a force model is loaded)."""

    def __enter__(self) -> None:
        try:
            import torch
        except ImportError:  # pragma: no cover - the stiffness reference needs no torch
            self._ctx = None
            return
        self._ctx = torch.inference_mode()
        self._ctx.__enter__()

    def __exit__(self, *exc: Any) -> None:
        if self._ctx is not None:
            self._ctx.__exit__(*exc)


class SimulatorObjective:
    """Every proposal is a simulator rollout; failed rollouts score NaN and are kept with their reason.

    ``rollouts`` > 1 measures each proposal's expected L_task instead: the mean over that many rollouts, each
    with its own draw of the domain's per-rollout spread (``Simulator.rollout(repeat=1..rollouts)``, none of
    them the draw a search trial of the same schedule got); NaN if any of them fails. That is how a solution
    is judged where one rollout is one sample of a distribution (``domain=bowl_offset``).
    ``trials`` holds every rollout, proposal by proposal.
    """

    def __init__(self, simulator: Any, demo: Any, skill: Skill, rollouts: int = 1):
        self.simulator = simulator
        self.demo = demo
        self.skill = skill
        self.rollouts = int(rollouts)
        self.trials: list[Any] = []

    def __call__(self, proposals: np.ndarray, first_trial: int = 0) -> np.ndarray:
        scores = []
        repeats = [0] if self.rollouts == 1 else range(1, self.rollouts + 1)
        for stiffness in self.skill.schedules(proposals):
            trials = [self.simulator.rollout(self.demo, self.skill.in_frame(stiffness), repeat=r) for r in repeats]
            self.trials.extend(trials)
            failed = any(t.failed for t in trials)
            scores.append([np.nan, np.nan] if failed else
                          [np.mean([self.skill.trial_task_loss(t) for t in trials]), trials[0].L_comp])
        return np.asarray(scores, dtype=np.float64)
