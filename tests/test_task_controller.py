"""The simulated task without controller artefacts: consistent attractor, damping options, the task check."""

import json

import numpy as np
import pytest

from dcm.control import damping_from_stiffness, equal_time_phases, schedule_from_phases
from dcm.data import task_check
from dcm.sim import BowlSpec, DemoSpec, Simulator
from dcm.sim.rollout import SimulatorError

FLAT = BowlSpec(shape="flat", rim_radius_m=0.15, depth_m=0.0, friction=0.3)
# A slow, short stroke on the plate: the normal force is steady, so any transient comes from the controller.
STROKE = DemoSpec(family="line", press_m=0.01, duration_s=4.0, approach_s=1.0, bowl=FLAT,
                  params={"start_xy_m": [-0.02, 0.0], "end_xy_m": [0.02, 0.0]})


@pytest.fixture(scope="module")
def panda_flat() -> Simulator:
    return Simulator(embodiment="panda", bowl=FLAT)


@pytest.mark.parametrize("phases", [(1500.0, 150.0), (150.0, 1500.0)])
def test_stiffness_change_keeps_the_normal_force(panda_flat: Simulator, phases: tuple[float, float]) -> None:
    """On the plate a phase change from one stiffness to another leaves Fz within 10 % of its steady value:
    gains and attractor move together, so the spring force stays where the demo had it."""
    demo = panda_flat.record_demo(STROKE)
    bounds = equal_time_phases(demo.horizon, 2)
    schedule = schedule_from_phases(np.repeat(np.array(phases)[:, None], 3, 1), bounds)
    trial = panda_flat.rollout(demo, schedule)
    assert not trial.failed
    steady = demo.force_demo[30:, 2].mean()
    after = trial.force_obs[bounds[1]:bounds[1] + 20, 2]  # the second after the change
    assert steady > 5.0
    assert np.abs(after - steady).max() < 0.1 * steady


def test_damping_modes() -> None:
    np.testing.assert_allclose(damping_from_stiffness(np.array([400.0]), 10.0), [2.0 * np.sqrt(4000.0)])
    unit = Simulator("tool", FLAT, damping="unit")
    critical = Simulator("tool", FLAT)
    np.testing.assert_allclose(unit.damping_mass, np.ones(6))
    assert critical.damping_mass[0] == pytest.approx(1.0)  # the tool's 1 kg: the same law as the paper's
    with pytest.raises(SimulatorError, match="damping = 'heavy'"):
        Simulator("tool", FLAT, damping="heavy")


def test_panda_apparent_mass_matches_the_model(panda_flat: Simulator) -> None:
    """The masses critical damping uses are the model's Cartesian inertia at the plate's centre (±30 %)."""
    import mujoco

    emb = panda_flat.embodiment
    emb.reset(np.zeros(6))
    m, d = emb.model, emb.data
    jac = np.zeros((6, m.nv))
    mujoco.mj_jacSite(m, d, jac[:3], jac[3:], emb._tcp)
    mass = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, mass, d.qM)
    j = jac[:, :7]
    lam = np.linalg.inv(j @ np.linalg.inv(mass[:7, :7]) @ j.T)
    np.testing.assert_allclose(type(emb).apparent_mass, np.diag(lam), rtol=0.35)


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
