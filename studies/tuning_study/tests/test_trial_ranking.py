"""Scoring predictors on a study's simulated trials (studies.tuning_study.trial_ranking), on hand-made arrays
and files.

The end-to-end run on a real tiny study is in test_study.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from studies.tuning_study.trial_ranking import (
    calibration_rows,
    front_hv,
    main,
    ranking_scores,
    score_tuning_agreement,
    tuned_summary,
)

REFERENCE = np.array([1.0, 3.0])


def _trials(n: int = 40, seed: int = 0) -> np.ndarray:
    """(n, 2) objectives of a skill where stiffer (higher L_comp) tracks better, plus noise."""
    rng = np.random.default_rng(seed)
    comp = rng.uniform(0.2, 2.5, n)
    task = 0.8 - 0.2 * comp + rng.normal(0, 0.05, n)
    return np.column_stack([task, comp])


def test_the_truth_scores_at_the_ceiling_and_its_reverse_below_random():
    objectives = _trials()
    truth = ranking_scores(objectives[:, 0], objectives, REFERENCE, n_validate=5)
    assert truth["R"] == pytest.approx(1.0) and truth["rho"] == pytest.approx(1.0) and truth["top3_regret"] == 0.0
    assert 0.9 < truth["front_hv"] <= 1.0                       # 5 picks of the true front
    assert front_hv(objectives[:, 0], objectives, REFERENCE, n_validate=len(objectives)) == pytest.approx(1.0)
    reverse = ranking_scores(-objectives[:, 0], objectives, REFERENCE, n_validate=5)
    assert reverse["R"] == pytest.approx(-1.0) and reverse["top3_regret"] > 1.0
    rows = calibration_rows(objectives, REFERENCE, n_validate=5)
    assert rows["simulator"] == truth
    assert abs(rows["shuffled"]["R"]) < 0.1 and rows["shuffled"]["top3_regret"] == pytest.approx(1.0, abs=0.15)
    assert reverse["front_hv"] < rows["shuffled"]["front_hv"] < truth["front_hv"]


def test_front_hv_is_nan_when_no_trial_beats_the_reference_point():
    objectives = _trials() + np.array([5.0, 0.0])
    assert np.isnan(front_hv(objectives[:, 0], objectives, REFERENCE, n_validate=5))


def test_agreement_with_tuning_counts_a_lower_regret_as_better_and_needs_three_predictors():
    scores = {n: {"R": r, "rho": r, "top3_regret": 1 - r, "front_hv": r} for n, r in
              (("a", 0.5), ("b", 0.7), ("c", 0.9))}
    agree = score_tuning_agreement(scores, {"a": 0.1, "b": 0.2, "c": 0.3})
    assert agree == pytest.approx({"R": 1.0, "rho": 1.0, "top3_regret": 1.0, "front_hv": 1.0})
    assert np.isnan(score_tuning_agreement(scores, {"a": 0.1, "b": 0.2})["R"])


def _study(folder, seeds, hv, gaps=None):
    folder.mkdir(parents=True)
    (folder / "study.json").write_text(json.dumps({"seeds": seeds, "tuners": ["dcm"], "hypervolume": {"dcm": hv}}))
    for seed, gap in zip(seeds, gaps or []):
        run = folder / "runs" / "dcm" / f"seed_{seed:03d}"
        run.mkdir(parents=True)
        picks = [{"predicted": {"L_task_N": 0.5 + gap}, "validated": {"L_task_N": 0.5}}]
        (run / "results.json").write_text(json.dumps({"robot_free": {"solutions": picks}}))
    return folder


def test_tuned_summary_takes_the_trial_seeds_and_the_optimism_of_kept_runs(tmp_path):
    kept = _study(tmp_path / "kept", [0, 1, 2], [0.3, 0.1, 0.2], gaps=[-0.1, -0.2, 0.0])
    copied = _study(tmp_path / "copied", [0, 1, 2, 3], [0.3, 0.1, 0.2, 0.9])
    summary = tuned_summary([f"a={kept}:dcm", f"b={copied}:dcm"], seeds=[0, 1, 2])
    assert summary["a"] == pytest.approx({"I_H": 0.2, "optimism_N": -0.1})
    assert summary["b"]["I_H"] == pytest.approx(0.2) and np.isnan(summary["b"]["optimism_N"])  # seed 3 not used
    with pytest.raises(ValueError, match="lacks the tuning seeds \\[5\\]"):
        tuned_summary([f"a={kept}:dcm"], seeds=[0, 5])
    with pytest.raises(ValueError, match="has no tuner 'ridge'"):
        tuned_summary([f"a={kept}:ridge"], seeds=[0])
    with pytest.raises(ValueError, match="LABEL=STUDY_FOLDER:TUNER"):
        tuned_summary([f"{kept}"], seeds=[0])


def test_cli_names_a_copied_report_and_a_missing_predictor(tmp_path):
    copied = _study(tmp_path / "copied", [0], [0.3])
    with pytest.raises(SystemExit, match="copied: no runs/dcm/seed_\\*/robot_based_trials.npz"):
        main([str(copied), f"DCM={copied / 'study.json'}"])
    with pytest.raises(SystemExit, match="missing.ckpt: no such file"):
        main([str(copied), f"DCM={tmp_path / 'missing.ckpt'}"])
