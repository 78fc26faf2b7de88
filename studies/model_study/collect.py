"""Score every run of a study sweep and aggregate over seeds: the numbers behind study.md/png/json.

Each finished run's selected checkpoint is evaluated on the valid and test splits of its dataset with
:func:`studies.model_study.model_table.cached_eval` (cached as ``eval_<dataset>_<split>.json`` in the run),
runs with the same setting (seed aside) form a cell, and the references (copy-F_demo, the stiffness ridge
fitted on the train split) come from the same evaluations, on the same trajectories.
"""

from __future__ import annotations

import logging
import os
import platform
import shlex
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dcm.configs import flatten
from dcm.models.references import STIFFNESS_RIDGE
from studies.model_study.matched_ridge import USAGE_RATE, matched_ridge_runs
from studies.model_study.model_table import COLUMNS, cached_eval
from studies.model_study.runs import (
    Run,
    StudyError,
    StudySpec,
    find_runs,
    init_runs,
    reference_values,
    setting_keys,
    study_spec,
)
from studies.model_study.stats import describe, welch_test

log = logging.getLogger("studies.model_study")

SPLITS = ("valid", "test")
REFERENCES = {"copy-F_demo": "copy_demo", "stiffness-only ridge": "stiffness_ridge"}


@dataclass
class Cell:
    """The runs of one setting (all seeds) and their scores per split."""

    values: dict[str, Any]
    runs: list[Run] = field(default_factory=list)
    scores: dict[str, list[dict[str, Any]]] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.values.items() if v is not None)


def metric_keys(spec: StudySpec) -> list[str]:
    """The study's metrics, then the model table's columns."""
    return list(dict.fromkeys([*spec.metrics, *(key for key, _ in COLUMNS)]))


def _order(value: Any, first: Any) -> tuple:
    """Sort key: the comparison's reference value first, then numbers by size, then text."""
    if value is None:
        return (2, 0.0, "")
    if first is not None and str(value) == str(first):
        return (-1, 0.0, "")
    try:
        return (0, float(value), "")
    except (TypeError, ValueError):
        return (1, 0.0, str(value))


def make_cells(runs: list[Run], keys: list[str], spec: StudySpec) -> list[Cell]:
    """Group runs by their values of ``keys``; ordered by series, then x (the comparison's reference first)."""
    cells: dict[tuple, Cell] = {}
    for run in runs:
        values = {k: run.value(k) for k in keys}
        cells.setdefault(tuple(str(v) for v in values.values()), Cell(values)).runs.append(run)
    for cell in cells.values():
        cell.runs.sort(key=lambda r: r.seed)

    first = reference_values(spec.comparisons)

    def order(cell: Cell) -> tuple:
        return tuple(_order(cell.values[k], first.get(k)) for k in keys)

    return sorted(cells.values(), key=order)


def dataset_splits(path: Path, wanted: tuple[str, ...]) -> list[str]:
    """The ``wanted`` splits the dataset file has (non-empty masks)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            masks = f.get("mask", {})
            return [s for s in wanted if s in masks and len(masks[s]) > 0]
    except OSError as err:
        raise StudyError(f"{path}: cannot open the runs' dataset ({err})") from None


def numbers(result: dict[str, Any]) -> dict[str, float]:
    """The numeric metrics of one evaluation (references and descriptions left out)."""
    return {k: float(v) for k, v in result.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def references(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """copy-F_demo and the ridge from one evaluation (the ridge's reason when it was skipped)."""
    refs = result.get("references", {})
    out = {}
    for label, key in REFERENCES.items():
        ref = refs.get(key, {})
        out[label] = {"skipped": ref["skipped"]} if "skipped" in ref else numbers(ref)
    return out


def compare(cells: list[Cell], spec: StudySpec, splits: list[str], keys: list[str]) -> list[dict[str, Any]]:
    """Welch's t-tests, per comparison (key, against): every cell against the cell that differs only in key."""
    by_values = {tuple(str(c.values[k]) for k in keys): c for c in cells}
    tests = []
    for compare_key, against in spec.comparisons:
        if compare_key not in keys:
            continue
        for cell in cells:
            if str(cell.values[compare_key]) == str(against):
                continue
            partner = by_values.get(tuple(str(against) if k == compare_key else str(cell.values[k]) for k in keys))
            if partner is None:
                continue
            for split in splits:
                for metric in spec.metrics:
                    test = welch_test([s.get(metric) for s in cell.scores.get(split, [])],
                                      [s.get(metric) for s in partner.scores.get(split, [])])
                    tests.append({"split": split, "metric": metric, "cell": cell.label, "against": partner.label,
                                  **test})
    return tests


def _multirun_overrides(sweep_dir: Path) -> tuple[list[str], list[str]]:
    """The task and Hydra overrides of the sweep's last launch, from Hydra's multirun.yaml."""
    path = sweep_dir / "multirun.yaml"
    overrides = ((yaml.safe_load(path.read_text()) or {}).get("hydra", {}).get("overrides", {})
                 if path.is_file() else {})
    return ([str(o) for o in overrides.get("task", [])],
            [str(o) for o in overrides.get("hydra", []) if o != "hydra.mode=MULTIRUN"])


def train_command(args: list[str]) -> str:
    """``python train.py -m <args>``; with the studies' conf dir when an experiment is named, since the
    experiments live there rather than in the product's conf."""
    conf = ["--config-dir", "studies/conf"] if any(a.lstrip("+").startswith("experiment=") for a in args) else []
    return " ".join(["python train.py -m", *conf, *(shlex.quote(a) for a in args)])


def cell_command(cell: Cell, sweep_dir: Path) -> str:
    """The ``train.py -m`` command that trains a cell's runs: the first run's own overrides
    (``.hydra/overrides.yaml``) with the cell's seeds, and the Hydra overrides of the sweep's launch. A study
    filled by several launches thus names each setting's command, not only the last launch's. Empty for the
    ridge the report fits itself."""
    if cell.values.get("model") == STIFFNESS_RIDGE:
        return ""  # fitted by the report itself
    own = cell.runs[0].path / ".hydra" / "overrides.yaml"
    if not own.is_file():  # an init_from checkpoint scored as it is: the sweep's launch names it
        task, hydra = _multirun_overrides(sweep_dir)
        return train_command(task + hydra)
    task = [str(o) for o in yaml.safe_load(own.read_text()) or [] if not str(o).startswith("seed=")]
    seeds = ",".join(str(s) for s in sorted({r.seed for r in cell.runs}))
    args = task + [f"seed={seeds}"] + _multirun_overrides(sweep_dir)[1]
    return train_command(args)


def machine() -> str:
    """One line describing this machine (where the evaluations ran)."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return (f"{platform.system()} {platform.machine()}, {cpu}, {os.cpu_count()} logical CPUs, {gpu}; "
            f"Python {platform.python_version()}, torch {torch.__version__}")


def common_config(runs: list[Run]) -> dict[str, Any]:
    """The flattened resolved settings every finished run shares (the study block left out)."""
    flats = [{k: v for k, v in flatten(r.config).items() if not k.startswith("study.")} for r in runs]
    return {k: v for k, v in flats[0].items() if all(k in f and f[k] == v for f in flats[1:])}


def collect(sweep_dir: Path, splits: tuple[str, ...] = SPLITS) -> dict[str, Any]:
    """Everything the report shows, as plain data (also written to study.json)."""
    runs = find_runs(sweep_dir)
    spec = study_spec(runs)
    finished = [r for r in runs if r.finished]
    unfinished = [str(r.path) for r in runs if not r.finished]
    if not finished:
        raise StudyError(f"{sweep_dir}: none of its {len(runs)} run directories has finished (no summary.json)")
    for path in unfinished:
        log.warning("unfinished run left out: %s", path)
    datasets = sorted({str(r.dataset) for r in finished})
    if len(datasets) > 1:
        raise StudyError(f"{sweep_dir}: its runs used different datasets {datasets}; report one dataset per sweep")
    dataset = Path(datasets[0])
    keys = setting_keys(spec, finished)
    scored = (finished + (init_runs(finished, sweep_dir) if spec.evaluate_init else [])
              + (matched_ridge_runs(finished, sweep_dir) if USAGE_RATE in keys else []))
    cells = make_cells(scored, keys, spec)
    use_splits = dataset_splits(dataset, splits)
    if not use_splits:
        raise StudyError(f"{dataset}: none of the splits {list(splits)} is in the file")
    refs: dict[str, Any] = {}
    split_info: dict[str, Any] = {}
    for cell in cells:
        for split in use_splits:
            results = []
            for run in cell.runs:
                log.info("scoring %s on %s", run.path.name, split)
                results.append(cached_eval(run.path, dataset, split))
            cell.scores[split] = [numbers(r) for r in results]
            if split not in refs and results:
                refs[split] = references(results[0])
                split_info[split] = {"n": results[0].get("n"), "n_skills": results[0].get("n_skills")}
    keys_out = metric_keys(spec)
    return {
        "study": asdict(spec), "sweep_dir": str(sweep_dir), "dataset": str(dataset), "splits": split_info,
        "setting_keys": keys, "machine": machine(),
        "unfinished": unfinished, "common_config": common_config(finished),
        "cells": [{"label": c.label, "values": c.values, "n_seeds": len(c.runs), "command": cell_command(c, sweep_dir),
                   "runs": [{"path": str(r.path), "seed": r.seed, "scores": {s: c.scores[s][i] for s in use_splits}}
                            for i, r in enumerate(c.runs)],
                   "summary": {s: {m: describe([x.get(m) for x in c.scores[s]]) for m in keys_out} for s in use_splits}}
                  for c in cells],
        "references": refs,
        "tests": compare(cells, spec, use_splits, keys),
    }

