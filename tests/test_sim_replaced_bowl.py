"""The benchmark's disturbances (3-D placement and tilt of the bowl, per-trial sensor bias) and the paced curve:
off by default, known answers where the physics gives one."""

from __future__ import annotations

import numpy as np
import pytest

from dcm.sim import BowlSpec, DemoSpec, DomainSpec, DomainSpecError, Simulator

FLAT = BowlSpec(shape="flat", rim_radius_m=0.12, hfield_res=48)
CAP = BowlSpec(rim_radius_m=0.12, depth_m=0.03, hfield_res=64)


def _line(bowl: BowlSpec) -> DemoSpec:
    return DemoSpec(family="line", params={"start_xy_m": [-0.03, 0.0], "end_xy_m": [0.03, 0.0]}, duration_s=2.0,
                    approach_s=0.4, bowl=bowl)


def test_new_spreads_default_off_and_fingerprint_as_before():
    """A domain that does not set them serialises, and so fingerprints, exactly as before they existed."""
    keys = set(DomainSpec().to_dict())
    assert not keys & {"bowl_shift_xy_std_m", "bowl_tilt_std_deg", "ft_bias_std"}
    assert set(DomainSpec.preset("replaced_bowl").to_dict()) >= {"bowl_shift_xy_std_m", "bowl_tilt_std_deg"}
    with pytest.raises(DomainSpecError, match="bowl_tilt_std_deg"):
        DomainSpec(bowl_tilt_std_deg=9.0)
    with pytest.raises(DomainSpecError, match="ft_bias_std"):
        DomainSpec(ft_bias_std=-0.1)


def test_horizontal_shift_of_a_flat_plate_changes_nothing():
    """Moving a flat plate sideways leaves the surface where it was: the normal force is the nominal one (up to
    the heightfield's facets under the tip moving; a 1.5 mm height offset moves it by ~0.8 N here)."""
    nominal = Simulator(embodiment="tool", bowl=FLAT)
    shifted = Simulator(embodiment="tool", bowl=FLAT, domain=DomainSpec(bowl_shift_xy_std_m=0.01))
    demo = nominal.record_demo(_line(FLAT))
    stiffness = nominal.constant_stiffness(demo, 600.0)
    plain, moved = nominal.rollout(demo, stiffness), shifted.rollout(demo, stiffness)
    assert any(moved.bowl_shift_xy_m)
    assert np.abs(moved.force_obs[:, 2] - plain.force_obs[:, 2]).mean() < 0.05


def test_shift_on_a_curved_bowl_and_tilt_move_the_normal_force():
    """On a cap the same shift changes the surface height under the path (force ~ K x height change), and a tilt
    does so on a flat plate away from its centre; the model is restored after every rollout."""
    for bowl, domain in ((CAP, DomainSpec(bowl_shift_xy_std_m=0.006)), (FLAT, DomainSpec(bowl_tilt_std_deg=3.0))):
        nominal = Simulator(embodiment="tool", bowl=bowl)
        moved = Simulator(embodiment="tool", bowl=bowl, domain=domain)
        spec = _line(bowl)
        spec.params = {"start_xy_m": [0.06, 0.0], "end_xy_m": [0.07, 0.0]}
        demo = nominal.record_demo(spec)
        stiffness = nominal.constant_stiffness(demo, 1500.0)
        gaps = [np.abs(moved.rollout(demo, stiffness, repeat=r).force_obs[-10:, 2]
                       - demo.force_demo[-10:, 2]).mean() for r in range(3)]
        assert max(gaps) > 0.3  # N: millimetres at 1500 N/m
        again = moved.rollout(demo, stiffness)
        np.testing.assert_array_equal(again.force_obs, moved.rollout(demo, stiffness).force_obs)
        geom = moved.embodiment.model.geom("bowl")
        assert np.allclose(geom.pos, 0.0) and np.allclose(geom.quat, [1, 0, 0, 0])


def test_per_trial_bias_is_constant_within_a_rollout():
    sim = Simulator(embodiment="tool", bowl=FLAT, domain=DomainSpec(ft_bias_std=[0.5, 0.5, 0.5, 0, 0, 0]))
    nominal = Simulator(embodiment="tool", bowl=FLAT)
    demo = nominal.record_demo(_line(FLAT))
    stiffness = sim.constant_stiffness(demo, 600.0)
    biased, plain = sim.rollout(demo, stiffness), nominal.rollout(demo, stiffness)
    np.testing.assert_allclose(biased.force_obs - plain.force_obs,
                               np.tile(biased.ft_bias_draw, (demo.horizon, 1)), atol=1e-9)
    assert biased.ft_bias_draw != sim.rollout(demo, stiffness, repeat=1).ft_bias_draw


def test_paced_curve_runs_each_segment_at_its_drawn_speed():
    """A segment's speed is its mean over a loop of the curve (the tool slows in bends): seed 2's segments span
    about a loop each, so their measured mean speeds are the drawn ones within 10 %."""
    spec = DemoSpec(family="paced_curve", params={"seed": 2, "blend_s": 0.4}, duration_s=12.0, bowl=CAP)
    speeds = spec.curve_draws()["speed_mps"]
    assert len(speeds) == 3 and np.all((speeds >= 0.02) & (speeds <= 0.20))
    path = spec.path(20.0)
    measured = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1) * 20.0
    for k, (low, high) in enumerate(((30, 75), (90, 155), (170, 225))):  # steps well inside each 4 s third
        assert measured[low:high].mean() == pytest.approx(speeds[k], rel=0.1)
    assert measured[:15].max() < 1e-3 and measured[-1] < 0.2 * speeds[-1]  # at rest during the approach, stopping
    same_shape = DemoSpec(family="curve", params={"seed": 2}, bowl=CAP).curve_draws()["coeffs"]
    np.testing.assert_array_equal(spec.curve_draws()["coeffs"], same_shape)
    assert DemoSpec.from_dict(spec.to_dict()) == spec


def test_paced_curve_fast_segment_is_off_by_default_and_one_drawn_segment_when_set():
    """Unset, the draws are those of a spec without the option; set, exactly one segment per skill is in the fast
    range, the others in the slow one, and which segment it is differs between seeds. A bad range is refused."""
    plain = DemoSpec(family="paced_curve", params={"seed": 5}, bowl=CAP)
    off = DemoSpec(family="paced_curve", params={"seed": 5, "fast_speed_mps": None}, bowl=CAP)
    np.testing.assert_array_equal(plain.curve_draws()["speed_mps"], off.curve_draws()["speed_mps"])
    assert "fast_speed_mps" not in plain.to_dict()["params"]
    where = set()
    for seed in range(12):
        params = {"seed": seed, "speed_mps": [0.02, 0.05], "fast_speed_mps": [0.10, 0.20]}
        speeds = DemoSpec(family="paced_curve", params=params, bowl=CAP).curve_draws()["speed_mps"]
        fast = speeds >= 0.10
        slow = speeds[~fast]
        assert fast.sum() == 1 and speeds[fast][0] <= 0.20 and np.all((slow >= 0.02) & (slow <= 0.05))
        where.add(int(np.argmax(fast)))
    assert where == {0, 1, 2}
    with pytest.raises(ValueError, match="fast_speed_mps"):
        DemoSpec(family="paced_curve", params={"seed": 5, "fast_speed_mps": [0.2, 0.1]}, bowl=CAP)
