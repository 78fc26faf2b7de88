"""How well each predictor ranks one skill's simulated trials, beside the I_H it tuned that skill to.

    python -m studies.tuning_study.trial_ranking STUDY LABEL=PREDICTOR ... [--tuned LABEL=STUDY:TUNER ...] [--out x.md]

Why: R within over a dataset's random schedules need not say which predictor tunes a skill better, since a
tuner's I_H is decided by the few schedules it validates from its predicted front. This scores predictors on
the schedules a tuner meets: the robot-based trials of a finished study (``python -m
studies.tuning_study.study``; MOTPE trials per tuning seed, dense near the front), each simulated, so their
true (L_task, L_comp) are known. Per predictor:

* ``R`` and ``rho``: Pearson and Spearman correlation of predicted and simulated L_task over the trials;
* ``top3_regret``: what keeping its 3 best-ranked trials loses (``dcm.models.metrics.within_skill_regret``);
* ``front_hv``: the tuner's choice replayed on these trials: the ``robot_free.n_validate`` picks spread along
  its predicted front (``dcm.tuning.run.pick_spread``; L_comp is exact), judged by their simulated
  objectives: their I_H ÷ the I_H of the simulated front of all trials.

Two rows calibrate ``front_hv``: the simulator itself (its picks from the true front; below 1 because only
``n_validate`` points are kept) and a shuffled predictor (the mean over permutations of the simulated
L_task). With ``--tuned`` each predictor's median I_H over the study's tuning seeds is added (and, when
that study kept its runs, its optimism: the median predicted − simulated L_task of its validated picks), and
the Spearman correlation over predictors of each score with that I_H says which score tells the better tuner.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.models.metrics import correlation, within_skill_regret
from dcm.tuning.pareto import hypervolume, pareto_mask

SCORES = ("R", "rho", "top3_regret", "front_hv")
SHUFFLES = 200  # permutations behind the shuffled row
SHUFFLE_SEED = 0


def front_hv(predicted_task: np.ndarray, objectives: np.ndarray, reference: np.ndarray, n_validate: int) -> float:
    """I_H of the simulated objectives of the ``n_validate`` trials a tuner would validate from the predicted
    front ÷ I_H of the simulated front of all trials (NaN when no trial beats the reference point)."""
    from dcm.tuning.pareto import pick_spread

    objectives = np.asarray(objectives, dtype=np.float64)
    best = hypervolume(objectives[pareto_mask(objectives)], reference)
    if best <= 0:
        return math.nan
    predicted = np.column_stack([np.asarray(predicted_task, dtype=np.float64), objectives[:, 1]])
    return hypervolume(objectives[pick_spread(predicted, n_validate)], reference) / best


def ranking_scores(predicted_task: np.ndarray, objectives: np.ndarray, reference: np.ndarray,
                   n_validate: int) -> dict[str, float]:
    """Every score of one predictor's L_task on trials with simulated ``objectives`` (N, 2)."""
    predicted_task = np.asarray(predicted_task, dtype=np.float64)
    true = np.asarray(objectives, dtype=np.float64)[:, 0]
    return {"R": correlation(predicted_task, true, "pearson"),
            "rho": correlation(predicted_task, true, "spearman"),
            "top3_regret": within_skill_regret(predicted_task, true, np.zeros(len(true)))[0],
            "front_hv": front_hv(predicted_task, objectives, reference, n_validate)}


def calibration_rows(objectives: np.ndarray, reference: np.ndarray, n_validate: int
                     ) -> dict[str, dict[str, float]]:
    """The simulator's own scores, and the mean scores of ``SHUFFLES`` permutations of its L_task."""
    rng = np.random.default_rng(SHUFFLE_SEED)
    shuffled = [ranking_scores(rng.permutation(objectives[:, 0]), objectives, reference, n_validate)
                for _ in range(SHUFFLES)]
    return {"simulator": ranking_scores(objectives[:, 0], objectives, reference, n_validate),
            "shuffled": {k: float(np.nanmean([s[k] for s in shuffled])) for k in SCORES}}


def score_tuning_agreement(scores: Mapping[str, Mapping[str, float]], tuned: Mapping[str, float]
                           ) -> dict[str, float]:
    """Spearman correlation, over the predictors with a tuned I_H, of each score with that I_H (the regret
    is negated, so +1 always means "the better score tuned better"); NaN with fewer than 3 predictors."""
    names = [n for n in tuned if n in scores and math.isfinite(tuned[n])]
    if len(names) < 3:
        return {k: math.nan for k in SCORES}
    ih = np.array([tuned[n] for n in names])
    sign = {"top3_regret": -1.0}
    return {k: correlation(sign.get(k, 1.0) * np.array([scores[n][k] for n in names]), ih, "spearman")
            for k in SCORES}


# ------------------------------------------------------------------------------------------------ study files
def study_trials(study: Path) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The distinct finite robot-based trials of a study: (N, P, 3) N/m, (N, 2) simulated objectives, and the
    tuning seeds they came from."""
    from dcm.tuning.optimize import TrialLog
    from dcm.tuning.setup import ROBOT_LOG

    logs = sorted((study / "runs" / "dcm").glob(f"seed_*/{ROBOT_LOG}"))
    if not logs:
        raise FileNotFoundError(f"{study}: no runs/dcm/seed_*/{ROBOT_LOG} (is it a `python -m "
                                "studies.tuning_study.study` folder with its runs, not a copied report?)")
    params, objectives = zip(*(TrialLog.load(log).arrays() for log in logs))
    params, objectives = np.concatenate(params), np.concatenate(objectives)
    finite = np.isfinite(objectives).all(axis=1)
    _, first = np.unique(params[finite].reshape(int(finite.sum()), -1), axis=0, return_index=True)
    keep = np.flatnonzero(finite)[np.sort(first)]
    return params[keep], objectives[keep], [int(log.parent.name.split("_")[1]) for log in logs]


def _study_config(study: Path) -> Any:
    from omegaconf import OmegaConf

    from studies.tuning_study.study_config import STUDY_SETTINGS

    path = study / STUDY_SETTINGS
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; give the folder of a `python -m studies.tuning_study.study` run")
    return OmegaConf.create(json.loads(path.read_text()))


def _predictor_kind(path: str) -> str:
    """The study tuner whose settings (sampler, ...) a predictor file gets: dcm, baseline or reference."""
    from dcm.models.checkpoint import checkpoint_kind

    return "reference" if path.lower().endswith(".json") else checkpoint_kind(path)


def predict_trials(study: Path, predictors: Mapping[str, str], params: np.ndarray
                   ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Each predictor's L_task on the trials, built as the study's robot-free runs of its kind build it
    (tuning seed 0's sample noise), and the study's skill settings (reference point, n_validate)."""
    from dcm.devices import resolve_device
    from dcm.tuning.objectives import ModelObjective
    from dcm.tuning.predictor import load_predictor
    from studies.tuning_study.study_config import Tuner, tune_config
    from studies.tuning_study.study_controls import setup_skill

    cfg = _study_config(study)
    reference = json.loads((study / "reference_point.json").read_text())
    setup, predicted = None, {}
    for label, path in predictors.items():
        kind = _predictor_kind(path)
        overrides = tuple(cfg.tuners.get(kind, {}).get("overrides", []) or [])
        tune_cfg = tune_config(cfg, Tuner(kind, path, overrides), 0, None, study)  # nothing is written
        setup = setup or setup_skill(tune_cfg)
        model = load_predictor(tune_cfg, setup.spec, resolve_device(tune_cfg.device, "device"))
        objective = ModelObjective(model, setup.skill, setup.simulator, setup.demo, tune_cfg.robot_free.n_samples,
                                   seed=0)
        batch = int(tune_cfg.robot_free.batch_size)
        predicted[label] = np.concatenate([objective(params[i : i + batch], first_trial=i)[:, 0]
                                           for i in range(0, len(params), batch)])
        print(f"  {label}: {len(params)} trials predicted in {objective.seconds_model:.1f} s", flush=True)
    settings = {"reference": [reference["L_task_N"], reference["L_comp_kNpm"]],
                "n_validate": int(cfg.robot_free.n_validate)}
    return predicted, settings


def _optimism(folder: Path, tuner: str, seeds: Sequence[int]) -> float:
    """Median over the validated picks of a study's runs of (predicted − simulated L_task) [N]: below 0 the
    search found schedules the predictor thought better than they are; NaN when the runs are not kept."""
    gaps = []
    for seed in seeds:
        path = folder / "runs" / tuner / f"seed_{seed:03d}" / "results.json"
        if not path.is_file():
            return math.nan
        for pick in json.loads(path.read_text())["robot_free"]["solutions"]:
            simulated = pick["validated"]["L_task_N"]  # None for a failed rollout
            gaps.append(pick["predicted"]["L_task_N"] - (math.nan if simulated is None else simulated))
    return float(np.nanmedian(gaps)) if gaps else math.nan


def tuned_summary(items: Sequence[str], seeds: Sequence[int]) -> dict[str, dict[str, float]]:
    """``LABEL=STUDY:TUNER`` -> that tuner's median I_H in that study over ``seeds`` (all must be there) and
    its optimism (:func:`_optimism`)."""
    from studies.tuning_study.study_pool import load_study, seed_values

    summary = {}
    for item in items:
        label, sep, rest = item.partition("=")
        folder, sep2, tuner = rest.rpartition(":")
        if not (sep and sep2 and label and folder and tuner):
            raise ValueError(f"--tuned {item!r}: give LABEL=STUDY_FOLDER:TUNER (e.g. DCM=outputs/study/x:dcm)")
        study = load_study(Path(folder))
        if tuner not in study["tuners"]:
            raise ValueError(f"--tuned {item!r}: {folder} has no tuner {tuner!r} (it has {study['tuners']})")
        missing = [s for s in seeds if s not in study["seeds"]]
        if missing:
            raise ValueError(f"--tuned {item!r}: {folder} lacks the tuning seeds {missing} of the trials")
        summary[label] = {"I_H": float(np.nanmedian(seed_values(study, tuner, seeds))),
                          "optimism_N": _optimism(Path(folder), tuner, seeds)}
    return summary


def ranking_table(report: Mapping[str, Any]) -> str:
    """Markdown: one row per predictor, then the calibration rows and the agreement with tuning."""
    tuned = report["tuned"]
    fmt = lambda v: "–" if v is None or not math.isfinite(v) else f"{v:.3f}"  # noqa: E731
    lines = [f"Command: `{report['command']}`", "",
             f"{report['n_trials']} distinct robot-based trials of `{report['study']}` (tuning seeds "
             f"{report['seeds'][0]}–{report['seeds'][-1]}); simulated L_task {report['task_range'][0]:.3f}–"
             f"{report['task_range'][1]:.3f} N. front_hv: I_H of the {report['n_validate']} picks from the "
             "predicted front ÷ I_H of the simulated front.", "",
             "| predictor | R | rho | top-3 regret | front_hv | tuned I_H (median) | optimism [N] |",
             "|---|---|---|---|---|---|---|"]
    rows = {**report["scores"], **{f"*{k}*": v for k, v in report["calibration"].items()}}
    for name, s in rows.items():
        done = tuned.get(name, {})
        lines.append(f"| {name} | " + " | ".join(fmt(s[k]) for k in SCORES)
                     + f" | {fmt(done.get('I_H'))} | {fmt(done.get('optimism_N'))} |")
    if tuned:
        agree = report["agreement"]
        lines += ["", f"Spearman over the {len([n for n in tuned if n in report['scores']])} tuned predictors of "
                  "each score with the tuned I_H (regret negated; +1: the better score tuned better): "
                  + ", ".join(f"{k} {fmt(agree[k])}" for k in SCORES) + "."]
    return "\n".join(lines) + "\n"


def _parse_predictors(items: Sequence[str]) -> dict[str, str]:
    from studies.tuning_study.study_pool import parse_labelled

    predictors = parse_labelled(items, "predictor as LABEL=CHECKPOINT_OR_REFERENCE_JSON")
    for label, path in predictors.items():
        if not Path(path).is_file():
            raise FileNotFoundError(f"'{label}={path}': {path}: no such file")
    return predictors


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path, help="folder of a finished `python -m studies.tuning_study.study` run")
    parser.add_argument("predictors", nargs="+", help="LABEL=CHECKPOINT or LABEL=reference JSON")
    parser.add_argument("--tuned", nargs="*", default=[], help="LABEL=STUDY_FOLDER:TUNER, that predictor's tuning")
    parser.add_argument("--out", type=Path, default=None, help="write the table here (numbers beside it as .json)")
    args = parser.parse_args(argv)
    try:
        predictors = _parse_predictors(args.predictors)
        params, objectives, seeds = study_trials(args.study)
        tuned = tuned_summary(args.tuned, seeds)
        unknown = sorted(set(tuned) - set(predictors))
        if unknown:
            raise ValueError(f"--tuned names {unknown}, which are not among the predictors {list(predictors)}")
        predicted, settings = predict_trials(args.study, predictors, params)
    except (ValueError, OSError) as err:
        raise SystemExit(f"error: {err}") from None
    reference, n_validate = np.asarray(settings["reference"]), settings["n_validate"]
    scores = {name: ranking_scores(p, objectives, reference, n_validate) for name, p in predicted.items()}
    command = " ".join(["python -m studies.tuning_study.trial_ranking", *(sys.argv[1:] if argv is None else argv)])
    report = {"command": command, "study": str(args.study), "seeds": seeds, "n_trials": len(params),
              "n_validate": n_validate, "reference_point": settings["reference"], "predictors": predictors,
              "task_range": [float(objectives[:, 0].min()), float(objectives[:, 0].max())], "scores": scores,
              "calibration": calibration_rows(objectives, reference, n_validate), "tuned": tuned,
              "agreement": score_tuning_agreement(scores, {n: t["I_H"] for n, t in tuned.items()})}
    table = ranking_table(report)
    print(table)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(table)
        args.out.with_suffix(".json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
