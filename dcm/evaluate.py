"""Score a predictor on any dataset file: ``python -m dcm.evaluate ckpt=<ckpt> dataset=<h5>``.

``ckpt`` is a DCM/Baseline checkpoint, a stiffness reference JSON (``python -m dcm.models.references fit``)
or ``copy_demo``. Prints a table of the headline metrics on stdout and, with ``out=<file>``, writes a JSON
file with the within-skill and pooled correlations of predicted vs true
L_task (``R_within``, its bootstrap 90 % interval ``R_within_lo`` / ``R_within_hi``, ``R_within_spearman``,
``R_within_n_skills``, ``R_pooled``; ``R`` = ``R_pooled``), ``top3_regret`` (what keeping the 3 best-ranked
schedules per skill loses: 0 the truly best, 1 a random pick),
``L_task_mae_N`` and, for force predictors, L_MSE (normalised units, learned models only), per-axis RMSE
[N, N·m], ``force_rmse_N``, ``force_rmse_copy_N``, ``force_rmse_ratio_copy`` and the part of the force error a
skill's trials share (``force_rmse_skill_common_N``, the same for copy-F_demo); for a model that predicts the
pose (``target_fields=force_and_pose``) also its path error ``path_rmse_m`` beside copy-x_demo's
``path_rmse_copy_m``; plus n and what produced them (model kind, T, sampler, samples, seed). L_task is the
``objective``'s (null: the checkpoint's own; ``objective=wipe`` or a mapping of its fields), recorded as
``objective``. ``per_skill`` lists, for every skill, how far its
schedules' L_task differ, how far the predictor errs between them and how well it ranks them
(:func:`dcm.models.metrics.per_skill_ranking`). A learned model is reported beside two references under
``references``: ``copy_demo`` and ``stiffness_ridge`` (fitted on the same file's train split, or
loaded from ``reference=<json>``), so every comparison shows them. Skills are the trajectories' ``demo_id``.
The dataset must have the model's channels and control rate; it need not be one the model saw.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from dcm.configs import CONF_DIR, check_integer, check_number
from dcm.console import error_line, one_line_warnings, quiet_libraries
from dcm.control.objectives import ObjectiveError, TaskObjective, task_window_start
from dcm.data.atomic import atomic_path, write_problem
from dcm.data.datamodule import TrajectoryDataset, dataset_channels
from dcm.data.schema import POSE_DELTA_WIDTH, TargetLayout, cond_slice, load_dataset, target_layout
from dcm.devices import resolve_device
from dcm.models.callbacks import evaluate_model
from dcm.models.configuration import ModelInputError
from dcm.models.dcm import DCM
from dcm.models.force_model import ForceModel
from dcm.models.metrics import REGRET_KEY, force_prediction_metrics, per_skill_ranking, ranking_metrics, undefined_metrics
from dcm.models.predict import (
    ContactPredictor,
    ForcePredictor,
    check_dataset,
    describe,
    load_model,
    predict_contact,
    predict_task_loss,
    predictor_objective,
    resolve_objective,
    with_prior,
)
from dcm.models.prior_blend import PriorBlend, check_prior
from dcm.models.references import (
    COPY_DEMO,
    STIFFNESS_RIDGE,
    CopyDemo,
    StiffnessRegression,
    dataset_phases,
    objective_preset,
)
from dcm.shipped import with_shipped_paths

log = logging.getLogger("dcm.evaluate")


def score(predictor: Any, data: TrajectoryDataset, skills: np.ndarray | None, n_samples: int | None = None,
          seed: int = 0, from_step: int = 0) -> dict[str, Any]:
    """Metrics of any predictor on a set of trajectories (see the module docstring for the keys); force
    errors and L_task count the steps from ``from_step`` on. A predictor that ranks schedules also gets
    ``per_skill`` (:func:`dcm.models.metrics.per_skill_ranking`) and ``undefined`` (why a ranking metric is NaN,
    :func:`dcm.models.metrics.undefined_metrics`) when ``skills`` are given."""
    out = _score(predictor, data, skills, n_samples, seed, from_step)
    if skills is not None:
        out["undefined"] = undefined_metrics(out, skills)
    return out


def _observed(data: TrajectoryDataset) -> tuple[np.ndarray, np.ndarray | None]:
    """The observed wrench (N,H,6) and, where the data's target holds it, the tool's translation x_obs (N,H,3)."""
    cond, target = data.cond.numpy(), data.target.numpy()
    F_obs = target[..., data.layout.force]
    if not data.layout.predicts_pose:
        return F_obs, None
    return F_obs, cond[..., cond_slice("x_demo")][..., :POSE_DELTA_WIDTH] + target[..., data.layout.pose]


def _score(predictor: Any, data: TrajectoryDataset, skills: np.ndarray | None, n_samples: int | None,
           seed: int, from_step: int) -> dict[str, Any]:
    if isinstance(predictor, ForceModel):
        metrics, arrays = evaluate_model(predictor, data, n_samples, seed, skills, from_step)
        L_pred, L_true = arrays["L_task_pred"], arrays["L_task_true"]
    else:
        cond = data.cond.numpy()
        F_obs, x_obs = _observed(data)
        x_demo, F_demo, x_attr, K = (cond[..., cond_slice(f)] for f in ("x_demo", "F_demo", "x_attr", "K"))
        objective = predictor_objective(predictor)
        if isinstance(predictor, (ContactPredictor, ForcePredictor)):  # copy the demo: a force floor, no ranking
            contact = predict_contact(predictor, x_demo, F_demo, x_attr, K, n_samples=n_samples)
            x_pred = np.asarray(contact.x_mean) if contact.has_pose and x_obs is not None else None
            metrics = force_prediction_metrics(np.asarray(contact.force_mean), F_obs, F_demo, skills,
                                               objective=objective, x_pred=x_pred, x_obs=x_obs,
                                               x_demo=x_demo if x_obs is not None else None, from_step=from_step)[0]
            return {"R": metrics["R_pooled"], **metrics}
        # a stiffness ridge predicts the L_task of the window and objective it was fitted on (checked by the
        # caller); a prior blend's force model counts the same and samples seeded, as evaluate_model does
        L_true = np.asarray(objective.task_loss(F_obs.astype(np.float64), F_demo.astype(np.float64),
                                                None if x_obs is None else x_obs.astype(np.float64),
                                                x_demo.astype(np.float64), from_step))
        generator = None
        if isinstance(predictor, PriorBlend):
            import torch

            generator = torch.Generator(device=predictor.device).manual_seed(int(seed))
        L_pred = predict_task_loss(predictor, x_demo, F_demo, x_attr, K, n_samples, generator, from_step)
        metrics = ranking_metrics(L_pred, L_true, skills)
    out: dict[str, Any] = {"R": metrics["R_pooled"], **metrics}
    if skills is not None:
        out["per_skill"] = per_skill_ranking(L_pred, L_true, skills)
    return out


def reference_scores(dataset: str | Path, data: TrajectoryDataset, skills: np.ndarray,
                     reference: str | Path | None, n_phases: int | None = None,
                     task_from_s: float = 0.0, from_step: int = 0,
                     objective: TaskObjective | None = None) -> dict[str, dict[str, Any]]:
    """copy_demo and stiffness_ridge on the same trajectories; the ridge is skipped, with why, if unusable.

    ``n_phases``: the phase count of the trajectories' schedules (from the file, or ``n_phases=`` for one
    that does not record it, e.g. imported robot logs), checked against the ridge's and used to fit one.
    ``task_from_s`` / ``from_step``: where the scored window starts, in seconds and in steps (a fitted ridge
    learns the L_task of the same window; a loaded one must have). ``objective``: the L_task both are scored
    with (None: the paper's); a fitted ridge learns it, a loaded one must have."""
    objective = TaskObjective() if objective is None else objective
    copy = CopyDemo(objective)
    out: dict[str, dict[str, Any]] = {COPY_DEMO: {**score(copy, data, skills, from_step=from_step),
                                                  **copy.describe()}}
    if reference is None and n_phases is None:  # e.g. imported robot logs
        out[STIFFNESS_RIDGE] = {"skipped": f"not fitted on the train split of {dataset}: its trajectories record no "
                                           "phase_stiffness_Npm; pass n_phases=<the phases of their stiffness "
                                           "schedules> or reference=<json>"}
        log.warning("stiffness reference skipped: %s", out[STIFFNESS_RIDGE]["skipped"])
        return out
    try:
        ridge = load_model(reference) if reference else StiffnessRegression.fit_dataset(
            dataset, "train", n_phases=n_phases, task_from_s=task_from_s, objective=objective)
        if not isinstance(ridge, StiffnessRegression):
            raise ModelInputError(f"reference={reference} is not a stiffness reference JSON")
        ridge.check_phases(n_phases, f"dataset {dataset}")
        ridge.check_window(task_from_s, f"reference={reference}")
        ridge.check_objective(objective, f"reference={reference}")
        out[STIFFNESS_RIDGE] = {**score(ridge, data, skills, from_step=from_step), **ridge.describe()}
    except ValueError as err:  # DatasetError (e.g. no train split), StiffnessScheduleError, ReferenceError
        if reference:  # asked for explicitly: an error, not a silent gap
            raise
        out[STIFFNESS_RIDGE] = {"skipped": f"not fitted on the train split of {dataset}: {err}; "
                                           "pass reference=<json>"}
        log.warning("stiffness reference skipped: %s", out[STIFFNESS_RIDGE]["skipped"])
    return out


def evaluate(ckpt: str | Path, dataset: str | Path, split: str = "test", n_samples: int | None = None,
             n_eval: int | None = None, seed: int = 0, device: str = "auto", reference: str | Path | None = None,
             sampler: str | None = None, sampling_steps: int | None = None,
             task_loss: str | None = None, task_from_s: float = 0.0, prior: str | Path | None = None,
             prior_weight: float = 0.0, n_phases: int | None = None,
             objective: TaskObjective | None = None) -> dict[str, Any]:
    """Metrics of predictor ``ckpt`` on ``split`` of ``dataset``, with the references for a learned model.

    ``sampler`` / ``sampling_steps`` override a DCM's sampler (ddpm | ddim | ddim_even, and its steps) for this run,
    ``task_loss`` how its samples give L_task (of_mean | over_samples; the same for the baseline).
    ``task_from_s``: score only the force from this time on, e.g. 1.0 to leave out the demos' approach and
    touch-down (:func:`dcm.control.objectives.task_window_start`). ``prior`` / ``prior_weight``: rank with the
    model's L_task blended with a stiffness ridge (:mod:`dcm.models.prior_blend`); force metrics are then left
    out, as the blend predicts L_task only. ``n_phases``: the phase count of the split's stiffness schedules, for
    a file whose trajectories do not record it (``phase_stiffness_Npm``); refused if they record another.
    ``objective``: the L_task to score (None: the predictor's own); one of another kind than a checkpoint's is
    refused (:func:`dcm.models.predict.resolve_objective`)."""
    check_prior(prior, prior_weight)
    predictor = load_model(ckpt, map_location="cpu")
    if isinstance(predictor, ForceModel):
        predictor = predictor.to(resolve_device(device))
    if sampler is not None or sampling_steps is not None:
        if not isinstance(predictor, DCM):
            raise ModelInputError(f"sampler / sampling_steps apply to a DCM checkpoint, not to {ckpt}")
        predictor.set_sampler(sampler, sampling_steps)
    if task_loss is not None:
        if not isinstance(predictor, ForceModel):
            raise ModelInputError(f"task_loss applies to a DCM or baseline checkpoint, not to {ckpt}")
        predictor.set_task_loss(task_loss)
    objective = resolve_objective(predictor, objective)
    model = predictor.model if isinstance(predictor, PriorBlend) else predictor
    if isinstance(model, ForceModel):
        model.set_objective(objective, f"ckpt={ckpt}")
    elif isinstance(predictor, CopyDemo):
        predictor.objective = objective
    predictor = with_prior(predictor, prior, prior_weight, f"ckpt={ckpt}")
    loaded = load_dataset(dataset, split=None if split == "all" else split)
    layout = data_layout(predictor, objective)
    cond_channels, target_channels = dataset_channels(loaded, layout.target_fields)
    check_dataset(predictor, cond_channels, target_channels, loaded.control_hz, source=f"dataset {dataset}")
    try:
        recorded = dataset_phases(loaded, required=False)
    except ModelInputError:  # schedules of several phase counts: no one count (nor a ridge) fits them all
        raise ModelInputError(f"dataset {dataset}: its trajectories' schedules have different phase counts "
                              "(phase_stiffness_Npm); evaluate a file of one phase count") from None
    if n_phases is not None and recorded is not None and int(n_phases) != recorded:
        raise ModelInputError(f"n_phases={n_phases}: the trajectories of {dataset} record {recorded}-phase schedules")
    n_phases = recorded if n_phases is None else int(n_phases)
    if isinstance(predictor, (StiffnessRegression, PriorBlend)):
        predictor.check_phases(n_phases, source=f"dataset {dataset}")
        predictor.check_window(task_from_s, source=f"prior={prior}" if prior else f"ckpt={ckpt}")
    try:
        from_step = task_window_start(task_from_s, loaded.control_hz, loaded.horizon)
    except ValueError as err:
        raise ModelInputError(f"dataset {dataset}: {err}") from None
    data = TrajectoryDataset.from_loaded(loaded, layout=layout)
    skills = loaded.demo_ids
    if n_eval is not None:
        if int(n_eval) < 1:
            raise ModelInputError(f"n_eval must be >= 1 or null, got {n_eval}")
        data, skills = data.subset(int(n_eval)), skills[: int(n_eval)]
    result: dict[str, Any] = {
        **score(predictor, data, skills, n_samples, seed, from_step),
        **describe(predictor, n_samples),
        "objective": objective.to_dict(),
        "task_from_s": float(task_from_s),
        "n": len(data),
        "n_skills": int(len(np.unique(skills))),
        "seed": int(seed),
        "ckpt": str(ckpt) if str(ckpt) == COPY_DEMO else str(Path(ckpt).resolve()),
        "dataset": str(Path(dataset).resolve()),
        "split": split,
        "control_hz": loaded.control_hz,
        "horizon": loaded.horizon,
    }
    if isinstance(predictor, (ForceModel, PriorBlend)):
        result["references"] = reference_scores(dataset, data, skills, reference, n_phases, task_from_s, from_step,
                                                objective)
    return result


def data_layout(predictor: Any, objective: TaskObjective) -> TargetLayout:
    """The target a predictor is scored against: a force model's own; for the others the force, and the pose
    too where the objective counts the path (the true L_task needs x_obs)."""
    model = predictor.model if isinstance(predictor, PriorBlend) else predictor
    if isinstance(model, ForceModel):
        return model.layout
    return target_layout("force_and_pose" if objective.counts_path else "force")


def parse_objective(value: Any) -> TaskObjective | None:
    """``objective=``: null (the predictor's own), a preset of conf/objective/ (``wipe``), or a mapping of the
    objective's fields (``objective.name=wipe objective.path_tolerance_m=0.01``)."""
    if value is None:
        return None
    if isinstance(value, str):
        return objective_preset(value)
    try:
        return TaskObjective.from_config(OmegaConf.to_container(value) if OmegaConf.is_config(value) else value)
    except ObjectiveError as err:
        raise ModelInputError(str(err)) from None


CONFIG = CONF_DIR / "evaluate.yaml"


def check_out(out: Any, inputs: dict[str, Any]) -> Path | None:
    """The metrics file of ``out=`` (None: none), refused now if it could not be written once evaluated or
    would replace one of the ``inputs`` (setting name -> path)."""
    if out is None:
        return None
    path = Path(str(out))
    if problem := write_problem(path):
        raise ValueError(f"out={path} cannot be written: {problem}")
    for key, value in inputs.items():
        if value is not None and Path(str(value)).exists() and Path(str(value)).resolve() == path.resolve():
            raise ValueError(f"out={path} is also {key}=; writing the metrics there would replace it")
    return path


# The table's ranking columns and the metrics they show.
TABLE_NAMES = {"R_within": "R_within", "R_within_lo": "90% interval", "R_within_hi": "90% interval",
               "R_within_spearman": "Spearman", REGRET_KEY: REGRET_KEY, "R_pooled": "R_pooled"}


def _fmt(value: Any) -> str:
    if not isinstance(value, float):
        return "-"
    return f"{value:.3f}" if np.isfinite(value) else "n/a"


def undefined_notes(rows: dict[str, dict[str, Any]]) -> list[str]:
    """One line per reason the table shows ``n/a``: what a metric needs that the split lacks, or what left it
    undefined on a split large enough, naming the predictors unless it holds for every row."""
    scored = {name: row for name, row in rows.items() if "skipped" not in row}
    reasons: dict[str, tuple[list[str], list[str]]] = {}  # reason -> (columns, predictors)
    for name, row in scored.items():
        for metric, reason in (row.get("undefined") or {}).items():
            columns, predictors = reasons.setdefault(reason, ([], []))
            if (column := TABLE_NAMES.get(metric, metric)) not in columns:
                columns.append(column)
            if name not in predictors:
                predictors.append(name)
    return [f"n/a{'' if len(predictors) == len(scored) else ' for ' + ', '.join(predictors)}: "
            f"{', '.join(columns)}: {reason}" for reason, (columns, predictors) in reasons.items()]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """CLI: ``key=value`` arguments over conf/evaluate.yaml; prints the table, writes ``out`` if given and
    returns the metrics. Warnings go to stderr."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    quiet_libraries()
    one_line_warnings()
    args = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in args):
        print(__doc__ + "\n" + CONFIG.read_text())
        return {}
    bad = [a for a in args if "=" not in a]
    if bad:
        raise SystemExit(error_line(f"arguments must be key=value, got {bad}"))
    cfg = OmegaConf.merge(OmegaConf.load(CONFIG), OmegaConf.from_dotlist(args))
    unknown = sorted(set(cfg.keys()) - set(OmegaConf.load(CONFIG).keys()))
    missing = sorted(k for k in ("ckpt", "dataset") if OmegaConf.is_missing(cfg, k))
    if unknown or missing:
        raise SystemExit(error_line(f"unknown keys {unknown} / missing keys {missing}; see python -m dcm.evaluate --help"))
    with_shipped_paths(cfg)  # ckpt=models/... from any directory
    try:
        out = check_out(cfg.out, {key: cfg[key] for key in ("ckpt", "dataset", "reference", "prior")})
        result = evaluate(cfg.ckpt, cfg.dataset, split=str(cfg.split), n_samples=cfg.n_samples, n_eval=cfg.n_eval,
                          seed=check_integer(cfg.seed, "seed", 0), device=str(cfg.device), reference=cfg.reference,
                          sampler=cfg.sampler, sampling_steps=cfg.sampling_steps, task_loss=cfg.task_loss,
                          task_from_s=check_number(cfg.task_from_s, "task_from_s"), prior=cfg.prior,
                          prior_weight=cfg.prior_weight,
                          n_phases=None if cfg.n_phases is None else check_integer(cfg.n_phases, "n_phases", 1),
                          objective=parse_objective(cfg.objective))
    except ValueError as err:  # ModelInputError, DatasetError, DatasetMismatchError, CheckpointKindError, ...
        raise SystemExit(error_line(err)) from None
    rows = {result["model"]: result, **result.get("references", {})}
    paths = any("path_rmse_m" in row for row in rows.values())  # a column only where a predictor has a path
    row_format = "%-16s %9s %15s %9s %12s %9s %11s %12s" + (" %14s" if paths else "")
    objective = TaskObjective.from_dict(result.get("objective"))
    scored = "" if objective.name == "paper" else f"; L_task: {objective.describe()}"  # the paper's goes unsaid
    print(f"n={result['n']} trajectories, {result['n_skills']} skills ({result['split']} split){scored}")
    print(row_format % ("predictor", "R_within", "90% interval", "Spearman", "top3_regret", "R_pooled",
                        "L_task_MAE", "force_RMSE", *(("path_RMSE_mm",) if paths else ())))
    for name, row in rows.items():
        interval = f"[{_fmt(row.get('R_within_lo'))}, {_fmt(row.get('R_within_hi'))}]"
        path_mm = row["path_rmse_m"] * 1e3 if isinstance(row.get("path_rmse_m"), float) else None
        print(row_format % (name, _fmt(row.get("R_within")), interval, _fmt(row.get("R_within_spearman")),
                            _fmt(row.get(REGRET_KEY)), _fmt(row.get("R_pooled")), _fmt(row.get("L_task_mae_N")),
                            _fmt(row.get("force_rmse_N")), *((_fmt(path_mm),) if paths else ())))
    for line in undefined_notes(rows):
        print(line)
    if out is not None:
        try:
            with atomic_path(out) as tmp:  # an old metrics file stays whole if this fails
                tmp.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
        except OSError as err:  # checked before evaluating, but a disk can fill up meanwhile
            raise SystemExit(error_line(f"out={out}: cannot write the metrics: {err}")) from None
        print(f"wrote {out}")
    return result


def cli() -> None:
    """Console script ``dcm-evaluate``: as :func:`main`, exit status 0 (a script's return value is its status)."""
    main()


if __name__ == "__main__":
    cli()
