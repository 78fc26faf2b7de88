"""The model card of a folder of shipped predictors: what each was trained on, how, and how well it ranks.

    python -m dcm.models.model_card models/ > models/README.md

It reads only the files: the card each exported checkpoint carries (:mod:`dcm.models.export`) and the fit
record of each stiffness reference JSON, so the card cannot drift from what is shipped.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

from dcm.models.export import checkpoint_card

METRICS = (("R_within", "R within skill"), ("R_within_spearman", "Spearman within"),
           ("force_rmse_ratio_copy", "force RMSE ÷ copy-F_demo"))


def _number(value: Any) -> str:
    return "–" if value is None or value != value else f"{value:.3f}"  # value != value: nan (too few trials)


def _evaluation_rows(name: str, evaluations: dict[str, Any]) -> list[str]:
    rows = []
    for key, result in sorted(evaluations.items()):
        tag = key.removeprefix("eval_")
        cells = [_number(result.get(metric)) for metric, _ in METRICS]
        refs = result.get("references") or {}
        ref_cells = [_number((refs.get("stiffness_ridge") or {}).get("R_within"))]
        settings = (f"{result.get('sampler')}, {result.get('sampling_steps')} steps, k={result.get('n_samples')}"
                    if result.get("model") == "dcm" else "one pass")
        rows.append(f"| {name} | {tag} ({result.get('n')} trials, {result.get('n_skills')} skills) | {settings} | "
                    + " | ".join(cells + ref_cells) + " |")
    return rows


def card_markdown(folder: Path) -> str:
    """Markdown describing every .ckpt and reference .json in ``folder``."""
    lines = ["# Shipped predictors", "",
             f"Written by `python -m dcm.models.model_card {folder.name}/`; every number comes from the files' own "
             "records (the training run's selected checkpoint, evaluated with `python -m dcm.evaluate`).", "",
             "| file | kind | MB | dcm | trained on (plan fingerprint) | trajectories used | command | selected on |",
             "|---|---|---|---|---|---|---|---|"]
    metric_rows: list[str] = []
    for path in sorted(folder.glob("*.ckpt")):
        card = checkpoint_card(path)
        data = card.get("dataset") or {}
        selected = card.get("selected_on") or {}
        lines.append(
            f"| `{path.name}` | {card.get('kind')} ({card.get('stage')}) | {path.stat().st_size / 1e6:.1f} | "
            f"{card.get('dcm_version')} | `{data.get('path')}` ({data.get('plan_fingerprint')}) | "
            f"{card.get('n_train_used')} | `{card.get('train_command')}` | "
            f"{selected.get('monitor')} = {_number(selected.get('value'))} at `{selected.get('checkpoint')}` |")
        metric_rows += _evaluation_rows(f"`{path.name}`", card.get("evaluations") or {})
    for path in sorted(folder.glob("*.json")):
        data = json.loads(path.read_text())
        fit = data.get("fit") or {}
        dataset = fit.get("dataset") or {}
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
        lines.append(f"| `{path.name}` | {data.get('kind')} (format {data.get('version')}) | "
                     f"{path.stat().st_size / 1e6:.2f} | sha256 {digest} | `{Path(str(dataset.get('path'))).name}` "
                     f"({(dataset.get('attrs') or {}).get('plan_fingerprint')}) | {fit.get('n_trajectories')} | "
                     f"`python -m dcm.models.references fit` | least squares, no selection |")
    lines += ["", "## How well they rank a skill's stiffness schedules", "",
              "R within skill: Pearson correlation of predicted and true L_task over one skill's trials, averaged "
              "over skills (what the tuner needs). copy-F_demo predicts L_task = 0 for every schedule, so it "
              "cannot rank; it is the yardstick of the force error instead. The last column is the stiffness-only "
              "ridge's R within skill on the same trials.", "",
              "| file | split | sampler | " + " | ".join(title for _, title in METRICS)
              + " | stiffness ridge R within |",
              "|---|---|---|" + "---|" * (len(METRICS) + 1), *metric_rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or not Path(args[0]).is_dir():
        print(f"usage: python -m dcm.models.model_card <folder of shipped predictors>; got {args}", file=sys.stderr)
        return 1
    print(card_markdown(Path(args[0])), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
