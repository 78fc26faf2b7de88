"""Acceptance of the shipped predictors on skills they never trained on, beside the references.

    make acceptance                                  # generates the files below once, then runs this module
    python -m studies.acceptance.acceptance [--models models] [--datasets data/test_wavelike.h5:test ...]

For each dataset split it scores every shipped force model (with its own sampler, and with DDIM-5, which is
what tune.py uses), every shipped stiffness ridge, and copy-F_demo, and writes
studies/acceptance/reports/acceptance.md. A predictor is scored only on files whose demos were recorded as
its training demos were (duration, leading demonstrator, the bowl grid a preset sets for all its bowls: the
preset its card names); one trained on a dataset without a preset is scored on every file. The target is
the DCM's within-skill R >= 0.85; the check prints whether it is met and never fails on it.
"""

from __future__ import annotations

import argparse
import functools
import platform
import sys
import time
from pathlib import Path

from dcm.data.recording import Recording, file_recording
from dcm.evaluate import evaluate
from dcm.models.checkpoint import checkpoint_card
from dcm.models.predict import trained_recording as predictor_recording
from studies.model_study.model_table import INTERVAL, cell, interval_cell

REPO = Path(__file__).resolve().parents[2]
REPORT = Path(__file__).resolve().parent / "reports" / "acceptance.md"

TARGET_R_WITHIN = 0.85
DATASETS = ("data/test_wavelike.h5:test", "data/acceptance.h5:test",  # 8 s demos (the *_sim, *_diverse files)
            "data/test_wavelike_contact.h5:test", "data/test_line_contact.h5:test",  # 12 s, leading demonstrator
            "data/acceptance_contact.h5:test",
            "data/test_wavelike_fine.h5:test", "data/test_line_fine.h5:test",  # the same on a 192 x 192 bowl grid
            "data/acceptance_fine.h5:test")
COLUMNS = ("R_within", INTERVAL, "R_within_spearman", "R_pooled", "force_rmse_N", "force_rmse_ratio_copy")


@functools.cache
def trained_recording(path: Path) -> Recording | None:
    """The recording of a predictor's training demos, read once per predictor for all the datasets."""
    return predictor_recording(path)


def _cells(row: dict) -> str:
    return " | ".join(interval_cell([row]) if key == INTERVAL else cell([row.get(key)]) for key in COLUMNS)


def acceptance_rows(models: Path, dataset: Path, split: str) -> tuple[list[str], dict[str, float]]:
    """Markdown rows for one dataset split, and each pre-trained DCM's R within skill per sampler."""
    here = file_recording(dataset)

    def matching(paths: list[Path]) -> list[Path]:
        return [p for p in paths if trained_recording(p) in (here, None)]

    ridges = matching(sorted(models.glob("stiffness_ridge_*.json")))
    rows, dcm_scores = [], {}
    result = None
    for ckpt in matching(sorted(models.glob("*.ckpt"))):
        card = checkpoint_card(ckpt)  # what the file holds, whatever it is named
        is_dcm = card.get("kind") == "dcm"
        for sampler, steps in ((None, None), ("ddim", 5)) if is_dcm else ((None, None),):
            # a shipped ridge as the reference, so evaluate() does not fit one (acceptance sets have no train split)
            result = evaluate(ckpt, dataset, split=split, reference=ridges[0] if ridges else None,
                              sampler=sampler, sampling_steps=steps)
            label = f"`{ckpt.name}` ({result['sampler']} {result['sampling_steps']})"
            rows.append(f"| {label} | {_cells(result)} |")
            if is_dcm and card.get("stage") == "pretrain":
                dcm_scores[label] = result["R_within"]
    if result is not None:
        rows.append(f"| copy_demo (reference) | {_cells(result['references']['copy_demo'])} |")
    for ridge in ridges:  # each shipped ridge, named: they differ in the data they were fitted on
        rows.append(f"| `{ridge.name}` (reference) | {_cells(evaluate(ridge, dataset, split=split))} |")
    header = (f"\n### `{dataset.name}`, {split} split: {result['n'] if result else 0} trials, "
              f"{result['n_skills'] if result else 0} skills, {here.describe()}\n\n"
              "| predictor | R within | R within: 90 % interval | Spearman within | R pooled | force RMSE [N] "
              "| ÷ copy-F_demo |\n|---|---|---|---|---|---|---|")
    return [header, *rows], dcm_scores


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=Path, default=REPO / "models")
    parser.add_argument("--datasets", nargs="+", default=list(DATASETS), help="dataset:split pairs")
    parser.add_argument("--out", type=Path, default=REPORT)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    lines = ["# Acceptance: the shipped predictors on skills they never trained on", "",
             f"`python -m studies.acceptance.acceptance` on {platform.node() or 'this machine'} ({platform.machine()}, "
             f"{__import__('os').cpu_count()} cores). Target: the DCM's R within skill >= {TARGET_R_WITHIN}. "
             "copy-F_demo predicts L_task = 0 for every schedule: it has no ranking, only a force error."]
    verdicts = []
    for pair in args.datasets:
        name, _, split = pair.partition(":")
        dataset = Path(name) if Path(name).is_absolute() else REPO / name
        if not dataset.is_file():
            print(f"error: {dataset} does not exist; see this module's docstring for the command that makes it",
                  file=sys.stderr)
            return 1
        rows, scores = acceptance_rows(args.models, dataset, split or "test")
        lines += rows
        verdicts += [f"- `{dataset.name}` {split}: {label} R within {value:.3f}: "
                     f"{'met' if value >= TARGET_R_WITHIN else 'NOT met'}" for label, value in scores.items()]
    lines += ["", "## Target", "", *verdicts, "", f"Scoring took {time.perf_counter() - start:.0f} s."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(verdicts))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
