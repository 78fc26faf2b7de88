"""The settings of a tune run (``conf/tune.yaml``) as typed values, read from the Hydra config once.

Every stage of a run gets the part it needs from :class:`TuneSettings` instead of the whole config. The values
are as given: :func:`dcm.tuning.checks.check_config` refuses the ones that cannot work, naming the setting.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any


@dataclass(frozen=True)
class RobotFreeSettings:
    """``robot_free``: the robot-free search and how the model predicts for it."""

    n_trials: int = 1000
    batch_size: int = 50
    batched_search: bool = True
    n_samples: int = 1
    n_validate: int = 5
    sampler: str | None = "auto"
    sampling_steps: int | None = 3
    precision: str | None = "float32"
    shared_steps: int | str | None = "auto"
    task_loss: str | None = None


@dataclass(frozen=True)
class LoopSettings:
    """``loop``: the robot in the loop (docs/robot_loop.md)."""

    rounds: int = 3
    batch: int = 5
    tolerance_N: float = 0.05
    correction: str = "gp"
    lengthscale: float = 0.5
    noise_ratio: float = 0.1
    ridge_alpha: float = 1.0
    n_trials: int = 300
    bowl_in_base: Any = None  # a 4x4 row-major pose, or None


@dataclass(frozen=True)
class SearchSettings:
    """``search``: the strategy of both searches and its options."""

    name: str = "motpe"
    options: dict[str, Any] | None = None


@dataclass(frozen=True)
class TuneSettings:
    """Every setting of ``conf/tune.yaml``; config groups that other commands share stay mappings (``stiffness``,
    ``demo``, ``domain``)."""

    ckpt: str | None
    demo: dict[str, Any]
    stiffness: dict[str, Any]
    domain: Any  # a preset name or a mapping (dcm.sim.domain.DomainSpec.resolve)
    search: SearchSettings
    robot_free: RobotFreeSettings
    robot_based_n_trials: int = 50
    demo_file: str | None = None
    embodiment: str = "panda"
    control_hz: float = 20.0
    seed: int = 0
    task_from_s: float = 0.0
    objective: Any = None  # conf/objective/: a mapping (dcm.control.objectives.TaskObjective), None = the paper's
    prior: str | None = None
    prior_weight: float = 0.0
    validation_rollouts: int = 1
    robot: str | None = None
    resume: str | None = None
    observations: str | None = None
    loop: LoopSettings | None = None
    reference_point: Any = None  # [L_task_N, L_comp_kNpm] or None
    overwrite: bool = False
    device: str = "auto"
    torch_threads: int | None = None
    source: Any = None  # the config read, which loop/config.yaml stores for resume=

    @classmethod
    def from_config(cls, cfg: Any) -> TuneSettings:
        """Read ``cfg`` (a composed ``conf/tune.yaml``, or a mapping of its keys); absent keys keep the defaults."""
        from omegaconf import OmegaConf

        node = cfg if OmegaConf.is_config(cfg) else OmegaConf.create(cfg)
        missing = OmegaConf.is_missing(node, "ckpt") if "ckpt" in node else True
        # out_dir is left unread: outside a Hydra run it may be an interpolation of Hydra's, and tune gets it apart
        plain = {key: _plain(node, key) for key in node if key != "out_dir" and not (key == "ckpt" and missing)}
        free = plain.pop("robot_free", None) or {}
        loop = plain.pop("loop", None)
        search = plain.pop("search", None) or {}
        based = plain.pop("robot_based", None) or {}
        known = {f.name for f in fields(cls)}
        return cls(ckpt=plain.pop("ckpt", None), demo=plain.pop("demo", None) or {},
                   stiffness=plain.pop("stiffness", None) or {}, domain=plain.pop("domain", None),
                   search=SearchSettings(search.get("name", "motpe"), search.get("options")),
                   robot_free=_only(RobotFreeSettings, free), robot_based_n_trials=based.get("n_trials", 50),
                   loop=None if loop is None else _only(LoopSettings, loop), source=node,
                   **{k: v for k, v in plain.items() if k in known and k != "source"})


def _plain(node: Any, key: str) -> Any:
    from omegaconf import OmegaConf

    value = node[key]
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def _only(kind: type, values: dict[str, Any]) -> Any:
    """``kind`` built from the keys of ``values`` it has (unknown keys of a config are left out)."""
    known = {f.name for f in fields(kind)}
    return kind(**{k: v for k, v in values.items() if k in known})


def as_settings(cfg: Any) -> TuneSettings:
    """``cfg`` as :class:`TuneSettings`: read from a config or mapping, or as it is."""
    return cfg if isinstance(cfg, TuneSettings) else TuneSettings.from_config(cfg)


__all__ = ["LoopSettings", "RobotFreeSettings", "SearchSettings", "TuneSettings", "as_settings"]
