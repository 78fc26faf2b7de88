"""Lightning DataModule over a dcm HDF5 dataset, held entirely in memory (datasets are small).

Batches are dicts of raw, un-normalised float32 tensors in physical units:

* ``cond``   (B, H, 24): per-step conditions ``x_demo(6) | F_demo(6) | x_attr(6) | K(6)`` —
  pose [m, rad] in the bowl frame, wrench [N, N·m], attractor pose [m, rad], stiffness diagonal [N/m, N·m/rad]
  (channel names: :func:`dcm.data.schema.cond_channel_names`);
* ``target`` (B, H, C): the observed contact wrench ``F_obs`` [N, N·m] and, for a model that predicts the pose
  (``target_fields=force_and_pose``), the realised translation ``x_obs - x_demo`` [m]
  (:class:`dcm.data.schema.TargetLayout`);
* ``skill``  (B,): the trial's ``demo_id`` (-1 where the file has none), the skill whose schedules the tuner ranks.

Normalisation to [-1, 1] lives in the model (its statistics come from :meth:`DCMDataModule.train_arrays`),
so that checkpoints carry it and fine-tuning keeps the pre-training statistics.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from dcm.data.schema import (
    CHANNELS,
    COND_FIELDS,
    FORCE_LAYOUT,
    DatasetMismatchError,
    LoadedDataset,
    TargetLayout,
    cond_channel_names,
    load_dataset,
    target_layout,
)

STAGES = ("pretrain", "finetune")


class DataModuleError(ValueError):
    """A DataModule argument is unusable (usage rate, stage, split ...)."""


def stack_conditions(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """Concatenate the condition fields of (N,H,6) arrays into (N,H,24) in the documented order."""
    return np.concatenate([np.asarray(arrays[f], dtype=np.float32) for f in COND_FIELDS], axis=-1)


def dataset_channels(dataset: LoadedDataset, target_fields: str = "force") -> tuple[list[str], list[str]]:
    """The condition/target channel names a dataset file declares (from its ``channels`` attribute), the target
    as a model of ``target_fields`` reads it."""
    declared = dataset.attrs.get("channels") or CHANNELS
    if not isinstance(declared, dict):
        raise DataModuleError(f"{dataset.path}: root attribute 'channels' is not a mapping: {declared!r}")
    cond = [f"{f}.{c}" for f in COND_FIELDS for c in declared.get(f, [])]
    return cond, target_layout(target_fields, declared).channel_names()


class TrajectoryDataset(Dataset):
    """(cond, target, skill) of whole trajectories, already stacked as tensors; ``layout`` says what the
    target's channels are."""

    def __init__(self, cond: np.ndarray, target: np.ndarray, names: list[str], L_task: np.ndarray,
                 skills: np.ndarray | None = None, layout: TargetLayout = FORCE_LAYOUT) -> None:
        self.cond = torch.as_tensor(cond, dtype=torch.float32)
        self.target = torch.as_tensor(target, dtype=torch.float32)
        if self.target.shape[-1] != layout.width:
            raise DataModuleError(f"targets have {self.target.shape[-1]} channels, the {layout.target_fields} "
                                  f"layout {layout.width}")
        self.layout = layout
        self.names = list(names)
        self.L_task = np.asarray(L_task, dtype=np.float64)
        self.skills = torch.as_tensor(np.full(len(self.names), -1) if skills is None else skills, dtype=torch.long)

    @classmethod
    def from_loaded(cls, dataset: LoadedDataset, index: np.ndarray | None = None,
                    layout: TargetLayout = FORCE_LAYOUT) -> TrajectoryDataset:
        """The trajectories (``index``: only those) with the target ``layout`` gives (default: F_obs)."""
        cond = stack_conditions(dataset.arrays)
        target = layout.from_arrays(dataset.arrays)
        names, L_task, skills = dataset.names, dataset.L_task, dataset.demo_ids
        if index is not None:
            cond, target, L_task, skills = cond[index], target[index], L_task[index], skills[index]
            names = [names[i] for i in index]
        return cls(cond, target, names, L_task, skills, layout)

    def __len__(self) -> int:
        return self.cond.shape[0]

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"cond": self.cond[i], "target": self.target[i], "skill": self.skills[i]}

    def subset(self, n: int | None) -> TrajectoryDataset:
        """The first ``n`` trajectories (all when ``n`` is None or larger): a fixed evaluation set."""
        if n is None or n >= len(self):
            return self
        return TrajectoryDataset(self.cond[:n].numpy(), self.target[:n].numpy(), self.names[:n], self.L_task[:n],
                                 self.skills[:n].numpy(), self.layout)


class SkillGroupBatchSampler(Sampler[list[int]]):
    """Training batches made of whole groups: ``group_size`` trials of one skill each.

    A loss that compares one skill's trials (the model's ``task_weight``) needs several of them in a batch;
    a plain shuffle of many skills seldom puts two of one skill in a batch. Every epoch shuffles each skill's
    trials, cuts them into groups (a skill's last group may be smaller; a trial without a skill, -1, is a group
    of its own), shuffles the groups and deals ``batch_size // group_size`` of them per batch. Every trial is
    seen once per epoch; the draws come from ``generator``.
    """

    def __init__(self, skills: torch.Tensor, batch_size: int, group_size: int, generator: torch.Generator) -> None:
        if not 1 <= int(group_size) <= int(batch_size):
            raise DataModuleError(f"skill_group must be in 1..batch_size={batch_size}, got {group_size}")
        skills = torch.as_tensor(skills, dtype=torch.long)
        known = skills[skills >= 0]
        self.by_skill = [torch.nonzero(skills == s).flatten() for s in torch.unique(known)]
        self.by_skill += [i.reshape(1) for i in torch.nonzero(skills < 0).flatten()]
        self.group_size = int(group_size)
        self.groups_per_batch = int(batch_size) // self.group_size
        self.generator = generator
        n_groups = sum(-(-len(idx) // self.group_size) for idx in self.by_skill)
        self.n_batches = -(-n_groups // self.groups_per_batch)

    def __len__(self) -> int:
        return self.n_batches

    def __iter__(self):
        groups: list[torch.Tensor] = []
        for idx in self.by_skill:
            groups.extend(idx[torch.randperm(len(idx), generator=self.generator)].split(self.group_size))
        order = torch.randperm(len(groups), generator=self.generator).tolist()
        for start in range(0, len(order), self.groups_per_batch):
            yield torch.cat([groups[g] for g in order[start:start + self.groups_per_batch]]).tolist()


def usage_index(n_total: int, usage_rate: float, seed: int) -> np.ndarray:
    """Sorted indices of the seeded fraction ``usage_rate`` of ``n_total`` training trajectories (at least one):
    the subset a run with this usage rate and seed trains on, so a reference can be fitted on the same one."""
    n_use = max(1, int(round(float(usage_rate) * n_total)))
    rng = np.random.default_rng(int(seed))
    return np.sort(rng.choice(n_total, size=n_use, replace=False))


class DCMDataModule(L.LightningDataModule):
    """Train/valid/test splits of one dataset file, taken from its masks.

    Args:
        path: the HDF5 file.
        stage: ``pretrain`` (simulated data) or ``finetune`` (realistic data or imported real logs); recorded
            for the run and checked by ``train.py``.
        usage_rate: seeded fraction 0 < r <= 1 of the training trajectories to use (at least one).
        seed: seed of the usage-rate subset.
        expect_control_hz: refuse a dataset recorded at another control rate (None accepts any).
        n_eval: trajectories of the valid/test split the metrics callback samples (None = all).
        skill_group: 0 shuffles the training trials one by one; g > 0 deals them in groups of g trials of one
            skill (:class:`SkillGroupBatchSampler`), which a model trained with ``task_weight`` > 0 needs.
            Single-device only: a distributed sampler does not split these batches.
        target_fields: the target the model learns (``force``: F_obs | ``force_and_pose``: F_obs and the
            translation x_obs - x_demo; :class:`dcm.data.schema.TargetLayout`).
    """

    def __init__(self, path: str | Path, stage: str = "pretrain", usage_rate: float = 1.0, seed: int = 0,
                 batch_size: int = 64, eval_batch_size: int = 256, num_workers: int = 0,
                 expect_control_hz: float | None = None, n_eval: int | None = 64, skill_group: int = 0,
                 target_fields: str = "force") -> None:
        super().__init__()
        if stage not in STAGES:
            raise DataModuleError(f"stage must be one of {STAGES}, got {stage!r}")
        usage_rate = float(usage_rate)
        if not 0.0 < usage_rate <= 1.0:
            raise DataModuleError(f"usage_rate must satisfy 0 < r <= 1, got {usage_rate}")
        if int(batch_size) < 1:
            raise DataModuleError(f"batch_size must be >= 1, got {batch_size}")
        if n_eval is not None and int(n_eval) < 1:
            raise DataModuleError(f"n_eval must be >= 1 or None, got {n_eval}")
        if not 0 <= int(skill_group) <= int(batch_size):
            raise DataModuleError(f"skill_group must be 0 (off) or in 1..batch_size={batch_size}, got {skill_group}")
        try:
            self.layout = target_layout(target_fields)
        except ValueError as err:
            raise DataModuleError(str(err)) from None
        self.path = Path(path)
        self.stage = stage
        self.usage_rate = usage_rate
        self.seed = int(seed)
        self.batch_size = int(batch_size)
        self.eval_batch_size = int(eval_batch_size)
        self.num_workers = int(num_workers)
        self.expect_control_hz = expect_control_hz
        self.n_eval = None if n_eval is None else int(n_eval)
        self.skill_group = int(skill_group)
        # plain types only, so checkpoints stay loadable with torch.load(weights_only=True)
        hparams = {"path": str(self.path), "stage": stage, "usage_rate": usage_rate, "seed": self.seed,
                   "batch_size": self.batch_size, "n_eval": self.n_eval, "expect_control_hz": expect_control_hz,
                   "skill_group": self.skill_group}
        if self.layout.predicts_pose:  # named only when it is not the default, as a force model's were
            hparams["target_fields"] = self.layout.target_fields
        self.save_hyperparameters(hparams)
        self.splits: dict[str, TrajectoryDataset] = {}
        self.attrs: dict[str, Any] = {}
        self.cond_channels: list[str] = []
        self.target_channels: list[str] = []
        self.n_train_total = 0
        # one shuffle stream for the whole fit; its state goes into checkpoints, so a resumed run shuffles its
        # remaining epochs as the uninterrupted run would have
        self.shuffle_generator = torch.Generator().manual_seed(self.seed)

    # ------------------------------------------------------------------ loading
    def _load(self, split: str) -> LoadedDataset:
        dataset = load_dataset(self.path, split=split, expect_control_hz=self.expect_control_hz)
        self.attrs = dataset.attrs
        self.cond_channels, self.target_channels = dataset_channels(dataset, self.layout.target_fields)
        expected = self.layout.channel_names()
        if self.cond_channels != cond_channel_names() or self.target_channels != expected:
            raise DatasetMismatchError(
                f"{self.path}: channels {self.cond_channels} -> {self.target_channels} differ from the "
                f"{cond_channel_names()} -> {expected} the models use")
        return dataset

    def usage_index(self, n_total: int) -> np.ndarray:
        """Sorted indices of the seeded usage-rate subset of ``n_total`` training trajectories."""
        return usage_index(n_total, self.usage_rate, self.seed)

    def setup(self, stage: str | None = None) -> None:
        """Load the splits a Lightning stage needs (fit: train+valid; validate: valid; test: test)."""
        wanted = {"fit": ("train", "valid"), "validate": ("valid",), "test": ("test",),
                  "predict": ("test",), None: ("train", "valid")}.get(stage, ("train", "valid"))
        for split in wanted:
            if split in self.splits:
                continue
            loaded = self._load(split)
            if split == "train":
                self.n_train_total = len(loaded)
                self.splits[split] = TrajectoryDataset.from_loaded(loaded, self.usage_index(len(loaded)), self.layout)
            else:
                self.splits[split] = TrajectoryDataset.from_loaded(loaded, layout=self.layout)

    def split(self, name: str) -> TrajectoryDataset:
        if name not in self.splits:
            self.setup({"train": "fit", "valid": "validate", "test": "test"}.get(name, "fit"))
        if name not in self.splits:
            raise DataModuleError(f"{self.path}: split {name!r} is not available")
        return self.splits[name]

    @property
    def control_hz(self) -> float:
        if not self.attrs:
            self.split("train")
        return float(self.attrs["control_hz"])

    @property
    def stiffness_frame(self) -> str:
        """The frame the file's stiffness channels are diagonals in (files older than the frame: world)."""
        if not self.attrs:
            self.split("train")
        return str(self.attrs.get("stiffness_frame", "world"))

    @property
    def data_spec(self) -> dict[str, Any]:
        """What a model trained on this file records of it (``dcm.models.configuration.DataSpec``); the frame only
        where it is not the world's, so a world-frame model's checkpoint stays as it was before the frame."""
        spec: dict[str, Any] = {"control_hz": self.control_hz}
        if self.stiffness_frame != "world":
            spec["stiffness_frame"] = self.stiffness_frame
        return spec

    def train_arrays(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The used training trajectories' raw conditions (N,H,24) and targets (N,H,C): what a model fits
        its normalisers on."""
        train = self.split("train")
        return train.cond, train.target

    def eval_set(self, split: str = "valid") -> TrajectoryDataset:
        """The fixed subset of a split that the metrics callback samples forces for."""
        return self.split(split).subset(self.n_eval)

    # ------------------------------------------------------------------ loaders
    def _loader(self, dataset: TrajectoryDataset, shuffle: bool, batch_size: int) -> DataLoader:
        generator = self.shuffle_generator if shuffle else None
        return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, num_workers=self.num_workers,
                          generator=generator, drop_last=False, persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        train = self.split("train")
        if not self.skill_group:
            return self._loader(train, True, self.batch_size)
        if not bool((train.skills >= 0).any()):
            raise DataModuleError(f"{self.path}: skill_group={self.skill_group} needs the trials' demo_id, "
                                  "and this file's training trials have none")
        sampler = SkillGroupBatchSampler(train.skills, self.batch_size, self.skill_group, self.shuffle_generator)
        return DataLoader(train, batch_sampler=sampler, num_workers=self.num_workers,
                          persistent_workers=self.num_workers > 0)

    def _eval_loader(self, dataset: TrajectoryDataset) -> DataLoader:
        """A valid/test loader. Under DDP each rank gets its own trials, none twice: Lightning's default
        DistributedSampler repeats trials to even out the shards, which would count them twice in val/loss.
        A split with fewer trials than ranks keeps the padding, since every rank must log each metric."""
        if not (torch.distributed.is_available() and torch.distributed.is_initialized()
                and len(dataset) >= torch.distributed.get_world_size() > 1):
            return self._loader(dataset, False, self.eval_batch_size)
        from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler

        return DataLoader(dataset, batch_size=self.eval_batch_size, num_workers=self.num_workers,
                          sampler=UnrepeatedDistributedSampler(dataset, shuffle=False), drop_last=False,
                          persistent_workers=self.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        return self._eval_loader(self.split("valid"))

    def test_dataloader(self) -> DataLoader:
        return self._eval_loader(self.split("test"))

    def state_dict(self) -> dict[str, Any]:
        return {"path": str(self.path), "stage": self.stage, "usage_rate": self.usage_rate, "seed": self.seed,
                "n_train_used": len(self.splits["train"]) if "train" in self.splits else None,
                "n_train_total": self.n_train_total, "shuffle_rng": self.shuffle_generator.get_state()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restore the shuffle stream; the subset itself is a pure function of (file, usage_rate, seed)."""
        if "shuffle_rng" in state_dict:  # a checkpoint may not hold it
            self.shuffle_generator.set_state(state_dict["shuffle_rng"])
