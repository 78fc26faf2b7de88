"""Metrics that answer the tuner's question: does a predictor rank ONE skill's stiffness schedules by L_task?

The tuner compares schedules of a single skill, so the number that matters is the **within-skill**
correlation between predicted and true L_task: computed per skill, then averaged over skills. The pooled
correlation over all trajectories is also reported, but it is dominated by differences *between* skills
(a steep bowl has a higher L_task whatever the stiffness) and can be high while every within-skill ranking
is wrong, or low while every ranking is right.

A "skill" here is one demo (the ``demo_id`` attribute of a trajectory): the tuner tunes one demonstrated
stroke. The ``skill`` attribute of a dataset names the preset's skill *family* ("spiral"), shared by all
spiral demos of ``sim``, so it is not the grouping the tuner sees.

Force metrics put a model's force RMSE next to that of copying the demonstrated force (``F_obs := F_demo``):
a model that does not beat copy-F_demo has learnt nothing about the contact beyond the demo. A model that
predicts the pose gets path metrics beside them, against copying the demonstrated pose (``x_obs := x_demo``).

L_task is the configured objective's (:class:`dcm.control.objectives.TaskObjective`, the paper's force RMSE in N
by default); the ``_N`` of ``L_task_mae_N`` and ``L_task_*_N`` is then its unit.

Pure numpy/scipy on arrays in physical units; every function returns plain floats (NaN when undefined).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

import numpy as np
from scipy import stats

from dcm.control.objectives import PAPER, TaskObjective, surface_normals, tangential
from dcm.data.schema import CHANNELS, FORCE_FIELD, POSE_DELTA_WIDTH

Method = Literal["pearson", "spearman"]
WRENCH_AXES: tuple[str, ...] = tuple(c.split("_")[0] for c in CHANNELS[FORCE_FIELD])  # Fx, Fy, Fz, Tx, Ty, Tz
MIN_TRIALS = 3  # a correlation over 2 points is always +-1: it says nothing about ranking
TOP_PICKS = 3  # schedules of a skill a tuner keeps in the regret metric (about the size of a validated front)
REGRET_KEY = f"top{TOP_PICKS}_regret"
CI_LEVEL, CI_RESAMPLES = 0.9, 1000  # the bootstrap interval of R_within
REGRET_TRIALS = max(MIN_TRIALS, TOP_PICKS + 1)  # a skill's trials the regret needs: more than it keeps
POOLED_TRIALS = 2  # R_pooled: any two trials with different L_task
# The trials each ranking metric needs: per skill, or over the whole split.
RANKING_NEEDS: dict[str, tuple[int, bool]] = {
    "R_within": (MIN_TRIALS, True), "R_within_lo": (MIN_TRIALS, True), "R_within_hi": (MIN_TRIALS, True),
    "R_within_spearman": (MIN_TRIALS, True), REGRET_KEY: (REGRET_TRIALS, True), "R_pooled": (POOLED_TRIALS, False)}


def correlation(pred: np.ndarray, true: np.ndarray, method: Method = "pearson") -> float:
    """Pearson or Spearman correlation of two 1-D arrays; NaN with < 2 points or a constant array."""
    pred = np.asarray(pred, dtype=np.float64).ravel()
    true = np.asarray(true, dtype=np.float64).ravel()
    if pred.shape != true.shape:
        raise ValueError(f"correlation: predicted shape {pred.shape} differs from true shape {true.shape}")
    keep = np.isfinite(pred) & np.isfinite(true)
    pred, true = pred[keep], true[keep]
    if pred.size < 2 or np.ptp(pred) == 0 or np.ptp(true) == 0:
        return float("nan")
    if method == "pearson":
        return float(stats.pearsonr(pred, true).statistic)
    if method == "spearman":
        return float(stats.spearmanr(pred, true).statistic)
    raise ValueError(f"correlation method {method!r} is unknown; expected 'pearson' or 'spearman'")


def _skill_trials(pred: np.ndarray, true: np.ndarray, skills: np.ndarray, min_trials: int,
                  caller: str) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Flat float arrays and, per skill with >= ``min_trials`` finite trials, the indices of those trials."""
    pred = np.asarray(pred, dtype=np.float64).ravel()
    true = np.asarray(true, dtype=np.float64).ravel()
    skills = np.asarray(skills).ravel()
    if not (pred.shape == true.shape == skills.shape):
        raise ValueError(f"{caller}: shapes differ: predicted {pred.shape}, true {true.shape}, skills {skills.shape}")
    finite = np.isfinite(pred) & np.isfinite(true)
    groups = [np.flatnonzero((skills == skill) & finite) for skill in np.unique(skills)]
    return pred, true, [g for g in groups if g.size >= min_trials]


def within_skill_correlation(pred: np.ndarray, true: np.ndarray, skills: np.ndarray, method: Method = "pearson",
                             min_trials: int = MIN_TRIALS) -> tuple[float, int]:
    """Mean over skills of the per-skill correlation, and how many skills entered the mean.

    Skills with fewer than ``min_trials`` finite trials, or a constant predicted or true L_task, have no
    defined ranking and are skipped; the mean is NaN when none is left. A plain (not Fisher-z) mean: each
    skill counts once, whatever its number of trials, as each tuning run does.
    """
    pred, true, groups = _skill_trials(pred, true, skills, min_trials, "within_skill_correlation")
    values = []
    for sel in groups:
        r = correlation(pred[sel], true[sel], method)
        if np.isfinite(r):
            values.append(r)
    return (float(np.mean(values)) if values else float("nan")), len(values)


def within_skill_regret(pred: np.ndarray, true: np.ndarray, skills: np.ndarray, n_top: int = TOP_PICKS
                        ) -> tuple[float, int]:
    """What keeping a predictor's ``n_top`` best-ranked schedules of each skill loses: (their mean true L_task
    - that of the truly best ``n_top``) / (the skill's mean - the same), averaged over skills, and how many
    skills entered the mean.

    0 keeps the truly best schedules, 1 is a random pick, above 1 is worse than random. Unlike R_within, it
    ignores how well a predictor orders the schedules a tuner discards, which decides a Pearson R on a skill
    whose L_task is flat but for a few bad trials. Skills with at most ``n_top`` finite trials, or a constant
    predicted or true L_task, are skipped; NaN when none is left.
    """
    pred, true, groups = _skill_trials(pred, true, skills, max(MIN_TRIALS, n_top + 1), "within_skill_regret")
    values = []
    for sel in groups:
        p, t = pred[sel], true[sel]
        if np.ptp(p) == 0 or np.ptp(t) == 0:
            continue
        kept, best = t[np.argsort(p, kind="stable")[:n_top]], np.sort(t)[:n_top]
        values.append((kept.mean() - best.mean()) / (t.mean() - best.mean()))
    return (float(np.mean(values)) if values else float("nan")), len(values)


def per_skill_ranking(pred: np.ndarray, true: np.ndarray, skills: np.ndarray, n_top: int = TOP_PICKS
                      ) -> list[dict[str, float | int | str]]:
    """One row per skill with >= :data:`MIN_TRIALS` finite trials: how far its schedules differ in L_task,
    how far the predictor errs between them, and how well it ranks them.

    Keys: ``skill``, ``n``, ``L_task_mean_N`` and ``L_task_sd_N`` (the true L_task's mean and spread over
    the skill's trials), ``error_sd_N`` (the spread of the L_task error ``pred - true`` over the same
    trials: an offset shared by the skill's schedules does not reorder them, so only this part can),
    ``signal_to_error`` (``L_task_sd_N / error_sd_N``), ``R``, ``R_spearman`` and ``regret``
    (:func:`within_skill_regret` of the skill alone). With errors independent of L_task, a predictor's R on
    a skill is about ``s / sqrt(1 + s**2)`` for ``s = signal_to_error``: schedules that differ by less than
    the predictor errs cannot be ranked by it, whatever its mean score over skills.
    """
    pred, true, groups = _skill_trials(pred, true, skills, MIN_TRIALS, "per_skill_ranking")
    labels = np.asarray(skills).ravel()
    rows: list[dict[str, float | int | str]] = []
    for sel in groups:
        p, t = pred[sel], true[sel]
        spread, error = float(t.std()), float((p - t).std())
        regret = within_skill_regret(p, t, np.zeros(sel.size), n_top)[0] if sel.size > n_top else float("nan")
        rows.append({"skill": str(labels[sel[0]]), "n": int(sel.size), "L_task_mean_N": float(t.mean()),
                     "L_task_sd_N": spread, "error_sd_N": error,
                     "signal_to_error": spread / error if error > 0 else float("inf"),
                     "R": correlation(p, t, "pearson"), "R_spearman": correlation(p, t, "spearman"),
                     "regret": regret})
    return rows


def _rowwise_pearson(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Pearson correlation of each row pair of two (B, n) arrays; NaN where a row is constant."""
    pred = pred - pred.mean(axis=1, keepdims=True)
    true = true - true.mean(axis=1, keepdims=True)
    norm = np.sqrt((pred**2).sum(axis=1) * (true**2).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, (pred * true).sum(axis=1) / norm, np.nan)


def within_skill_interval(pred: np.ndarray, true: np.ndarray, skills: np.ndarray, level: float = CI_LEVEL,
                          n_resamples: int = CI_RESAMPLES, seed: int = 0,
                          min_trials: int = MIN_TRIALS) -> tuple[float, float]:
    """Bootstrap interval of the within-skill Pearson R: trials resampled with replacement inside each skill.

    It says how much a split can tell: one skill of 30 trials whose L_task barely varies gives an interval
    wide enough to hold both a useless and a good ranking. Seeded, so the same inputs give the same bounds.
    """
    pred, true, groups = _skill_trials(pred, true, skills, min_trials, "within_skill_interval")
    rng = np.random.default_rng(seed)
    per_skill = []
    for sel in groups:
        draw = sel[rng.integers(0, sel.size, size=(n_resamples, sel.size))]
        per_skill.append(_rowwise_pearson(pred[draw], true[draw]))
    if not per_skill:
        return float("nan"), float("nan")
    rs = np.stack(per_skill)  # (skills, resamples); NaN where a resample made a skill's L_task constant
    counts = np.isfinite(rs).sum(axis=0)
    means = np.nansum(rs, axis=0)[counts > 0] / counts[counts > 0]
    if means.size == 0:
        return float("nan"), float("nan")
    tail = 50.0 * (1.0 - level)
    lo, hi = np.percentile(means, [tail, 100.0 - tail])
    return float(lo), float(hi)


def ranking_metrics(L_pred: np.ndarray, L_true: np.ndarray, skills: np.ndarray | None) -> dict[str, float]:
    """Predicted vs true L_task [N] over trajectories of one split.

    Keys: ``R_within`` / ``R_within_spearman`` (per-skill Pearson / Spearman averaged over skills; the
    checkpoint-selection metric), ``R_within_n_skills`` (skills used), ``R_within_lo`` / ``R_within_hi`` (the
    bootstrap 90 % interval of ``R_within``, :func:`within_skill_interval`), ``R_pooled`` (Pearson over all
    trajectories), ``L_task_mae_N`` (mean absolute error of L_task), ``top3_regret``
    (:func:`within_skill_regret`: what keeping the 3 best-ranked schedules per skill loses).
    ``skills=None`` (no labels) leaves the within-skill values NaN.
    """
    L_pred = np.asarray(L_pred, dtype=np.float64).ravel()
    L_true = np.asarray(L_true, dtype=np.float64).ravel()
    if skills is None:
        r_within, r_within_s, regret, n_skills = float("nan"), float("nan"), float("nan"), 0
        interval = (float("nan"), float("nan"))
    else:
        r_within, n_skills = within_skill_correlation(L_pred, L_true, skills, "pearson")
        r_within_s, _ = within_skill_correlation(L_pred, L_true, skills, "spearman")
        interval = within_skill_interval(L_pred, L_true, skills)
        regret, _ = within_skill_regret(L_pred, L_true, skills)
    finite = np.isfinite(L_pred) & np.isfinite(L_true)
    return {
        "R_within": r_within,
        "R_within_spearman": r_within_s,
        "R_within_n_skills": int(n_skills),
        "R_within_lo": interval[0],
        "R_within_hi": interval[1],
        REGRET_KEY: regret,
        "R_pooled": correlation(L_pred, L_true, "pearson"),
        "L_task_mae_N": float(np.abs(L_pred[finite] - L_true[finite]).mean()) if finite.any() else float("nan"),
    }


def ranking_shortfall(name: str, skills: np.ndarray, split: str = "this split") -> str | None:
    """``"needs >= 3 trials per skill; this split has 1"`` when a split whose trials have these ``skills`` is too
    small to define ranking metric ``name`` (a key of :data:`RANKING_NEEDS`), else None."""
    if name not in RANKING_NEEDS:
        return None
    need, per_skill = RANKING_NEEDS[name]
    labels = np.asarray(skills).ravel()
    have = (int(np.unique(labels, return_counts=True)[1].max()) if labels.size else 0) if per_skill else labels.size
    return f"needs >= {need} trials{' per skill' if per_skill else ''}; {split} has {have}" if have < need else None


def undefined_metrics(metrics: Mapping[str, float], skills: np.ndarray, split: str = "this split",
                      prefix: str = "") -> dict[str, str]:
    """Why each ranking metric that ``metrics`` holds as NaN is undefined, so that a command says it instead of
    printing NaN: :func:`ranking_shortfall`, or, on a split large enough, a constant L_task. ``prefix`` is the
    metrics' key prefix (``"test/"``), ``split`` how the reason names the split."""
    out = {}
    for name in RANKING_NEEDS:
        value = metrics.get(prefix + name)
        if value is not None and not np.isfinite(value):
            out[prefix + name] = (ranking_shortfall(name, skills, split)
                                  or "the predicted or the true L_task is constant")
    return out


def force_rmse(force_a: np.ndarray, force_b: np.ndarray) -> float:
    """RMSE [N] between two (..., H, >=3) wrench arrays over everything and the 3 force axes."""
    a = np.asarray(force_a, dtype=np.float64)[..., :3]
    b = np.asarray(force_b, dtype=np.float64)[..., :3]
    return float(np.sqrt(np.mean((a - b) ** 2)))


def force_metrics(F_pred: np.ndarray, F_obs: np.ndarray, F_demo: np.ndarray) -> dict[str, float]:
    """Force accuracy of a prediction (N, H, 6) against the observed wrench, next to copy-F_demo's.

    Keys: ``rmse_<axis>`` per wrench axis [N or N·m], ``force_rmse_N`` (force axes together),
    ``force_rmse_copy_N`` (the same for predicting F_obs := F_demo), ``force_rmse_ratio_copy``
    (model / copy: below 1 the model beats copying the demo).
    """
    F_pred = np.asarray(F_pred, dtype=np.float64)
    F_obs = np.asarray(F_obs, dtype=np.float64)
    axis_rmse = np.sqrt(np.mean((F_pred - F_obs).reshape(-1, F_obs.shape[-1]) ** 2, axis=0))
    out = {f"rmse_{axis}": float(v) for axis, v in zip(WRENCH_AXES, axis_rmse)}
    model, copy = force_rmse(F_pred, F_obs), force_rmse(F_demo, F_obs)
    out.update(force_rmse_N=model, force_rmse_copy_N=copy,
               force_rmse_ratio_copy=model / copy if copy > 0 else float("nan"))
    return out


def skill_common_rmse(force_a: np.ndarray, force_b: np.ndarray, skills: np.ndarray) -> float:
    """RMS [N] of the part of the force error (a - b) that a skill's trials share: per skill, the mean error
    over its trials at each step and force axis, counted once per trial.

    It is the error in the path's own force profile, the same whatever the schedule, so it mostly shifts a
    skill's L_task rather than reorder its schedules; the rest of the error (``sqrt(total² - common²)``)
    is what varies with the schedule. A skill of one trial shares all of its error.
    """
    error = (np.asarray(force_a, dtype=np.float64) - np.asarray(force_b, dtype=np.float64))[..., :3]
    skills = np.asarray(skills).ravel()
    if skills.shape != error.shape[:1]:
        raise ValueError(f"skill_common_rmse: {skills.shape[0]} skills for {error.shape[0]} trajectories")
    common = np.empty_like(error)
    for skill in np.unique(skills):
        sel = skills == skill
        common[sel] = error[sel].mean(axis=0)
    return float(np.sqrt(np.mean(common**2)))


def path_rmse(x_pred: np.ndarray, x_obs: np.ndarray, x_demo: np.ndarray, F_demo: np.ndarray,
              from_step: int = 0) -> float:
    """RMSE [m] of a predicted against the observed tool translation (N, H, >=3), over everything from step
    ``from_step`` on, in the surface's tangent plane along the demo (:func:`dcm.control.objectives.surface_normals`):
    the part of the pose that the path error of L_task counts."""
    normals = surface_normals(x_demo, F_demo)[..., from_step:, :]
    a, b = (np.asarray(x, dtype=np.float64)[..., from_step:, :POSE_DELTA_WIDTH] for x in (x_pred, x_obs))
    return float(np.sqrt(np.mean((tangential(a - b, normals) ** 2).sum(-1))))


def pose_metrics(x_pred: np.ndarray, x_obs: np.ndarray, x_demo: np.ndarray, F_demo: np.ndarray,
                 from_step: int = 0) -> dict[str, float]:
    """Path accuracy of a pose prediction against the observed pose, next to copy-x_demo's.

    Keys: ``path_rmse_m`` (:func:`path_rmse`), ``path_rmse_copy_m`` (the same for predicting x_obs := x_demo)
    and ``path_rmse_ratio_copy`` (model / copy: below 1 the model beats copying the demo).
    """
    model = path_rmse(x_pred, x_obs, x_demo, F_demo, from_step)
    copy = path_rmse(x_demo, x_obs, x_demo, F_demo, from_step)
    return {"path_rmse_m": model, "path_rmse_copy_m": copy,
            "path_rmse_ratio_copy": model / copy if copy > 0 else float("nan")}


def force_prediction_metrics(F_pred: np.ndarray, F_obs: np.ndarray, F_demo: np.ndarray,
                             skills: np.ndarray | None, L_pred: np.ndarray | None = None,
                             objective: TaskObjective = PAPER, x_pred: np.ndarray | None = None,
                             x_obs: np.ndarray | None = None, x_demo: np.ndarray | None = None,
                             from_step: int = 0) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    """:func:`force_metrics` plus :func:`ranking_metrics` of the L_task the prediction implies, and with
    ``skills`` the part of the model's and copy-F_demo's force error a skill's trials share
    (:func:`skill_common_rmse`: ``force_rmse_skill_common_N``, ``force_rmse_skill_common_copy_N``); for a
    pose prediction ``x_pred`` (N, H, 3) also :func:`pose_metrics`.

    Arrays span whole trajectories; errors and L_task count the steps from ``from_step`` on. Returns
    ``(metrics, L_task_pred, L_task_true)``; L_task is ``objective``'s (the path counted when it counts it:
    then ``x_obs`` and ``x_demo`` are needed, and ``x_pred`` unless ``L_pred`` is given), of the prediction
    unless the model gives its own ``L_pred`` (``ForceModel.predicted_task_loss``).
    """
    def f64(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.asarray(a, np.float64)

    if L_pred is None:
        L_pred = np.asarray(objective.task_loss(f64(F_pred), f64(F_demo), f64(x_pred), f64(x_demo), from_step))
    L_true = np.asarray(objective.task_loss(f64(F_obs), f64(F_demo), f64(x_obs), f64(x_demo), from_step))
    window = (Ellipsis, slice(int(from_step), None), slice(None))
    F_pred, F_obs, F_demo_w = (np.asarray(a)[window] for a in (F_pred, F_obs, F_demo))
    metrics = force_metrics(F_pred, F_obs, F_demo_w)
    if skills is not None:
        metrics.update(force_rmse_skill_common_N=skill_common_rmse(F_pred, F_obs, skills),
                       force_rmse_skill_common_copy_N=skill_common_rmse(F_demo_w, F_obs, skills))
    if x_pred is not None and x_obs is not None and x_demo is not None:
        metrics.update(pose_metrics(x_pred, x_obs, x_demo, F_demo, from_step))
    return {**metrics, **ranking_metrics(L_pred, L_true, skills)}, L_pred, L_true


__all__ = ["CI_LEVEL", "CI_RESAMPLES", "MIN_TRIALS", "POOLED_TRIALS", "RANKING_NEEDS", "REGRET_KEY", "REGRET_TRIALS",
           "TOP_PICKS", "WRENCH_AXES", "correlation", "force_metrics", "force_prediction_metrics", "force_rmse",
           "path_rmse", "per_skill_ranking", "pose_metrics", "ranking_metrics", "ranking_shortfall",
           "skill_common_rmse", "undefined_metrics", "within_skill_correlation", "within_skill_interval",
           "within_skill_regret"]
