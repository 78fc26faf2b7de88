"""The arm's own joint friction (``DomainSpec.joint_friction``): off by default, the identified model's sign and
size, its effect on a Panda rollout, and the refusals."""

import numpy as np
import pytest

from dcm.sim import BowlSpec, DemoSpec, DomainSpec, DomainSpecError, Simulator
from dcm.sim.panda import (
    GAZ2019_PHI1_NM,
    GAZ2019_PHI2_SPRAD,
    GAZ2019_PHI3_RADPS,
    PandaEmbodiment,
    gaz2019_friction_torque,
)

FLAT = BowlSpec(shape="flat", rim_radius_m=0.15, depth_m=0.0, friction=0.3)
GAZ = DomainSpec(joint_friction="gaz2019")


@pytest.fixture(scope="module")
def nominal_sim() -> Simulator:
    return Simulator(embodiment="panda", bowl=FLAT)


@pytest.fixture(scope="module")
def demo(nominal_sim: Simulator):
    return nominal_sim.record_demo(DemoSpec(family="wavelike", bowl=FLAT, duration_s=2.0, approach_s=0.4))


def _source_formula(qvel: np.ndarray) -> np.ndarray:
    """tau_f as get_FrictionTorque.m writes it."""
    a, k, s = GAZ2019_PHI1_NM, GAZ2019_PHI2_SPRAD, GAZ2019_PHI3_RADPS
    return a / (1 + np.exp(-k * (qvel + s))) - a / (1 + np.exp(-k * s))


def test_default_domain_has_no_joint_friction_and_keeps_its_fingerprint() -> None:
    assert DomainSpec().joint_friction == "none"
    assert not DomainSpec().has_joint_friction
    assert not DomainSpec(joint_friction="gaz2019", joint_friction_scale=0.0).has_joint_friction
    assert "joint_friction" not in DomainSpec().to_dict()
    assert "joint_friction_scale" not in DomainSpec.preset("realistic").to_dict()
    dom = DomainSpec.load("conf/domain/joint_friction.yaml")
    assert dom == DomainSpec.preset("joint_friction") and dom.has_joint_friction
    assert DomainSpec.from_dict(dom.to_dict()) == dom
    scaled = DomainSpec(joint_friction="gaz2019", joint_friction_scale=0.5)
    assert DomainSpec.from_dict(scaled.to_dict()) == scaled


def test_gaz2019_torque_opposes_the_motion_with_the_identified_amplitude() -> None:
    """tau_f (what the motor supplies) has the sign of qdot, so the joint feels -tau_f against its motion; it is 0
    at rest and, at high speed, spans phi1 between its two saturations (tau(+inf) - tau(-inf) = phi1)."""
    speeds = np.array([-3.0, -0.5, -0.05, -1e-3, 0.0, 1e-3, 0.05, 0.5, 3.0])
    for v in speeds:
        qvel = np.full(7, v)
        tau_f = gaz2019_friction_torque(qvel)
        np.testing.assert_allclose(tau_f, _source_formula(qvel), rtol=1e-9, atol=1e-15)
        assert np.all(np.sign(tau_f) == np.sign(v))
        assert np.all(-tau_f * qvel <= 0.0)  # the joint's friction power: dissipative
    fast = 20.0  # rad/s: phi2 * 20 >= 100, saturated to double precision
    span = gaz2019_friction_torque(np.full(7, fast)) - gaz2019_friction_torque(np.full(7, -fast))
    np.testing.assert_allclose(span, GAZ2019_PHI1_NM, rtol=1e-12)
    np.testing.assert_allclose(GAZ2019_PHI1_NM, [0.546, 0.872, 0.641, 1.279, 0.839, 0.303, 0.565], atol=6e-4)
    np.testing.assert_allclose(gaz2019_friction_torque(np.full(7, 0.7), scale=2.5),
                               2.5 * gaz2019_friction_torque(np.full(7, 0.7)), rtol=1e-12)


def test_the_panda_applies_minus_tau_f_at_every_physics_step() -> None:
    """With one physics step per control period, the joint torque added in that step is exactly
    -tau_f(qdot at the step's start) on top of the controller's held torques."""
    panda = PandaEmbodiment(FLAT, GAZ, control_dt=0.002, physics_dt=0.002, visual=False)
    panda.reset(np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0]))
    stiffness = np.array([800.0, 800.0, 800.0, 20.0, 20.0, 20.0])
    moved = 0
    for k in range(40):
        qvel_start = panda.data.qvel[:7].copy()
        panda.step(np.array([0.002 * k, 0.0, 0.05, 0.0, 0.0, 0.0]), stiffness)
        friction = panda.data.qfrc_applied[:7] - panda._held_slow
        np.testing.assert_allclose(friction, -gaz2019_friction_torque(qvel_start), rtol=1e-9, atol=1e-12)
        moved += int(np.abs(qvel_start).max() > 1e-3)
    assert moved > 20


def test_no_friction_and_a_zero_scale_reproduce_the_frictionless_rollout(nominal_sim: Simulator, demo) -> None:
    stiffness = nominal_sim.constant_stiffness(demo, 300.0)
    reference = nominal_sim.rollout(demo, stiffness)
    for domain in (DomainSpec(joint_friction="none", joint_friction_scale=3.0),
                   DomainSpec(joint_friction="gaz2019", joint_friction_scale=0.0)):
        trial = Simulator(embodiment="panda", bowl=FLAT, domain=domain).rollout(demo, stiffness)
        np.testing.assert_array_equal(trial.x_obs, reference.x_obs)
        np.testing.assert_array_equal(trial.force_obs, reference.force_obs)


def test_gaz2019_friction_makes_the_tool_lag(nominal_sim: Simulator, demo) -> None:
    """The controller does not know the friction: at 300 N/m the tool trails the demo's path further."""
    stiffness = nominal_sim.constant_stiffness(demo, 300.0)
    without = nominal_sim.rollout(demo, stiffness)
    with_friction = Simulator(embodiment="panda", bowl=FLAT, domain=GAZ).rollout(demo, stiffness)
    assert not with_friction.failed
    assert not np.array_equal(with_friction.force_obs, without.force_obs)

    def path_rmse_m(trial) -> float:
        return float(np.sqrt(np.mean(np.sum((trial.x_obs[:, :2] - demo.x_demo[:, :2]) ** 2, axis=1))))

    assert path_rmse_m(with_friction) > 1.3 * path_rmse_m(without)


@pytest.mark.parametrize(("fields", "field"), [
    ({"joint_friction": "coulomb"}, "joint_friction"),
    ({"joint_friction": None}, "joint_friction"),
    ({"joint_friction": "gaz2019", "joint_friction_scale": -0.1}, "joint_friction_scale"),
    ({"joint_friction": "gaz2019", "joint_friction_scale": float("inf")}, "joint_friction_scale"),
    ({"joint_friction": "gaz2019", "joint_friction_scale": float("nan")}, "joint_friction_scale"),
    ({"joint_friction": "gaz2019", "joint_friction_scale": "high"}, "joint_friction_scale"),
])
def test_bad_joint_friction_values_are_refused_in_one_line(fields: dict, field: str) -> None:
    with pytest.raises(DomainSpecError, match=f"domain.{field} = ") as err:
        DomainSpec(**fields)
    assert "\n" not in str(err.value)


def test_the_tool_embodiment_refuses_joint_friction() -> None:
    with pytest.raises(DomainSpecError, match="domain.joint_friction = 'gaz2019'.*embodiment='panda'") as err:
        Simulator(embodiment="tool", bowl=FLAT, domain=DomainSpec.preset("joint_friction"))
    assert "\n" not in str(err.value)
