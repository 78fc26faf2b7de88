"""The ``train.py`` / ``dcm-train`` command: Hydra composes conf/train.yaml, :func:`dcm.training.train.train` runs it.

A user error (bad setting, unusable dataset or checkpoint, a missing resume folder, an accelerator this
machine lacks) ends in one ``error: ...`` line on stderr and exit code 2; ``HYDRA_FULL_ERROR=1`` shows the
traceback instead. A sweep keeps Hydra's handling: the failed job is marked, the others still run.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import warnings
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from dcm.configs import CONF_DIR, group_choice_problem, register_resolvers
from dcm.console import error_line, print_error, quiet_libraries, to_run_log
from dcm.devices import DeviceError, check_accelerator
from dcm.training.checks import (
    TrainConfigError,
    check_data_argument,
    check_dataset_overrides,
    check_resume_argument,
    check_trainer,
    run_objective,
)
from dcm.training.run_dir import SUMMARY_FILE

# Third-party lines that say nothing about this run, each silenced by its logger or its exact message.
_NOTICE_PREFIXES = ("💡 Tip:",)  # Lightning's advertisements of its cloud services (litlogger, litmodels)
_NOTICE_LOGGERS = ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero")


class _DropNotices(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(_NOTICE_PREFIXES)


def quiet_notices() -> None:
    """Silence the library notices a training run adds to those :func:`dcm.console.quiet_libraries` hushes, and
    nothing else."""
    for name in _NOTICE_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, _DropNotices) for f in logger.filters):
            logger.addFilter(_DropNotices())
    # torch's pytree API as Lightning calls it; the behaviour is unchanged
    warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated")
    # ForceMetricsCallback's advice on R_within; SelectionCheckpoint gives it, knowing the monitor
    warnings.filterwarnings("ignore", message=r"(val|test)/R_within is undefined")


def one_handler_for_lightning() -> None:
    """Leave Lightning's log records to the handlers Hydra gave the root logger (the console and train.log).

    Importing ``lightning`` gives its package logger a console handler of its own, and its records still
    propagate to the root logger: under Hydra every Lightning line, the model summary too, printed twice."""
    if not logging.getLogger().handlers:  # no Hydra logging (a library call): Lightning's own handler is the only one
        return
    lightning = logging.getLogger("lightning")
    for handler in list(lightning.handlers):
        if type(handler) is logging.StreamHandler:
            lightning.removeHandler(handler)


def _stop(err: Exception) -> None:
    """One ``error:`` line on stderr and in the run's train.log, exit code 2; a sweep or HYDRA_FULL_ERROR=1
    re-raises instead."""
    if os.environ.get("HYDRA_FULL_ERROR") == "1" or HydraConfig.get().mode == RunMode.MULTIRUN:
        raise err
    print_error(err)
    to_run_log(error_line(err))  # the run directory's train.log says why the run stopped
    sys.exit(2)


# An absolute path: Hydra resolves a relative one against the package when this module is imported
# (train.py, dcm-train), where the repository's conf/ is no package.
@hydra.main(config_path=str(CONF_DIR), config_name="train")
def hydra_main(cfg: DictConfig) -> float | None:
    """One run (one job of a sweep); returns the selection score for Hydra's sweepers."""
    quiet_libraries()  # log lines to stderr: stdout carries the closing summary
    quiet_notices()
    try:
        check_dataset_overrides(HydraConfig.get().overrides.task)
        check_accelerator(cfg.trainer.get("accelerator", "auto"))  # before Lightning's import, which takes seconds
        if not cfg.get("resume"):  # a resumed run's trainer is its saved one, checked once the overrides apply
            check_trainer(cfg.trainer, str(cfg.checkpoint.monitor))
            run_objective(cfg)
    except (TrainConfigError, DeviceError) as err:
        _stop(err)
    from dcm.training.train import USER_ERRORS, closing_summary, resolve_resume, reuse_run, train  # Lightning: slow

    one_handler_for_lightning()

    try:
        if cfg.get("resume"):
            cfg, run_dir = resolve_resume(cfg)
            summary = train(cfg, run_dir)
        else:
            run_dir = Path(HydraConfig.get().runtime.output_dir)
            summary = reuse_run(cfg, run_dir)
            if summary is not None:
                print(f"{run_dir}: finished before with the same config ({SUMMARY_FILE}): skipped")
            else:
                summary = train(cfg, run_dir)
    except USER_ERRORS as err:
        _stop(err)
    from lightning.pytorch.utilities import rank_zero_only

    if rank_zero_only.rank == 0:  # under DDP every rank gets here; the summary is printed once
        print(closing_summary(summary), flush=True)
    score = summary.get("best_score")
    return None if score is None or not math.isfinite(score) else float(score)


def main() -> None:
    """Entry point of train.py and ``dcm-train``: ``resume=<dir>`` and ``data=`` are checked before Hydra
    creates an output folder, so a wrong one leaves nothing behind."""
    quiet_notices()
    try:
        if problem := group_choice_problem(sys.argv[1:]):
            raise TrainConfigError(problem)
        check_data_argument(sys.argv[1:])
        check_resume_argument(sys.argv[1:])
    except TrainConfigError as err:
        print_error(err)
        sys.exit(2)
    register_resolvers()  # the configs' ${dcm.*} resolvers, read by Hydra before hydra_main runs
    hydra_main()


if __name__ == "__main__":
    main()
