"""The stiffness-only ridge fitted on exactly the training subset each run of a usage-rate study saw.

A ridge fitted on the whole train split is no fair reference for a model trained on 10 % of it. When a
study's runs vary ``usage_rate``, the ridge is fitted for every distinct (usage_rate, seed) of its finished
runs on the same seeded subset (:func:`dcm.data.datamodule.usage_index`) and saved under ``<sweep>/ridge/``;
each becomes a run of the series ``model=stiffness_ridge``, scored and tested like the models.
"""

from __future__ import annotations

import json
from pathlib import Path

from dcm.configs import load_json
from dcm.data.datamodule import usage_index
from dcm.models.references import STIFFNESS_RIDGE, StiffnessRegression
from studies.model_study.runs import Run

USAGE_RATE = "usage_rate"  # the setting key that turns the matched ridge on


def matched_ridge_runs(runs: list[Run], sweep_dir: Path) -> list[Run]:
    """One ridge per distinct (usage_rate, seed) of the finished ``runs``, as runs to score."""
    out: dict[tuple[float, int], Run] = {}
    for run in runs:
        rate, seed = float(run.config.get(USAGE_RATE, 1.0)), int(run.seed)
        if not run.finished or (rate, seed) in out:
            continue
        folder = sweep_dir / "ridge" / f"usage_rate-{rate}__seed-{seed}"
        ckpt = folder / f"{STIFFNESS_RIDGE}.json"
        if not ckpt.is_file():  # fitting is deterministic: a saved one is the same ridge
            n_train = int(load_json(run.path / "summary.json")["n_train_total"])  # the run's train split size
            index = usage_index(n_train, rate, seed)
            StiffnessRegression.fit_dataset(run.dataset, "train", index=index).save(ckpt)
        (folder / "summary.json").write_text(json.dumps({"best_checkpoint": str(ckpt), "model": STIFFNESS_RIDGE,
                                                         USAGE_RATE: rate, "seed": seed}, indent=2) + "\n")
        config = {USAGE_RATE: rate, "seed": seed, "data": run.config["data"]}
        out[(rate, seed)] = Run(path=folder, seed=seed, overrides={}, config=config,
                                choices={"model": STIFFNESS_RIDGE})
    return list(out.values())
