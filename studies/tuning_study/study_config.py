"""Settings of a multi-seed study (``studies/conf/study.yaml``): checks, the tuners it runs, and each run's
tune config.

Every (tuner, seed) run is an ordinary :func:`dcm.tuning.run.tune` run. Its config is the product's
``conf/tune.yaml`` as composed by Hydra (so settings added to the tuner later get their defaults), with the
study's skill, search and robot-free settings, the tuner's checkpoint, the seed, the study's reference point
and the tuner's own ``tuners.<name>.overrides`` put in. Only the DCM's runs carry the robot-based search
(``robot_based.n_trials`` = the largest N): it does not depend on the predictor, so one run per seed serves
every N by truncation.

``study.yaml`` lives with the studies, but its groups (demo, stiffness, domain, search) and ``tune.yaml`` are
the product's, so composing it needs both config dirs on Hydra's search path: :func:`compose_study` and
:func:`with_product_conf` (for the command line) put the product's there.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

STUDY_CONF_DIR = Path(__file__).resolve().parents[1] / "conf"  # studies/conf: study.yaml
CONF_DIR = Path(__file__).resolve().parents[2] / "conf"  # the product's conf: tune.yaml and the groups study.yaml uses
STUDY_SETTINGS = "study_config.json"  # what a study folder was started with; a resume must match it


def with_product_conf(argv: Sequence[str]) -> list[str]:
    """Hydra command-line arguments with the product's conf dir added (``--config-dir``) unless one is given."""
    argv = list(argv)
    if any(a in ("--config-dir", "-cd") or a.startswith("--config-dir=") for a in argv):
        return argv
    return ["--config-dir", str(CONF_DIR), *argv]


def compose_study(overrides: Sequence[str] = ()) -> Any:
    """``studies/conf/study.yaml`` with ``overrides``, composed outside of a Hydra app (as tests and scripts do)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(STUDY_CONF_DIR)):
        return compose("study", overrides=[f"hydra.searchpath=['file://{CONF_DIR}']", *overrides])


class StudyConfigError(ValueError):
    """A study setting that cannot work; the one-line message names the setting."""


@dataclass(frozen=True)
class Tuner:
    """One robot-free tuner of the study: its name, predictor and extra tune settings."""

    name: str  # dcm | baseline | reference
    ckpt: str
    overrides: tuple[str, ...] = field(default_factory=tuple)
    robot_based_trials: int = 0  # only the DCM's runs hold the robot-based search


def plain(value: Any) -> Any:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def _integer(value: Any, key: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise StudyConfigError(f"{key} = {value!r} must be an integer >= {minimum}")
    return value


def robot_trial_counts(cfg: Any) -> list[int]:
    """The robot-based budgets N to report, ascending (``robot_based.n_trials``)."""
    counts = plain(cfg.robot_based.n_trials)
    counts = [counts] if isinstance(counts, int) else counts
    if not isinstance(counts, list) or not counts:
        raise StudyConfigError(f"robot_based.n_trials = {counts!r} must be a list of trial counts, e.g. [5, 20, 50]")
    return sorted({_integer(n, "robot_based.n_trials[]", 1) for n in counts})


def seeds(cfg: Any) -> list[int]:
    first = _integer(cfg.first_seed, "first_seed", 0)
    return list(range(first, first + _integer(cfg.seeds, "seeds", 1)))


def tuners(cfg: Any) -> list[Tuner]:
    """The robot-free tuners this study runs, in report order; the DCM first (it is tested against the rest)."""
    from omegaconf import OmegaConf

    if OmegaConf.is_missing(cfg, "ckpt") or not cfg.ckpt:
        raise StudyConfigError("ckpt is required: python -m studies.tuning_study.study ckpt=<dcm.ckpt>")
    given = [("dcm", cfg.ckpt), ("baseline", cfg.baseline_ckpt), ("reference", cfg.reference_json)]
    result = []
    for name, ckpt in given:
        if not ckpt:
            continue
        if not Path(str(ckpt)).is_file():
            key = {"dcm": "ckpt", "baseline": "baseline_ckpt", "reference": "reference_json"}[name]
            raise StudyConfigError(f"{key} = {ckpt}: no such file")
        overrides = plain(cfg.tuners.get(name, {}).get("overrides", [])) or []
        if not isinstance(overrides, list) or not all(isinstance(o, str) and "=" in o for o in overrides):
            raise StudyConfigError(f"tuners.{name}.overrides = {overrides!r} must be a list of key=value strings")
        result.append(Tuner(name, str(ckpt), tuple(overrides),
                            max(robot_trial_counts(cfg)) if name == "dcm" else 0))
    return result


def check_study(cfg: Any) -> None:
    """Check the study's own settings in well under a second (each run's tune settings are checked by tune)."""
    seeds(cfg)
    robot_trial_counts(cfg)
    tuners(cfg)
    _integer(cfg.prior.n_levels, "prior.n_levels", 1)
    _integer(cfg.validation_rollouts, "validation_rollouts", 1)
    ref = cfg.reference_point
    if ref.value is None:
        for key in ("task_factor", "comp_factor"):
            value = ref[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
                raise StudyConfigError(f"reference_point.{key} = {value!r} must be a number > 0")
        _integer(ref.seed, "reference_point.seed", 0)
    if not 0 < float(cfg.alpha) < 1:
        raise StudyConfigError(f"alpha = {cfg.alpha!r} must be in (0, 1)")
    if cfg.get("threads") is not None:
        _integer(cfg.threads, "threads", 1)
    if float(cfg.robot_minutes_per_trial) <= 0:
        raise StudyConfigError(f"robot_minutes_per_trial = {cfg.robot_minutes_per_trial!r} must be > 0")


def _compose_tune() -> Any:
    """The product's ``conf/tune.yaml`` with its defaults, inside a running Hydra app (whose search path holds
    the product's conf dir) or not."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        return compose(config_name="tune")
    with initialize_config_dir(config_dir=str(CONF_DIR)):
        return compose(config_name="tune")


def _apply_override(cfg: Any, item: str, where: str) -> None:
    from omegaconf import OmegaConf

    key = item.split("=", 1)[0].strip()
    missing = object()
    if OmegaConf.select(cfg, key, default=missing) is missing:
        raise StudyConfigError(f"{where}: {key} is not a tune.py setting (conf/tune.yaml)")
    OmegaConf.update(cfg, key, OmegaConf.select(OmegaConf.from_dotlist([item]), key), merge=False)


def tune_config(cfg: Any, tuner: Tuner, seed: int, reference: list[float] | None, out_dir: Path) -> Any:
    """The ``conf/tune.yaml`` config of one (tuner, seed) run of the study (``reference``: its I_H point)."""
    from omegaconf import OmegaConf

    base = OmegaConf.to_container(_compose_tune(), resolve=False)
    base.pop("out_dir", None)  # ${hydra:...}: set below
    base.update(demo=plain(cfg.demo), demo_file=cfg.demo_file, stiffness=plain(cfg.stiffness),
                search=plain(cfg.search), embodiment=cfg.embodiment, domain=plain(cfg.domain),
                control_hz=cfg.control_hz, task_from_s=float(cfg.get("task_from_s", 0.0)), device=cfg.device,
                seed=int(seed), ckpt=tuner.ckpt,
                validation_rollouts=int(cfg.validation_rollouts),
                reference_point=None if reference is None else [float(v) for v in reference], out_dir=str(out_dir))
    base["robot_free"] = {**base["robot_free"], **plain(cfg.robot_free)}
    base["robot_based"] = {**base["robot_based"], "n_trials": tuner.robot_based_trials}
    run_cfg = OmegaConf.create(base)
    for item in tuner.overrides:
        _apply_override(run_cfg, item, f"tuners.{tuner.name}.overrides")
    OmegaConf.set_struct(run_cfg, True)
    return run_cfg


def study_settings(cfg: Any) -> dict[str, Any]:
    """What the study's numbers depend on (seed count and output folder excluded: a study may be extended)."""
    settings = plain(cfg)
    for key in ("seeds", "out_dir", "hydra", "alpha", "robot_minutes_per_trial", "threads"):
        settings.pop(key, None)
    if not settings.get("task_from_s"):  # left out at its default, so folders whose settings lack it still resume
        settings.pop("task_from_s", None)
    return json.loads(json.dumps(settings, default=str))


def check_resume(cfg: Any, out_dir: Path) -> None:
    """Record the study's settings in a new folder; refuse a folder where another study finished runs.

    A folder without a finished run takes the new settings (and forgets its cached reference point), so a
    study that stopped on a bad setting restarts in place once it is fixed; unfinished runs' trial logs are
    still guarded by tune's own fingerprints.
    """
    from dcm.configs import config_diff

    path = out_dir / STUDY_SETTINGS
    settings = study_settings(cfg)
    if path.is_file():
        old = json.loads(path.read_text())
        if old == settings:
            return
        if any((out_dir / "runs").glob("*/*/results.json")):
            raise StudyConfigError(f"{out_dir} holds a study started with other settings: "
                                   + "; ".join(config_diff(old, settings))
                                   + "; use another hydra.run.dir (or out_dir)")
        (out_dir / "reference_point.json").unlink(missing_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(settings, indent=2))
