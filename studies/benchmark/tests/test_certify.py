"""Known answers for the certification statistics and the oracle (constant schedules, no disturbance, a plate)."""

from __future__ import annotations

import numpy as np
import pytest

from studies.benchmark import stats
from studies.benchmark import task as bench
from studies.benchmark.oracle import run_skill, task_losses

REF = np.array([3.0, 5.0])


def test_constant_schedules_only_gain_nothing():
    task = np.array([2.0, 1.5, 1.2])
    comp = np.array([0.5, 1.0, 2.0])
    out = stats.variable_gain(task, comp, np.ones(3, dtype=bool))
    assert out["gain"] == 0.0 and out["max_gain"] == 0.0


def test_variable_gain_against_the_constants_within_its_compliance():
    # constants at L_comp 1 and 2 (losses 2.0, 1.0); a per-phase schedule at L_comp 1 with loss 1.6: 20 % below the
    # constant it may be compared with (the 2.0 one), not the stiffer 1.0 one.
    task = np.array([2.0, 1.0, 1.6])
    comp = np.array([1.0, 2.0, 1.0])
    constant = np.array([True, True, False])
    out = stats.variable_gain(task, comp, constant)
    assert out["gain"] == 0.0  # the best schedule overall is a constant
    assert out["max_gain"] == pytest.approx(0.2)
    task[2] = 0.8  # now the best overall, and cheaper than the stiff constant
    assert stats.variable_gain(task, comp, constant)["gain"] == pytest.approx(0.6)


def test_approach_share():
    assert stats.approach_share(np.array([[1.0, 3.0]]), np.array([[4.0, 4.0]])) == pytest.approx(0.5)


def test_hypervolume_of_a_subset_and_rules():
    task, comp = np.array([1.0, 2.0, 2.5]), np.array([4.0, 1.0, 3.0])
    full = stats.front_hypervolume(task, comp, REF)
    assert full == pytest.approx(2.0 * 1.0 + 1.0 * 4.0 - 1.0 * 1.0)  # union of the two boxes
    assert stats.front_hypervolume(task, comp, REF, [2]) < full
    # one skill where schedule 1 alone holds most of the front: the greedy rule picks it first
    assert stats.greedy_rule([task], [comp], [REF], 2)[:1] == [1]


def test_identical_skills_have_no_single_schedule_regret():
    tasks = np.tile([[1.0, 0.8, 0.9]], (4, 1))
    out = stats.single_schedule_regret(tasks, np.array([1.0, 2.0, 1.5]))
    assert out["single"] == 1 and out["median"] == pytest.approx(0.0)
    tasks[:] = [1.0, 0.5, 0.9]
    tasks[0] = [1.0, 1.0, 0.5]  # skill 0 prefers schedule 2, cheaper than the common pick (schedule 1)
    out = stats.single_schedule_regret(tasks, np.array([1.0, 2.0, 1.5]))
    assert out["single"] == 1 and out["regrets"][0] == pytest.approx(1.0) and out["regrets"][1] == 0.0


def test_oracle_without_disturbance_rolls_out_the_same_trial(tmp_path):
    """Nominal domain on a flat plate: every rollout of a schedule is the same, so the mean of R is the single
    rollout, and a constant schedule split into phases is the constant schedule."""
    flat = {"duration_s": 2.0, "approach_s": 0.4, "bowl": {"shape": "flat", "rim_radius_m": 0.14, "hfield_res": 48},
            "params": {"seed": 1, **bench.FAMILY_PARAMS, "blend_s": 0.3}}
    schedules = np.array([[400.0, 400.0, 400.0], [150.0, 1000.0, 400.0]])
    path = run_skill(1, tmp_path, rollouts=3, domain="nominal", spec_override=flat, schedules=schedules,
                     embodiment="tool")
    data = np.load(path)
    losses = task_losses(data, from_contact=False)
    assert np.all(np.isfinite(losses))
    np.testing.assert_allclose(losses, losses[:, :1].repeat(3, axis=1), rtol=0, atol=1e-12)
    assert data["L_comp"][0] == pytest.approx(0.4 * np.sqrt(3))
    assert np.all(task_losses(data, from_contact=True) > 0)
    assert run_skill(1, tmp_path, rollouts=3) == path  # a finished skill is kept (resume)


def test_oracle_schedules_hold_grid_prior_and_demo():
    sched = bench.oracle_schedules()
    assert sched.kinds.count("grid") == len(bench.GRID_LEVELS_NPM) ** bench.N_PHASES
    constants = {row[0] for row in sched.phase_Npm if len(set(row)) == 1}
    assert set(bench.PRIOR_LEVELS_NPM) <= constants and bench.DEMO_STIFFNESS_NPM in constants
    assert len(bench.PRIOR_LEVELS_NPM) == 5


def test_revisions_change_only_their_family_params():
    """The default revision is the task PROTOCOL.md describes; "fast_third" draws one fast third per skill."""
    from dcm.sim import DemoSpec

    assert bench.skill_spec(2000) == bench.skill_spec(2000, "paced")
    assert bench.skill_spec(2000)["params"] == {"seed": 2000, **bench.FAMILY_PARAMS}
    speeds = DemoSpec.from_dict(bench.skill_spec(2000, "fast_third")).curve_draws()["speed_mps"]
    assert (speeds >= 0.10).sum() == 1 and speeds.min() >= 0.02
    with pytest.raises(ValueError, match="revision 'nope'"):
        bench.skill_spec(2000, "nope")


def test_probe_schedules_put_the_stiffness_in_the_fastest_third():
    from studies.benchmark.probe import probe_schedules

    rows = probe_schedules(np.array([0.03, 0.15, 0.04]))
    per_phase = rows[~np.all(rows == rows[:, :1], axis=1)]
    assert len(per_phase) == 4 and np.all(per_phase[:, 1] >= 1000.0) and np.all(per_phase[:, [0, 2]] <= 400.0)
    assert {row[0] for row in rows if len(set(row)) == 1} == {*bench.PRIOR_LEVELS_NPM, bench.DEMO_STIFFNESS_NPM}
