"""dcm.models.metrics on hand-made cases: within-skill vs pooled correlation, skipping, force RMSE vs copy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from dcm.models.metrics import (
    correlation,
    force_metrics,
    force_prediction_metrics,
    per_skill_ranking,
    ranking_metrics,
    skill_common_rmse,
    within_skill_correlation,
    within_skill_interval,
    within_skill_regret,
)


def test_pooled_high_but_every_within_skill_ranking_inverted() -> None:
    # two skills at very different levels; inside each, the predicted order is the reverse of the true one
    true = np.array([1.0, 2.0, 3.0, 10.0, 11.0, 12.0])
    pred = np.array([1.3, 1.2, 1.1, 10.3, 10.2, 10.1])
    skills = np.array([0, 0, 0, 1, 1, 1])
    m = ranking_metrics(pred, true, skills)
    assert m["R_pooled"] > 0.95
    assert m["R_within"] == pytest.approx(-1.0) and m["R_within_spearman"] == pytest.approx(-1.0)
    assert m["R_within_n_skills"] == 2
    assert m["L_task_mae_N"] == pytest.approx(np.abs(pred - true).mean())


def test_pooled_negative_but_every_within_skill_ranking_right() -> None:
    # the levels are swapped between skills, the orders inside each skill are right
    true = np.array([1.0, 2.0, 3.0, 10.0, 11.0, 12.0])
    pred = np.array([11.0, 12.0, 13.0, 1.0, 2.0, 3.0])
    m = ranking_metrics(pred, true, np.array([5, 5, 5, 9, 9, 9]))
    assert m["R_pooled"] < -0.8
    assert m["R_within"] == pytest.approx(1.0) and m["R_within_spearman"] == pytest.approx(1.0)


def test_shuffled_predictions_give_zero_within_skill_correlation() -> None:
    rng = np.random.default_rng(0)
    n_skills, n_trials = 300, 10
    skills = np.repeat(np.arange(n_skills), n_trials)
    true = rng.lognormal(size=n_skills * n_trials) + 10.0 * skills / n_skills  # levels differ by skill
    pred = true.copy()
    for s in range(n_skills):  # the right values, in a random order within each skill
        sel = skills == s
        pred[sel] = rng.permutation(true[sel])
    m = ranking_metrics(pred, true, skills)
    assert abs(m["R_within"]) < 0.05 and abs(m["R_within_spearman"]) < 0.05
    assert m["R_within_n_skills"] == n_skills
    assert m["R_pooled"] > 0.5  # the levels alone make the pooled correlation look good


def test_regret_is_zero_for_the_right_order_one_for_a_random_pick_and_above_for_the_reverse() -> None:
    rng = np.random.default_rng(2)
    n_skills, n_trials = 400, 12
    skills = np.repeat(np.arange(n_skills), n_trials)
    true = rng.lognormal(size=n_skills * n_trials) + skills  # levels differ by skill: regret is per skill
    assert within_skill_regret(2.0 * true + 5.0, true, skills) == (0.0, n_skills)  # any monotone map keeps the best
    shuffled = np.concatenate([rng.permutation(true[skills == s]) for s in range(n_skills)])
    assert within_skill_regret(shuffled, true, skills)[0] == pytest.approx(1.0, abs=0.05)
    assert within_skill_regret(-true, true, skills)[0] > 2.0
    assert ranking_metrics(-true, true, skills)["top3_regret"] == within_skill_regret(-true, true, skills)[0]


def test_regret_sees_what_a_pearson_r_driven_by_one_bad_trial_hides() -> None:
    # one skill whose L_task is flat but for one bad trial (the held-out line is like this): a predictor that
    # spots the bad trial and orders the rest backwards has a high Pearson R and keeps the worst of the rest
    true = np.array([0.50, 0.20, 0.21, 0.22, 0.23, 0.24, 0.25, 0.26])
    pred = np.array([0.90, 0.26, 0.25, 0.24, 0.23, 0.22, 0.21, 0.20])
    skills = np.zeros(true.size, dtype=int)
    m = ranking_metrics(pred, true, skills)
    assert m["R_within"] > 0.9 and m["R_within_spearman"] < 0.0
    kept, best = np.array([0.26, 0.25, 0.24]).mean(), np.array([0.20, 0.21, 0.22]).mean()
    assert m["top3_regret"] == pytest.approx((kept - best) / (true.mean() - best))


def test_regret_skips_skills_with_too_few_trials_or_a_constant_prediction() -> None:
    true = np.array([1.0, 2.0, 3.0, 4.0, 1.0, 2.0, 3.0, 4.0, 1.0, 2.0, 3.0])
    pred = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 5.0, 5.0, 5.0, 3.0, 2.0, 1.0])
    skills = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2])  # skill 1: constant prediction, skill 2: only 3 trials
    assert within_skill_regret(pred, true, skills) == (0.0, 1)
    assert math.isnan(within_skill_regret(pred[4:], true[4:], skills[4:])[0])


def test_mean_over_skills_matches_scipy_per_skill() -> None:
    rng = np.random.default_rng(1)
    pred, true = rng.normal(size=12), rng.normal(size=12)
    skills = np.repeat([0, 1, 2], 4)
    expected = np.mean([stats.pearsonr(pred[skills == s], true[skills == s]).statistic for s in range(3)])
    assert within_skill_correlation(pred, true, skills)[0] == pytest.approx(expected)
    expected_s = np.mean([stats.spearmanr(pred[skills == s], true[skills == s]).statistic for s in range(3)])
    assert within_skill_correlation(pred, true, skills, "spearman")[0] == pytest.approx(expected_s)


def test_small_or_constant_skills_are_skipped_and_counted() -> None:
    true = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 1.0, 2.0, 3.0, 7.0, 8.0])
    pred = np.array([1.0, 2.0, 3.0, 0.5, 0.5, 0.5, 0.5, 0.5, 1.0, 0.0])
    skills = np.array([0, 0, 0, 1, 1, 1, 1, 1, 2, 2])  # 1: constant prediction; 2: two trials only
    assert within_skill_correlation(pred, true, skills) == (pytest.approx(1.0), 1)
    r, n = within_skill_correlation(np.zeros(6), np.arange(6.0), np.zeros(6))  # copy-F_demo: L_task 0 everywhere
    assert math.isnan(r) and n == 0
    m = ranking_metrics(pred, true, None)
    assert math.isnan(m["R_within"]) and m["R_within_n_skills"] == 0 and np.isfinite(m["R_pooled"])
    assert math.isnan(correlation(np.ones(4), np.arange(4.0)))


def test_spearman_sees_a_monotone_ranking_that_pearson_underrates() -> None:
    true = np.arange(1.0, 7.0)
    pred = np.exp(3 * true)
    skills = np.zeros(6, int)
    assert within_skill_correlation(pred, true, skills, "spearman")[0] == pytest.approx(1.0)
    assert within_skill_correlation(pred, true, skills, "pearson")[0] < 0.9


def test_force_rmse_next_to_copy_demo() -> None:
    rng = np.random.default_rng(2)
    F_demo = rng.normal(size=(4, 20, 6))
    F_obs = F_demo + rng.normal(scale=2.0, size=F_demo.shape)
    copy = force_metrics(F_demo, F_obs, F_demo)
    assert copy["force_rmse_N"] == pytest.approx(copy["force_rmse_copy_N"]) and copy["force_rmse_ratio_copy"] == 1.0
    exact = force_metrics(F_obs, F_obs, F_demo)
    assert exact["force_rmse_N"] == 0.0 and exact["force_rmse_ratio_copy"] == 0.0
    half = force_metrics(F_demo + 0.5 * (F_obs - F_demo), F_obs, F_demo)
    assert half["force_rmse_ratio_copy"] == pytest.approx(0.5)
    assert half["rmse_Fz"] == pytest.approx(np.sqrt(np.mean((0.5 * (F_obs - F_demo)[..., 2]) ** 2)))
    assert set(half) >= {"rmse_Fx", "rmse_Fy", "rmse_Fz", "rmse_Tx", "rmse_Ty", "rmse_Tz"}
    # the L_task implied by the forces: copy-F_demo predicts 0 everywhere, so it ranks nothing
    m, L_pred, L_true = force_prediction_metrics(F_demo, F_obs, F_demo, np.zeros(4, int))
    assert np.all(L_pred == 0) and math.isnan(m["R_within"]) and m["L_task_mae_N"] == pytest.approx(L_true.mean())


def test_skill_common_error_splits_a_path_bias_from_what_varies_with_the_schedule() -> None:
    rng = np.random.default_rng(3)
    F_obs = rng.normal(size=(6, 30, 6))
    skills = np.array([0, 0, 0, 1, 1, 1])
    bias = rng.normal(size=(2, 30, 6))  # one force-profile error per skill, the same for each of its trials
    biased = F_obs + bias[skills]
    assert skill_common_rmse(biased, F_obs, skills) == pytest.approx(np.sqrt(np.mean(bias[..., :3] ** 2)))
    # zero-mean scatter within every skill shares nothing
    scatter = rng.normal(size=(3, 30, 6))
    scattered = F_obs + np.concatenate([scatter - scatter.mean(0), scatter - scatter.mean(0)])
    assert skill_common_rmse(scattered, F_obs, skills) == pytest.approx(0.0, abs=1e-12)
    # pooled over both skills the two biases would partly cancel; per skill they do not
    assert skill_common_rmse(biased, F_obs, skills) > skill_common_rmse(biased, F_obs, np.zeros(6, int))
    m = force_prediction_metrics(biased, F_obs, F_obs + 2.0, skills)[0]
    assert m["force_rmse_skill_common_N"] == pytest.approx(m["force_rmse_N"])
    assert m["force_rmse_skill_common_copy_N"] == pytest.approx(2.0)
    assert "force_rmse_skill_common_N" not in force_prediction_metrics(biased, F_obs, F_obs, None)[0]
    with pytest.raises(ValueError, match="5 skills for 6 trajectories"):
        skill_common_rmse(biased, F_obs, skills[:5])


def test_interval_is_narrow_for_many_trials_and_wide_when_one_trial_carries_the_correlation() -> None:
    rng = np.random.default_rng(2)
    true = rng.normal(size=200)
    pred = true + 0.5 * rng.normal(size=200)  # R = 1 / sqrt(1.25) = 0.89
    lo, hi = within_skill_interval(pred, true, np.zeros(200))
    assert lo < within_skill_correlation(pred, true, np.zeros(200))[0] < hi and hi - lo < 0.1
    # the wavelike test skill's case: 29 trials unrelated to the truth, one outlier both get right
    true, pred = rng.normal(size=30) * 0.01, rng.normal(size=30) * 0.01
    true[0], pred[0] = 0.2, 0.2
    r = within_skill_correlation(pred, true, np.zeros(30))[0]
    lo, hi = within_skill_interval(pred, true, np.zeros(30))
    assert r > 0.8 and lo < 0.1 and hi > 0.9
    assert within_skill_interval(pred, true, np.zeros(30)) == (lo, hi)  # seeded
    m = ranking_metrics(pred, true, np.zeros(30))
    assert (m["R_within_lo"], m["R_within_hi"]) == (lo, hi)
    assert all(math.isnan(v) for v in within_skill_interval(np.zeros(4), np.arange(4.0), np.zeros(4)))


def test_per_skill_rows_say_how_far_schedules_differ_against_how_far_the_predictor_errs() -> None:
    rng = np.random.default_rng(0)
    n = 4000
    true = np.concatenate([rng.normal(1.0, 0.02, n), rng.normal(5.0, 0.10, n), [3.0, 3.1]])
    noise = rng.normal(0.0, 0.02, 2 * n)
    pred = np.concatenate([true[:2 * n] + noise + 0.5, [3.0, 3.1]])  # an offset shared by a skill reorders nothing
    skills = np.repeat(["a", "b", "c"], [n, n, 2])
    rows = per_skill_ranking(pred, true, skills)
    assert [r["skill"] for r in rows] == ["a", "b"]  # two trials give no ranking
    a, b = rows
    assert a["n"] == n and a["L_task_mean_N"] == pytest.approx(1.0, abs=2e-3)
    assert a["L_task_sd_N"] == pytest.approx(0.02, rel=0.05) and a["error_sd_N"] == pytest.approx(0.02, rel=0.05)
    for row, s in ((a, 1.0), (b, 5.0)):  # independent errors: R = s / sqrt(1 + s^2), s = signal / error
        assert row["signal_to_error"] == pytest.approx(s, rel=0.05)
        assert row["R"] == pytest.approx(s / math.sqrt(1 + s**2), abs=0.02)
        assert row["R_spearman"] == pytest.approx(stats.spearmanr(pred[skills == row["skill"]],
                                                                  true[skills == row["skill"]]).statistic)
    exact = per_skill_ranking(true + 7.0, true, skills)[0]
    assert exact["error_sd_N"] == pytest.approx(0.0, abs=1e-12) and exact["R"] == pytest.approx(1.0)
    assert exact["regret"] == 0.0 and exact["signal_to_error"] > 1e6
