"""Reference predictors: phase values from K, the stiffness-only ridge, load_model, and dcm.evaluate with them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import train_tiny
from test_models_synthetic import write_synthetic_dataset

from dcm.control import equal_time_phases, filter_schedule, schedule_from_phases
from dcm.data.schema import load_dataset
from dcm.evaluate import evaluate
from dcm.evaluate import main as evaluate_main
from dcm.models.baseline import Baseline
from dcm.models.configuration import ModelInputError
from dcm.models.metrics import within_skill_correlation
from dcm.models.predict import load_model, predict_task_loss
from dcm.models.references import CopyDemo, ReferenceError, StiffnessRegression, load_reference
from dcm.models.references import main as references_main
from dcm.models.stiffness_features import StiffnessScheduleError, feature_names, features, phase_values


# ----------------------------------------------------------------------------------------------- phase values
@pytest.mark.parametrize("boundaries", [[0, 13, 27, 40], [0, 5, 31, 40], [0, 53, 107, 160]])
def test_phase_values_are_read_back_from_the_schedule(boundaries: list[int]) -> None:
    values = np.array([[300.0, 400.0, 500.0], [1200.0, 150.0, 800.0], [700.0, 700.0, 1499.0]])
    K = schedule_from_phases(values, np.array(boundaries), 20.0).astype(np.float32)
    np.testing.assert_allclose(phase_values(K, 3), values, rtol=1e-6)


def test_equal_consecutive_phases_are_shared_out_by_duration() -> None:
    a, b = [300.0, 400.0, 500.0], [900.0, 100.0, 1000.0]
    for values in ([a, a, b], [a, b, b], [a, a, a]):
        K = schedule_from_phases(np.array(values), equal_time_phases(40, 3))
        np.testing.assert_array_equal(phase_values(K, 3), values)


def test_a_filtered_or_non_phase_schedule_is_refused() -> None:
    K = schedule_from_phases(np.array([[300.0] * 3, [1200.0] * 3, [600.0] * 3]), equal_time_phases(40, 3))
    with pytest.raises(StiffnessScheduleError, match="constant segments"):
        phase_values(filter_schedule(K, 0.05), 3, where="K[7]")
    with pytest.raises(StiffnessScheduleError, match="expects a commanded schedule of at most 2 phases"):
        phase_values(K, 2)


def test_phase_values_match_the_datasets_searched_values(tiny_dataset_path: Path) -> None:
    loaded = load_dataset(tiny_dataset_path)
    for K, meta in zip(loaded.arrays["K"], loaded.meta):
        np.testing.assert_allclose(phase_values(K, 3), meta["phase_stiffness_Npm"], rtol=1e-6)


# ----------------------------------------------------------------------------------------------- the ridge
def _synthetic_skills(n_skills: int, n_trials: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Schedules whose L_task = skill level x a known function of stiffness (soft and jumpy = worse)."""
    rng = np.random.default_rng(seed)
    boundaries = equal_time_phases(30, 3)
    values = rng.uniform(100, 1500, size=(n_skills * n_trials, 3, 3))
    K = np.stack([schedule_from_phases(v, boundaries) for v in values])
    skills = np.repeat(np.arange(n_skills), n_trials)
    level = rng.uniform(-1.5, 1.5, size=n_skills)[skills]  # skills differ far more than schedules do
    effect = 0.15 * (1000.0 / values).sum(axis=(1, 2)) + 0.3 * np.abs(np.diff(values, axis=1)).sum(axis=(1, 2)) / 1000
    log_L = level + effect + rng.normal(0, 0.05, size=len(skills))
    return K, np.exp(log_L), skills


def test_ridge_recovers_a_known_within_skill_ranking_on_unseen_skills() -> None:
    K, L_task, skills = _synthetic_skills(40, 12, seed=0)
    train = skills < 30
    model = StiffnessRegression.fit(K[train], L_task[train], skills[train], n_phases=3, control_hz=20.0)
    pred = predict_task_loss(model, None, None, None, K[~train])
    r, n = within_skill_correlation(pred, L_task[~train], skills[~train], "spearman")
    assert n == 10 and r > 0.9
    # the level is the global one: right on average, blind to which skill is hard
    assert abs(np.log(pred).mean() - np.log(L_task[train]).mean()) < 0.2
    assert model.info["cv"] is not None and model.info["alpha"] in model.info["cv"]["alphas"]


def test_ridge_json_round_trip_and_errors(tmp_path: Path) -> None:
    K, L_task, skills = _synthetic_skills(6, 8, seed=1)
    model = StiffnessRegression.fit(K, L_task, skills, n_phases=3, control_hz=20.0, alpha=1.0)
    path = model.save(tmp_path / "ref.json")
    loaded = load_model(path)
    assert isinstance(loaded, StiffnessRegression)
    np.testing.assert_allclose(loaded.predict_task_loss(None, None, None, K), model.predict_task_loss(None, None, None, K))
    data = json.loads(path.read_text())
    assert data["kind"] == "stiffness_ridge" and data["features"]["names"] == feature_names(3)
    assert len(data["coefficients"]) == features(np.ones((1, 3, 3))).shape[1] == 30
    data["features"]["spec"] = "other"
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(ReferenceError, match=r"bad.json: field features.spec"):
        load_reference(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text('{"format": "something"}')
    with pytest.raises(ReferenceError, match="other.json: not a dcm reference file"):
        load_model(tmp_path / "other.json")
    with pytest.raises(StiffnessScheduleError, match="at most 3 phases"):  # a 4-phase schedule
        model.predict_task_loss(None, None, None, schedule_from_phases(np.arange(1, 13).reshape(4, 3) * 100.0,
                                                                        equal_time_phases(40, 4)))


def test_load_model_names_what_it_cannot_load(tmp_path: Path) -> None:
    with pytest.raises(ModelInputError, match=r"nosuch.ckpt: no such file; expected .*copy_demo"):
        load_model(tmp_path / "nosuch.ckpt")
    (tmp_path / "notes.ckpt").write_text("not a checkpoint\n")
    with pytest.raises(ModelInputError, match="notes.ckpt") as err:
        load_model(tmp_path / "notes.ckpt")
    assert "\n" not in str(err.value)
    copy = load_model("copy_demo")
    F = np.random.default_rng(0).normal(size=(2, 10, 6))
    assert isinstance(copy, CopyDemo) and np.all(predict_task_loss(copy, F, F, F, F) == 0)


# ----------------------------------------------------------------------------------------------- dcm.evaluate
@pytest.fixture(scope="module")
def baseline_ckpt(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny Baseline trained 3 steps: enough for the evaluation plumbing."""
    return train_tiny(Baseline, tiny_dataset_path, tmp_path_factory.mktemp("ref_ckpt") / "baseline.ckpt", 3)


RANKING = {"R_within", "R_within_spearman", "R_within_n_skills", "R_pooled", "R", "L_task_mae_N", "top3_regret"}
FORCES = {"force_rmse_N", "force_rmse_copy_N", "force_rmse_ratio_copy", "rmse_Fx", "rmse_Fz"}


def test_evaluate_reports_the_references_beside_the_model(baseline_ckpt: Path, tiny_dataset_path: Path,
                                                          tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    evaluate_main([f"ckpt={baseline_ckpt}", f"dataset={tiny_dataset_path}", "split=valid", f"out={out}"])
    result = json.loads(out.read_text())
    assert result["model"] == "baseline" and result["n"] == 3 and result["n_skills"] == 1
    assert RANKING | FORCES | {"L_MSE"} <= set(result) and result["R_within_n_skills"] == 1
    copy, ridge = result["references"]["copy_demo"], result["references"]["stiffness_ridge"]
    assert RANKING | FORCES <= set(copy) and copy["force_rmse_ratio_copy"] == 1.0 and math.isnan(copy["R_within"])
    assert copy["force_rmse_N"] == pytest.approx(result["force_rmse_copy_N"])
    assert RANKING <= set(ridge) and ridge["fitted_split"] == "train" and ridge["R_within_n_skills"] == 1
    # per skill: the model and the ridge rank, copy-F_demo does not
    for row in (result, ridge):
        (one,) = row["per_skill"]
        assert one["n"] == 3 and one["R"] == pytest.approx(row["R_within"])
    assert "per_skill" not in copy

    # a saved reference is used as given; the references evaluate alone, by name or file
    ref = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    with_ref = evaluate(baseline_ckpt, tiny_dataset_path, split="valid", reference=ref)
    assert with_ref["references"]["stiffness_ridge"]["ckpt"] == str(ref)
    assert with_ref["references"]["stiffness_ridge"]["R_within"] == pytest.approx(ridge["R_within"])
    alone = evaluate(ref, tiny_dataset_path, split="valid")
    assert alone["model"] == "stiffness_ridge" and "references" not in alone and "force_rmse_N" not in alone
    assert alone["R_within"] == pytest.approx(ridge["R_within"])
    copy_alone = evaluate("copy_demo", tiny_dataset_path, split="test")
    assert copy_alone["model"] == "copy_demo" and copy_alone["force_rmse_ratio_copy"] == 1.0


def test_evaluate_scores_the_force_after_the_approach(baseline_ckpt: Path, tiny_dataset_path: Path,
                                                     tmp_path: Path) -> None:
    """task_from_s scores the window from that time on, for the model and both references; a saved ridge
    must have learned the same window's L_task."""
    loaded = load_dataset(tiny_dataset_path, split="valid")
    start = int(round(0.5 * loaded.control_hz))
    result = evaluate(baseline_ckpt, tiny_dataset_path, split="valid", task_from_s=0.5)
    assert result["task_from_s"] == 0.5
    gap = loaded.arrays["F_obs"][:, start:, :3] - loaded.arrays["F_demo"][:, start:, :3]
    assert result["force_rmse_copy_N"] == pytest.approx(float(np.sqrt(np.mean(gap.astype(np.float64) ** 2))))
    assert result["references"]["copy_demo"]["force_rmse_N"] == pytest.approx(result["force_rmse_copy_N"])
    assert result["force_rmse_copy_N"] != pytest.approx(evaluate(baseline_ckpt, tiny_dataset_path, split="valid")
                                                         ["force_rmse_copy_N"])

    windowed = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "w.json"),
                                "--task-from-s", "0.5"])
    assert load_reference(windowed).task_from_s == 0.5
    fitted_here = result["references"]["stiffness_ridge"]  # fitted on the same window in memory
    assert evaluate(windowed, tiny_dataset_path, split="valid", task_from_s=0.5)["R_within"] == pytest.approx(
        fitted_here["R_within"], nan_ok=True)
    whole = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "whole.json")])
    with pytest.raises(ReferenceError, match=r"whole.json ranks L_task from 0 s on.*--task-from-s 0.5"):
        evaluate(baseline_ckpt, tiny_dataset_path, split="valid", reference=whole, task_from_s=0.5)
    with pytest.raises(ModelInputError, match="task_from_s = 99.0 s must be >= 0 and before the end"):
        evaluate(baseline_ckpt, tiny_dataset_path, split="valid", task_from_s=99.0)


def test_evaluate_says_why_the_ridge_is_missing(baseline_ckpt: Path, tmp_path: Path) -> None:
    # synthetic trajectories carry no phase_stiffness_Npm: the ridge cannot tell the number of phases
    data = write_synthetic_dataset(tmp_path / "synth.h5", n_train=6, n_valid=3, n_test=3)
    result = evaluate(baseline_ckpt, data, split="test")
    assert "phase_stiffness_Npm" in result["references"]["stiffness_ridge"]["skipped"]
    assert "force_rmse_N" in result["references"]["copy_demo"]
    with pytest.raises(SystemExit, match="missing.json: no such file"):
        evaluate_main([f"ckpt={baseline_ckpt}", f"dataset={data}", f"reference={tmp_path / 'missing.json'}",
                       f"out={tmp_path / 'x.json'}"])


def test_a_prior_blend_ranks_between_the_model_and_the_ridge(baseline_ckpt: Path, tiny_dataset_path: Path,
                                                            tmp_path: Path) -> None:
    """L = L_model^(1-w) L_ridge^w: w = 0 is the model's ranking, w = 1 the ridge's; a bad weight or a prior
    that is not a ridge is named."""
    from dcm.models.predict import with_prior
    from dcm.models.prior_blend import PriorWeightWarning

    ref = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    alone = evaluate(baseline_ckpt, tiny_dataset_path, split="all")
    ridge = evaluate(ref, tiny_dataset_path, split="all")
    with pytest.warns(PriorWeightWarning, match=f"prior = {ref} at prior_weight = 0 ranks with the model alone"):
        model_only = evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=ref, prior_weight=0.0)
    assert model_only["R_within"] == pytest.approx(alone["R_within"], abs=1e-12)
    assert model_only["prior_weight"] == 0.0 and model_only["prior"] == str(ref) and model_only["model"] == "baseline"
    assert "force_rmse_N" not in model_only and "stiffness_ridge" in model_only["references"]
    prior_only = evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=ref, prior_weight=1.0)
    assert prior_only["R_within"] == pytest.approx(ridge["R_within"], abs=1e-9)
    half = evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=ref, prior_weight=0.5)
    assert half["per_skill"] and half["R_within"] != pytest.approx(alone["R_within"])
    with pytest.raises(ValueError, match=r"prior_weight = 1.5 must be a number in \[0, 1\]"):
        evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=ref, prior_weight=1.5)
    with pytest.raises(ValueError, match=r"prior_weight = nan"):
        evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=ref, prior_weight=float("nan"))
    with pytest.raises(ValueError, match=f"prior = {baseline_ckpt} is not a stiffness reference JSON"):
        evaluate(baseline_ckpt, tiny_dataset_path, split="all", prior=baseline_ckpt, prior_weight=0.5)
    with pytest.raises(ValueError, match="ckpt=copy_demo: prior applies to a DCM or baseline checkpoint"):
        with_prior(load_model("copy_demo"), ref, 0.5, "ckpt=copy_demo")


def test_fit_hushes_library_chatter(tmp_path: Path) -> None:
    import logging

    from dcm.console import QUIET_LOGGERS

    data = write_synthetic_dataset(tmp_path / "synth.h5", n_train=6, n_valid=3, n_test=3)
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)
    references_main(["fit", "--dataset", str(data), "--out", str(tmp_path / "ref.json"), "--n-phases", "2"])
    assert all(logging.getLogger(name).level == logging.WARNING for name in QUIET_LOGGERS)


def test_fit_refuses_an_out_it_cannot_write_before_fitting(tiny_dataset_path: Path, tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("")
    with pytest.raises(SystemExit, match=r"^error: --out .*a_file/r.json cannot be written: .*a_file is not a "
                                         r"writable directory"):
        references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "a_file" / "r.json")])
