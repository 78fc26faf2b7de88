"""The fixed-rule control: its schedules, and a run against a study of a short skill, refused on another skill."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from studies.tuning_study.fixed_rule import grid_schedules, hv, main, rule_schedules, run
from studies.tuning_study.study_config import Tuner, compose_study, tune_config
from studies.tuning_study.study_controls import demo_reference_point, prior_levels, setup_skill
from tests.conftest import short_wave_demo


def test_rule_schedules_pair_touchdown_and_wipe_levels_and_the_grid_spans_every_combination():
    rule = rule_schedules([600.0, 700.0], [100.0], 3)
    np.testing.assert_allclose(rule[:, :, 0], [[600.0, 100.0, 100.0], [700.0, 100.0, 100.0]])
    assert np.all(rule == rule[:, :, :1])  # isotropic
    np.testing.assert_allclose(rule_schedules([800.0], [100.0, 300.0], 2)[:, :, 2], [[800.0, 100.0], [800.0, 300.0]])
    grid = grid_schedules(100.0, 1500.0, 3, 3)
    assert grid.shape == (27, 3, 3) and len({tuple(g[:, 0]) for g in grid}) == 27
    assert set(grid[:, 0, 0]) == {100.0, 800.0, 1500.0}


def test_the_rule_is_compared_with_a_studys_seeds_and_refused_on_another_skill(tiny_checkpoint: Path, tmp_path: Path,
                                                                             capsys):
    demo = short_wave_demo(tmp_path)
    overrides = [f"ckpt={tiny_checkpoint}", f"demo_file={demo}", "embodiment=tool", "prior.n_levels=3"]
    cfg = compose_study(overrides)
    setup = setup_skill(tune_config(cfg, Tuner("dcm", str(tiny_checkpoint)), 0, None, tmp_path / "setup"))
    reference = demo_reference_point(setup, 1.5, 1.0)
    point = np.array([reference["L_task_N"], reference["L_comp_kNpm"]])
    levels = prior_levels(setup.space.min_Npm, setup.space.max_Npm, 3)
    prior = hv(setup.evaluate(np.repeat(np.repeat(levels[:, None, None], 3, axis=1), 3, axis=2)), point)
    study = tmp_path / "study"
    study.mkdir()
    study_json = {"seeds": [0, 1, 2], "reference_point": {**reference, "seed": 0},
                  "hypervolume": {"dcm": [0.0, 10.0, 10.0], "prior": [prior] * 3}, "robot_trials": {"dcm": 5}}
    (study / "study.json").write_text(json.dumps(study_json))

    result = run(study, tmp_path / "rule", overrides, [300.0, 400.0, 500.0, 600.0, 700.0], None, 2, "test")
    rollouts = setup.evaluate(rule_schedules([300.0, 400.0, 500.0, 600.0, 700.0], [setup.space.min_Npm], 3))
    assert result["rule_ih"] == pytest.approx(hv(rollouts, point)) and result["rule_ih"] > 0
    assert result["check"]["prior"] == pytest.approx(prior)
    dcm = result["statistics"]["tests"]["dcm"]
    assert (dcm["wins"], dcm["losses"]) == (1, 2)  # the rule beats the DCM's 0 and loses to its two 10s
    assert len(result["grid"]["front"]) >= 1 and result["grid"]["n_schedules"] == 8
    assert "| fixed rule | 5 |" in (tmp_path / "rule" / "rule.md").read_text()

    study_json["reference_point"]["L_task_N"] *= 1.1  # a study of another recording
    (study / "study.json").write_text(json.dumps(study_json))
    with pytest.raises(SystemExit, match="error: the skill is not the study's"):
        main([str(study), "--out", str(tmp_path / "other"), *overrides])
    with pytest.raises(SystemExit, match="error: --wipe-Npm has 2 levels"):
        main([str(study), "--out", str(tmp_path / "other"), "--wipe-Npm", "100,200", *overrides])
