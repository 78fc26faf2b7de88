"""The certification statistics T1-T5, as pure functions of an oracle's expected losses.

Inputs per skill: ``task`` (S,) the expected L_task [N] of each schedule (mean over rollouts, inf if any
failed), ``comp`` (S,) its L_comp [kN/m], ``constant`` (S,) True where the schedule holds one stiffness
throughout. Each function documents its definition; the known-answer tests pin them down.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dcm.tuning.pareto import hypervolume

COMP_TOL = 1e-9  # "equal or lower L_comp" up to round-off


def approach_share(sq_approach: np.ndarray, sq_total: np.ndarray) -> float:
    """T1: the median over (schedule, rollout) of the approach's share of a trajectory's squared force error."""
    ok = np.isfinite(sq_total) & (sq_total > 0)
    return float(np.median(sq_approach[ok] / sq_total[ok])) if ok.any() else float("nan")


def best_constant_within(task: np.ndarray, comp: np.ndarray, constant: np.ndarray, budget: float) -> float:
    """The lowest expected L_task of a constant schedule with L_comp <= ``budget``; inf if there is none."""
    pick = constant & (comp <= budget + COMP_TOL)
    return float(task[pick].min()) if pick.any() else float("inf")


def variable_gain(task: np.ndarray, comp: np.ndarray, constant: np.ndarray) -> dict[str, float]:
    """T2 for one skill.

    ``gain``: the best schedule overall (lowest expected L_task) against the best constant schedule of equal or
    lower L_comp, ``1 - L(best) / L(best constant within L_comp(best))``; 0 when the best is a constant. When
    no constant is as cheap as the best schedule, it is compared with the cheapest constant (which then has
    more L_comp, so the gain is understated, not overstated).
    ``max_gain``: the largest such gain of any schedule against the constants within its own L_comp (the
    definition of the earlier probe; optimistic, since it maximises over noisy estimates).
    """
    finite = np.isfinite(task)
    best = int(np.argmin(np.where(finite, task, np.inf)))
    reference = best_constant_within(task, comp, constant, comp[best])
    if not np.isfinite(reference):
        cheapest = np.flatnonzero(constant)[np.argmin(comp[constant])]
        reference = float(task[cheapest])
    gain = 0.0 if constant[best] else 1.0 - float(task[best]) / reference
    gains = []
    for i in np.flatnonzero(finite & ~constant):
        ref = best_constant_within(task, comp, constant, comp[i])
        if np.isfinite(ref):
            gains.append(1.0 - float(task[i]) / ref)
    return {"gain": gain, "max_gain": max(gains, default=0.0), "best": best, "best_task": float(task[best]),
            "constant_task": reference}


def front_hypervolume(task: np.ndarray, comp: np.ndarray, reference: np.ndarray,
                      pick: np.ndarray | None = None) -> float:
    """I_H of the schedules ``pick`` (all if None), judged by their expected losses, against ``reference``."""
    idx = np.arange(len(task)) if pick is None else np.asarray(pick)
    points = np.column_stack([task[idx], comp[idx]])
    points = points[np.all(np.isfinite(points), axis=1)]
    return hypervolume(points, reference) if len(points) else 0.0


def greedy_rule(tasks: Sequence[np.ndarray], comps: Sequence[np.ndarray], references: Sequence[np.ndarray],
                size: int) -> list[int]:
    """The best fixed rule of ``size`` schedules for a set of skills: schedules added one at a time, each the one
    that most raises the mean over skills of I_H(rule) / I_H(all schedules). Fit on train skills only."""
    full = [front_hypervolume(t, c, r) for t, c, r in zip(tasks, comps, references)]
    chosen: list[int] = []
    for _ in range(size):
        scores = []
        for cand in range(len(tasks[0])):
            if cand in chosen:
                scores.append(-np.inf)
                continue
            pick = np.array(chosen + [cand])
            scores.append(np.mean([front_hypervolume(t, c, r, pick) / max(f, 1e-12)
                                   for t, c, r, f in zip(tasks, comps, references, full)]))
        chosen.append(int(np.argmax(scores)))
    return chosen


def single_schedule_regret(tasks: np.ndarray, comp: np.ndarray) -> dict[str, object]:
    """T4. ``tasks`` (K, S): expected L_task of every schedule on each of K skills; ``comp`` (S,) is the same on
    every skill (equal-time phases, one horizon).

    The best single schedule is the one of lowest geometric-mean L_task over the skills (each skill's losses
    weigh by ratio, not by scale). Each skill's regret is ``L(single) / L(own best within L_comp(single)) - 1``:
    its own best at equal or lower L_comp. Returns the single schedule, the per-skill regrets and their median.
    """
    tasks = np.asarray(tasks, dtype=np.float64)
    usable = np.all(np.isfinite(tasks), axis=0)
    log_mean = np.where(usable, np.log(np.where(usable, tasks, 1.0)).mean(axis=0), np.inf)
    single = int(np.argmin(log_mean))
    within = comp <= comp[single] + COMP_TOL
    own = np.where(within[None, :], tasks, np.inf).min(axis=1)
    regrets = tasks[:, single] / own - 1.0
    return {"single": single, "regrets": regrets.tolist(), "median": float(np.median(regrets))}


def ridge_features_input(diagonal: np.ndarray) -> np.ndarray:
    """The commanded schedules (S, P, 6) of per-phase diagonals (S, P, 3), one control step per phase: what
    ``dcm.models.references.StiffnessRegression`` reads its per-phase values from (equal-time phases, so one step
    per phase is exact), with the rotational 20 N·m/rad every schedule has."""
    diagonal = np.asarray(diagonal, dtype=np.float64)
    return np.concatenate([diagonal, np.full(diagonal.shape, 20.0)], axis=-1)


def fit_stiffness_ridge(diagonals: Sequence[np.ndarray], tasks: Sequence[np.ndarray]) -> object:
    """T5's ranker: the project's stiffness-only ridge (``StiffnessRegression``: log L_task on per-phase K, 1/K and
    phase-to-phase changes, centred within each skill, ridge strength by grouped cross-validation) fitted on the
    expected L_task of every schedule of each skill (schedules with an inf loss left out)."""
    from dcm.models.references import StiffnessRegression

    K, L, skills = [], [], []
    for k, (diag, task) in enumerate(zip(diagonals, tasks)):
        ok = np.isfinite(task) & (task > 0)
        K.append(ridge_features_input(diag)[ok])
        L.append(np.asarray(task)[ok])
        skills.append(np.full(int(ok.sum()), k))
    n_phases = int(np.asarray(diagonals[0]).shape[1])
    return StiffnessRegression.fit(np.concatenate(K), np.concatenate(L), np.concatenate(skills), n_phases,
                                   control_hz=20.0)


def ridge_spearman(model: object, diagonal: np.ndarray, task: np.ndarray) -> float:
    """The within-skill Spearman of the ridge's predicted L_task against one skill's expected L_task."""
    from scipy.stats import spearmanr

    ok = np.isfinite(task)
    pred = model.predict_log_task_loss(ridge_features_input(diagonal)[ok])  # type: ignore[attr-defined]
    return float(spearmanr(pred, np.asarray(task)[ok]).statistic)


def ridge_ranking(train: Sequence[tuple[np.ndarray, np.ndarray]],
                  evaluate: Sequence[tuple[np.ndarray, np.ndarray]] | None = None) -> dict[str, object]:
    """T5: how well a stiffness-only ridge fitted on ``train`` skills ((S, P, 3) diagonals, (S,) expected L_task)
    ranks the schedules of each ``evaluate`` skill (within-skill Spearman), and their median. With ``evaluate``
    None it is leave-one-skill-out over ``train`` (the design-time proxy on the train skills). T5 holds when the
    median is <= 0.7: the schedule's stiffness alone does not rank a new skill's schedules well."""
    if evaluate is None:
        rhos = []
        for k in range(len(train)):
            rest = [t for j, t in enumerate(train) if j != k]
            model = fit_stiffness_ridge([d for d, _ in rest], [t for _, t in rest])
            rhos.append(ridge_spearman(model, *train[k]))
        mode = "leave-one-skill-out"
    else:
        model = fit_stiffness_ridge([d for d, _ in train], [t for _, t in train])
        rhos = [ridge_spearman(model, d, t) for d, t in evaluate]
        mode = "fitted on the train skills"
    return {"spearman": rhos, "median": float(np.median(rhos)), "mode": mode}
