"""One table for model comparisons: every model over its seeds, beside the references, on named splits.

    python -m studies.model_study.model_table --dataset data/sim.h5 --splits valid test \
        --runs "DCM=outputs/train/dcm_s*" "baseline=outputs/train/baseline_s*" \
        --out studies/model_study/reports/models_sim.md

Each run directory's selected checkpoint (``summary.json``'s ``best_checkpoint``, else ``last.ckpt``) is scored
by :func:`dcm.evaluate.evaluate` on each split; the result is cached next to the run
(``eval_<dataset>_<split>[_<tag>].json``) so re-running the table costs nothing. Cells give the median over
seeds and the range; the interval column gives the bootstrap 90 % interval of R within skill (trials
resampled within skills, median bounds over seeds), which says how much the split's trials can tell. The
references (copy-F_demo and the stiffness-only ridge, fitted on the dataset's train split) come from the
same evaluations, so they sit on exactly the trajectories the models were scored on. Below the table, a Welch
t-test over seeds compares every other model with the first (R within skill and force RMSE, per split).
``--per-skill`` adds one row per skill: how far its schedules' L_task differ beside how far each predictor
errs between them, which says where a mean R within skill comes from. ``--sampler`` and ``--sampling-steps``
set a DCM's sampler; a one-pass model (the baseline) has none, is scored as it is, and the table says so.
"""

from __future__ import annotations

import argparse
import glob
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control.objectives import TASK_LOSSES
from dcm.models.metrics import REGRET_KEY, TOP_PICKS
from dcm.training.run_dir import run_checkpoint, run_finished
from studies.model_study.stats import ALPHA, p_text, welch_test

INTERVAL = "R_within_interval"  # a column of two keys: R_within_lo and R_within_hi
EVAL_OPTIONS = ("sampler", "sampling_steps", "n_samples", "task_loss", "task_from_s")  # in cache-name order
DCM_ONLY = {"sampler": "--sampler", "sampling_steps": "--sampling-steps"}  # option -> its flag
COLUMNS = (("force_rmse_N", "force RMSE [N]"), ("force_rmse_ratio_copy", "÷ copy-F_demo"),
           ("R_within", "R within skill"), (INTERVAL, "R within: 90 % interval"),
           ("R_within_spearman", "Spearman within"), (REGRET_KEY, f"top-{TOP_PICKS} regret"),
           ("R_pooled", "R pooled"))


def cached_eval(run_dir: Path, dataset: Path, split: str, tag: str = "", **overrides: Any) -> dict[str, Any]:
    """``dcm.evaluate.evaluate`` of the run's checkpoint, cached in the run directory.

    The cache holds while it names the same checkpoint and is newer than it: a run still training rewrites
    ``last.ckpt`` under the same path.
    """
    from dcm.evaluate import evaluate

    name = f"eval_{dataset.stem}_{split}{'_' + tag if tag else ''}.json"
    path = run_dir / name
    ckpt = run_checkpoint(run_dir)
    if path.is_file() and path.stat().st_mtime_ns >= ckpt.stat().st_mtime_ns:
        cached = json.loads(path.read_text())
        if cached.get("ckpt") == str(ckpt.resolve()) and REGRET_KEY in cached and "per_skill" in cached:
            return cached
    result = evaluate(ckpt, dataset, split=split, **overrides)
    path.write_text(json.dumps(result, indent=1))
    return result


def overrides_tag(overrides: dict[str, Any]) -> str:
    """The cache-name tag of an evaluation's overrides ("" for a plain evaluation)."""
    parts = [f"{key}{overrides[key]}" for key in EVAL_OPTIONS if key in overrides]
    if "reference" in overrides:
        parts.append("ref-" + Path(overrides["reference"]).stem)
    if "prior" in overrides:
        parts.append(f"prior-{Path(overrides['prior']).stem}-w{overrides['prior_weight']:g}")
    return "_".join(parts)


def run_overrides(run_dir: Path, overrides: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The overrides that apply to a run's checkpoint, and the DCM-only ones left out because it is not a
    DCM (``dcm.evaluate`` refuses a sampler for a one-pass model)."""
    from dcm.models.checkpoint import checkpoint_kind

    dropped = [key for key in DCM_ONLY if key in overrides]
    if not dropped or checkpoint_kind(run_checkpoint(run_dir)) == "dcm":
        return overrides, []
    return {k: v for k, v in overrides.items() if k not in DCM_ONLY}, dropped


def cell(values: list[float]) -> str:
    """Median over seeds, with the range when there is more than one seed."""
    values = [v for v in values if v is not None and np.isfinite(v)]
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    return f"{np.median(values):.3f} [{min(values):.3f}–{max(values):.3f}]"


def interval_cell(results: list[dict[str, Any]]) -> str:
    """The bootstrap interval of R_within (trials resampled within skills), median bounds over seeds."""
    bounds = [(r.get("R_within_lo"), r.get("R_within_hi")) for r in results]
    bounds = [(lo, hi) for lo, hi in bounds if lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi)]
    if not bounds:
        return "–"
    lo, hi = np.median(np.array(bounds), axis=0)
    return f"{lo:.2f} to {hi:.2f}"


def table(rows: dict[str, dict[str, list[dict[str, Any]]]], splits: list[str]) -> str:
    """Markdown: one row per model (and reference), one column group per split."""
    head = ["model", "seeds"] + [f"{s}: {label}" for s in splits for _, label in COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, per_split in rows.items():
        n = max(len(v) for v in per_split.values())
        cells = [label, str(n)]
        for split in splits:
            results = per_split.get(split, [])
            cells += [interval_cell(results) if key == INTERVAL else cell([r.get(key) for r in results])
                      for key, _ in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _median(values: list[Any]) -> float:
    finite = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.median(finite)) if finite else float("nan")


def per_skill_table(rows: dict[str, dict[str, list[dict[str, Any]]]], splits: list[str]) -> str:
    """Markdown: one row per skill, its true L_task spread, and per predictor the median over seeds of its R
    on that skill and of the spread of its L_task error there (``dcm.models.metrics.per_skill_ranking``)."""
    ranked = [label for label, per_split in rows.items()
              if any(r.get("per_skill") for results in per_split.values() for r in results)]
    head = (["split", "skill", "trials", "L_task mean [N]", "L_task sd [N]"]
            + [f"{label}: {what}" for label in ranked for what in ("R", "error sd [N]")])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    def fmt(v):
        return (f"{v:.3f}" if np.isfinite(v) else "–")
    for split in splits:
        truths = {s["skill"]: s for label in ranked for r in rows[label].get(split, [])  # the same for every predictor
                  for s in r.get("per_skill", [])}
        for skill, truth in truths.items():
            cells = [split, skill, str(truth["n"]), f"{truth['L_task_mean_N']:.4f}", f"{truth['L_task_sd_N']:.4f}"]
            for label in ranked:
                found = [s for r in rows[label].get(split, []) for s in r.get("per_skill", []) if s["skill"] == skill]
                error = _median([s["error_sd_N"] for s in found])
                cells += [fmt(_median([s["R"] for s in found])), f"{error:.4f}" if np.isfinite(error) else "–"]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def significance(rows: dict[str, dict[str, list[dict[str, Any]]]], models: list[str], splits: list[str]) -> str:
    """Markdown: a Welch t-test over seeds of every model after the first against the first, per split."""
    if len(models) < 2:
        return ""
    first = models[0]
    lines = [f"Welch t-test over seeds against {first} (two-sided p, bold below {ALPHA}; difference of means, "
             f"model − {first}):", "",
             "| model | split | R within: difference | R within: p | force RMSE [N]: difference | force RMSE: p |",
             "|---|---|---|---|---|---|"]
    for label in models[1:]:
        for split in splits:
            cells = [label, split]
            for key in ("R_within", "force_rmse_N"):
                test = welch_test([r.get(key) for r in rows[label].get(split, [])],
                                  [r.get(key) for r in rows[first].get(split, [])])
                diff = test["difference"]
                cells += [f"{diff:+.3f}" if np.isfinite(diff) else "–", p_text(test["p"])]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def collect(runs: dict[str, list[Path]], dataset: Path, splits: list[str],
            overrides: dict[Path, dict[str, Any]]) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """Evaluations per model label and split, plus the two reference rows from the first run's evaluation;
    ``overrides`` holds each run's evaluation options (:func:`run_overrides`)."""
    rows: dict[str, dict[str, list[dict[str, Any]]]] = {}
    refs: dict[str, dict[str, list[dict[str, Any]]]] = {"copy-F_demo": {}, "stiffness-only ridge": {}}
    for label, dirs in runs.items():
        rows[label] = {}
        for split in splits:
            results = [cached_eval(d, dataset, split, overrides_tag(overrides[d]), **overrides[d]) for d in dirs]
            rows[label][split] = results
            if results and split not in refs["copy-F_demo"]:
                ref = results[0].get("references", {})
                copy = ref.get("copy_demo", {})
                refs["copy-F_demo"][split] = [copy] if copy else []
                ridge = ref.get("stiffness_ridge", {})
                refs["stiffness-only ridge"][split] = [ridge] if "R_within" in ridge else []
    rows.update(refs)
    return rows


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, type=Path)
    parser.add_argument("--splits", nargs="+", default=["valid", "test"])
    parser.add_argument("--runs", nargs="+", required=True, help='LABEL=GLOB of run directories, e.g. "DCM=outputs/train/dcm_s*"')
    parser.add_argument("--sampler", default=None, help="DCM sampler override (ddpm | ddim)")
    parser.add_argument("--sampling-steps", type=int, default=None)
    parser.add_argument("--n-samples", type=int, default=None)
    parser.add_argument("--task-loss", default=None, choices=TASK_LOSSES,
                        help="DCM: how k samples give L_task (default: the checkpoint's own)")
    parser.add_argument("--task-from-s", type=float, default=None,
                        help="score the force from this time [s] on (1.0: without the demos' approach)")
    parser.add_argument("--reference", default=None,
                        help="stiffness reference JSON for the ridge row (default: fitted on the dataset's train split)")
    parser.add_argument("--prior", default=None,
                        help="rank with each model's L_task blended with this stiffness reference JSON "
                             "(dcm/models/prior_blend.py); force columns are then empty")
    parser.add_argument("--prior-weight", type=float, default=None, help="the blend's weight in [0, 1]")
    parser.add_argument("--per-skill", action="store_true",
                        help="add a table per skill: its L_task spread beside each predictor's R and error there")
    parser.add_argument("--out", type=Path, default=None, help="write the Markdown table here")
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(argv)
    runs: dict[str, list[Path]] = {}
    for spec in args.runs:
        label, sep, pattern = spec.partition("=")
        if not sep:
            parser.error(f"--runs {spec!r}: expected LABEL=GLOB")
        dirs = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_dir())
        if not dirs:
            parser.error(f"--runs {spec!r}: no run directory matches {pattern!r}")
        finished = [d for d in dirs if run_finished(d)]
        if unfinished := [str(d) for d in dirs if d not in finished]:
            print(f"--runs {spec!r}: skipped, still training or killed (no summary.json): {', '.join(unfinished)}",
                  file=sys.stderr)
        if not finished:
            parser.error(f"--runs {spec!r}: no finished run (with summary.json) matches {pattern!r}")
        runs[label] = finished
    overrides = {key: getattr(args, key) for key in EVAL_OPTIONS if getattr(args, key) is not None}
    if args.reference:
        overrides["reference"] = args.reference
    if (args.prior is None) != (args.prior_weight is None):
        parser.error("--prior and --prior-weight go together")
    if args.prior is not None:
        overrides.update(prior=args.prior, prior_weight=args.prior_weight)
    per_run: dict[Path, dict[str, Any]] = {}
    notes = []
    try:
        for label, dirs in runs.items():
            dropped: list[str] = []
            for run_dir in dirs:
                per_run[run_dir], left_out = run_overrides(run_dir, overrides)
                dropped += [key for key in left_out if key not in dropped]
            if dropped:
                flags = " ".join(f"{DCM_ONLY[key]} {overrides[key]}" for key in dropped)
                notes.append(f"{label}: a one-pass model, scored without {flags} (DCM options)")
        rows = collect(runs, args.dataset, args.splits, per_run)
    except (ValueError, FileNotFoundError) as err:  # ModelInputError, DatasetError, a run without checkpoint
        raise SystemExit(f"error: {err}") from None
    text = table(rows, args.splits)
    if notes:
        text += "\n\n" + "\n".join(notes)
    tests = significance(rows, list(runs), args.splits)
    if tests:
        text += "\n\n" + tests
    if args.per_skill:
        text += ("\n\nPer skill (median over seeds): a skill's schedules can be ranked only where they differ "
                 "in L_task by more than the predictor errs between them (`L_task sd` against `error sd`).\n\n"
                 + per_skill_table(rows, args.splits))
    header = (f"Dataset `{args.dataset}`; median [range] over seeds; checkpoints selected on val/R_within. "
              f"Command: `python -m studies.model_study.model_table {shlex.join(argv)}`")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(header + "\n\n" + text + "\n")
    print(text)
    return text


if __name__ == "__main__":
    main()
