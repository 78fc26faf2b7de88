"""The robot-loop study end to end on the tool embodiment: every arm judged, a resumed study skips finished
cases, and the report pairs the arms."""

from __future__ import annotations

import json
from pathlib import Path

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
