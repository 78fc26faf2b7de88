"""Fit a force model (DCM or the single-pass baseline) from a composed conf/train.yaml, in one run directory.

The command line is :mod:`dcm.training.cli`; the run directory's files are :mod:`dcm.training.run_dir`'s.
A run directory that already holds a finished run of the same config is skipped (its summary.json is
reused), and an unfinished one is resumed, so re-running a sweep only trains what is missing; one holding
another config is refused.

Every split the run will read (train, valid, and test when ``test_after_fit``) is validated before fitting,
so a bad file fails at start, not after hours of training.
"""

from __future__ import annotations

import dataclasses
import inspect
import logging
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_class, to_absolute_path
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from dcm.configs import config_diff
from dcm.control.objectives import PAPER, TaskObjective
from dcm.data.datamodule import DCMDataModule
from dcm.data.generate import GenerationError
from dcm.data.schema import read_root_attrs
from dcm.devices import check_accelerator
from dcm.models.callbacks import ForceMetricsCallback, RandomStateCallback, RunETACallback, metric_names
from dcm.models.checkpoint import checkpoint_kind, read_checkpoint
from dcm.models.configuration import CheckpointKindError
from dcm.models.dcm import DCM
from dcm.models.force_model import ForceModel
from dcm.models.metrics import ranking_shortfall, undefined_metrics
from dcm.models.nets import get_score_net_class
from dcm.shipped import shipped_path
from dcm.training import run_dir as rd
from dcm.training.checks import TrainConfigError, check_resume_dir, check_trainer, run_objective

log = logging.getLogger(__name__)

# Fields a fine-tuning run may change; everything else (net, T, schedule, normaliser) comes from init_from.
# The objective is one: it says what the task term and checkpoint selection rank, not what the net computes.
FINETUNE_FIELDS = ("lr", "weight_decay", "warmup_steps", "lr_schedule", "ema_decay", "eval_batch_size",
                   "sampler", "sampling_steps", "n_samples", "task_weight", "task_from_s", "objective")
PRESET_FILE = "data/{name}.h5"  # a preset's own dataset file, as conf/train.yaml's data.path defaults to it
# Checkpoint names abbreviate the metrics selected on most often; any other is named in full.
METRIC_ABBREVIATIONS = {"val/R_within": "Rw", "val/R_pooled": "Rp"}
# The data block of a config.yaml written before the dataset group: keys that now live elsewhere.
LEGACY_DATA_KEYS = ("preset", "generate_overrides", "stage", "usage_rate", "seed")
# Test metrics the closing summary prints (summary.json holds them all).
SUMMARY_TEST_METRICS = ("R_within", "R_within_spearman", "R_pooled", "force_rmse_N", "force_rmse_ratio_copy",
                        "path_rmse_m", "path_rmse_ratio_copy", "L_MSE")


# What a user can get wrong (settings, files): reported in one line. Every dcm input error is a ValueError
# (TrainConfigError, DatasetError, DataModuleError, CheckpointKindError, DeviceError ...).
USER_ERRORS = (ValueError, GenerationError)


# ------------------------------------------------------------------------------------------------ dataset
def preset_path(cfg: DictConfig) -> Path | None:
    """The file of the run's ``dataset`` preset (absolute), or None for a config without one."""
    dataset = cfg.get("dataset")
    if not dataset or not dataset.get("name"):
        return None
    return Path(to_absolute_path(PRESET_FILE.format(name=dataset.name)))


def config_search_path() -> list[str]:
    """The config dirs the running Hydra app was given beyond conf/ (``--config-dir``, ``hydra.searchpath``).

    Generation composes the preset with them, so a research preset (studies/conf/dataset) trains as it
    generates."""
    if not HydraConfig.initialized():
        return []
    return [f"{source.schema}://{source.path}" for source in HydraConfig.get().runtime.config_sources
            if source.provider not in ("hydra", "main", "schema")]


def dataset_path(cfg: DictConfig) -> Path:
    """The dataset file ``data.path``; the preset's own file is generated first if it does not exist yet.

    Only the preset's own file is ever generated: a path the user named must exist, so a typo cannot start
    a long simulation into an unexpected place."""
    if cfg.data.get("path") in (None, "???"):
        raise TrainConfigError("data.path is required (an existing file, or a dataset=<preset> to generate)")
    path = Path(to_absolute_path(str(cfg.data.path)))
    if path.exists():
        return path
    own = preset_path(cfg)
    if own is None or path != own:
        raise TrainConfigError(f"data.path={path} does not exist (only a preset's own file "
                               f"{PRESET_FILE.format(name='<name>')} is generated)")
    if rank_zero_only.rank != 0:  # the tasks of a cluster job start at once: one writer, or a torn file
        raise TrainConfigError(f"data.path={path} does not exist; with several tasks per job, generate it before "
                               f"submitting: dcm-generate dataset={cfg.dataset.name}")
    log.info("dataset %s is absent: generating preset %r", path, str(cfg.dataset.name))
    from dcm.data.generate import ensure_dataset  # imports the simulator: only when needed

    search_path = config_search_path()
    overrides = [f"hydra.searchpath=[{','.join(search_path)}]"] if search_path else []
    return Path(ensure_dataset(str(cfg.dataset.name), path, overrides))


def target_fields(cfg: DictConfig) -> str:
    """What the run's model predicts (``model.target_fields``; a fine-tuned model's own, from ``init_from``), so
    that the data give the target it learns."""
    if cfg.get("init_from"):
        hparams = read_checkpoint(init_checkpoint(cfg)).get("hyper_parameters") or {}
        return str(hparams.get("target_fields", "force"))
    return str(cfg.model.get("target_fields", "force"))


def build_datamodule(cfg: DictConfig, path: Path) -> DCMDataModule:
    d = cfg.data
    return DCMDataModule(path, stage=cfg.stage, usage_rate=cfg.usage_rate, seed=cfg.seed,
                         batch_size=d.batch_size, eval_batch_size=d.eval_batch_size, num_workers=d.num_workers,
                         expect_control_hz=d.get("expect_control_hz"), n_eval=d.get("n_eval"),
                         skill_group=d.get("skill_group", 0), target_fields=target_fields(cfg))


def _has_split(path: Path, split: str) -> bool:
    try:
        import h5py

        with h5py.File(path, "r") as f:
            return split in f.get("mask", {}) and len(f["mask"][split]) > 0
    except OSError:
        return False


# -------------------------------------------------------------------------------------------------- model
def init_checkpoint(cfg: DictConfig) -> Path:
    """``init_from`` as an absolute path, refused unless it holds the selected model's kind."""
    ckpt = Path(to_absolute_path(shipped_path(str(cfg.init_from))))  # models/... from any directory
    kind, selected = checkpoint_kind(ckpt), get_class(str(cfg.model._target_)).model_kind
    if kind != selected:
        raise CheckpointKindError(f"init_from={ckpt} holds a {kind!r} model but model={selected!r} "
                                  f"was selected; pass model={kind}")
    return ckpt


def model_config(cfg: DictConfig) -> dict[str, Any]:
    """``cfg.model`` as plain data, with the run's ``objective`` group (absent from a config saved before it:
    the paper's) as the model's ``objective``."""
    model_cfg: dict[str, Any] = OmegaConf.to_container(cfg.model, resolve=True)  # type: ignore[assignment]
    if cfg.get("objective") is not None:
        model_cfg["objective"] = TaskObjective.from_config(cfg.objective).to_dict()
    return model_cfg


def new_model(cfg: DictConfig, data_spec: dict[str, Any] | None = None) -> ForceModel:
    """The untrained model ``cfg.model`` names, with the ``net`` (and, for a DCM, ``schedule``) groups and the
    ``objective`` passed in."""
    model_cfg = model_config(cfg)
    cls: type[ForceModel] = get_class(model_cfg.pop("_target_"))
    if issubclass(cls, DCM):
        model_cfg["schedule"] = OmegaConf.to_container(cfg.schedule, resolve=True)
    model_cfg["net"] = OmegaConf.to_container(cfg.net, resolve=True)
    return cls(data_spec=data_spec, **model_cfg)


def build_model(cfg: DictConfig, dm: DCMDataModule) -> ForceModel:
    """A fresh model (normaliser fitted on the training split), or one initialised from ``init_from``."""
    model_cfg = model_config(cfg)
    cls: type[ForceModel] = get_class(model_cfg.pop("_target_"))
    if cfg.stage == "finetune" and not cfg.init_from:
        raise TrainConfigError("stage=finetune needs init_from=<checkpoint of the pre-trained model>")
    if cfg.init_from:
        ckpt = init_checkpoint(cfg)
        init = cls.load_from_checkpoint(ckpt)
        init.data_spec.check(dm.cond_channels, dm.target_channels, dm.control_hz, source=str(dm.path),
                             stiffness_frame=dm.stiffness_frame)
        hparams = dict(init.hparams)
        hparams.update({k: model_cfg[k] for k in FINETUNE_FIELDS if k in model_cfg})
        model = cls(**hparams)
        model.load_state_dict(init.state_dict())  # weights, EMA and the pre-training normaliser
        if model.ema_net is not None:
            model.net.load_state_dict(model.ema_net.state_dict())  # continue from the averaged weights
        log.info("initialised from %s (normaliser kept from pre-training)", ckpt)
        return model
    model = new_model(cfg, dm.data_spec)
    model.fit_normalizers(*dm.train_arrays())
    return model


def check_task_batches(model: ForceModel, dm: DCMDataModule) -> None:
    """``model.task_weight`` > 0 compares trials of one skill within a batch, so it needs grouped batches."""
    if model.cfg.task_weight > 0 and dm.skill_group < 2:
        raise TrainConfigError(f"model.task_weight={model.cfg.task_weight} compares trials of one skill within a "
                               f"batch; set data.skill_group to 2 or more (got {dm.skill_group})")


# ---------------------------------------------------------------------------------------------- selection
def checkpoint_filename(checkpoint_cfg: Mapping[str, Any]) -> str:
    """The selected checkpoints' file name template, built from ``checkpoint.monitor`` unless one is given.

    A given template may name no metric but the monitor: another one (e.g. val/R_within while selecting on
    val/R_pooled) can be undefined on the data and would name every file ``...nan.ckpt``."""
    monitor = str(checkpoint_cfg["monitor"])
    given = checkpoint_cfg.get("filename")
    if not given:
        name = METRIC_ABBREVIATIONS.get(monitor, monitor.rsplit("/", 1)[-1])
        return f"epoch{{epoch:03d}}-{name}{{{monitor}:.3f}}"
    others = sorted({key for key in re.findall(r"\{([^}:]+)", str(given)) if key not in ("epoch", "step", monitor)})
    if others:
        raise TrainConfigError(f"checkpoint.filename={given!r} names {', '.join(others)} but checkpoint.monitor is "
                               f"{monitor}; name the monitor only, or set checkpoint.filename=null")
    return str(given)


def check_monitor(checkpoint_cfg: Mapping[str, Any], task_term: bool, target_fields: str = "force") -> None:
    """Refuse a ``checkpoint.monitor`` no callback logs for a model of ``target_fields`` (the path metrics are
    a pose model's), or a ``checkpoint.mode`` that is not min/max, before training: Lightning finds either only
    at the first validation, epochs later, with a traceback."""
    mode = checkpoint_cfg.get("mode")
    if mode not in ("min", "max"):
        raise TrainConfigError(f"checkpoint.mode={mode}: must be min or max")
    monitor = str(checkpoint_cfg["monitor"])
    losses = ("loss", "loss_force", "loss_task") if task_term else ("loss",)
    logged = [f"val/{name}" for name in (*metric_names(target_fields), *losses)]
    if monitor not in logged and not monitor.startswith("train/loss"):
        raise TrainConfigError(f"checkpoint.monitor={monitor}: not a logged metric; one of {', '.join(logged)}")


class SelectionCheckpoint(ModelCheckpoint):
    """Top-k checkpoints on the monitor, where a validation whose monitor is undefined (NaN) is no candidate.

    Lightning ranks a NaN as the worst score yet keeps it while fewer than k files exist, so an undefined
    metric would "select" the first epochs. Here such epochs are skipped (the run then falls back on
    last.ckpt) and the user is told once what to monitor instead, unless ``told`` (the run said so at its
    start). It counts the validations it saw (``validations``, kept in the checkpoint), so a run's summary
    can tell "undefined at every validation" from "no validation ran"."""

    def __init__(self, *args: Any, told: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._warned_undefined = told
        self.validations = 0

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self.validations += 1
        super().on_validation_end(trainer, pl_module)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "validations": self.validations}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        super().load_state_dict(state_dict)
        self.validations = int(state_dict.get("validations", 0))

    def check_monitor_top_k(self, trainer: L.Trainer, current: torch.Tensor | None = None) -> bool:
        if current is not None and not bool(torch.isfinite(current)):
            if not self._warned_undefined and trainer.is_global_zero:
                self._warned_undefined = True
                advice = ("; use checkpoint.monitor=val/R_pooled for this data"
                          if self.monitor != "val/R_pooled" else "")
                log.warning("%s is undefined at epoch %d (e.g. too few trials per skill): no checkpoint is selected "
                            "on it%s", self.monitor, trainer.current_epoch, advice)
            return False
        return super().check_monitor_top_k(trainer, current)


# ------------------------------------------------------------------------------------------------ the run
def train(cfg: DictConfig, run_dir: Path) -> dict[str, Any]:
    """Fit (or resume) one run in ``run_dir``; returns the summary also written to summary.json."""
    check_accelerator(cfg.trainer.get("accelerator", "auto"))
    ckpt_dir, last = rd.checkpoint_dir(run_dir), rd.last_checkpoint(run_dir)
    resuming = bool(cfg.get("resume"))
    if resuming:
        read_checkpoint(last)  # plain data only: a file that would run code is refused here, in one line
    filename = checkpoint_filename(cfg.checkpoint)
    run_objective(cfg)
    check_monitor(cfg.checkpoint, task_term=float(cfg.model.get("task_weight") or 0.0) > 0,
                  target_fields=target_fields(cfg))
    check_trainer(cfg.trainer, str(cfg.checkpoint.monitor))
    run_dir.mkdir(parents=True, exist_ok=True)
    L.seed_everything(int(cfg.seed), workers=True)

    path = dataset_path(cfg)
    read_root_attrs(path)  # fail fast on a file that is not a dcm dataset
    if not resuming and rank_zero_only.rank == 0:  # under DDP every rank runs train(); one writes the run dir
        rd.write_config(run_dir, planned_config(cfg))

    dm = build_datamodule(cfg, path)
    dm.setup("fit")
    if cfg.test_after_fit and _has_split(path, "test"):
        dm.setup("test")  # validated now: a NaN in the test split must not surface after the whole fit
    model = build_model(cfg, dm)
    check_task_batches(model, dm)

    monitor = str(cfg.checkpoint.monitor)
    if shortfall := split_shortfall(monitor, dm, "valid"):
        log.warning("checkpoint.monitor=%s %s: no checkpoint can be selected on it, the run keeps its last one%s",
                    monitor, shortfall, "; use checkpoint.monitor=val/R_pooled" if "per skill" in shortfall else "")
    checkpoint = SelectionCheckpoint(dirpath=ckpt_dir, monitor=monitor, mode=cfg.checkpoint.mode,
                                     save_top_k=int(cfg.checkpoint.save_top_k), save_last=False,
                                     filename=filename, auto_insert_metric_name=False, told=shortfall is not None)
    # last.ckpt after every training epoch (not only every validation), so a killed run loses little
    last_checkpoint = ModelCheckpoint(dirpath=ckpt_dir, filename=rd.LAST_CHECKPOINT_STEM, monitor=None,
                                      save_top_k=1, every_n_epochs=1, save_on_train_epoch_end=True,
                                      enable_version_counter=False)
    callbacks = [ForceMetricsCallback(**OmegaConf.to_container(cfg.metrics, resolve=True)), checkpoint,
                 last_checkpoint, LearningRateMonitor(logging_interval="epoch"), RunETACallback(),
                 RandomStateCallback()]
    logger = TensorBoardLogger(save_dir=str(run_dir), name=rd.TB_DIR, version="", default_hp_metric=False)
    trainer_kwargs = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer = L.Trainer(default_root_dir=str(run_dir), logger=logger, callbacks=callbacks, **trainer_kwargs)
    trainer.fit(model, datamodule=dm, ckpt_path=str(last) if resuming else None, weights_only=True)

    # the best on the monitor, else (a monitor undefined at every validation) the last; published as best.ckpt
    selected = Path(checkpoint.best_model_path) if checkpoint.best_model_path else (last if last.exists() else None)
    best_score = checkpoint.best_model_score if checkpoint.best_model_path else None
    if selected is None:  # e.g. trainer.max_time ran out within the first epoch
        raise TrainConfigError(f"the run stopped after {trainer.global_step} step(s), before its first epoch ended "
                               f"(trainer.max_time={cfg.trainer.get('max_time')}): no checkpoint was written; give it "
                               "more time")
    if trainer.is_global_zero:
        rd.publish_best(run_dir, selected)
    summary: dict[str, Any] = {
        "run_dir": str(run_dir), "model": model.model_kind, "stage": cfg.stage, "dataset": str(path),
        "n_train_used": len(dm.split("train")), "n_train_total": dm.n_train_total, "usage_rate": cfg.usage_rate,
        "seed": int(cfg.seed), "epochs": int(trainer.current_epoch), "global_step": int(trainer.global_step),
        "best_checkpoint": str(rd.best_checkpoint(run_dir)), "selected_from": selected.name, "monitor": monitor,
        "best_score": None if best_score is None else float(best_score),
        "validations": checkpoint.validations, "check_val_every_n_epoch": cfg.trainer.get("check_val_every_n_epoch"),
    }
    undefined = {}
    if best_score is None and checkpoint.validations and (shortfall := split_shortfall(monitor, dm, "valid")):
        undefined[monitor] = shortfall
    if cfg.test_after_fit and _has_split(path, "test"):
        results = trainer.test(model, datamodule=dm, ckpt_path=str(selected), verbose=False, weights_only=True)
        summary["test"] = {k: float(v) for k, v in (results[0] if results else {}).items()}
        undefined.update(undefined_metrics(summary["test"], dm.eval_set("test").skills.numpy(), "the test split",
                                           prefix="test/"))
    elif cfg.test_after_fit:
        log.warning("no test split in %s: skipping the test pass", path)
    summary["undefined"] = undefined
    if trainer.is_global_zero:
        rd.write_summary(run_dir, summary)
    return summary


def split_shortfall(monitor: str, dm: DCMDataModule, split: str) -> str | None:
    """Why ``split`` is too small to define the ranking metric ``monitor`` names (``val/R_within`` ...), else None."""
    return ranking_shortfall(monitor.split("/", 1)[-1], dm.eval_set(split).skills.numpy(), f"the {split} split")


def closing_summary(summary: Mapping[str, Any]) -> str:
    """What a run ends with on stdout: the selected checkpoint, its score on the monitor (or why it has none),
    the test metrics (or why they are undefined)."""
    score, monitor = summary.get("best_score"), summary.get("monitor")
    undefined = summary.get("undefined") or {}
    source = f" ({summary['selected_from']})" if summary.get("selected_from") else ""
    lines = [f"selected checkpoint: {summary.get('best_checkpoint') or '(none)'}{source}"]
    if isinstance(score, (int, float)) and math.isfinite(score):
        lines.append(f"  {monitor} = {score:.4f}")
    elif summary.get("validations") == 0:
        lines.append(f"  no validation ran: the run stopped after {summary.get('epochs')} epoch(s), "
                     f"{summary.get('global_step')} step(s), before the first at epoch "
                     f"{summary.get('check_val_every_n_epoch')} (trainer.check_val_every_n_epoch), so none selected on "
                     f"{monitor}: this is the last checkpoint; give the run more epochs, steps or time")
    else:
        why = f" ({undefined[monitor]})" if monitor in undefined else ""
        lines.append(f"  {monitor} was undefined at every validation{why}: this is the last checkpoint")
    test = summary.get("test") or {}
    values = ", ".join(f"{name} {test[f'test/{name}']:.4g}" for name in SUMMARY_TEST_METRICS
                       if f"test/{name}" in test and f"test/{name}" not in undefined)
    reasons: dict[str, list[str]] = {}
    for name in SUMMARY_TEST_METRICS:
        if (reason := undefined.get(f"test/{name}")) is not None:
            reasons.setdefault(reason, []).append(name)
    if values:
        lines.append(f"  test: {values}")
    lines += [f"  test {', '.join(names)} n/a: {reason}" for reason, names in reasons.items()]
    lines.append(f"  all metrics: {rd.summary_path(Path(str(summary.get('run_dir', '.'))))}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------- config of a run
def planned_config(cfg: DictConfig) -> dict[str, Any]:
    """The config train() saves in config.yaml (paths made absolute), without generating any dataset.

    The checkpoint file name is the one used. The ``dataset`` preset is kept only when ``data.path`` is its
    own file: any other file is described by its own attributes, not by a preset it may not come from.
    A run from ``init_from`` records what it trains: every model field but FINETUNE_FIELDS, the net and the
    noise schedule as the checkpoint holds them, not the command line's unused defaults.
    """
    planned = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    planned.data.path = str(Path(to_absolute_path(str(cfg.data.path))))
    planned.checkpoint.filename = checkpoint_filename(cfg.checkpoint)
    if "dataset" in planned and preset_path(cfg) != Path(planned.data.path):
        planned.dataset = None
    if cfg.init_from:
        planned.init_from = str(init_checkpoint(cfg))
        hparams = read_checkpoint(planned.init_from).get("hyper_parameters") or {}
        config_cls = get_class(str(cfg.model._target_)).config_cls
        applied = config_cls.from_kwargs({k: v for k, v in hparams.items() if k != "data_spec"})
        for key in planned.model:
            if key != "_target_" and key not in FINETUNE_FIELDS and hasattr(applied, key):
                planned.model[key] = getattr(applied, key)
        planned.net = hparams.get("net", planned.net)
        planned.schedule = hparams.get("schedule", planned.schedule)
    return OmegaConf.to_container(planned)  # type: ignore[return-value]


def option_defaults(group: str, planned: dict[str, Any]) -> dict[str, Any]:
    """The defaults a checkpoint falls back on for options of config ``group`` (``model`` or ``net``) it lacks.

    ``model``: the fields of the model's config dataclass (``ForceModelConfig.from_kwargs`` fills them in).
    ``net``: the keyword defaults of the score net's constructor (``build_score_net`` passes the rest through).
    """
    if group == "model":
        config_cls = get_class(str(planned["model"]["_target_"])).config_cls
        return {f.name: f.default for f in dataclasses.fields(config_cls) if f.default is not dataclasses.MISSING}
    parameters = inspect.signature(get_score_net_class(str(planned["net"]["name"]))).parameters.values()
    return {p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty}


def with_added_option_defaults(saved: dict[str, Any], planned: dict[str, Any]) -> dict[str, Any]:
    """``saved`` with the model and net options (and the objective group) it predates filled in, where ``planned``
    keeps their defaults.

    A checkpoint written before an option existed loads with the option's default, so its run trained exactly
    that default. Without this, every option added to the model or the net would make every earlier run of a
    study "another config", finished or not.
    """
    out = dict(saved)
    if "objective" not in saved and planned.get("objective") is not None:  # run before the objective group
        if TaskObjective.from_config(planned["objective"]) == PAPER:  # which trained the paper's
            out["objective"] = planned["objective"]
    for group in ("model", "net"):
        if not isinstance(planned.get(group), dict):
            continue
        defaults = option_defaults(group, planned)
        filled = dict(saved.get(group) or {})
        for key, value in planned[group].items():
            if key not in filled and key in defaults and defaults[key] == value:
                filled[key] = value
        out[group] = filled
    return out


def with_dataset_group(saved: dict[str, Any], planned: dict[str, Any]) -> dict[str, Any]:
    """A config.yaml written before the ``dataset`` group, in today's layout: its data block without the keys
    that moved out of it, and its ``data.preset`` as the dataset (``data.path``, compared as it is, names
    the file). Such a run is then "the same config" as one planned today with the same settings."""
    if "dataset" in saved or not isinstance(saved.get("data"), dict):
        return saved
    data = saved["data"]
    preset = data.get("preset")
    dataset = planned.get("dataset")
    if preset is None or not isinstance(dataset, dict) or dataset.get("name") != preset:
        dataset = None if preset is None else {"name": preset}
    return {**saved, "data": {k: v for k, v in data.items() if k not in LEGACY_DATA_KEYS}, "dataset": dataset}


def reuse_run(cfg: DictConfig, run_dir: Path) -> dict[str, Any] | None:
    """What an existing ``run_dir`` already holds, so a re-run sweep (same sweep dir) costs nothing.

    A finished run of the same config returns its summary.json; a killed one (last.ckpt, no summary) is
    continued (sets ``cfg.resume``); a run of another config is refused, naming what differs (a model or net
    option added since the run counts as the same while it keeps its default; so does an edited ``study``
    block). A folder without checkpoints (a run that failed before its first epoch) is simply reused.
    """
    if not rd.config_path(run_dir).is_file() or not (rd.run_finished(run_dir)
                                                    or rd.last_checkpoint(run_dir).is_file()):
        return None
    planned = planned_config(cfg)
    old = with_added_option_defaults(with_dataset_group(rd.read_config(run_dir), planned), planned)
    differs = config_diff(old, planned, ignore=("resume", "study"))  # the study block says how to report, not train
    if differs:
        raise TrainConfigError(f"{run_dir} holds a run of another config ({'; '.join(differs)}); delete it or "
                               "choose another hydra.run.dir / hydra.sweep.dir")
    if rd.run_finished(run_dir):
        return rd.read_summary(run_dir)
    log.info("%s: unfinished run of the same config: resuming it from %s/%s", run_dir, rd.CHECKPOINT_DIR,
             rd.LAST_CHECKPOINT)
    cfg.resume = str(run_dir)
    return None


# ------------------------------------------------------------------------------------------------- resume
def resolve_resume(cfg: DictConfig) -> tuple[DictConfig, Path]:
    """The saved config and directory of the run to resume."""
    run_dir = check_resume_dir(Path(to_absolute_path(str(cfg.resume))))
    saved = rd.config_path(run_dir)
    resumed = OmegaConf.load(saved)
    # other key=value overrides on the command line apply on top, e.g. trainer.max_epochs=200 to extend a run
    extra = [o for o in HydraConfig.get().overrides.task if not o.startswith(("resume=", "hydra."))]
    for override in extra:
        key = override.split("=", 1)[0].lstrip("+~")
        if OmegaConf.select(resumed, key, default=None) is None and key not in ("init_from",):
            log.warning("resume: override %r names no key of the saved config", override)
        resumed.merge_with(OmegaConf.from_dotlist([override.lstrip("+")]))
    resumed.resume = str(run_dir)
    check_trainer(resumed.trainer, str(resumed.checkpoint.monitor))  # before the saved config takes the overrides
    if extra:
        OmegaConf.save(resumed, saved, resolve=True)
    return resumed, run_dir


__all__ = ["FINETUNE_FIELDS", "USER_ERRORS", "SelectionCheckpoint", "TrainConfigError", "build_datamodule",
           "build_model", "check_monitor", "check_task_batches", "checkpoint_filename", "closing_summary",
           "config_search_path", "dataset_path", "init_checkpoint", "model_config", "new_model", "option_defaults",
           "planned_config", "preset_path", "resolve_resume", "reuse_run", "target_fields", "train",
           "with_added_option_defaults", "with_dataset_group"]
