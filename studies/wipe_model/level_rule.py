"""The model-free reference of the wipe model's table: rank a skill's schedules by their stiffness level alone.

    python -m studies.wipe_model.level_rule --dataset data/diverse_contact_wipe.h5 [--fit-split train]
        [--split valid] [--out <file>.json]

Why: the model-free prior of the tuning studies is five constant stiffness levels, a tuner without a model. As a
*ranker* of the stiffness schedules a split holds, its counterpart is the rule "the stiffer (or the softer), the
lower L_task": predicted L_task = sign x L_comp (the mean norm of the translational stiffness, which is linear in
a constant schedule's level). The sign is the one that ranks the ``--fit-split`` (train) better within skill,
so nothing of the scored split chooses it. The scored L_task is the one the file stores (its stiffness search's
objective: ``wipe`` for a file generated with ``objective=wipe``), ranked with the metrics ``dcm-evaluate``
prints (:func:`dcm.models.metrics.ranking_metrics`).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.schema import load_dataset
from dcm.models.metrics import ranking_metrics, within_skill_correlation


def level_sign(dataset: str | Path, split: str = "train") -> tuple[float, float]:
    """+1 when a higher stiffness level predicts a higher L_task within skill on ``split``, else -1; and that
    split's within-skill Spearman of L_comp against L_task."""
    loaded = load_dataset(dataset, split=split)
    rho, _ = within_skill_correlation(loaded.L_comp, loaded.L_task, loaded.demo_ids, "spearman")
    return (1.0 if rho >= 0 else -1.0), float(rho)


def level_rule(dataset: str | Path, split: str = "valid", fit_split: str = "train") -> dict[str, Any]:
    """The ranking metrics of predicted L_task = sign x L_comp on ``split`` (sign from ``fit_split``)."""
    sign, rho_fit = level_sign(dataset, fit_split)
    loaded = load_dataset(dataset, split=split)
    metrics = ranking_metrics(sign * loaded.L_comp, loaded.L_task, loaded.demo_ids)
    return {"model": "stiffness_level_rule", "sign": sign, "fit_split": fit_split,
            f"{fit_split}_spearman_L_comp": rho_fit, "split": split, "n": len(loaded),
            "n_skills": int(len(np.unique(loaded.demo_ids))), "objective": loaded.attrs.get("objective"),
            "dataset": str(dataset), **metrics}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--split", default="valid")
    parser.add_argument("--fit-split", default="train")
    parser.add_argument("--out", default=None, help="metrics JSON to write")
    args = parser.parse_args(argv)
    result = level_rule(args.dataset, args.split, args.fit_split)
    print(f"stiffness level rule (sign {result['sign']:+.0f} from {args.fit_split}, whose within-skill Spearman "
          f"of L_comp vs L_task is {result[f'{args.fit_split}_spearman_L_comp']:.3f}) on {args.split}, "
          f"n={result['n']}, {result['n_skills']} skills: R_within {result['R_within']:.3f} "
          f"[{result['R_within_lo']:.3f}, {result['R_within_hi']:.3f}], Spearman {result['R_within_spearman']:.3f}, "
          f"top3_regret {result['top3_regret']:.3f}")
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2, default=str) + "\n")
        print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    main()
