"""Known answers for the designs of issue 67: the wipe objective's losses from the oracle's stored sums, the
surface frame through the oracle, the anisotropic schedule sets, and T5 (the stiffness-only ridge)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from dcm.control.objectives import TaskObjective
from studies.benchmark import stats
from studies.benchmark import task as bench
from studies.benchmark.certify import load_skill, prior_indices, schedule_kinds
from studies.benchmark.oracle import run_skill, squared_error_sums, task_losses

WIPE = bench.objective("wipe")
FLAT = {"duration_s": 2.0, "approach_s": 0.4, "bowl": {"shape": "flat", "rim_radius_m": 0.14, "hfield_res": 48},
        "params": {"seed": 1, **bench.FAMILY_PARAMS, "blend_s": 0.3}}


def _sums(rng: np.random.Generator) -> dict[str, np.ndarray]:
    total, path = rng.uniform(5.0, 9.0, (3, 2)), rng.uniform(1e-4, 4e-4, (3, 2))
    return {"sq_total": total, "sq_approach": total * 0.2, "path_sq_total": path, "path_sq_approach": path * 0.3,
            "failed": np.array([[False, False], [False, True], [False, False]]), "horizon": 40, "approach_steps": 8}


def test_wipe_objective_is_the_configured_one():
    conf = yaml.safe_load((Path(__file__).parents[3] / "conf" / "objective" / "wipe.yaml").read_text())
    assert WIPE == TaskObjective.from_config(conf)
    assert bench.objective("paper") == TaskObjective()


def test_wipe_with_an_infinite_path_tolerance_is_the_paper_loss():
    data = _sums(np.random.default_rng(0))
    no_path = TaskObjective("wipe", 1.0, math.inf)
    for from_contact in (False, True):
        np.testing.assert_allclose(task_losses(data, from_contact, no_path), task_losses(data, from_contact))
    np.testing.assert_allclose(squared_error_sums(data, no_path)[1], data["sq_total"])
    # the wipe loss from contact, by hand: force and path RMSE over the 32 steps after the approach
    force = np.sqrt(data["sq_total"][0, 0] * 0.8 / 32)
    path = np.sqrt(data["path_sq_total"][0, 0] * 0.7 / 32)
    assert task_losses(data, True, WIPE)[0, 0] == pytest.approx(math.hypot(force, path / 0.005))
    assert np.isinf(task_losses(data, True, WIPE)[1, 1])
    approach, total = squared_error_sums(data, WIPE)
    assert approach[0, 0] / total[0, 0] == pytest.approx(
        (0.2 * data["sq_total"][0, 0] + 0.3 * data["path_sq_total"][0, 0] / 0.005 ** 2)
        / (data["sq_total"][0, 0] + data["path_sq_total"][0, 0] / 0.005 ** 2))
    with pytest.raises(ValueError, match="no path errors"):
        task_losses({k: v for k, v in data.items() if not k.startswith("path")}, True, WIPE)


@pytest.mark.parametrize("frame", ["world", "surface"])
def test_oracle_sums_give_the_objectives_trial_loss(tmp_path, frame):
    """The oracle's stored sums give TaskObjective.trial_task_loss of the same rollout, in either frame."""
    from dcm.control import StiffnessSchedule, equal_time_phases, schedule_from_phases
    from dcm.sim import DemoSpec, DomainSpec, Simulator

    rows = np.array([[[400.0, 400.0, 150.0], [1000.0, 1000.0, 150.0], [400.0, 400.0, 400.0]]])
    path = run_skill(1, tmp_path, rollouts=1, domain="nominal", spec_override=FLAT, schedules=rows,
                     embodiment="tool", frame=frame)
    data = np.load(path)
    assert str(data["frame"]) == frame
    spec = DemoSpec.from_dict({**bench.skill_spec(1), **FLAT})
    sim = Simulator(embodiment="tool", bowl=spec.bowl, domain=DomainSpec.preset("nominal"), control_hz=bench.CONTROL_HZ)
    demo = sim.record_demo(spec)
    K = schedule_from_phases(rows[0], equal_time_phases(demo.horizon, bench.N_PHASES))
    trial = sim.rollout(demo, StiffnessSchedule.for_demo(K, frame, demo.x_demo, demo.force_demo), common_draws=True)
    start = int(data["approach_steps"])
    for objective in (WIPE, bench.objective("paper")):
        expected = objective.trial_task_loss(trial, demo.x_demo, demo.force_demo, start)
        assert task_losses(data, True, objective)[0, 0] == pytest.approx(expected, rel=1e-9)


def test_schedule_sets_hold_the_prior_the_demo_and_their_constants():
    for name in bench.SCHEDULE_SETS:
        sched = bench.schedule_set(name)
        diag = sched.diagonal()
        assert len({tuple(r.ravel()) for r in diag}) == len(diag)  # no schedule twice
        constant, isotropic = schedule_kinds(diag)
        iso_levels = {float(r[0, 0]) for r, c, i in zip(diag, constant, isotropic) if c and i}
        assert set(bench.PRIOR_LEVELS_NPM) | {bench.DEMO_STIFFNESS_NPM} <= iso_levels
        skill = {"constant": constant, "isotropic": isotropic, "kinds": sched.kinds, "diagonal": diag}
        assert sorted(float(diag[i, 0, 0]) for i in prior_indices(skill)) == list(bench.PRIOR_LEVELS_NPM)
    surface = bench.schedule_set("surface_tn")
    assert surface.frame == "surface" and len(surface.phase_Npm) <= 100
    diag = surface.diagonal()
    assert np.all(diag[:, :, 0] == diag[:, :, 1])  # one tangential stiffness
    constant, isotropic = schedule_kinds(diag)
    # the anisotropic constants (one (K_t, K_n) in every phase) count as constant, so T2 measures time variation
    assert (constant & ~isotropic).sum() == len(bench.TANGENT_LEVELS_NPM) * len(bench.NORMAL_LEVELS_NPM) - 2
    world = bench.schedule_set("world_axis")
    assert world.frame == "world"
    assert {tuple(r) for r in bench.oracle_schedules().phase_Npm} <= {tuple(r[:, 0]) for r in world.diagonal()}
    assert bench.schedule_set("isotropic_grid").labels() == bench.oracle_schedules().labels()
    assert bench.schedule_label(diag[len(diag) // 2], "surface").count("/") == bench.N_PHASES - 1
    assert bench.schedule_label(np.array([[400.0, 400.0, 150.0]] * 3), "surface") == "t400n150/t400n150/t400n150"


def test_constant_only_sets_gain_nothing_and_anisotropic_constants_are_constant():
    diag = np.array([np.full((3, 3), 400.0), np.tile([2500.0, 2500.0, 150.0], (3, 1)),
                     np.tile([1000.0, 1000.0, 400.0], (3, 1))])
    constant, isotropic = schedule_kinds(diag)
    assert constant.all() and isotropic.tolist() == [True, False, False]
    out = stats.variable_gain(np.array([1.2, 0.9, 1.0]), np.array([0.7, 3.5, 1.5]), constant)
    assert out["gain"] == 0.0 and out["max_gain"] == 0.0


def test_designs_name_known_entries_and_the_friction_domain_adds_only_friction():
    for design in bench.DESIGNS.values():
        bench.schedule_set(design["schedules"]), bench.objective(design["objective"]), bench.domain(design["domain"])
        assert design["revision"] in bench.REVISIONS
    assert bench.DESIGNS["paper_isotropic"] == {"objective": "paper", "schedules": "isotropic_grid",
                                               "domain": bench.DOMAIN, "revision": bench.REVISION}
    plain, gaz = bench.domain("replaced_bowl").to_dict(), bench.domain("replaced_bowl_gaz2019").to_dict()
    changed = {k for k in set(plain) | set(gaz) if plain.get(k) != gaz.get(k)}
    assert changed == {"name", "joint_friction"} and gaz["joint_friction"] == "gaz2019"


def _skills(rng: np.random.Generator, n: int, shuffle: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """Skills whose log L_task is one function of the per-phase stiffness plus a skill offset and a little noise."""
    diag = bench.schedule_set("surface_tn").diagonal()
    kt, kn = diag[:, :, 0] / 1000.0, diag[:, :, 2] / 1000.0
    base = (0.5 / kt).sum(axis=1) + (0.8 * kn).sum(axis=1) + 0.4 * kn[:, 1]
    out = []
    for k in range(n):
        log_task = base + k + 0.01 * rng.standard_normal(len(diag))
        out.append((diag, np.exp(rng.permutation(log_task) if shuffle else log_task)))
    return out


def test_ridge_ranks_skills_that_share_the_stiffness_relation():
    rng = np.random.default_rng(1)
    skills = _skills(rng, 4)
    own = stats.ridge_ranking(skills[:3], skills[:1])  # evaluated on a skill it was fitted on
    assert own["median"] > 0.95
    assert stats.ridge_ranking(skills)["median"] > 0.95  # leave-one-skill-out: a new skill of the same relation
    assert stats.ridge_ranking(skills[:3], skills[3:])["mode"] == "fitted on the train skills"


def test_ridge_on_shuffled_labels_ranks_nothing():
    rng = np.random.default_rng(2)
    out = stats.ridge_ranking(_skills(rng, 4, shuffle=True), _skills(rng, 6, shuffle=True))
    assert abs(out["median"]) < 0.25 and len(out["spearman"]) == 6


def test_load_skill_reads_an_anisotropic_set(tmp_path):
    rows = np.array([np.full((3, 3), 800.0), np.tile([1000.0, 1000.0, 150.0], (3, 1)),
                     np.array([[400.0, 400.0, 150.0], [2500.0, 2500.0, 150.0], [400.0, 400.0, 150.0]])])
    run_skill(1, tmp_path, rollouts=2, domain="nominal", spec_override=FLAT, schedules=rows, embodiment="tool",
              frame="surface", kinds=["demo", "design", "design"])
    sk = load_skill(tmp_path, 1, True, WIPE)
    assert sk["frame"] == "surface" and sk["constant"].tolist() == [True, True, False]
    assert sk["isotropic"].tolist() == [True, False, False]
    assert sk["reference"][0] == pytest.approx(1.5 * sk["task"][0])
    assert 0.0 <= sk["approach_share"] <= 1.0
