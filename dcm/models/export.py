"""Export a train.py run as a slim, self-describing checkpoint to ship (its format: dcm.models.checkpoint).

    python -m dcm.models.export outputs/train/<run> models/dcm_diverse_contact.ckpt

The export loads the run's selected checkpoint with this code (strict parameter names), so the stamped
``dcm_version`` is one that is known to load it, and stores a card (``dcm_card``): the dataset and its plan
fingerprint, the training overrides and config, and the run's metrics.
:func:`dcm.models.checkpoint.checkpoint_card` reads it back without building the model.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from dcm.models.checkpoint import export_checkpoint
from dcm.models.configuration import ModelInputError
from dcm.models.predict import load_model


def _dataset_identity(path: str | None) -> dict[str, Any]:
    """Name, plan fingerprint and size of the dataset a run trained on (what regenerates it)."""
    if not path or not Path(path).is_file():
        return {"path": path, "available": False}
    import h5py

    with h5py.File(path, "r") as f:
        attrs = {key: f.attrs[key] for key in ("dataset", "plan_fingerprint", "embodiment", "seed",
                                               "n_trajectories_total", "dcm_version") if key in f.attrs}
    return {"path": Path(path).name, **{k: v.item() if hasattr(v, "item") else str(v) for k, v in attrs.items()}}


def run_finished(run_dir: Path) -> bool:
    """Whether a train.py run has ended: it writes summary.json last, so a run still training or killed has none."""
    return (run_dir / "summary.json").is_file()


def run_checkpoint(run_dir: Path) -> Path:
    """The checkpoint a train.py run selected (on its monitor), or its last one."""
    summary = run_dir / "summary.json"
    if summary.is_file():
        best = json.loads(summary.read_text()).get("best_checkpoint")
        if best and Path(best).is_file():
            return Path(best)
    last = run_dir / "checkpoints" / "last.ckpt"
    if not last.is_file():
        raise FileNotFoundError(f"{run_dir}: no summary.json best_checkpoint and no checkpoints/last.ckpt")
    return last


def run_card(run_dir: Path) -> dict[str, Any]:
    """The card of a train.py run: config, overrides, dataset identity and the metrics it logged."""
    summary = json.loads((run_dir / "summary.json").read_text())
    overrides_file = run_dir / ".hydra" / "overrides.yaml"
    overrides = [line[2:].strip() for line in overrides_file.read_text().splitlines() if line.startswith("- ")] \
        if overrides_file.is_file() else []
    selected = str(run_checkpoint(run_dir).resolve())
    evaluations = {path.stem: data for path in sorted(run_dir.glob("eval_*.json"))
                   if (data := json.loads(path.read_text())).get("ckpt") == selected}  # of these very weights
    return {
        "model": summary.get("model"),
        "stage": summary.get("stage"),
        "seed": summary.get("seed"),
        "epochs": summary.get("epochs"),
        "global_step": summary.get("global_step"),
        "selected_on": {"monitor": summary.get("monitor"), "value": summary.get("best_score"),
                        "checkpoint": Path(str(summary.get("best_checkpoint"))).name},
        "train_command": "python train.py " + " ".join(o for o in overrides if not o.startswith("hydra.")),
        "dataset": _dataset_identity(summary.get("dataset")),
        "n_train_used": summary.get("n_train_used"),
        "test_metrics": summary.get("test"),
        "evaluations": evaluations,
        "config": (run_dir / "config.yaml").read_text() if (run_dir / "config.yaml").is_file() else None,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", type=Path, help="a train.py run directory (its selected checkpoint) or a .ckpt")
    parser.add_argument("out", type=Path, help="the slim checkpoint to write")
    parser.add_argument("--name", help="a short name stored in the card (e.g. dcm_sim)")
    args = parser.parse_args(argv)
    try:
        source, card = args.source, {"name": args.name or args.out.stem}
        if source.is_dir():
            card, source = {**run_card(source), **card}, run_checkpoint(source)
        out = export_checkpoint(source, args.out, card, verify=load_model)
    except (ModelInputError, OSError) as err:
        print(f"error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["run_card", "run_checkpoint", "run_finished"]
