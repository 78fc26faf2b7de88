"""The multi-seed study: statistics on hand-made results, and a tiny study end to end that resumes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import dcm.tuning.run as tuning_run
from dcm.models.references import main as references_main
from dcm.tuning.pareto import hypervolume
from studies.tuning_study.study import run_study
from studies.tuning_study.study_config import StudyConfigError, compose_study
from studies.tuning_study.study_controls import prior_levels
from studies.tuning_study.study_stats import aggregate, landscape, paired_test
from studies.tuning_study.trial_ranking import main as ranking_main
from tests.conftest import short_wave_demo

REPO = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------------------------------- statistics
def test_aggregate_reports_medians_iqr_and_detects_a_clear_shift_only():
    dcm = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    shifted = [v - 0.5 - 0.01 * i for i, v in enumerate(dcm)]  # worse on every seed
    null = [v + (0.1 * (i // 2 + 1) if i % 2 else -0.1 * (i // 2 + 1)) for i, v in enumerate(dcm)]  # +/- evenly
    stats = aggregate({"dcm": dcm, "shifted": shifted, "null": null, "same": list(dcm)})

    summary = stats["tuners"]["dcm"]
    assert (summary["n"], summary["median"], summary["q1"], summary["q3"], summary["iqr"]) == (9, 5.0, 3.0, 7.0, 4.0)
    shift = stats["tests"]["shifted"]
    assert shift["p"] == pytest.approx(2 / 2**9) and shift["significant"]  # exact: all 9 differences positive
    assert (shift["wins"], shift["losses"]) == (9, 0) and shift["median_difference"] > 0
    assert stats["tests"]["null"]["p"] > 0.5 and not stats["tests"]["null"]["significant"]
    assert stats["tests"]["same"]["p"] == 1.0 and stats["tests"]["same"]["ties"] == 9
    assert set(stats["tests"]) == {"shifted", "null", "same"}  # the subject is not tested against itself


def test_paired_test_drops_missing_seeds_and_refuses_unpaired_lists():
    result = paired_test([1.0, 2.0, math.nan, 4.0], [0.5, 1.5, 3.0, None])
    assert result["n_pairs"] == 2 and result["wins"] == 2
    assert paired_test([1.0], [0.0])["p"] is None  # one pair: no test
    with pytest.raises(ValueError, match="one value per seed"):
        paired_test([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="subject tuner 'dcm'"):
        aggregate({"baseline": [1.0]})


def test_landscape_on_a_skill_where_stiffer_tracks_better_and_on_a_flat_one():
    stiffness = np.linspace(100.0, 1500.0, 11)[:, None, None] * np.ones((11, 3, 3))
    steep = landscape(stiffness, 1000.0 / stiffness[:, 0, 0])  # L_task ~ 1/K: 10 N at 100 N/m, 0.67 at 1500
    assert steep["n_trials"] == 11 and steep["spearman_mean_K"] == pytest.approx(-1.0)
    assert steep["median"] == pytest.approx(1000.0 / 800.0) and steep["spread_q90_q10"] > 5.0
    flat = landscape(stiffness, np.full(11, 0.25))
    assert flat["spread_q90_q10"] == pytest.approx(1.0) and math.isnan(flat["spearman_mean_K"])


def test_prior_levels_are_bin_midpoints():
    np.testing.assert_allclose(prior_levels(100.0, 1500.0, 5), [240.0, 520.0, 800.0, 1080.0, 1360.0])


# ------------------------------------------------------------------------------------------- end to end
def _study_config(ckpt: Path, reference: Path, demo: Path, out_dir: Path, *extra: str):
    return compose_study([
        f"ckpt={ckpt}", f"reference_json={reference}", f"demo_file={demo}", "embodiment=tool", "seeds=2",
        f"out_dir={out_dir}", "robot_free.n_trials=8", "robot_free.batch_size=4", "robot_free.n_validate=2",
        "robot_based.n_trials=[2,6]", "search.options.n_startup_trials=4", "prior.n_levels=3", *extra,
    ])


def test_a_tiny_study_runs_end_to_end_and_resumes_without_redoing_runs(tiny_checkpoint: Path, tiny_dataset_path: Path,
                                                                       tmp_path: Path, monkeypatch):
    demo = short_wave_demo(tmp_path)
    reference = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    out = tmp_path / "study"
    cfg = _study_config(tiny_checkpoint, reference, demo, out)

    calls: list[Path] = []
    real_tune = tuning_run.tune

    def counting_tune(run_cfg, run_dir):
        calls.append(Path(run_dir))
        return real_tune(run_cfg, run_dir)

    monkeypatch.setattr(tuning_run, "tune", counting_tune)
    report = run_study(cfg, out)

    tuners = ["dcm", "reference", "prior", "robot_based_2", "robot_based_6"]
    assert report["tuners"] == tuners and report["seeds"] == [0, 1]
    assert len(calls) == 4  # dcm and reference, two seeds each (the prior needs no tune run)
    assert all(len(report["hypervolume"][t]) == 2 for t in tuners)
    assert all(v >= 0.0 for t in tuners for v in report["hypervolume"][t])
    for seed in range(2):  # a prefix of one robot-based run: more trials never shrink the hypervolume
        assert report["hypervolume"]["robot_based_2"][seed] <= report["hypervolume"]["robot_based_6"][seed]
    ref = report["reference_point"]
    assert ref["source"] == "demo_stiffness"
    assert ref["L_task_N"] == pytest.approx(1.5 * ref["demo_stiffness_L_task_N"])
    assert ref["L_comp_kNpm"] == pytest.approx(math.sqrt(3.0) * 1.5)  # every axis at max_Npm = 1500 N/m
    dcm_results = json.loads((out / "runs/dcm/seed_001/results.json").read_text())
    assert dcm_results["seed"] == 1 and dcm_results["robot_based"]["n_trials"] == 6
    assert dcm_results["predictor"]["sampler"] == "ddim"  # the DCM's per-tuner overrides reached its runs
    assert dcm_results["reference_point"]["L_task_N"] == pytest.approx(ref["L_task_N"])  # one point everywhere
    assert json.loads((out / "runs/reference/seed_000/results.json").read_text())["robot_based"]["n_trials"] == 0
    assert set(report["statistics"]["tests"]) == {"reference", "prior", "robot_based_2", "robot_based_6"}
    for name in ("study.json", "study.md", "study.png", "cost.md"):
        assert (out / name).stat().st_size > 0
    assert "robot-based N=6" in (out / "study.md").read_text()
    assert report["landscape"]["n_trials"] == 12  # both seeds' robot-based trials
    assert "What stiffness does to this skill, over the 12 robot-based trials" in (out / "study.md").read_text()
    assert "virtual trials" in (out / "cost.md").read_text()

    # Resuming: finished runs are kept; only the one whose results.json is gone runs again (from its logs).
    (out / "runs/reference/seed_001/results.json").unlink()
    calls.clear()
    again = run_study(cfg, out)
    assert calls == [out / "runs/reference/seed_001"]
    assert again["hypervolume"] == report["hypervolume"]

    # A folder started with other settings is refused before any work.
    changed = _study_config(tiny_checkpoint, reference, demo, out, "robot_free.n_trials=10")
    with pytest.raises(StudyConfigError, match=r"other settings: robot_free.n_trials: 8 -> 10"):
        run_study(changed, out)

    # The finished study's robot-based trials score its predictors (studies.tuning_study.trial_ranking).
    ranking_main([str(out), f"DCM={tiny_checkpoint}", f"ridge={reference}", "--tuned", f"DCM={out}:dcm",
                  f"ridge={out}:reference", "--out", str(tmp_path / "ranking.md")])
    ranking = json.loads((tmp_path / "ranking.json").read_text())
    assert ranking["seeds"] == [0, 1] and 2 <= ranking["n_trials"] <= 12  # distinct finite trials of both seeds
    assert ranking["calibration"]["simulator"]["R"] == pytest.approx(1.0)
    assert ranking["tuned"]["DCM"]["I_H"] == pytest.approx(float(np.median(report["hypervolume"]["dcm"])))
    assert np.isfinite(ranking["tuned"]["DCM"]["optimism_N"])  # the study kept its runs
    assert set(ranking["scores"]) == {"DCM", "ridge"} and "| ridge |" in (tmp_path / "ranking.md").read_text()


def test_with_validation_rollouts_every_front_is_judged_by_its_expected_loss(tiny_checkpoint: Path,
                                                                            tiny_dataset_path: Path, tmp_path: Path):
    """In a domain with a per-rollout spread, the robot-based search truncated to N is judged as the robot-free
    tuners are: its front's picks re-run ``validation_rollouts`` times, not its own lucky draws."""
    reference = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    out = tmp_path / "study"
    cfg = _study_config(tiny_checkpoint, reference, short_wave_demo(tmp_path), out, "seeds=1", "domain=bowl_offset",
                        "validation_rollouts=2")
    report = run_study(cfg, out)
    point = np.array([report["reference_point"]["L_task_N"], report["reference_point"]["L_comp_kNpm"]])
    for n in (2, 6):
        picks = json.loads((out / f"runs/robot_based_{n}/seed_000/results.json").read_text())
        assert picks["validation_rollouts"] == 2 and 1 <= len(picks["solutions"]) <= 2
        assert all(s["validated"]["L_task_N"] != s["observed"]["L_task_N"] for s in picks["solutions"])
        judged = np.array([[s["validated"]["L_task_N"], s["validated"]["L_comp_kNpm"]] for s in picks["solutions"]])
        assert report["hypervolume"][f"robot_based_{n}"][0] == pytest.approx(hypervolume(judged, point))
    # N = all trials: the DCM's tune run validated those picks already, and its numbers are the study's.
    tuned = json.loads((out / "runs/dcm/seed_000/results.json").read_text())["robot_based"]
    assert picks["solutions"] == tuned["solutions"] and picks["validation_seconds"] == tuned["validation_seconds"]
    # The prior's middle level is the demo's own 800 N/m: at seed 0 its two draws are the reference point's.
    middle = json.loads((out / "runs/prior/seed_000/results.json").read_text())["solutions"][1]
    assert middle["phase_stiffness_Npm"][0] == [800.0, 800.0, 800.0]
    assert middle["validated"]["L_task_N"] == pytest.approx(report["reference_point"]["demo_stiffness_L_task_N"])
    assert "mean L_task over 2 rollouts" in (out / "study.md").read_text()


def test_robot_based_picks_take_the_tune_runs_validation_of_the_same_picks(tmp_path: Path):
    """A front the tune run validated over as many rollouts is not rolled out again (no simulator is touched);
    other picks or another rollout count are."""
    from types import SimpleNamespace

    from studies.tuning_study.study_controls import run_robot_based_picks

    params = np.array([[[100.0] * 3], [[900.0] * 3], [[500.0] * 3]])
    observed = np.array([[0.5, 0.1], [0.2, 0.9], [0.9, 0.95]])  # the first two are the front
    tuned = {"validation_rollouts": 4, "validation_seconds": 1.5,
             "solutions": [{"phase_stiffness_Npm": params[i].tolist(), "observed": {}, "validated": {"L_task_N": v}}
                           for i, v in ((0, 0.7), (1, 0.3))]}

    def no_rollouts(rollouts: int):
        raise AssertionError(f"rolled out {rollouts} times")

    setup = SimpleNamespace(simulator=SimpleNamespace(seed=3), objective=no_rollouts)
    results = run_robot_based_picks(setup, params, observed, 2, 4, tmp_path, tuned)
    assert results["solutions"] == tuned["solutions"] and results["validation_seconds"] == 1.5
    assert json.loads((tmp_path / "results.json").read_text())["tuner"] == "robot_based_3"
    for rollouts, n_validate in ((2, 2), (4, 1)):  # another rollout count; other picks
        with pytest.raises(AssertionError, match="rolled out"):
            run_robot_based_picks(setup, params, observed, n_validate, rollouts, tmp_path, tuned)
