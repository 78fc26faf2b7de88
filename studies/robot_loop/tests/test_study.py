"""The robot-loop study end to end on the tool embodiment: every arm judged, a resumed study skips finished
cases, and the report pairs the arms."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from studies.robot_loop.study import main


def test_a_tiny_study_judges_every_arm_resumes_and_reports(tiny_checkpoint: Path, tmp_path: Path):
    out = tmp_path / "study"
    args = ["--ckpt", str(tiny_checkpoint), "--demos", "wavelike", "--seeds", "0", "1", "--out", str(out),
            "--batch", "2", "--picks", "2", "--judge", "2", "--free-trials", "16", "--loop-trials", "8",
            "--robot-based", "6", "8", "--override", "embodiment=tool", "demo.duration_s=2.0", "demo.approach_s=0.4",
            "robot_free.batch_size=8", "robot_free.sampling_steps=5", "search.options.n_startup_trials=4"]
    main(args)
    cases = sorted((out / "cases").rglob("seed_*.json"))
    assert len(cases) == 2
    case = json.loads(cases[0].read_text())
    assert {"loop_gp_5", "loop_gp_15", "loop_none_10", "one_shot_5", "prior_15", "robot_based_8"} <= set(case["arms"])
    assert case["arms"]["loop_gp_15"]["n_trials"] == 6  # 3 rounds of 2 trials
    assert all(len(a["judged"]) <= 2 and a["hypervolume"] >= 0.0 for a in case["arms"].values())
    stamp = cases[0].stat().st_mtime_ns
    main(args)  # finished cases are kept
    assert cases[0].stat().st_mtime_ns == stamp
    report = tmp_path / "report.md"
    main(["--out", str(out), "--report", str(report)])
    text = report.read_text()
    assert "| loop_gp_15 | prior_15 |" in text and "one checkpoint" in text


def _case(ckpt: str, seed: int, loop: float, one_shot: float) -> dict:
    arms = {"loop_gp_15": loop, "one_shot_5": one_shot}
    return {"ckpt": ckpt, "demo": "line", "seed": seed, "judge_rollouts": 8, "picks": 5, "seconds": 1.0,
            "arms": {name: {"hypervolume": value, "prediction_mae_N": [0.05, 0.02, 0.02]}
                     for name, value in arms.items()}}


def test_the_report_tests_over_trained_models_with_one_mean_per_checkpoint():
    from studies.robot_loop.report import paired, per_model, report

    # checkpoint a: differences +0.1 and -0.3 (mean -0.1); b: +0.2 and +0.4 (mean +0.3)
    cases = [_case("m/a.ckpt", 0, 0.6, 0.5), _case("m/a.ckpt", 1, 0.2, 0.5),
             _case("m/b.ckpt", 2, 0.7, 0.5), _case("m/b.ckpt", 3, 0.9, 0.5)]
    means = per_model(cases, "loop_gp_15", "one_shot_5")
    assert means.keys() == {"a.ckpt", "b.ckpt"}
    assert means["a.ckpt"] == pytest.approx(-0.1) and means["b.ckpt"] == pytest.approx(0.3)
    by_model = paired(cases, "loop_gp_15", "one_shot_5", by_model=True)
    assert (by_model["n_pairs"], by_model["wins"]) == (2, 1) and by_model["median_difference"] == pytest.approx(0.1)
    assert paired(cases, "loop_gp_15", "one_shot_5")["n_pairs"] == 4
    text = report(cases)
    assert "Paired over trained models" in text and "| a.ckpt | -0.1000 |" in text
    assert "not independent replicates" in text and "one checkpoint, so" not in text
