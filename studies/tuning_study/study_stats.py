"""Statistics of a multi-seed tuning study: median and IQR of I_H per tuner, and paired tests against the DCM.

Pure functions on plain numbers, so they are tested on hand-made results. A seed pairs the tuners: every
tuner of seed s tuned the same skill with search seed s, so the DCM and a control are compared by the
Wilcoxon signed-rank test on their per-seed differences, not by two independent samples.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np


def summarize(values: Sequence[float]) -> dict[str, float | int]:
    """n, median, quartiles, IQR, mean, min and max of the finite values (NaN where there are none)."""
    finite = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    if not len(finite):
        return {"n": 0, **{key: math.nan for key in ("median", "q1", "q3", "iqr", "mean", "min", "max")}}
    q1, median, q3 = np.percentile(finite, [25, 50, 75])
    return {"n": int(len(finite)), "median": float(median), "q1": float(q1), "q3": float(q3),
            "iqr": float(q3 - q1), "mean": float(finite.mean()), "min": float(finite.min()), "max": float(finite.max())}


def paired_test(first: Sequence[float], second: Sequence[float]) -> dict[str, float | int | None]:
    """Two-sided Wilcoxon signed-rank test of ``first`` vs ``second``, paired by position (seed).

    Pairs with a missing (NaN/None) value are dropped, then :func:`signed_rank_test` tests the differences.
    """
    if len(first) != len(second):
        raise ValueError(f"paired test needs one value per seed on both sides, got {len(first)} and {len(second)}")
    pairs = [(a, b) for a, b in zip(first, second)
             if a is not None and b is not None and math.isfinite(a) and math.isfinite(b)]
    return signed_rank_test([a - b for a, b in pairs])


def signed_rank_test(differences: Sequence[float]) -> dict[str, float | int | None]:
    """Two-sided Wilcoxon signed-rank test of paired differences against zero.

    Zero differences are dropped before testing, so scipy gives its exact p up to 50 untied pairs. ``p`` is 1
    when every difference is zero and None with fewer than two pairs (no test possible); ``wins`` counts the
    positive differences.
    """
    from scipy.stats import wilcoxon

    diff = np.asarray(differences, dtype=np.float64)
    result: dict[str, float | int | None] = {
        "n_pairs": len(diff), "median_difference": float(np.median(diff)) if len(diff) else math.nan,
        "wins": int((diff > 0).sum()), "losses": int((diff < 0).sum()), "ties": int((diff == 0).sum()),
        "statistic": None, "p": None,
    }
    if len(diff) < 2:
        return result
    if not np.any(diff):
        result.update(statistic=0.0, p=1.0)
        return result
    test = wilcoxon(diff[diff != 0], alternative="two-sided")
    result.update(statistic=float(test.statistic), p=float(test.pvalue))
    return result


def aggregate(results: Mapping[str, Sequence[float]], subject: str = "dcm", alpha: float = 0.05) -> dict:
    """Per tuner: summary of I_H over seeds; per control: the paired test of ``subject`` against it.

    ``results`` maps a tuner to its I_H per seed, every list in the same seed order (NaN for a missing run).
    Returns ``{"tuners": {name: summary}, "tests": {control: test + "significant"}, "subject", "alpha"}``.
    """
    if subject not in results:
        raise ValueError(f"aggregate: no results for the subject tuner {subject!r}; have {sorted(results)}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha} must be in (0, 1)")
    tests = {}
    for control, values in results.items():
        if control == subject:
            continue
        test = paired_test(results[subject], values)
        test["significant"] = test["p"] is not None and test["p"] < alpha
        tests[control] = test
    return {"subject": subject, "alpha": alpha,
            "tuners": {name: summarize(values) for name, values in results.items()}, "tests": tests}


def landscape(phase_stiffness: np.ndarray, task_loss: np.ndarray) -> dict[str, float | int]:
    """How much the stiffness moves this skill's L_task, over simulated trials (N, P, 3) and their L_task (N,).

    A skill whose L_task hardly changes between schedules leaves the tuner little to rank: its front is then
    set by L_comp, which every tuner computes exactly, and a better contact model cannot show. Returns the
    L_task quantiles (10 / 50 / 90 %), the spread q90 / q10, and Spearman's rho of L_task against the mean
    stiffness of the schedule (negative: stiffer tracks better).
    """
    from scipy.stats import spearmanr

    task_loss = np.asarray(task_loss, dtype=np.float64).reshape(-1)
    mean_k = np.asarray(phase_stiffness, dtype=np.float64).reshape(len(task_loss), -1).mean(axis=1)
    q10, q50, q90 = np.percentile(task_loss, [10, 50, 90])
    varies = len(task_loss) > 2 and np.ptp(mean_k) > 0 and np.ptp(task_loss) > 0
    rho = spearmanr(task_loss, mean_k).statistic if varies else math.nan
    return {"n_trials": int(len(task_loss)), "q10": float(q10), "median": float(q50), "q90": float(q90),
            "spread_q90_q10": float(q90 / q10) if q10 > 0 else math.nan, "spearman_mean_K": float(rho)}
