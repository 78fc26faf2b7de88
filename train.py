"""Train a force model (DCM or the single-pass baseline) with Lightning; configs in conf/train.yaml.

    python train.py                                       # default DCM (T=30, RetNet d=128, linear) on data/sim.h5
    python train.py model=baseline data=tiny              # the T=1 regression baseline on the tiny preset
    python train.py -m model.diffusion_steps=1,5,10,30 seed=0,1,2      # sweep: one run dir per job
    python train.py stage=finetune init_from=<ckpt> data=realistic     # keeps the pre-training normaliser
    python train.py resume=<run_dir>                      # continue a killed run from <run_dir>/checkpoints/last.ckpt
    python train.py resume=<run_dir> trainer.max_epochs=400   # ... or extend it (key=value overrides apply)
    python train.py -m +experiment=diffusion_steps        # a paper study (conf/experiment/): report with dcm.model_study
    python train.py -m +experiment=usage_rate hydra/launcher=joblib hydra.launcher.n_jobs=4   # runs in parallel
    python train.py -m +experiment=usage_rate hydra/launcher=submitit_slurm hydra.launcher.partition=<p> \
        hydra.launcher.timeout_min=120 hydra.launcher.cpus_per_task=4   # one SLURM job per run (pip install -e .[cluster])

Each run directory holds config.yaml (resolved), tb/ (TensorBoard), checkpoints/ (top-k on checkpoint.monitor, default val/R_within, + last.ckpt)
and summary.json. A run directory that already holds a finished run of the same config is skipped (its
summary.json is reused), and an unfinished one is resumed, so re-running a sweep only trains what is missing;
one holding another config is refused.

Every split the run will read (train, valid, and test when ``test_after_fit``) is validated before fitting.
A user error (bad setting, unusable dataset or checkpoint, a missing resume folder, an accelerator this
machine lacks) ends in one ``error: ...`` line on stderr and exit code 2; ``HYDRA_FULL_ERROR=1`` shows the
traceback instead.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import logging
import math
import os
import sys
from pathlib import Path
from typing import Any, Sequence

import hydra
import lightning as L
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from hydra.utils import get_class, to_absolute_path
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from dcm.cli import check_accelerator, config_diff, load_json
from dcm.data.datamodule import DCMDataModule
from dcm.data.generate import GenerationError
from dcm.data.schema import read_root_attrs
from dcm.models.callbacks import ForceMetricsCallback, RandomStateCallback, RunETACallback
from dcm.models.checkpoint import checkpoint_kind, read_checkpoint
from dcm.models.configuration import CheckpointKindError
from dcm.models.dcm import DCM
from dcm.models.force_model import ForceModel
from dcm.models.nets import get_score_net_class

log = logging.getLogger("dcm.train")

# Fields a fine-tuning run may change; everything else (net, T, schedule, normaliser) comes from init_from.
FINETUNE_FIELDS = ("lr", "weight_decay", "warmup_steps", "lr_schedule", "ema_decay", "eval_batch_size",
                   "sampler", "sampling_steps", "n_samples", "task_weight", "task_from_s")


class TrainConfigError(ValueError):
    """An inconsistent train.py configuration (stage, init_from, resume ...)."""


# What a user can get wrong (settings, files): reported in one line. Every dcm input error is a ValueError
# (TrainConfigError, DatasetError, DataModuleError, CheckpointKindError, DeviceError ...).
USER_ERRORS = (ValueError, GenerationError)


def dataset_path(data_cfg: DictConfig) -> Path:
    """The dataset file, generated from its preset first if it does not exist yet."""
    if data_cfg.path in (None, "???"):
        raise TrainConfigError("data.path is required (e.g. data=path data.path=/abs/file.h5)")
    path = Path(to_absolute_path(str(data_cfg.path)))
    if not path.exists():
        if not data_cfg.get("preset"):
            raise TrainConfigError(f"dataset {path} does not exist and data.preset is null: nothing to generate")
        log.info("dataset %s is absent: generating preset %r", path, data_cfg.preset)
        from dcm.data.generate import ensure_dataset  # imports the simulator: only when needed

        path = Path(ensure_dataset(str(data_cfg.preset), path, list(data_cfg.get("generate_overrides") or [])))
    return path


def build_datamodule(cfg: DictConfig, path: Path) -> DCMDataModule:
    d = cfg.data
    return DCMDataModule(path, stage=cfg.stage, usage_rate=cfg.usage_rate, seed=cfg.seed,
                         batch_size=d.batch_size, eval_batch_size=d.eval_batch_size, num_workers=d.num_workers,
                         expect_control_hz=d.get("expect_control_hz"), n_eval=d.get("n_eval"),
                         skill_group=d.get("skill_group", 0))


def init_checkpoint(cfg: DictConfig) -> Path:
    """``init_from`` as an absolute path, refused unless it holds the selected model's kind."""
    ckpt = Path(to_absolute_path(str(cfg.init_from)))
    kind, selected = checkpoint_kind(ckpt), get_class(str(cfg.model._target_)).model_kind
    if kind != selected:
        raise CheckpointKindError(f"init_from={ckpt} holds a {kind!r} model but model={selected!r} "
                                  f"was selected; pass model={kind}")
    return ckpt


def build_model(cfg: DictConfig, dm: DCMDataModule) -> ForceModel:
    """A fresh model (normaliser fitted on the training split), or one initialised from ``init_from``."""
    model_cfg: dict[str, Any] = OmegaConf.to_container(cfg.model, resolve=True)  # type: ignore[assignment]
    cls: type[ForceModel] = get_class(model_cfg.pop("_target_"))
    data_spec = {"control_hz": dm.control_hz}
    if cfg.stage == "finetune" and not cfg.init_from:
        raise TrainConfigError("stage=finetune needs init_from=<checkpoint of the pre-trained model>")
    if cfg.init_from:
        ckpt = init_checkpoint(cfg)
        init = cls.load_from_checkpoint(ckpt)
        init.data_spec.check(dm.cond_channels, dm.target_channels, dm.control_hz, source=str(dm.path))
        hparams = dict(init.hparams)
        hparams.update({k: model_cfg[k] for k in FINETUNE_FIELDS if k in model_cfg})
        model = cls(**hparams)
        model.load_state_dict(init.state_dict())  # weights, EMA and the pre-training normaliser
        if model.ema_net is not None:
            model.net.load_state_dict(model.ema_net.state_dict())  # continue from the averaged weights
        log.info("initialised from %s (normaliser kept from pre-training)", ckpt)
        return model
    model = new_model(cfg, data_spec)
    model.fit_normalizers(*dm.train_arrays())
    return model


def check_task_batches(model: ForceModel, dm: DCMDataModule) -> None:
    """``model.task_weight`` > 0 compares trials of one skill within a batch, so it needs grouped batches."""
    if model.cfg.task_weight > 0 and dm.skill_group < 2:
        raise TrainConfigError(f"model.task_weight={model.cfg.task_weight} compares trials of one skill within a "
                               f"batch; set data.skill_group to 2 or more (got {dm.skill_group})")


def new_model(cfg: DictConfig, data_spec: dict[str, Any] | None = None) -> ForceModel:
    """The untrained model ``cfg.model`` names, with the ``net`` (and, for a DCM, ``schedule``) groups passed in."""
    model_cfg: dict[str, Any] = OmegaConf.to_container(cfg.model, resolve=True)  # type: ignore[assignment]
    cls: type[ForceModel] = get_class(model_cfg.pop("_target_"))
    if issubclass(cls, DCM):
        model_cfg["schedule"] = OmegaConf.to_container(cfg.schedule, resolve=True)
    model_cfg["net"] = OmegaConf.to_container(cfg.net, resolve=True)
    return cls(data_spec=data_spec, **model_cfg)


def _has_split(path: Path, split: str) -> bool:
    try:
        import h5py

        with h5py.File(path, "r") as f:
            return split in f.get("mask", {}) and len(f["mask"][split]) > 0
    except OSError:
        return False


def train(cfg: DictConfig, run_dir: Path) -> dict[str, Any]:
    """Fit (or resume) one run in ``run_dir``; returns the summary also written to summary.json."""
    check_accelerator(cfg.trainer.get("accelerator", "auto"))
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt_dir = run_dir / "checkpoints"
    last = ckpt_dir / "last.ckpt"
    resuming = bool(cfg.get("resume"))
    if resuming:
        read_checkpoint(last)  # plain data only: a file that would run code is refused here, in one line
    L.seed_everything(int(cfg.seed), workers=True)

    path = dataset_path(cfg.data)
    read_root_attrs(path)  # fail fast on a file that is not a dcm dataset
    if not resuming:
        cfg.data.path = str(path)
        OmegaConf.save(OmegaConf.create(planned_config(cfg)), run_dir / "config.yaml")

    dm = build_datamodule(cfg, path)
    dm.setup("fit")
    if cfg.test_after_fit and _has_split(path, "test"):
        dm.setup("test")  # validated now: a NaN in the test split must not surface after the whole fit
    model = build_model(cfg, dm)
    check_task_batches(model, dm)

    checkpoint = ModelCheckpoint(dirpath=ckpt_dir, monitor=cfg.checkpoint.monitor, mode=cfg.checkpoint.mode,
                                 save_top_k=int(cfg.checkpoint.save_top_k), save_last=False,
                                 filename=cfg.checkpoint.filename, auto_insert_metric_name=False)
    # last.ckpt after every training epoch (not only every validation), so a killed run loses little
    last_checkpoint = ModelCheckpoint(dirpath=ckpt_dir, filename="last", monitor=None, save_top_k=1,
                                      every_n_epochs=1, save_on_train_epoch_end=True, enable_version_counter=False)
    callbacks = [ForceMetricsCallback(**OmegaConf.to_container(cfg.metrics, resolve=True)), checkpoint,
                 last_checkpoint,
                 LearningRateMonitor(logging_interval="epoch"), RunETACallback(), RandomStateCallback()]
    logger = TensorBoardLogger(save_dir=str(run_dir), name="tb", version="", default_hp_metric=False)
    trainer_kwargs = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer = L.Trainer(default_root_dir=str(run_dir), logger=logger, callbacks=callbacks, **trainer_kwargs)
    trainer.fit(model, datamodule=dm, ckpt_path=str(last) if resuming else None, weights_only=True)

    best = checkpoint.best_model_path or (str(last) if last.exists() else "")
    best_score = checkpoint.best_model_score
    summary: dict[str, Any] = {
        "run_dir": str(run_dir), "model": model.model_kind, "stage": cfg.stage, "dataset": str(path),
        "n_train_used": len(dm.split("train")), "n_train_total": dm.n_train_total, "usage_rate": cfg.usage_rate,
        "seed": int(cfg.seed), "epochs": int(trainer.current_epoch), "global_step": int(trainer.global_step),
        "best_checkpoint": best, "monitor": cfg.checkpoint.monitor,
        "best_score": None if best_score is None else float(best_score),
    }
    if cfg.test_after_fit and best and _has_split(path, "test"):
        results = trainer.test(model, datamodule=dm, ckpt_path=best, verbose=False, weights_only=True)
        summary["test"] = {k: float(v) for k, v in (results[0] if results else {}).items()}
    elif cfg.test_after_fit:
        log.warning("no test split in %s (or no checkpoint): skipping the test pass", path)
    if trainer.is_global_zero:
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    return summary


def planned_config(cfg: DictConfig) -> dict[str, Any]:
    """The config train() saves in config.yaml (paths made absolute), without generating any dataset.

    A run from ``init_from`` records what it trains: every model field but FINETUNE_FIELDS, the net and the
    noise schedule as the checkpoint holds them, not the command line's unused defaults.
    """
    planned = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    planned.data.path = str(Path(to_absolute_path(str(cfg.data.path))))
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
    """``saved`` with the model and net options it predates filled in, where ``planned`` keeps their defaults.

    A checkpoint written before an option existed loads with the option's default, so its run trained exactly
    that default. Without this, every option added to the model or the net would make every earlier run of a
    study "another config", finished or not.
    """
    out = dict(saved)
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


def reuse_run(cfg: DictConfig, run_dir: Path) -> dict[str, Any] | None:
    """What an existing ``run_dir`` already holds, so a re-run sweep (same sweep dir) costs nothing.

    A finished run of the same config returns its summary.json; a killed one (last.ckpt, no summary) is
    continued (sets ``cfg.resume``); a run of another config is refused, naming what differs (a model or net
    option added since the run counts as the same while it keeps its default; so does an edited ``study``
    block). A folder without checkpoints (a run that failed before its first epoch) is simply reused.
    """
    saved, summary, last = run_dir / "config.yaml", run_dir / "summary.json", run_dir / "checkpoints" / "last.ckpt"
    if not saved.is_file() or not (summary.is_file() or last.is_file()):
        return None
    planned = planned_config(cfg)
    old = with_added_option_defaults(OmegaConf.to_container(OmegaConf.load(saved)), planned)
    differs = config_diff(old, planned, ignore=("resume", "study"))  # the study block says how to report, not train
    if differs:
        raise TrainConfigError(f"{run_dir} holds a run of another config ({'; '.join(differs)}); delete it or "
                               "choose another hydra.run.dir / hydra.sweep.dir")
    if summary.is_file():
        return load_json(summary)
    log.info("%s: unfinished run of the same config: resuming it from checkpoints/last.ckpt", run_dir)
    cfg.resume = str(run_dir)
    return None


def check_resume_dir(run_dir: Path) -> Path:
    """The run directory to resume, refused unless it holds a saved config and ``checkpoints/last.ckpt``."""
    if not run_dir.is_dir():
        raise TrainConfigError(f"resume={run_dir}: no such directory")
    if not (run_dir / "config.yaml").is_file():
        raise TrainConfigError(f"resume={run_dir}: no config.yaml there (is it a train.py run directory?)")
    if not (run_dir / "checkpoints" / "last.ckpt").is_file():
        raise TrainConfigError(f"resume={run_dir}: no checkpoints/last.ckpt to resume from")
    return run_dir


def check_resume_argument(argv: Sequence[str]) -> None:
    """Check ``resume=<dir>`` before Hydra starts, so a wrong folder leaves no new outputs/train/<time>/ behind."""
    for arg in argv:
        if arg.startswith("resume="):
            value = arg.split("=", 1)[1].strip("'\"")
            if value and value != "null":
                check_resume_dir(Path(value).expanduser().absolute())


def resolve_resume(cfg: DictConfig) -> tuple[DictConfig, Path]:
    """The saved config and directory of the run to resume."""
    run_dir = check_resume_dir(Path(to_absolute_path(str(cfg.resume))))
    saved = run_dir / "config.yaml"
    resumed = OmegaConf.load(saved)
    # other key=value overrides on the command line apply on top, e.g. trainer.max_epochs=200 to extend a run
    extra = [o for o in HydraConfig.get().overrides.task if not o.startswith(("resume=", "hydra."))]
    for override in extra:
        key = override.split("=", 1)[0].lstrip("+~")
        if OmegaConf.select(resumed, key, default=None) is None and key not in ("init_from",):
            log.warning("resume: override %r names no key of the saved config", override)
        resumed.merge_with(OmegaConf.from_dotlist([override.lstrip("+")]))
    resumed.resume = str(run_dir)
    if extra:
        OmegaConf.save(resumed, saved, resolve=True)
    return resumed, run_dir


@hydra.main(version_base=None, config_path="conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    try:
        if cfg.get("resume"):
            cfg, run_dir = resolve_resume(cfg)
            summary = train(cfg, run_dir)
        else:
            run_dir = Path(HydraConfig.get().runtime.output_dir)
            summary = reuse_run(cfg, run_dir)
            if summary is not None:
                print(f"{run_dir}: finished before with the same config (summary.json): skipped")
            else:
                summary = train(cfg, run_dir)
    except USER_ERRORS as err:
        # a sweep keeps Hydra's handling (the job is marked failed, the others still run)
        if os.environ.get("HYDRA_FULL_ERROR") == "1" or HydraConfig.get().mode == RunMode.MULTIRUN:
            raise
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    score = summary.get("best_score")
    return None if score is None or not math.isfinite(score) else float(score)  # for Hydra sweepers


if __name__ == "__main__":
    try:
        check_resume_argument(sys.argv[1:])
    except TrainConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    main()
