"""The runs of one study sweep (``python train.py -m --config-dir studies/conf +experiment=<study>``): their
settings, seeds and spec.

A run's setting is what its overrides (``.hydra/overrides.yaml``) change, except the seed; its value for a
key is read from the resolved ``config.yaml`` (``model.diffusion_steps`` = 30) or, for a config group, from
Hydra's choices (``model`` = ``dcm``). The study spec (x axis, series, comparison, metrics) comes from the
experiment's ``study:`` block, which every run saves in its config.yaml.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dcm.training.run_dir import run_finished

# overrides that never define a setting: the seed (aggregated over), the experiment itself, and paths
NOT_SETTINGS = ("seed", "experiment", "data.path", "init_from", "resume", "trainer.max_time")
DEFAULT_METRICS = ("L_MSE", "force_rmse_N", "R_within", "R_pooled")
INIT_STAGE = "pretrain"  # the x value of an init_from checkpoint scored as it is (no fine-tuning)


class StudyError(ValueError):
    """A sweep directory or run that cannot be reported; the message names the path and what is wrong."""


@dataclass
class Run:
    """One train.py run of a sweep (or an init_from checkpoint scored as it is)."""

    path: Path
    seed: int
    overrides: dict[str, str]
    config: dict[str, Any]
    choices: dict[str, str] = field(default_factory=dict)
    finished: bool = True

    def value(self, key: str) -> Any:
        """The run's setting for ``key``: a config value, else a config-group choice, else the override text."""
        node: Any = self.config
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node is not None and not isinstance(node, (dict, list)):
            return node
        return self.choices.get(key, self.overrides.get(key))

    @property
    def dataset(self) -> Path:
        return Path(self.config["data"]["path"])


@dataclass
class StudySpec:
    """What a study plots and tests (the ``study:`` block of studies/conf/experiment/<study>.yaml)."""

    name: str
    title: str
    x: str
    series: str | None = None
    log_x: bool = False
    # Welch tests to run: (key, against) pairs, each cell tested against the cell that differs only in key
    comparisons: tuple[tuple[str, Any], ...] = ()
    metrics: tuple[str, ...] = DEFAULT_METRICS
    evaluate_init: bool = False


def _read_yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise StudyError(f"{path}: cannot read ({err})") from None


def parse_override(line: str) -> tuple[str, str]:
    """``+experiment=x`` -> ``("experiment", "x")``; ``~key`` (a deletion) -> ``("key", "")``."""
    key, _, value = line.partition("=")
    return key.lstrip("+~"), value


def read_run(path: Path) -> Run:
    """A run directory written by train.py under Hydra (``.hydra/overrides.yaml`` and ``config.yaml``)."""
    overrides = dict(parse_override(str(o)) for o in _read_yaml(path / ".hydra" / "overrides.yaml") or [])
    config_file = path / "config.yaml"
    config = _read_yaml(config_file) if config_file.is_file() else {}
    hydra_file = path / ".hydra" / "hydra.yaml"
    hydra = _read_yaml(hydra_file) if hydra_file.is_file() else {}
    choices = {k: str(v) for k, v in ((hydra or {}).get("hydra", {}).get("runtime", {}).get("choices") or {}).items()
               if "/" not in k}
    seed = overrides.get("seed", (config or {}).get("seed", 0))
    return Run(path=path, seed=int(seed), overrides={k: v for k, v in overrides.items() if k not in NOT_SETTINGS},
               config=config or {}, choices=choices, finished=run_finished(path))


def find_runs(sweep_dir: Path) -> list[Run]:
    """Every run directory of a sweep (those holding ``.hydra/overrides.yaml``), finished or not."""
    if not sweep_dir.is_dir():
        raise StudyError(f"{sweep_dir}: no such sweep directory "
                         "(run `python train.py -m --config-dir studies/conf +experiment=<study>` first)")
    dirs = sorted(d for d in sweep_dir.iterdir() if (d / ".hydra" / "overrides.yaml").is_file())
    if not dirs:
        raise StudyError(f"{sweep_dir}: no train.py run directory in it (none holds .hydra/overrides.yaml)")
    return [read_run(d) for d in dirs]


def study_spec(runs: list[Run]) -> StudySpec:
    """The spec saved in the runs' config; a plain sweep without one plots its first varying override.

    Runs launched before the experiment's ``study:`` block was edited keep the old one; the newest run's wins."""
    with_block = [r for r in runs if isinstance(r.config.get("study"), dict)]
    newest = max(with_block, key=lambda r: (r.path / "config.yaml").stat().st_mtime_ns, default=None)
    block = newest.config["study"] if newest else None
    if block is None:
        varying = varying_keys(runs)
        if not varying:
            raise StudyError(f"{runs[0].path.parent}: no study block in config.yaml and no override varies "
                             "besides the seed: nothing to compare")
        return StudySpec(name=runs[0].path.parent.name, title=f"Sweep over {', '.join(varying)}", x=varying[0],
                         series=varying[1] if len(varying) > 1 else None)
    compare = block.get("compare") or []
    compare = [compare] if isinstance(compare, dict) else compare
    if not all(isinstance(c, dict) and "key" in c and "against" in c for c in compare):
        raise StudyError(f"{newest.path / 'config.yaml'}: study.compare must be {{key: ..., against: ...}} or a "
                         f"list of them, got {block.get('compare')!r}")
    return StudySpec(name=str(block.get("name", runs[0].path.parent.name)), title=str(block.get("title", "")),
                     x=str(block["x"]), series=block.get("series"), log_x=bool(block.get("log_x", False)),
                     comparisons=tuple((str(c["key"]), c["against"]) for c in compare),
                     metrics=tuple(block.get("metrics") or DEFAULT_METRICS),
                     evaluate_init=bool(block.get("evaluate_init", False)))


def reference_values(comparisons: Any) -> dict[str, Any]:
    """Per compared key, the value its first comparison tests against (drawn and listed first)."""
    first: dict[str, Any] = {}
    for key, against in comparisons:
        first.setdefault(key, against)
    return first


def varying_keys(runs: list[Run]) -> list[str]:
    """Override keys (seed aside) whose value is not the same in every run, in first-seen order."""
    keys = list(dict.fromkeys(k for r in runs for k in r.overrides))
    return [k for k in keys if len({str(r.overrides.get(k)) for r in runs}) > 1]


def setting_keys(spec: StudySpec, runs: list[Run]) -> list[str]:
    """The keys that tell cells apart: the study's x and series, then any other varying override."""
    keys = [k for k in (spec.series, spec.x) if k]
    return keys + [k for k in varying_keys(runs) if k not in keys]


def init_runs(runs: list[Run], sweep_dir: Path) -> list[Run]:
    """The distinct ``init_from`` checkpoints of the finished runs, as runs to score without fine-tuning.

    Each gets a folder ``<sweep>/init/<model>_<name>_<hash>/`` whose summary.json names the checkpoint, so
    its evaluations are cached there like a run's."""
    found: dict[tuple[str, str], Run] = {}
    for run in runs:
        ckpt = run.config.get("init_from")
        if not run.finished or not ckpt:
            continue
        model = str(run.value("model"))
        if (model, ckpt) in found:
            continue
        digest = hashlib.sha1(str(ckpt).encode()).hexdigest()[:8]
        folder = sweep_dir / "init" / f"{model}_{Path(ckpt).stem}_{digest}"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "summary.json").write_text(json.dumps({"best_checkpoint": str(ckpt), "stage": INIT_STAGE,
                                                         "model": model}, indent=2) + "\n")
        config = {"stage": INIT_STAGE, "data": run.config["data"], "init_checkpoint": str(ckpt)}
        seed = sum(1 for m, _ in found if m == model)
        found[(model, ckpt)] = Run(path=folder, seed=seed, overrides={}, config=config, choices={"model": model})
    return list(found.values())
