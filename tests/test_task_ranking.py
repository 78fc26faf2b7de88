"""The within-skill L_task training term: the loss on hand-made cases, skill-grouped batches, shared draws,
and both models training with it."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch

from dcm.data.datamodule import DataModuleError, DCMDataModule, SkillGroupBatchSampler
from dcm.models import diffusion
from dcm.models.baseline import Baseline
from dcm.models.configuration import ModelInputError
from dcm.models.dcm import DCM
from dcm.models.task_ranking import centered_by_group, within_skill_task_error

TINY_NET = {"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2}


def test_centering_and_the_error_ignore_each_skills_level() -> None:
    groups = torch.tensor([7, 7, 3, 3, 3])
    values = torch.tensor([1.0, 3.0, 10.0, 11.0, 12.0])
    torch.testing.assert_close(centered_by_group(values, groups), torch.tensor([-1.0, 1.0, -1.0, 0.0, 1.0]))
    # right up to a per-skill offset: no error, although every value is off
    assert float(within_skill_task_error(values + torch.tensor([5.0, 5.0, -2.0, -2.0, -2.0]), values, groups)) == 0.0
    # one skill's order reversed: its deviations (-1, 1) become (1, -1), an error of 2 on 2 of 5 trials
    swapped = torch.tensor([3.0, 1.0, 10.0, 11.0, 12.0])
    assert float(within_skill_task_error(swapped, values, groups)) == pytest.approx(2 * 2.0**2 / 5)


def test_trials_alone_in_their_skill_do_not_count_but_keep_the_graph() -> None:
    pred = torch.tensor([1.0, 2.0, 4.0], requires_grad=True)
    alone = within_skill_task_error(pred, torch.tensor([0.0, 9.0, 0.0]), torch.tensor([1, 2, 3]))
    assert alone.requires_grad and float(alone.detach()) == 0.0
    loss = within_skill_task_error(pred, torch.tensor([0.0, 9.0, 0.0]), torch.tensor([1, 1, 3]))
    loss.backward()  # only the two trials of skill 1 get a gradient
    assert pred.grad is not None and pred.grad[2] == 0.0 and pred.grad[0] != 0.0


def test_skill_group_batches_deal_every_trial_once_in_groups_of_one_skill() -> None:
    skills = torch.tensor([0] * 6 + [1] * 5 + [2] * 4 + [-1, -1])
    sampler = SkillGroupBatchSampler(skills, batch_size=6, group_size=3, generator=torch.Generator().manual_seed(0))
    batches = list(sampler)
    assert len(batches) == len(sampler) == 4  # groups: 2 + 2 + 2 (3 + 1) + 2 singletons = 8, two per batch
    assert sorted(i for b in batches for i in b) == list(range(len(skills)))
    for batch in batches:
        labels = skills[batch].tolist()
        known = [s for s in labels if s >= 0]
        assert len(set(known)) + labels.count(-1) <= 2, labels  # at most two groups per batch
        assert all(known[i] == known[i + 1] or known[i + 1] not in known[:i + 1] for i in range(len(known) - 1))
    again = list(SkillGroupBatchSampler(skills, 6, 3, torch.Generator().manual_seed(0)))
    assert again == batches  # seeded
    assert list(sampler) != batches  # the next epoch is dealt anew
    with pytest.raises(DataModuleError, match="skill_group"):
        SkillGroupBatchSampler(skills, batch_size=4, group_size=5, generator=torch.Generator())


def test_datamodule_groups_the_training_batches(tiny_dataset_path: Path) -> None:
    dm = DCMDataModule(tiny_dataset_path, batch_size=6, skill_group=3)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    skills = batch["skill"].tolist()
    assert len(skills) == 6 and skills[0] == skills[1] == skills[2] >= 0 and skills[3] == skills[4] == skills[5]
    with pytest.raises(DataModuleError, match="skill_group"):
        DCMDataModule(tiny_dataset_path, batch_size=4, skill_group=5)


def test_grouped_rows_share_their_step_and_noise() -> None:
    sched = diffusion.make_scheduler("ddpm", "linear", 30, "sample")
    seen = {}

    def spy(cond, x, t):
        seen["x"], seen["t"] = x, t
        return x * 0.5

    x0 = torch.zeros(6, 8, 6)  # equal x0: rows of one group must get equal noisy inputs
    groups = torch.tensor([4, 4, 4, 9, 9, 9])
    output, target, estimate = diffusion.denoising_outputs(spy, torch.zeros(6, 8, 24), x0, sched,
                                                           torch.Generator().manual_seed(1), groups=groups)
    assert torch.equal(seen["t"][:3], seen["t"][:1].expand(3)) and torch.equal(seen["x"][0], seen["x"][2])
    assert not torch.equal(seen["x"][0], seen["x"][3])
    assert torch.equal(estimate, output) and torch.equal(target, x0)  # x0-prediction: the output is the estimate
    # without groups the draws are diffusion_loss's own
    gen_a, gen_b = torch.Generator().manual_seed(2), torch.Generator().manual_seed(2)
    out, tgt, _ = diffusion.denoising_outputs(spy, torch.zeros(6, 8, 24), x0 + 1, sched, gen_a)
    loss = diffusion.diffusion_loss(spy, torch.zeros(6, 8, 24), x0 + 1, sched, gen_b)
    torch.testing.assert_close(torch.nn.functional.mse_loss(out, tgt), loss)


@pytest.mark.parametrize("kind", diffusion.PREDICTION_TYPES)
def test_predicted_sample_inverts_the_training_target(kind: str) -> None:
    sched = diffusion.make_scheduler("ddpm", "linear", 10, kind)
    gen = torch.Generator().manual_seed(0)
    x0, noise = torch.rand(3, 5, 6, generator=gen), torch.randn(3, 5, 6, generator=gen)
    usable = [t for t in range(10) if float(sched.alphas_cumprod[t]) >= 0.05]  # epsilon divides by sqrt(ab)
    t = torch.tensor([usable[0], usable[len(usable) // 2], usable[-1]])
    x_t = diffusion.add_noise(sched, x0, noise, t)
    estimate = diffusion.predicted_sample(sched, x_t, diffusion.training_target(sched, x0, noise, t), t)
    torch.testing.assert_close(estimate, x0, atol=1e-4, rtol=1e-4)


def test_bad_task_settings_are_named() -> None:
    with pytest.raises(ModelInputError, match="task_weight"):
        Baseline(net=dict(TINY_NET), task_weight=-1.0)
    with pytest.raises(ModelInputError, match="task_from_s"):
        DCM(net=dict(TINY_NET), task_from_s=float("nan"))


@pytest.mark.parametrize("cls", [DCM, Baseline])
def test_the_task_term_adds_to_the_loss_only_when_asked(cls: type, tiny_dataset_path: Path) -> None:
    dm = DCMDataModule(tiny_dataset_path, batch_size=6, skill_group=3)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    losses = {}
    for weight in (0.0, 100.0):
        L.seed_everything(0)
        model = cls(net=dict(TINY_NET), data_spec={"control_hz": dm.control_hz}, task_weight=weight,
                    task_from_s=0.5)
        model.fit_normalizers(*dm.train_arrays())
        losses[weight] = float(model._batch_loss(model.net, batch, torch.Generator().manual_seed(0)))
        losses[f"force only {weight}"] = float(model.loss(
            model.net, model.normalized_cond(batch["cond"]), model.normalized_target(batch["cond"], batch["target"]),
            torch.Generator().manual_seed(0)))
    assert losses[0.0] == pytest.approx(losses["force only 0.0"], rel=1e-6)  # weight 0: the force loss as before
    assert losses[100.0] > losses[0.0]  # an untrained net ranks nothing: the term is positive
