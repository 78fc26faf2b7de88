"""The run directory: what train writes and every other tool (export, studies, model tables) reads.

    <run_dir>/config.yaml      the resolved config that trained; resume and re-runs compare against it
    <run_dir>/summary.json     written last, so it marks a run that has ended; names the selected checkpoint
    <run_dir>/checkpoints/     best.ckpt, the selected checkpoint under a name that does not change;
                               last.ckpt (every epoch, what resume continues); the top-k on checkpoint.monitor
    <run_dir>/tb/              TensorBoard logs
    <run_dir>/.hydra/          Hydra's record of the command (overrides.yaml)

The names live here only, so a change of format is one edit.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.json"
CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.ckpt"
BEST_CHECKPOINT = "best.ckpt"
LAST_CHECKPOINT_STEM = "last"  # Lightning's ModelCheckpoint takes the name without its suffix
TB_DIR = "tb"
OVERRIDES_FILE = Path(".hydra") / "overrides.yaml"
EVALUATION_GLOB = "eval_*.json"  # evaluations of the run's checkpoints, cached beside them by the study tools


def config_path(run_dir: Path) -> Path:
    return Path(run_dir) / CONFIG_FILE


def summary_path(run_dir: Path) -> Path:
    return Path(run_dir) / SUMMARY_FILE


def checkpoint_dir(run_dir: Path) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR


def last_checkpoint(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / LAST_CHECKPOINT


def best_checkpoint(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / BEST_CHECKPOINT


def publish_best(run_dir: Path, selected: Path) -> Path:
    """Copy the selected checkpoint to best.ckpt (atomically), the one path the guides and tools name."""
    import shutil

    best = best_checkpoint(run_dir)
    if Path(selected).resolve() != best.resolve():
        tmp = best.with_name(best.name + ".tmp")
        shutil.copyfile(selected, tmp)
        tmp.replace(best)
    return best


def write_config(run_dir: Path, config: Mapping[str, Any]) -> Path:
    """Save the resolved config of a run (plain YAML, no Hydra interpolations left)."""
    from omegaconf import OmegaConf

    path = config_path(run_dir)
    OmegaConf.save(OmegaConf.create(dict(config)), path)
    return path


def read_config(run_dir: Path) -> dict[str, Any]:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(config_path(run_dir)))  # type: ignore[return-value]


def write_summary(run_dir: Path, summary: Mapping[str, Any]) -> Path:
    """Write summary.json; train writes it last, when the run has ended."""
    path = summary_path(run_dir)
    path.write_text(json.dumps(dict(summary), indent=2, sort_keys=True) + "\n")
    return path


def read_summary(run_dir: Path) -> dict[str, Any]:
    return json.loads(summary_path(run_dir).read_text())


def run_finished(run_dir: Path) -> bool:
    """Whether a run has ended: summary.json is written last, so a run still training or killed has none."""
    return summary_path(run_dir).is_file()


def run_checkpoint(run_dir: Path) -> Path:
    """The checkpoint a finished run selected (on its monitor); the last one of a run without a selection.

    summary.json stores the selection's absolute path; a run directory that was moved or copied still holds it
    under the same name. A selection that cannot be found is an error, never its last checkpoint instead.
    """
    if run_finished(run_dir) and (best := read_summary(run_dir).get("best_checkpoint")):
        for candidate in (Path(best), checkpoint_dir(run_dir) / Path(best).name):
            if candidate.is_file():
                return candidate
        raise FileNotFoundError(f"{run_dir}: {SUMMARY_FILE} names the selected checkpoint {best}, which is neither "
                                f"there nor in {CHECKPOINT_DIR}/")
    last = last_checkpoint(run_dir)
    if not last.is_file():
        raise FileNotFoundError(f"{run_dir}: no {SUMMARY_FILE} best_checkpoint and no "
                                f"{CHECKPOINT_DIR}/{LAST_CHECKPOINT}")
    return last


def run_overrides(run_dir: Path) -> list[str]:
    """The command-line overrides the run was started with (Hydra's record; [] without one)."""
    path = Path(run_dir) / OVERRIDES_FILE
    if not path.is_file():
        return []
    return [line[2:].strip() for line in path.read_text().splitlines() if line.startswith("- ")]


def _dataset_identity(path: str | None) -> dict[str, Any]:
    """Name, plan fingerprint and size of the dataset a run trained on (what regenerates it)."""
    if not path or not Path(path).is_file():
        return {"path": path, "available": False}

    from dcm.data.recording import stored_recording
    from dcm.data.schema import read_root_attrs

    root = read_root_attrs(path)
    attrs = {key: root[key] for key in ("dataset", "plan_fingerprint", "embodiment", "seed", "n_trajectories_total",
                                        "dcm_version") if key in root}
    identity = {"path": Path(path).name, **{k: v.item() if hasattr(v, "item") else str(v) for k, v in attrs.items()}}
    if (recorded := stored_recording(root, path)) is not None:
        identity["recording"] = recorded
    return identity


def run_card(run_dir: Path) -> dict[str, Any]:
    """The card of a run: config, overrides, dataset identity and the metrics it logged."""
    summary = read_summary(run_dir)
    selected = str(run_checkpoint(run_dir).resolve())
    evaluations = {path.stem: data for path in sorted(Path(run_dir).glob(EVALUATION_GLOB))
                   if (data := json.loads(path.read_text())).get("ckpt") == selected}  # of these very weights
    config = config_path(run_dir)
    return {
        "model": summary.get("model"),
        "stage": summary.get("stage"),
        "seed": summary.get("seed"),
        "epochs": summary.get("epochs"),
        "global_step": summary.get("global_step"),
        "selected_on": {"monitor": summary.get("monitor"), "value": summary.get("best_score"),
                        "checkpoint": summary.get("selected_from") or Path(str(summary.get("best_checkpoint"))).name},
        "train_command": "python train.py " + " ".join(o for o in run_overrides(run_dir)
                                                       if not o.startswith("hydra.")),
        "dataset": _dataset_identity(summary.get("dataset")),
        "n_train_used": summary.get("n_train_used"),
        "test_metrics": summary.get("test"),
        "evaluations": evaluations,
        "config": config.read_text() if config.is_file() else None,
    }


__all__ = ["BEST_CHECKPOINT", "CHECKPOINT_DIR", "CONFIG_FILE", "EVALUATION_GLOB", "LAST_CHECKPOINT",
           "LAST_CHECKPOINT_STEM", "OVERRIDES_FILE", "SUMMARY_FILE", "TB_DIR", "best_checkpoint", "checkpoint_dir",
           "config_path", "last_checkpoint", "publish_best", "read_config", "read_summary", "run_card",
           "run_checkpoint", "run_finished", "run_overrides", "summary_path", "write_config", "write_summary"]
