"""The checkpoint file: reading it, what wrote it (model kind, code version), its card, and the slim export.

Every dcm checkpoint is read here, as plain data: ``torch.load(weights_only=True)`` rebuilds tensors and
plain containers only, so a file from elsewhere cannot run code when it is loaded (a pickle can name any
callable). Checkpoints that dcm writes need nothing more, so no type is added to torch's allow-list. A shipped
checkpoint is *slim*: weights, normalisers and hyper-parameters, without the optimiser state, loops and
callbacks a training checkpoint carries (3x the weights), plus a card (``dcm_card``) naming the dataset, the
recipe and what the weights were selected on. The card of a folder of shipped predictors is its README::

    python -m dcm.models.checkpoint card models/      # rewrites models/README.md from the files
"""

from __future__ import annotations

import json
import pickle
import re
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from dcm import __version__
from dcm.console import one_line
from dcm.models.configuration import (
    CheckpointIncompatibleError,
    CheckpointKindError,
    CheckpointUnsafeError,
    CheckpointVersionWarning,
    ModelInputError,
)

KIND_KEY = "dcm_model_kind"  # checkpoint key naming the class that wrote it
VERSION_KEY = "dcm_version"  # checkpoint key naming the code version that wrote it
CARD_KEY = "dcm_card"  # checkpoint key holding the card of an exported checkpoint
KEEP_KEYS = ("pytorch-lightning_version", "state_dict", "hparams_name", "hyper_parameters", KIND_KEY)


def _unpickled(err: pickle.UnpicklingError) -> str:
    """What torch's weights-only reader refused to rebuild, from its message."""
    text = str(err)
    if found := re.search(r"GLOBAL ([\w.]+)", text):
        return found.group(1)
    if found := re.search(r"Unsupported operand (\d+)", text):
        return f"pickle opcode {found.group(1)}"
    return "objects other than tensors and plain containers"


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """A checkpoint's raw dict, read as plain data and checked to be a Lightning checkpoint.

    A file that needs more than plain data raises :class:`CheckpointUnsafeError` without running any of it;
    every error is one line naming ``path``.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelInputError(f"checkpoint {path} does not exist")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        if "weights only" not in str(err).lower():
            raise ModelInputError(f"checkpoint {path} is not readable: {one_line(err)}") from err
        raise CheckpointUnsafeError(f"{path}: not a plain-data dcm checkpoint (would unpickle {_unpickled(err)}); "
                                    "refusing to load it") from None
    except Exception as err:  # noqa: BLE001 - a truncated or foreign file: not a usable checkpoint
        raise ModelInputError(f"checkpoint {path} is not readable: {one_line(err)}") from err
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise ModelInputError(f"checkpoint {path} is not a Lightning checkpoint (no state_dict)")
    return ckpt


def _checkpoint_kind(path: str | Path) -> tuple[str | None, dict[str, Any]]:
    """The model kind and hyper-parameters stored in a checkpoint, without building the model."""
    ckpt = read_checkpoint(path)
    return ckpt.get(KIND_KEY), dict(ckpt.get("hyper_parameters") or {})


def checkpoint_kind(path: str | Path) -> str:
    """The model kind a checkpoint was written by; raises if it is not a dcm force-model checkpoint."""
    kind, _ = _checkpoint_kind(path)
    if kind is None:
        raise CheckpointKindError(f"checkpoint {path} was not written by a dcm force model (no model kind)")
    return str(kind)


def check_code_version(path: str | Path, written_by: str | None) -> None:
    """Warn when a checkpoint comes from another dcm version: it loads, but its numbers may differ."""
    if written_by != __version__:
        warnings.warn(f"checkpoint {path} was written by dcm {written_by or '(unknown, before 0.2.0)'}; "
                      f"this is dcm {__version__}", CheckpointVersionWarning, stacklevel=3)


def _incompatible(path: str | Path, written_by: str | None, err: RuntimeError) -> CheckpointIncompatibleError:
    """A clear error for parameter names that changed between code versions."""
    text = str(err)
    labels = {"Missing key(s)": "missing", "Unexpected key(s)": "unexpected"}
    names = [f"{labels[label]} {part.split(':', 1)[1].strip().rstrip('.')}" for part in text.split("\n\t")
             for label in labels if part.startswith(label)]
    detail = "; ".join(names)[:300] or one_line(text)[:300]
    return CheckpointIncompatibleError(
        f"checkpoint {path} (dcm {written_by or 'unknown'}) does not fit this code (dcm {__version__}): "
        f"parameter names changed: {detail}. Retrain, or load it with the dcm version that wrote it")


def checkpoint_card(path: str | Path) -> dict[str, Any]:
    """The card stored in an exported checkpoint ({} for a training checkpoint), with its kind and version."""
    raw = read_checkpoint(path)
    return {"kind": raw.get(KIND_KEY), "dcm_version": raw.get(VERSION_KEY), **(raw.get(CARD_KEY) or {})}


def export_checkpoint(source: str | Path, out: str | Path, card: dict[str, Any] | None = None,
                      verify: Callable[[Path], Any] | None = None) -> Path:
    """Write the slim checkpoint of the checkpoint ``source`` to ``out``, stamped with this code's version and
    carrying ``card``.

    ``verify(source)`` should build the model with this code (the export command passes
    :func:`dcm.models.predict.load_model`, which refuses parameter names the code does not know), so that
    the stamped version is one known to load the weights. It is passed in because this module sits below
    the model classes.
    """
    source, out = Path(source), Path(out)
    raw = read_checkpoint(source)
    if verify is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CheckpointVersionWarning)  # the card records the writer's version
            verify(source)
    slim = {key: raw[key] for key in KEEP_KEYS if key in raw}
    slim[VERSION_KEY] = __version__
    slim[CARD_KEY] = {**(card or {}), "exported_from": {"checkpoint": source.name,
                                                        "written_by_dcm": raw.get(VERSION_KEY)}}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    torch.save(slim, tmp)
    tmp.replace(out)
    return out


# ----------------------------------------------------------------------------------------------- the card
NOT_SHIPPED = "## Not shipped, reproducible"  # the README's hand-written part starts here; the card keeps it


def _number(value: Any) -> str:
    return "–" if value is None or value != value else f"{value:.3f}"  # value != value: nan


def _distill_command(path: Path, card: dict[str, Any]) -> str:
    """The ``dcm-distill`` command of a one-step student's card, its settings as options."""
    distilled, data = card["distilled"], card.get("dataset") or {}
    options = [f"--{k.replace('_', '-')} {distilled[k]}" for k in ("draws", "teacher_steps", "epochs", "batch_size",
                                                                   "lr", "seed") if k in distilled]
    return " ".join(["dcm-distill", f"{path.parent.name}/{distilled.get('teacher')}", f"data/{data.get('path')}",
                     f"--out {path.parent.name}/{path.name}", *options])


def _checkpoint_row(path: Path) -> str:
    card = checkpoint_card(path)
    data = card.get("dataset") or {}
    selected = card.get("selected_on") or {}
    kind, recipe = f"{card.get('kind')} ({card.get('stage')})", f"`{card.get('train_command')}`"
    selection = f"{selected.get('monitor')} = {_number(selected.get('value'))} at `{selected.get('checkpoint')}`"
    if card.get("distilled"):  # a one-step student: the teacher's recipe, then its distillation
        kind, recipe = f"{card.get('kind')}, one-step student", f"{recipe}, then `{_distill_command(path, card)}`"
        selection = f"the teacher's {selection}{_own_valid_ranking(card)}"
    return (f"| `{path.name}` | {kind} | `{data.get('path')}` ({data.get('plan_fingerprint')}), "
            f"{card.get('n_train_used')} trajectories | {recipe} | {selection} |")


def _own_valid_ranking(card: dict[str, Any]) -> str:
    """A student is not selected itself, so its row quotes its own valid evaluation beside the teacher's
    selection: a user comparing rows must not read the teacher's figure as the student's."""
    for name, metrics in sorted((card.get("evaluations") or {}).items()):
        if "valid" in name and "R_within" in metrics:
            return f"; its own R_within on valid {_number(metrics['R_within'])} (`{name}`)"
    return "; no evaluation of its own"


def _reference_row(path: Path) -> str:
    data = json.loads(path.read_text())
    fit = data.get("fit") or {}
    dataset = fit.get("dataset") or {}
    name = Path(str(dataset.get("path"))).name
    options = [f"--split {fit['split']}"] if fit.get("split", "train") != "train" else []
    options += [] if fit.get("cv") else [f"--alpha {fit.get('alpha'):g}"]
    options += [f"--task-from-s {fit['task_from_s']:g}"] if fit.get("task_from_s") else []
    command = " ".join(["python -m dcm.models.references fit", f"--dataset data/{name}",
                        f"--out {path.parent.name}/{path.name}", *options])
    cv = fit.get("cv") or {}
    selected = (f"alpha = {fit.get('alpha'):g} by {cv.get('n_folds')}-fold grouped cross-validation on "
                f"{fit.get('split')}" if cv else "least squares, alpha given")
    return (f"| `{path.name}` | {data.get('kind')} (format {data.get('version')}) | `{name}` "
            f"({(dataset.get('attrs') or {}).get('plan_fingerprint')}), {fit.get('n_trajectories')} trajectories | "
            f"`{command}` | {selected} |")


def card_markdown(folder: str | Path) -> str:
    """The README of a folder of shipped predictors, from the files alone: a row per checkpoint (its card)
    and per reference JSON (its fit record), then the README's hand-written part from ``NOT_SHIPPED`` on."""
    folder = Path(folder)
    lines = ["# Shipped predictors", "",
             f"Written by `python -m dcm.models.checkpoint card {folder.name}/` from the files' own records. "
             "A checkpoint is the run's selected checkpoint (on the validation split), exported with "
             "`python -m dcm.training.export <run_dir> --out <file>`; a one-step student is its teacher's, "
             "distilled with `dcm-distill` (the selection is the teacher's).", "",
             "| file | kind | trained on (plan fingerprint) | recipe | selected on |", "|---|---|---|---|---|"]
    lines += [_checkpoint_row(path) for path in sorted(folder.glob("*.ckpt"))]
    lines += [_reference_row(path) for path in sorted(folder.glob("*.json"))]
    text = "\n".join(lines) + "\n"
    readme = folder / "README.md"
    kept = readme.read_text().partition(NOT_SHIPPED) if readme.is_file() else ("", "", "")
    return text + ("\n" + kept[1] + kept[2] if kept[1] else "")


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or args[0] != "card" or not Path(args[1]).is_dir():
        print(f"usage: python -m dcm.models.checkpoint card <folder of shipped predictors>; got {args}",
              file=sys.stderr)
        return 1
    readme = Path(args[1]) / "README.md"
    readme.write_text(card_markdown(args[1]))
    print(f"wrote {readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["CARD_KEY", "KEEP_KEYS", "KIND_KEY", "NOT_SHIPPED", "VERSION_KEY", "CheckpointUnsafeError", "card_markdown",
           "check_code_version", "checkpoint_card", "checkpoint_kind", "export_checkpoint", "read_checkpoint"]
