"""The simulated task without controller artefacts: consistent attractor and damping options."""

import numpy as np
import pytest

from dcm.control import damping_from_stiffness, equal_time_phases, schedule_from_phases
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
