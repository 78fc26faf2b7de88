"""Slim, self-describing checkpoints to ship: weights, normalisers and hyper-parameters plus a model card.

    python -m dcm.training.export outputs/train/<run> models/dcm_sim.ckpt

A training checkpoint also carries the optimiser state, loops and callbacks (3x the weights); a user who
predicts, tunes or fine-tunes needs none of it. The export loads the run's selected checkpoint with this
code (strict parameter names), so the stamped ``dcm_version`` is one that is known to load it, and stores a
card (``dcm_card``): the dataset and its plan fingerprint, the training overrides and config, and the
run's metrics. :func:`checkpoint_card` reads it back without building the model.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

import torch

from dcm import __version__
from dcm.models.configuration import CheckpointVersionWarning, ModelInputError
from dcm.models.dcm import KIND_KEY, VERSION_KEY, read_checkpoint
from dcm.training.run_dir import run_card, run_checkpoint

CARD_KEY = "dcm_card"
KEEP_KEYS = ("pytorch-lightning_version", "state_dict", "hparams_name", "hyper_parameters", KIND_KEY)


def export_checkpoint(source: Path, out: Path, card: dict[str, Any] | None = None) -> Path:
    """Write the slim checkpoint of ``source`` (a .ckpt, or a run directory: its selected checkpoint)."""
    from dcm.models.predict import load_model

    if source.is_dir():
        card = {**run_card(source), **(card or {})}
        source = run_checkpoint(source)
    raw = read_checkpoint(source)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CheckpointVersionWarning)  # recorded below instead
        load_model(source)  # strict: refuses parameter names this code does not know
    slim = {key: raw[key] for key in KEEP_KEYS if key in raw}
    slim[VERSION_KEY] = __version__
    slim[CARD_KEY] = {**(card or {}), "exported_from": {"checkpoint": source.name,
                                                        "written_by_dcm": raw.get(VERSION_KEY)}}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    torch.save(slim, tmp)
    tmp.replace(out)
    return out


def checkpoint_card(path: str | Path) -> dict[str, Any]:
    """The card stored in an exported checkpoint ({} for a training checkpoint), with its kind and version."""
    raw = read_checkpoint(path)
    return {"kind": raw.get(KIND_KEY), "dcm_version": raw.get(VERSION_KEY), **(raw.get(CARD_KEY) or {})}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", type=Path, help="a train.py run directory (its selected checkpoint) or a .ckpt")
    parser.add_argument("out", type=Path, help="the slim checkpoint to write")
    parser.add_argument("--name", help="a short name stored in the card (e.g. dcm_sim)")
    args = parser.parse_args(argv)
    try:
        out = export_checkpoint(args.source, args.out, {"name": args.name or args.out.stem})
    except (ModelInputError, OSError) as err:
        print(f"error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["CARD_KEY", "checkpoint_card", "export_checkpoint", "run_card", "run_checkpoint"]
