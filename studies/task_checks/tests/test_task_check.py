"""The task check (studies.task_checks.task_check): does the simulated task reward stiffness, without
controller artefacts? Known answers, bad input, and one tiny skill end to end."""

import json

import numpy as np
import pytest

from dcm.control import equal_time_phases
from dcm.sim import BowlSpec, DemoSpec, Simulator
from studies.task_checks import task_check


@pytest.mark.parametrize(("domain", "named"), [("{\"joint_friction\": 0.5}", "joint_friction"),
                                               ("{\"joint_frictionloss\": ", "not a JSON mapping"),
                                               ("rough", "'rough'")])
def test_task_check_bad_domain_is_named(domain: str, named: str, capsys) -> None:
    with pytest.raises(SystemExit):
        task_check.main(["--dataset", "tiny", "--splits", "valid", "--max-skills", "1", "--domain", domain])
    err = capsys.readouterr().err
    assert "--domain" in err and named in err


def test_phase_additivity_known_answers() -> None:
    err_a, err_b = np.full(10, 2.0), np.full(10, 1.0)
    bounds = np.array([0, 5, 10])
    # a "schedule" whose error equals the constant runs' phase by phase adds up exactly
    assert task_check.phase_additivity(np.r_[err_a[:5], err_b[5:]], [err_a, err_b], bounds) == pytest.approx(1.0)
    # a transient that doubles the error of the second phase
    assert task_check.phase_additivity(np.r_[err_a[:5], 2 * err_b[5:]], [err_a, err_b], bounds) == pytest.approx(20 / 15)


def test_task_check_on_one_skill(tmp_path) -> None:
    """At small scale on one tiny skill (the Panda, 2 s, a leading demonstrator): a constant 'schedule' adds
    up to 1, stiffer tracks better, and the report is written."""
    out = tmp_path / "tc"
    result = task_check.main(["--dataset", "tiny", "--splits", "valid", "--max-skills", "1", "--n-random", "4",
                              "--embodiment", "panda", "--demo-lead", "--out", str(out)])
    assert (out / "task_check.png").is_file()
    saved = json.loads((out / "task_check.json").read_text())
    assert saved["demo_lead"] is True and saved["duration_s"] == 2.0
    (skill,) = saved["skills"].values()
    assert skill["sweep_L_task"][0] > skill["sweep_L_task"][-1]  # 100 N/m tracks worse than 2,500 N/m
    assert len(skill["random_L_task"]) == 4
    assert result["summary"]["spiral"]["n_skills"] == 1
    # after the approach: the same rollouts, their error counted from 0.5 s on
    wipe = task_check.main(["--dataset", "tiny", "--splits", "valid", "--max-skills", "1", "--n-random", "0",
                            "--embodiment", "panda", "--demo-lead", "--task-from-s", "0.5", "--out", str(out)])
    (after,) = wipe["skills"].values()
    assert wipe["task_from_s"] == 0.5 and np.isfinite(after["sweep_L_task"]).all()
    assert after["sweep_L_task"] != pytest.approx(skill["sweep_L_task"])
    # in another domain: joint friction the attractor does not know changes every rollout's force
    rough = task_check.main(["--dataset", "tiny", "--splits", "valid", "--max-skills", "1", "--n-random", "0",
                             "--embodiment", "panda", "--demo-lead", "--out", str(out),
                             "--domain", '{"name": "rough", "joint_frictionloss": 0.5}'])
    (in_rough,) = rough["skills"].values()
    assert rough["domain"]["name"] == "rough" and rough["domain"]["joint_frictionloss"] == 0.5
    assert saved["domain"]["name"] == "nominal"
    assert in_rough["sweep_L_task"] != pytest.approx(skill["sweep_L_task"])
    sim = Simulator("tool", BowlSpec())
    demo = sim.record_demo(DemoSpec(family="spiral", press_m=0.01, duration_s=2.0, approach_s=0.4))
    flat = sim.constant_stiffness(demo, 600.0)
    const = task_check.squared_error(sim.rollout(demo, flat).force_obs, demo.force_demo)
    bounds = equal_time_phases(demo.horizon, 3)
    assert task_check.phase_additivity(const, [const] * 3, bounds) == pytest.approx(1.0)
