"""Impedance math: attractor, damping, schedules, limits and filtering."""

import numpy as np
import pytest

from dcm.control import (
    StiffnessFilter,
    StiffnessLimits,
    StiffnessOutOfRange,
    attractor_from_demo,
    changepoint_phases,
    compliance_loss,
    damping_from_stiffness,
    equal_time_phases,
    filter_schedule,
    schedule_from_phases,
    task_loss,
)


def test_damping_is_unit_mass_critical():
    np.testing.assert_allclose(damping_from_stiffness(np.array([400.0, 100.0])), [40.0, 20.0])


def test_static_attractor_sits_force_over_stiffness_below_the_demo():
    horizon = 20
    x_demo = np.zeros((horizon, 6))
    force = np.zeros((horizon, 6))
    force[:, 2] = 8.0  # the surface pushes up on the tool
    stiffness = np.full((horizon, 6), 400.0)
    x_attr = attractor_from_demo(x_demo, force, stiffness, dt=0.05)
    np.testing.assert_allclose(x_attr[:, 2], -8.0 / 400.0)
    np.testing.assert_allclose(x_attr[:, [0, 1, 3, 4, 5]], 0.0)


def test_attractor_balances_the_impedance_law_on_a_moving_demo():
    dt, horizon = 0.05, 100
    t = np.arange(horizon) * dt
    x_demo = np.zeros((horizon, 6))
    x_demo[:, 0] = 0.05 * np.sin(t)
    force = np.zeros((horizon, 6))
    force[:, 2] = 5.0 + np.cos(t)
    stiffness = np.full((horizon, 6), 900.0)
    inertia = 1.5
    x_attr = attractor_from_demo(x_demo, force, stiffness, dt, inertia=inertia)
    velocity = np.gradient(x_demo, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    commanded = stiffness * (x_attr - x_demo) - damping_from_stiffness(stiffness) * velocity
    np.testing.assert_allclose(commanded, inertia * acceleration - force, atol=1e-9)


def test_attractor_rejects_bad_shapes_and_nonpositive_stiffness():
    with pytest.raises(ValueError, match="shape"):
        attractor_from_demo(np.zeros((5, 3)), np.zeros((5, 3)), np.ones((5, 3)), 0.05)
    stiffness = np.ones((5, 6))
    stiffness[2, 1] = 0.0
    with pytest.raises(StiffnessOutOfRange, match=r"K\[2, y\]"):
        attractor_from_demo(np.zeros((5, 6)), np.zeros((5, 6)), stiffness, 0.05)


def test_limits_name_the_offending_value():
    stiffness = np.full((10, 6), 20.0)
    stiffness[:, :3] = 500.0
    StiffnessLimits().check(stiffness)
    stiffness[7, 2] = 1e5
    with pytest.raises(StiffnessOutOfRange, match=r"t=7, z\] = 100000 N/m"):
        StiffnessLimits().check(stiffness)
    stiffness[7, 2] = np.nan
    with pytest.raises(StiffnessOutOfRange, match="nan"):
        StiffnessLimits().check(stiffness)


def test_schedule_holds_one_stiffness_per_phase():
    bounds = equal_time_phases(10, 3)
    assert bounds.tolist() == [0, 3, 7, 10]
    schedule = schedule_from_phases(np.array([[100, 200, 300], [400, 500, 600], [700, 800, 900]]), bounds, 25.0)
    assert schedule.shape == (10, 6)
    np.testing.assert_array_equal(schedule[3:7, :3], [[400, 500, 600]] * 4)
    np.testing.assert_array_equal(schedule[:, 3:], 25.0)
    with pytest.raises(ValueError, match="boundaries"):
        schedule_from_phases(np.ones((2, 3)), np.array([0, 5, 5]))
    with pytest.raises(ValueError, match="n_phases"):
        equal_time_phases(2, 3)


def test_changepoints_find_steps_in_the_force():
    force = np.concatenate([np.full(40, 2.0), np.full(30, 9.0), np.full(50, 4.0)])
    force = force + np.random.default_rng(0).normal(0, 0.1, force.shape)
    assert changepoint_phases(force[:, None], 3).tolist() == [0, 40, 70, 120]


def test_filter_smooths_a_stiffness_drop_with_the_given_time_constant():
    dt, tau = 0.05, 0.2
    schedule = np.full((40, 6), 1500.0)
    schedule[10:] = 200.0
    applied = filter_schedule(schedule, dt, tau)
    np.testing.assert_allclose(applied[:10], 1500.0)
    np.testing.assert_allclose(applied[10], 1500.0 - 1300.0 * (1 - np.exp(-dt / tau)))
    # after 4 time constants the drop is 98 % complete
    assert abs(applied[10 + int(4 * tau / dt), 0] - 200.0) < 0.02 * 1300
    limited = StiffnessFilter(tau_s=0.0, dt=dt, max_rate=1000.0)
    limited.reset(np.full(6, 1500.0))
    assert limited.step(np.full(6, 200.0))[0] == pytest.approx(1450.0)


def test_objectives_have_documented_units():
    force_demo = np.zeros((2, 10, 6))
    force_obs = np.zeros((2, 10, 6))
    force_obs[1, :, :3] = 2.0
    force_obs[:, :, 3:] = 100.0  # torques do not count
    np.testing.assert_allclose(task_loss(force_obs, force_demo), [0.0, 2.0])
    stiffness = np.zeros((10, 6))
    stiffness[:, :3] = [300.0, 400.0, 0.0]
    assert compliance_loss(stiffness) == pytest.approx(0.5)


def test_the_scored_window_starts_after_the_approach():
    from dcm.control.objectives import task_window_start

    assert task_window_start(0.0, 20.0, 240) == 0 and task_window_start(1.0, 20.0, 240) == 20
    assert task_window_start(0.52, 20.0, 240) == 10  # rounded to the control grid
    for bad in (-0.1, 12.0, float("nan")):
        with pytest.raises(ValueError, match=f"task_from_s = {bad} s must be >= 0 and before the end of the 12 s"):
            task_window_start(bad, 20.0, 240)
    # a touch-down a step late: 8 N for one step holds most of the error of a trajectory tracked to 0.1 N
    force_demo, force_obs = np.zeros((1, 240, 6)), np.full((1, 240, 6), 0.1)
    force_demo[0, 10:, 2] = force_obs[0, 11:, 2] = 8.0
    start = task_window_start(1.0, 20.0, 240)
    assert task_loss(force_obs, force_demo)[0] > 3 * task_loss(force_obs[:, start:], force_demo[:, start:])[0]
    # the window as task_loss's own argument: the same as slicing the time axis, for one trajectory or a batch
    np.testing.assert_allclose(task_loss(force_obs, force_demo, start), [0.1 * np.sqrt(2 / 3)])
    np.testing.assert_allclose(task_loss(force_obs[0], force_demo[0], start),
                               task_loss(force_obs[0, start:], force_demo[0, start:]))
    assert task_loss(force_obs, force_demo, 0)[0] == task_loss(force_obs, force_demo)[0]


def test_a_batch_of_schedules_gets_the_attractors_of_one_schedule_at_a_time():
    """Robot-free tuning builds a whole batch's attractors at once; each must be the one of its own call."""
    from dcm.control.impedance import attractor_from_demo, filter_schedule

    rng = np.random.default_rng(0)
    horizon = 40
    x_demo = np.cumsum(rng.normal(0.0, 1e-3, (horizon, 6)), axis=0)
    force_demo = rng.normal(0.0, 3.0, (horizon, 6))
    schedules = np.repeat(rng.uniform(100.0, 1500.0, (5, 4, 6)), horizon // 4, axis=1)
    mass = np.array([3.0, 3.0, 4.0, 0.1, 0.1, 0.1])
    applied = filter_schedule(schedules, 0.05)
    batch = attractor_from_demo(x_demo, force_demo, applied, 0.05, inertia=mass, mass=mass)
    for k, schedule in enumerate(schedules):
        one = filter_schedule(schedule, 0.05)
        np.testing.assert_array_equal(applied[k], one)
        np.testing.assert_array_equal(batch[k], attractor_from_demo(x_demo, force_demo, one, 0.05, inertia=mass,
                                                                    mass=mass))
